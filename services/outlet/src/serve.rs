//! `outlet serve`: the sidecar's services as processes on iceoryx2 shared memory.
//! Each waits on a WaitSet for its inputs' notifications (no polling) and keeps
//! serving whatever arrives: a bad input is counted, logged and dropped.

use anyhow::{Context, Result};
use clap::{Args, Subcommand};
use iceoryx2::prelude::*;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_normal::{PlaneParams, fit_wall_plane};
use outlet_protocol::HoleKind;
use outlet_protocol::wire::{
    CloudHeader, DetectionMsg, FrameHeader, HoleMsg, MAX_HOLES, PixelFormat, SCHEMA_VERSION, WallPlaneMsg, service,
};

#[derive(Args, Debug)]
pub struct ServeArgs {
    #[command(subcommand)]
    pub service: Service,
}

#[derive(Subcommand, Debug)]
pub enum Service {
    /// The normal estimator: stereo clouds in, wall planes out.
    Normal,
    /// The detector: camera frames in, detections out.
    Detector {
        /// Template: `2x1`, `2x2` or a file written by `outlet train`.
        #[arg(long, default_value = "2x1")]
        template: String,
    },
    /// The pose service: detections and wall planes in, hole poses out.
    Pose {
        /// The template the detector uses (its hole geometry).
        #[arg(long, default_value = "2x1")]
        template: String,
        /// A plane older or newer than this is not joined with a detection (ms).
        #[arg(long, default_value_t = 200.0)]
        max_plane_age_ms: f64,
    },
}

pub fn serve(args: ServeArgs) -> Result<()> {
    match args.service {
        Service::Normal => serve_normal(),
        Service::Detector { template } => serve_detector(&template),
        Service::Pose { template, max_plane_age_ms } => serve_pose(&template, max_plane_age_ms),
    }
}

/// Counters every service keeps.
#[derive(Debug, Default)]
struct Counters {
    inputs: u64,
    outputs: u64,
    rejected: u64,
}

fn name(s: &str) -> Result<ServiceName> {
    ServiceName::new(s).map_err(|e| anyhow::anyhow!("service name {s:?}: {e:?}"))
}

/// An output: a publisher and the notifier that wakes its readers.
struct Output<T: std::fmt::Debug + ZeroCopySend + 'static> {
    publisher: iceoryx2::port::publisher::Publisher<ipc::Service, T, ()>,
    notifier: iceoryx2::port::notifier::Notifier<ipc::Service>,
}

impl<T: std::fmt::Debug + ZeroCopySend + 'static> Output<T> {
    fn open(node: &Node<ipc::Service>, service_name: &str) -> Result<Self> {
        let service = node
            .service_builder(&name(service_name)?)
            .publish_subscribe::<T>()
            .open_or_create()
            .map_err(|e| anyhow::anyhow!("{service_name}: {e:?}"))?;
        let events = node
            .service_builder(&name(service_name)?)
            .event()
            .open_or_create()
            .map_err(|e| anyhow::anyhow!("{service_name} events: {e:?}"))?;
        Ok(Self {
            publisher: service.publisher_builder().create().map_err(|e| anyhow::anyhow!("publisher: {e:?}"))?,
            notifier: events.notifier_builder().create().map_err(|e| anyhow::anyhow!("notifier: {e:?}"))?,
        })
    }

    /// Publishes and notifies; a failure is logged, the service goes on.
    fn send(&self, msg: T, counters: &mut Counters) {
        let sent = match self.publisher.loan_uninit() {
            Ok(s) => s.write_payload(msg).send().map_err(|e| format!("{e:?}")),
            Err(e) => Err(format!("{e:?}")),
        };
        match sent {
            Ok(_) => {
                counters.outputs += 1;
                if let Err(e) = self.notifier.notify() {
                    tracing::warn!("notifying readers: {e:?}");
                }
            }
            Err(e) => tracing::warn!("publishing: {e}"),
        }
    }
}

/// The listener of a service's notifications.
fn listener(node: &Node<ipc::Service>, service_name: &str) -> Result<iceoryx2::port::listener::Listener<ipc::Service>> {
    node.service_builder(&name(service_name)?)
        .event()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("{service_name} events: {e:?}"))?
        .listener_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("{service_name} listener: {e:?}"))
}

