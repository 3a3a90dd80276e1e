//! The pose service: detections ([`service::DETECTIONS`]) joined with the wall
//! plane closest in time ([`service::PLANES`]) into hole poses
//! ([`service::HOLE_POSES`]): the `plane` mode with a plane near enough in
//! time, else `mono`. A plane that cannot explain the holes gives a result
//! with status `plane_mismatch` and no pose, never a quiet `mono` one; a mono
//! pose whose mirror explains the pixels as well gives `ambiguous`.
//!
//! It also reads the stereo clouds ([`service::CLOUDS`]) in place, holding the
//! newest one: where the cloud of a plane's frame has points on the receptacle
//! face around the holes, the face's offset ahead of the plane is measured
//! there rather than taken as nominal (`outlet::solve_plane_with_cloud`).

use super::{Output, Runtime, clear};
use anyhow::Result;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use nalgebra::{Matrix2, Matrix3, Point2, Unit, Vector3};
use outlet::health::{Health, now_ns};
use outlet_pose::{Mode, Observations, OutletPose, PoseError, solve_mono};
use outlet_protocol::wire::{
    CloudHeader, DetectionMsg, HolePosesMsg, MAX_HOLES, SCHEMA_VERSION, WallPlaneMsg, pose_status, service,
};
use outlet_protocol::{HoleKind, OutletGeometry, shm};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// Planes kept to join each detection with the one closest in time.
const RECENT_PLANES: usize = 16;
/// The kept holes' whitened cost per degree of freedom above which a plane that
/// leaves more than `max_rms_px` cannot explain the detection: residuals five
/// times their own sigmas. Below it the covariance is widened by that factor
/// instead (the demo's frame 185: two holes off, 10.8, a pose 0.1 mm right).
const MAX_VARIANCE_FACTOR: f64 = 25.0;
/// For this long after start, a detection waits `plane_wait_ms` for a first
/// plane even though none has come yet: the normal estimator may start later
/// than the detector, and a mono pose then is one the plane would have bettered.
const STARTUP_GRACE: Duration = Duration::from_secs(5);

