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
}

pub fn serve(args: ServeArgs) -> Result<()> {
    match args.service {
        Service::Normal => serve_normal(),
        Service::Detector { template } => serve_detector(&template),
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

/// Clouds in ([`service::CLOUDS`]), wall planes out ([`service::PLANES`]).
fn serve_normal() -> Result<()> {
    let node = NodeBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("iceoryx2 node: {e:?}"))?;
    let clouds = node
        .service_builder(&name(service::CLOUDS)?)
        .publish_subscribe::<[f32]>()
        .user_header::<CloudHeader>()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("cloud service: {e:?}"))?;
    let cloud_events = node
        .service_builder(&name(service::CLOUDS)?)
        .event()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("cloud events: {e:?}"))?;
    let planes = node
        .service_builder(&name(service::PLANES)?)
        .publish_subscribe::<WallPlaneMsg>()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("plane service: {e:?}"))?;
    let plane_events = node
        .service_builder(&name(service::PLANES)?)
        .event()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("plane events: {e:?}"))?;
    let subscriber = clouds.subscriber_builder().create().map_err(|e| anyhow::anyhow!("subscriber: {e:?}"))?;
    let listener = cloud_events.listener_builder().create().map_err(|e| anyhow::anyhow!("listener: {e:?}"))?;
    let publisher = planes.publisher_builder().create().map_err(|e| anyhow::anyhow!("publisher: {e:?}"))?;
    let notifier = plane_events.notifier_builder().create().map_err(|e| anyhow::anyhow!("notifier: {e:?}"))?;
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
                        let sent = match publisher.loan_uninit() {
                            Ok(s) => s.write_payload(msg).send().map_err(|e| format!("{e:?}")),
                            Err(e) => Err(format!("{e:?}")),
                        };
                        match sent {
                            Ok(_) => {
                                counters.outputs += 1;
                                let _ = notifier.notify();
                            }
                            Err(e) => tracing::warn!("publishing a plane: {e}"),
                        }
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
    let frame_events = node
        .service_builder(&name(service::FRAMES)?)
        .event()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("frame events: {e:?}"))?;
    let detections = node
        .service_builder(&name(service::DETECTIONS)?)
        .publish_subscribe::<DetectionMsg>()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("detection service: {e:?}"))?;
    let detection_events = node
        .service_builder(&name(service::DETECTIONS)?)
        .event()
        .open_or_create()
        .map_err(|e| anyhow::anyhow!("detection events: {e:?}"))?;
    let subscriber = frames.subscriber_builder().create().map_err(|e| anyhow::anyhow!("subscriber: {e:?}"))?;
    let listener = frame_events.listener_builder().create().map_err(|e| anyhow::anyhow!("listener: {e:?}"))?;
    let publisher = detections.publisher_builder().create().map_err(|e| anyhow::anyhow!("publisher: {e:?}"))?;
    let notifier = detection_events.notifier_builder().create().map_err(|e| anyhow::anyhow!("notifier: {e:?}"))?;
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
                let sent = match publisher.loan_uninit() {
                    Ok(s) => s.write_payload(msg).send().map_err(|e| format!("{e:?}")),
                    Err(e) => Err(format!("{e:?}")),
                };
                match sent {
                    Ok(_) => {
                        counters.outputs += 1;
                        let _ = notifier.notify();
                    }
                    Err(e) => tracing::warn!("publishing a detection: {e}"),
                }
            }
        }
        CallbackProgression::Continue
    };
    waitset.wait_and_process(on_event).map_err(|e| anyhow::anyhow!("waiting: {e:?}")).context("detector")?;
    tracing::info!(?counters, "detector stops");
    Ok(())
}