/// Clouds in ([`service::CLOUDS`]), wall planes out ([`service::PLANES`]).
fn serve_normal() -> Result<()> {
    let node = NodeBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("iceoryx2 node: {e:?}"))?;
    let clouds = node
        .service_builder(&name(service::CLOUDS)?)
        .publish_subscribe::<[f32]>()
        .user_header::<CloudHeader>()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("cloud service: {e:?}"))?;
    let subscriber = clouds.subscriber_builder().create().map_err(|e| anyhow::anyhow!("subscriber: {e:?}"))?;
    let listener = listener(&node, service::CLOUDS)?;
    let output = Output::<WallPlaneMsg>::open(&node, service::PLANES)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("waitset: {e:?}"))?;
    let guard = waitset.attach_notification(&listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let params = PlaneParams::default();
    let mut counters = Counters::default();
    tracing::info!("normal estimator ready: {} -> {}", service::CLOUDS, service::PLANES);
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        if id.has_event_from(&guard) {
            if let Err(e) = listener.try_wait(|_| {}) {
                tracing::warn!("clearing cloud notifications: {e:?}");
            }
            loop {
                let sample = match subscriber.receive() {
                    Ok(Some(s)) => s,
                    Ok(None) => break,
                    Err(e) => {
                        tracing::warn!("receiving a cloud: {e:?}");
                        break;
                    }
                };
                counters.inputs += 1;
                let header = *sample.user_header();
                let fitted = header.validate(sample.payload().len()).map_err(|e| e.to_string()).and_then(|()| {
                    let n = header.points as usize;
                    let points: Vec<[f32; 3]> =
                        sample.payload()[..3 * n].chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
                    fit_wall_plane(&points, &params).map_err(|e| e.to_string())
                });
                match fitted {
                    Ok(plane) => {
                        let c = plane.covariance;
                        let msg = WallPlaneMsg {
                            schema_version: SCHEMA_VERSION,
                            inliers: plane.inliers.min(u32::MAX as usize) as u32,
                            frame_id: header.frame_id,
                            capture_time_ns: header.capture_time_ns,
                            normal: [plane.normal.x, plane.normal.y, plane.normal.z],
                            distance_m: plane.distance_m,
                            tangent: plane.tangent.map(|t| [t.x, t.y, t.z]),
                            covariance: [
                                c[(0, 0)],
                                c[(0, 1)],
                                c[(0, 2)],
                                c[(1, 0)],
                                c[(1, 1)],
                                c[(1, 2)],
                                c[(2, 0)],
                                c[(2, 1)],
                                c[(2, 2)],
                            ],
                        };
                        output.send(msg, &mut counters);
                    }
                    Err(reason) => {
                        counters.rejected += 1;
                        tracing::warn!(frame = header.frame_id, "cloud rejected: {reason}");
                    }
                }
            }
        }
        CallbackProgression::Continue
    };
    waitset.wait_and_process(on_event).map_err(|e| anyhow::anyhow!("waiting: {e:?}")).context("normal estimator")?;
    tracing::info!(?counters, "normal estimator stops");
    Ok(())
}

/// The grey image the detector reads, from a frame's pixels (any stride).
fn rgb_of(header: &FrameHeader, format: PixelFormat, pixels: &[u8]) -> Option<image::RgbImage> {
    let (w, h, stride) = (header.width as usize, header.height as usize, header.stride as usize);
    let mut rgb = Vec::with_capacity(w * h * 3);
    for row in pixels.chunks(stride).take(h) {
        match format {
            PixelFormat::Mono8 => row[..w].iter().for_each(|&v| rgb.extend_from_slice(&[v, v, v])),
            PixelFormat::Rgb8 => rgb.extend_from_slice(&row[..3 * w]),
            PixelFormat::Bgr8 => row[..3 * w].chunks_exact(3).for_each(|p| rgb.extend_from_slice(&[p[2], p[1], p[0]])),
        }
    }
    image::RgbImage::from_raw(header.width, header.height, rgb)
}