pub fn run(rt: &Runtime) -> Result<()> {
    let config = &rt.config.pose;
    let geometry = outlet::templates::load(&config.template)?.geometry;
    let detection_sub = shm::messages::<DetectionMsg>(&rt.node, service::DETECTIONS)?
        .subscriber_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("detection subscriber: {e:?}"))?;
    let plane_sub = shm::messages::<WallPlaneMsg>(&rt.node, service::PLANES)?
        .subscriber_builder()
        .create()
        .map_err(|e| anyhow::anyhow!("plane subscriber: {e:?}"))?;
    let cloud_sub =
        shm::clouds(&rt.node)?.subscriber_builder().create().map_err(|e| anyhow::anyhow!("cloud subscriber: {e:?}"))?;
    let detection_listener = rt.listener(service::DETECTIONS)?;
    let plane_listener = rt.listener(service::PLANES)?;
    let cloud_listener = rt.listener(service::CLOUDS)?;
    let output = Output::<HolePosesMsg>::open(rt, service::HOLE_POSES)?;
    let waitset = rt.waitset()?;
    let detections = waitset.attach_notification(&detection_listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let planes = waitset.attach_notification(&plane_listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let clouds = waitset.attach_notification(&cloud_listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    // The newest cloud, held in shared memory (one borrowed sample) until a newer one comes.
    let mut cloud: Option<iceoryx2::sample::Sample<ipc::Service, [f32], CloudHeader>> = None;
    let tick = waitset.attach_interval(rt.heartbeat_period()).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let mut recent: VecDeque<WallPlaneMsg> = VecDeque::with_capacity(RECENT_PLANES);
    // Detections waiting for the plane of their frame, with when they arrived.
    let mut pending: VecDeque<(DetectionMsg, Instant)> = VecDeque::new();
    let mut last_plane: Option<Instant> = None;
    // The capture time of the last outlet sent out.
    let mut last_sent_ns: Option<u64> = None;
    let service_started = Instant::now();
    let plane_wait = Duration::from_secs_f64(config.plane_wait_ms / 1e3);
    let mut health = Health::new(rt.name);
    tracing::info!("pose service ready ({})", config.template);
    let publish = |d: &DetectionMsg, recent: &VecDeque<WallPlaneMsg>, cloud: Option<Cloud>, health: &mut Health| {
        let started = Instant::now();
        match solve(d, &geometry, recent, cloud, config) {
            Ok(None) => {} // no outlet in that frame
            Ok(Some(outcome)) => {
                if output.send(poses_msg(d, &geometry, &outcome)) {
                    health.output(d.capture_time_ns, started.elapsed().as_secs_f64() * 1e3);
                }
            }
            Err(reason) => {
                health.rejected(&reason);
                tracing::warn!(frame = d.frame_id, "no pose: {reason}");
            }
        }
    };
    loop {
        let timeout = pending.front().map_or(Duration::MAX, |(_, at)| plane_wait.saturating_sub(at.elapsed()));
        let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
            if id.has_event_from(&tick) {
                rt.beat(&mut health);
            }
            if id.has_event_from(&planes) {
                clear(&plane_listener);
                while let Ok(Some(p)) = plane_sub.receive() {
                    let p = *p.payload();
                    if p.schema_version == SCHEMA_VERSION
                        && p.normal.iter().chain([&p.distance_m]).all(|v| v.is_finite())
                    {
                        if recent.len() == RECENT_PLANES {
                            recent.pop_front();
                        }
                        recent.push_back(p);
                        last_plane = Some(Instant::now());
                    } else {
                        let reason = format!("plane {}: wrong schema or not finite", p.frame_id);
                        health.rejected(&reason);
                        tracing::warn!("{reason}");
                    }
                }
            }
            if id.has_event_from(&clouds) {
                clear(&cloud_listener);
                loop {
                    match cloud_sub.receive() {
                        Ok(Some(c)) => cloud = Some(c),
                        Ok(None) => break,
                        Err(e) => {
                            tracing::warn!("receiving a cloud: {e:?}");
                            break;
                        }
                    }
                }
            }
            if id.has_event_from(&detections) {
                clear(&detection_listener);
                while let Ok(Some(d)) = detection_sub.receive() {
                    health.input();
                    pending.push_back((*d.payload(), Instant::now()));
                }
            }
            CallbackProgression::Continue
        };
        match waitset.wait_and_process_once_with_timeout(on_event, timeout) {
            Ok(WaitSetRunResult::TerminationRequest) => break,
            Ok(WaitSetRunResult::Interrupt) if super::interrupted_to_stop() => break,
            Ok(_) => {}
            Err(e) => return Err(anyhow::anyhow!("waiting: {e:?}")),
        }
        // A detection goes out once the plane of its moment is in (a plane as
        // late or later), when planes stopped coming, or after `plane_wait`.
        // Planes flow while one came lately, or while they keep pace with the
        // frames however slow these are: the newest plane is of the last frame
        // sent out or later (at 2.5 frames a second no plane is younger than
        // 200 ms when a detection comes before its own, which was then solved in
        // mono). One detection sent without its plane stops that until a newer
        // plane comes.
        let newest_plane_ns = recent.iter().map(|p| p.capture_time_ns).max();
        let planes_flowing = last_plane.is_some_and(|t| t.elapsed().as_secs_f64() * 1e3 < config.max_plane_age_ms)
            || (last_plane.is_none() && service_started.elapsed() < STARTUP_GRACE)
            || matches!((newest_plane_ns, last_sent_ns), (Some(p), Some(s)) if p >= s);
        while let Some((d, at)) = pending.front() {
            let plane_in = recent.iter().any(|p| p.capture_time_ns >= d.capture_time_ns);
            if d.hole_count == 0 || plane_in || !planes_flowing || at.elapsed() >= plane_wait {
                if d.hole_count > 0 {
                    last_sent_ns = Some(d.capture_time_ns);
                }
                publish(d, &recent, cloud.as_ref().and_then(cloud_points), &mut health);
                pending.pop_front();
            } else {
                break;
            }
        }
    }
    rt.stopped(&health);
    Ok(())
}

/// A cloud's capture time and its points.
type Cloud<'a> = (u64, &'a [[f32; 3]]);

