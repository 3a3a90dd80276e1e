//! The normal estimator: clouds in ([`service::CLOUDS`]), wall planes out ([`service::PLANES`]).

use super::{Output, Runtime, clear, newest};
use anyhow::Result;
use iceoryx2::prelude::*;
use outlet::health::Health;
use outlet_normal::{PlaneParams, WallPlane, fit_wall_plane};
use outlet_protocol::shm;
use outlet_protocol::wire::{CloudHeader, SCHEMA_VERSION, WallPlaneMsg, service};
use std::time::Instant;

pub fn run(rt: &Runtime) -> Result<()> {
    let subscriber =
        shm::clouds(&rt.node)?.subscriber_builder().create().map_err(|e| anyhow::anyhow!("cloud subscriber: {e:?}"))?;
    let listener = rt.listener(service::CLOUDS)?;
    let output = Output::<WallPlaneMsg>::open(rt, service::PLANES)?;
    let waitset = rt.waitset()?;
    let clouds = waitset.attach_notification(&listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let tick = waitset.attach_interval(rt.heartbeat_period()).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let params = PlaneParams {
        sigma_at_1m: rt.config.normal.sigma_at_1m,
        estimate_noise_scale: rt.config.normal.estimate_noise_scale,
        ..PlaneParams::default()
    };
    let mut health = Health::new(rt.name);
    tracing::info!("normal estimator ready: {} -> {}", service::CLOUDS, service::PLANES);
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        if id.has_event_from(&tick) {
            rt.beat(&mut health);
        }
        if id.has_event_from(&clouds) {
            clear(&listener);
            // Only the newest cloud matters: older ones waiting are dropped.
            if let Some(sample) = newest(&subscriber, &mut health) {
                let header = *sample.user_header();
                let started = Instant::now();
                let fitted = header.validate(sample.payload().len()).map_err(|e| e.to_string()).and_then(|()| {
                    let n = header.points as usize;
                    let points: Vec<[f32; 3]> =
                        sample.payload()[..3 * n].chunks_exact(3).map(|p| [p[0], p[1], p[2]]).collect();
                    fit_wall_plane(&points, &params).map_err(|e| format!("cloud {}: {e}", header.frame_id))
                });
                drop(sample);
                match fitted {
                    Ok(plane) => {
                        if output.send(plane_msg(&header, &plane)) {
                            health.output(header.capture_time_ns, started.elapsed().as_secs_f64() * 1e3);
                        }
                    }
                    Err(reason) => {
                        health.rejected(&reason);
                        tracing::warn!(frame = header.frame_id, "cloud rejected: {reason}");
                    }
                }
            }
        }
        CallbackProgression::Continue
    };
    super::run_until_stopped(&waitset, on_event)?;
    rt.stopped(&health);
    Ok(())
}

fn plane_msg(header: &CloudHeader, plane: &WallPlane) -> WallPlaneMsg {
    let c = plane.covariance;
    WallPlaneMsg {
        schema_version: SCHEMA_VERSION,
        inliers: plane.inliers.min(u32::MAX as usize) as u32,
        frame_id: header.frame_id,
        capture_time_ns: header.capture_time_ns,
        normal: [plane.normal.x, plane.normal.y, plane.normal.z],
        distance_m: plane.distance_m,
        tangent: plane.tangent.map(|t| [t.x, t.y, t.z]),
        covariance: std::array::from_fn(|k| c[(k / 3, k % 3)]),
    }
}