/// Frames in ([`service::FRAMES`]), detections out ([`service::DETECTIONS`]);
/// a frame without the outlet gives a detection with no holes.
fn serve_detector(template: &str) -> Result<()> {
    let detector = Detector::new(outlet::templates::load(template)?, DetectorParams::default());
    let node = NodeBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("iceoryx2 node: {e:?}"))?;
    let frames = node
        .service_builder(&name(service::FRAMES)?)
        .publish_subscribe::<[u8]>()
        .user_header::<FrameHeader>()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("frame service: {e:?}"))?;
    let subscriber = frames.subscriber_builder().create().map_err(|e| anyhow::anyhow!("subscriber: {e:?}"))?;
    let listener = listener(&node, service::FRAMES)?;
    let output = Output::<DetectionMsg>::open(&node, service::DETECTIONS)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("waitset: {e:?}"))?;
    let guard = waitset.attach_notification(&listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let mut counters = Counters::default();
    tracing::info!("detector ready ({template}): {} -> {}", service::FRAMES, service::DETECTIONS);
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        if id.has_event_from(&guard) {
            if let Err(e) = listener.try_wait(|_| {}) {
                tracing::warn!("clearing frame notifications: {e:?}");
            }
            loop {
                let sample = match subscriber.receive() {
                    Ok(Some(s)) => s,
                    Ok(None) => break,
                    Err(e) => {
                        tracing::warn!("receiving a frame: {e:?}");
                        break;
                    }
                };
                counters.inputs += 1;
                let header = *sample.user_header();
                let checked =
                    header.validate(sample.payload().len()).map_err(|e| e.to_string()).and_then(|(format, camera)| {
                        rgb_of(&header, format, sample.payload())
                            .map(|image| (image, camera))
                            .ok_or_else(|| format!("frame {}: pixels do not fill the image", header.frame_id))
                    });
                let (image, camera) = match checked {
                    Ok(v) => v,
                    Err(reason) => {
                        counters.rejected += 1;
                        tracing::warn!(frame = header.frame_id, "frame rejected: {reason}");
                        continue;
                    }
                };
                let t = std::time::Instant::now();
                let report = detector.detect(&image, Some(&camera));
                let mut msg = DetectionMsg {
                    schema_version: SCHEMA_VERSION,
                    hole_count: 0,
                    frame_id: header.frame_id,
                    capture_time_ns: header.capture_time_ns,
                    score: 0,
                    reserved: 0,
                    detect_ms: t.elapsed().as_secs_f64() * 1e3,
                    width: camera.width,
                    height: camera.height,
                    intrinsics: [camera.fx, camera.fy, camera.cx, camera.cy],
                    distortion: camera.distortion,
                    holes: [HoleMsg::default(); MAX_HOLES],
                };
                if let Some(d) = &report.detection {
                    msg.score = d.score as u32;
                    msg.hole_count = d.holes.len().min(MAX_HOLES) as u32;
                    for (slot, h) in msg.holes.iter_mut().zip(&d.holes) {
                        *slot = HoleMsg {
                            kind: match h.kind {
                                HoleKind::Power => 1,
                                HoleKind::Ground => 2,
                            },
                            refined: h.refined as u32,
                            pixel: [h.pixel.x, h.pixel.y],
                        };
                    }
                }
                output.send(msg, &mut counters);
            }
        }
        CallbackProgression::Continue
    };
    waitset.wait_and_process(on_event).map_err(|e| anyhow::anyhow!("waiting: {e:?}")).context("detector")?;
    tracing::info!(?counters, "detector stops");
    Ok(())
}