/// The points of a held cloud sample; None (with a warning) when its header
/// does not fit its payload.
fn cloud_points(sample: &iceoryx2::sample::Sample<ipc::Service, [f32], CloudHeader>) -> Option<Cloud<'_>> {
    let header = sample.user_header();
    match header.validate(sample.payload().len()) {
        Ok(()) => {
            let (points, _) = sample.payload().as_chunks::<3>();
            Some((header.capture_time_ns, points.get(..header.points as usize)?))
        }
        Err(e) => {
            tracing::warn!(frame = header.frame_id, "cloud not used for the face: {e}");
            None
        }
    }
}

/// What the pose service says about one detection.
enum Outcome {
    /// A pose to act on.
    Pose(OutletPose),
    /// No pose, and why (`pose_status`), with the mode that was tried.
    Refused { mode: Mode, status: u32 },
}

/// The pose of the outlet a detection found; None when it found none.
fn solve(
    d: &DetectionMsg,
    geometry: &OutletGeometry,
    recent: &VecDeque<WallPlaneMsg>,
    cloud: Option<Cloud>,
    config: &outlet::config::PoseConfig,
) -> Result<Option<Outcome>, String> {
    if d.schema_version != SCHEMA_VERSION {
        return Err(format!("detection {}: schema {} (this build: {SCHEMA_VERSION})", d.frame_id, d.schema_version));
    }
    if d.hole_count == 0 {
        return Ok(None);
    }
    if d.hole_count as usize != geometry.holes.len() {
        return Err(format!(
            "detection {}: {} holes, the template `{}` has {}",
            d.frame_id,
            d.hole_count,
            config.template,
            geometry.holes.len()
        ));
    }
    let camera = d.camera().map_err(|e| format!("detection {}: {e}", d.frame_id))?;
    let model: Vec<Point2<f64>> = geometry.holes.iter().map(|h| h.position()).collect();
    let holes = &d.holes[..model.len()];
    let pixels: Vec<Point2<f64>> = holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect();
    // Each hole's own sigma from the detector's fit (the configured one where it has none).
    let sigmas: Vec<f64> = holes.iter().map(|h| h.sigma_px).collect();
    // And its shape (a zero shape, not given, is read as the same on both axes).
    let shapes: Vec<Matrix2<f64>> =
        holes.iter().map(|h| Matrix2::new(h.shape[0], h.shape[1], h.shape[1], h.shape[2])).collect();
    let obs = Observations {
        model_mm: &model,
        pixels: &pixels,
        camera: &camera,
        pixel_sigma: config.pixel_sigma,
        pixel_sigmas: Some(&sigmas),
        pixel_shapes: Some(&shapes),
    };
    let plane = recent
        .iter()
        .min_by_key(|p| p.capture_time_ns.abs_diff(d.capture_time_ns))
        .filter(|p| (p.capture_time_ns.abs_diff(d.capture_time_ns) as f64) / 1e6 <= config.max_plane_age_ms);
    let refused = |mode, status| Ok(Some(Outcome::Refused { mode, status }));
    match plane {
        Some(p) => {
            let wall = outlet_normal::WallPlane {
                normal: Unit::new_normalize(Vector3::from(p.normal)),
                distance_m: p.distance_m,
                covariance: Matrix3::from_row_slice(&p.covariance),
                tangent: p.tangent.map(Vector3::from),
                inliers: p.inliers as usize,
                rms_m: f64::NAN,
            };
            let model_error = outlet::ModelError {
                face_offset_sigma_mm: config.face_offset_sigma_mm,
                plane_tilt_sigma_deg: config.plane_tilt_sigma_deg,
                plane_distance_sigma_mm: config.plane_distance_sigma_mm,
            };
            // The plane's own cloud, if it is the one held.
            let points = cloud.filter(|(stamp, _)| *stamp == p.capture_time_ns).map_or(&[][..], |(_, points)| points);
            match outlet::solve_plane_with_cloud(&obs, &wall, points, geometry, &model_error).map(|(pose, _)| pose) {
                // Pixels off by more than max_rms_px count against the plane only
                // where their own sigmas do not explain them (a hole the detector
                // knows it placed poorly carries a large sigma_px).
                Ok(pose) if pose.rms_px <= config.max_rms_px || pose.variance_factor <= MAX_VARIANCE_FACTOR => {
                    Ok(Some(Outcome::Pose(pose)))
                }
                // A plane of another wall, a wrong stereo fit or a wrong hole: the
                // plane and the pixels disagree. Mono would hide it (the demo's
                // frame 185 went 31 mm wrong that way): say so instead.
                Ok(pose) => {
                    tracing::warn!(
                        frame = d.frame_id,
                        plane_frame = p.frame_id,
                        outliers = ?pose.outliers,
                        "the plane leaves {:.1} px RMS: no pose (plane_mismatch)",
                        pose.rms_px
                    );
                    refused(Mode::Plane, pose_status::PLANE_MISMATCH)
                }
                Err(
                    e @ (PoseError::BehindCamera
                    | PoseError::GrazingNormal { .. }
                    | PoseError::BadPlane
                    | PoseError::PlaneDisagrees { .. }),
                ) => {
                    tracing::warn!(frame = d.frame_id, plane_frame = p.frame_id, "{e}: no pose (plane_mismatch)");
                    refused(Mode::Plane, pose_status::PLANE_MISMATCH)
                }
                Err(e) => Err(format!("detection {}: {e}", d.frame_id)),
            }
        }
        None => match solve_mono(&obs) {
            Ok(pose) => Ok(Some(Outcome::Pose(pose))),
            Err(e @ PoseError::Ambiguous { .. }) => {
                tracing::info!(frame = d.frame_id, "{e}");
                refused(Mode::Mono, pose_status::AMBIGUOUS)
            }
            Err(e) => Err(format!("detection {}: {e}", d.frame_id)),
        },
    }
}

fn mode_code(mode: Mode) -> u32 {
    match mode {
        Mode::Mono => 1,
        Mode::Normal => 2,
        Mode::Plane => 3,
    }
}

fn poses_msg(d: &DetectionMsg, geometry: &OutletGeometry, outcome: &Outcome) -> HolePosesMsg {
    let mut msg = HolePosesMsg {
        schema_version: SCHEMA_VERSION,
        hole_count: 0,
        frame_id: d.frame_id,
        capture_time_ns: d.capture_time_ns,
        published_ns: now_ns(),
        mode: 0,
        status: 0,
        outlier_mask: 0,
        reserved: 0,
        rotation: [f64::NAN; 9],
        translation_m: [f64::NAN; 3],
        kinds: [0; MAX_HOLES],
        positions_m: [[0.0; 3]; MAX_HOLES],
        covariances_m2: [[0.0; 9]; MAX_HOLES],
    };
    let pose = match outcome {
        Outcome::Refused { mode, status } => {
            msg.mode = mode_code(*mode);
            msg.status = *status;
            return msg;
        }
        Outcome::Pose(pose) => pose,
    };
    let r = pose.pose.rotation.to_rotation_matrix();
    let t = pose.pose.translation.vector;
    msg.mode = mode_code(pose.mode);
    msg.status = pose_status::OK;
    msg.hole_count = pose.holes_cam_m.len().min(MAX_HOLES) as u32;
    msg.rotation = std::array::from_fn(|k| r[(k / 3, k % 3)]);
    msg.translation_m = [t.x, t.y, t.z];
    msg.outlier_mask = pose.outliers.iter().filter(|k| **k < 32).fold(0, |m, k| m | (1u32 << k));
    for (k, ((h, c), hole)) in
        pose.holes_cam_m.iter().zip(&pose.covariances).zip(&geometry.holes).take(MAX_HOLES).enumerate()
    {
        msg.positions_m[k] = [h.x, h.y, h.z];
        msg.covariances_m2[k] = std::array::from_fn(|j| c[(j / 3, j % 3)]);
        msg.kinds[k] = match hole.kind {
            HoleKind::Power => 1,
            HoleKind::Ground => 2,
        };
    }
    msg
}