/// Detections ([`service::DETECTIONS`]) joined with the wall plane closest in
/// time ([`service::PLANES`]) into hole poses ([`service::HOLE_POSES`]): the
/// `plane` mode with a plane near enough in time, else `mono`.
fn serve_pose(template: &str, max_plane_age_ms: f64) -> Result<()> {
    use nalgebra::{Matrix3, Point2, Unit, Vector3};
    use outlet_pose::{Mode, Observations, PlaneMeasurement, solve_mono, solve_plane};
    use outlet_protocol::wire::HolePosesMsg;
    let geometry = outlet::templates::load(template)?.geometry;
    let model: Vec<Point2<f64>> = geometry.holes.iter().map(|h| h.position()).collect();
    let node = NodeBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("iceoryx2 node: {e:?}"))?;
    let detections = node
        .service_builder(&name(service::DETECTIONS)?)
        .publish_subscribe::<DetectionMsg>()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("detection service: {e:?}"))?;
    let planes = node
        .service_builder(&name(service::PLANES)?)
        .publish_subscribe::<WallPlaneMsg>()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("plane service: {e:?}"))?;
    let detection_sub = detections.subscriber_builder().create().map_err(|e| anyhow::anyhow!("subscriber: {e:?}"))?;
    let plane_sub = planes.subscriber_builder().create().map_err(|e| anyhow::anyhow!("subscriber: {e:?}"))?;
    let detection_listener = listener(&node, service::DETECTIONS)?;
    let plane_listener = listener(&node, service::PLANES)?;
    let output = Output::<HolePosesMsg>::open(&node, service::HOLE_POSES)?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("waitset: {e:?}"))?;
    let detection_guard =
        waitset.attach_notification(&detection_listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let plane_guard = waitset.attach_notification(&plane_listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    // The last few planes, to join each detection with the one closest in time.
    let mut recent: std::collections::VecDeque<WallPlaneMsg> = std::collections::VecDeque::with_capacity(16);
    let mut counters = Counters::default();
    tracing::info!("pose service ready ({template})");
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        if id.has_event_from(&plane_guard) {
            let _ = plane_listener.try_wait(|_| {});
            while let Ok(Some(p)) = plane_sub.receive() {
                let p = *p.payload();
                if p.schema_version == SCHEMA_VERSION && p.normal.iter().chain([&p.distance_m]).all(|v| v.is_finite()) {
                    if recent.len() == 16 {
                        recent.pop_front();
                    }
                    recent.push_back(p);
                } else {
                    counters.rejected += 1;
                    tracing::warn!(frame = p.frame_id, "plane rejected: wrong schema or not finite");
                }
            }
        }
        if id.has_event_from(&detection_guard) {
            let _ = detection_listener.try_wait(|_| {});
            while let Ok(Some(d)) = detection_sub.receive() {
                let d = *d.payload();
                counters.inputs += 1;
                if d.schema_version != SCHEMA_VERSION || d.hole_count as usize != model.len() {
                    continue; // no outlet in that frame (or another template's)
                }
                let camera = match d.camera() {
                    Ok(c) => c,
                    Err(e) => {
                        counters.rejected += 1;
                        tracing::warn!("detection rejected: {e}");
                        continue;
                    }
                };
                let pixels: Vec<Point2<f64>> =
                    d.holes[..model.len()].iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect();
                let obs = Observations { model_mm: &model, pixels: &pixels, camera: &camera, pixel_sigma: 0.25 };
                let plane = recent
                    .iter()
                    .min_by_key(|p| p.capture_time_ns.abs_diff(d.capture_time_ns))
                    .filter(|p| (p.capture_time_ns.abs_diff(d.capture_time_ns) as f64) / 1e6 <= max_plane_age_ms);
                let solved = match plane {
                    Some(p) => {
                        let measurement = PlaneMeasurement {
                            normal: Unit::new_normalize(Vector3::from(p.normal)),
                            distance_m: p.distance_m,
                            covariance: Matrix3::from_row_slice(&p.covariance),
                            tangent: p.tangent.map(Vector3::from),
                            face_offset_m: geometry.face_offset_mm / 1000.0,
                        };
                        solve_plane(&obs, &measurement)
                    }
                    None => solve_mono(&obs),
                };
                let pose = match solved {
                    Ok(p) => p,
                    Err(e) => {
                        counters.rejected += 1;
                        tracing::warn!(frame = d.frame_id, "no pose: {e}");
                        continue;
                    }
                };
                let r = pose.pose.rotation.to_rotation_matrix();
                let t = pose.pose.translation.vector;
                let mut msg = HolePosesMsg {
                    schema_version: SCHEMA_VERSION,
                    hole_count: pose.holes_cam_m.len().min(MAX_HOLES) as u32,
                    frame_id: d.frame_id,
                    capture_time_ns: d.capture_time_ns,
                    published_ns: std::time::SystemTime::now()
                        .duration_since(std::time::UNIX_EPOCH)
                        .map_or(0, |x| x.as_nanos() as u64),
                    mode: match pose.mode {
                        Mode::Mono => 1,
                        Mode::Normal => 2,
                        Mode::Plane => 3,
                    },
                    reserved: 0,
                    rotation: std::array::from_fn(|k| r[(k / 3, k % 3)]),
                    translation_m: [t.x, t.y, t.z],
                    positions_m: [[0.0; 3]; MAX_HOLES],
                    covariances_m2: [[0.0; 9]; MAX_HOLES],
                };
                for (k, (h, c)) in pose.holes_cam_m.iter().zip(&pose.covariances).take(MAX_HOLES).enumerate() {
                    msg.positions_m[k] = [h.x, h.y, h.z];
                    msg.covariances_m2[k] = std::array::from_fn(|j| c[(j / 3, j % 3)]);
                }
                output.send(msg, &mut counters);
            }
        }
        CallbackProgression::Continue
    };
    waitset.wait_and_process(on_event).map_err(|e| anyhow::anyhow!("waiting: {e:?}")).context("pose service")?;
    tracing::info!(?counters, "pose service stops");
    Ok(())
}
