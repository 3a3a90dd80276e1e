//! The renderer as a camera: at `rate_hz`, a rendered frame on
//! [`service::FRAMES`], its stereo cloud on [`service::CLOUDS`] and the ground
//! truth on [`service::TRUTH`], all with the same frame id and capture stamp.
//! Each scene of the scenario is seen for `frames_per_scene` frames by a camera
//! approaching it, then the next (or one of `views` rendered once, in turn).

use super::camera_out::CameraOutput;
use super::{Output, Runtime};
use anyhow::Result;
use iceoryx2::prelude::*;
use outlet::health::Health;
use outlet_protocol::CameraModel;
use outlet_protocol::wire::{MAX_HOLES, PixelFormat, SCHEMA_VERSION, TruthMsg, service};
use outlet_sim::RenderedFrame;
use std::time::{Duration, Instant};

/// The camera of a `width` x `height` simulated sensor: the default VGA camera's
/// field of view and lens.
pub fn camera(width: u32, height: u32) -> Result<CameraModel> {
    let vga = CameraModel::default_vga();
    let f = vga.fx * width as f64 / 640.0;
    Ok(CameraModel::new(
        width,
        height,
        [f, f, (width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0],
        vga.distortion,
    )?)
}

/// How far the camera moves towards the wall per frame while it stays on one
/// scene (m), and sideways: an arm approaching at 5 cm/s seen at 10 Hz.
const APPROACH_STEP_M: f64 = 0.005;
const DRIFT_STEP_M: f64 = 0.001;

/// Renders frame `index` of the scenario: scene `index / frames_per_scene`, seen
/// by a camera that has moved `index % frames_per_scene` steps towards the
/// wall since the scene's own view; None (logged) when it has no valid pose.
fn render(config: &outlet::config::SimCameraConfig, camera: &CameraModel, index: u64) -> Option<RenderedFrame> {
    let per_scene = u64::from(config.frames_per_scene.max(1));
    let (scene_index, step) = (index / per_scene, index % per_scene);
    match outlet_sim::sample_scene(&config.scenario, config.seed, scene_index, camera) {
        Ok(scene) if step == 0 => Some(outlet_sim::render_frame(&scene, &format!("sim-{index}"))),
        Ok(scene) => {
            let k = step as f64;
            let moved =
                scene.pose.inverse() * nalgebra::Isometry3::translation(DRIFT_STEP_M * k, 0.0, APPROACH_STEP_M * k);
            let seen = outlet_sim::approach::seen_from(&scene, &moved, scene.noise_seed.wrapping_add(step));
            Some(outlet_sim::render_frame(&seen, &format!("sim-{index}")))
        }
        Err(e) => {
            tracing::warn!("view {index}: {e}");
            None
        }
    }
}

fn truth_msg(frame: &RenderedFrame, frame_id: u64, capture_time_ns: u64) -> TruthMsg {
    let truth = &frame.truth;
    let mut msg = TruthMsg {
        schema_version: SCHEMA_VERSION,
        hole_count: 0,
        frame_id,
        capture_time_ns,
        positions_m: [[f64::NAN; 3]; MAX_HOLES],
        rotation: [f64::NAN; 9],
        translation_m: [f64::NAN; 3],
    };
    if let Some(pose) = &truth.pose {
        msg.rotation = std::array::from_fn(|k| pose.rotation[k / 3][k % 3]);
        msg.translation_m = pose.translation_m;
        let positions: Vec<[f64; 3]> = truth.holes.iter().filter_map(|h| h.position_m).collect();
        if positions.len() == truth.holes.len() {
            msg.hole_count = positions.len().min(MAX_HOLES) as u32;
            for (slot, p) in msg.positions_m.iter_mut().zip(positions) {
                *slot = p;
            }
        }
    }
    msg
}

pub fn run(rt: &Runtime) -> Result<()> {
    let config = &rt.config.sim_camera;
    let camera = camera(config.width, config.height)?;
    let frame_bytes = (camera.width * camera.height * 3) as usize;
    let output = CameraOutput::open(rt, frame_bytes, frame_bytes)?;
    let truth = Output::<TruthMsg>::open(rt, service::TRUTH)?;

    let replay: Vec<RenderedFrame> = (0..config.views as u64).filter_map(|i| render(config, &camera, i)).collect();
    if config.views > 0 && replay.is_empty() {
        anyhow::bail!("none of the {} views of {} could be rendered", config.views, config.scenario);
    }
    let waitset = rt.waitset()?;
    let period = Duration::from_secs_f64(1.0 / config.rate_hz);
    let shutter = waitset.attach_interval(period).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let tick = waitset.attach_interval(rt.heartbeat_period()).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let mut health = Health::new(rt.name);
    let mut frame_id = 0u64;
    tracing::info!(
        "sim-camera ready: {} at {} Hz, {}x{} -> {}, {}, {}",
        config.scenario,
        config.rate_hz,
        camera.width,
        camera.height,
        service::FRAMES,
        service::CLOUDS,
        service::TRUTH
    );
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        if id.has_event_from(&tick) {
            rt.beat(&mut health);
        }
        if id.has_event_from(&shutter) {
            frame_id += 1;
            health.input();
            let started = Instant::now();
            let live;
            let frame = if replay.is_empty() {
                live = render(config, &camera, frame_id - 1);
                match &live {
                    Some(f) => f,
                    None => return CallbackProgression::Continue,
                }
            } else {
                &replay[((frame_id - 1) % replay.len() as u64) as usize]
            };
            let render_ms = started.elapsed().as_secs_f64() * 1e3;
            // The frame first, then its cloud, both with the frame's stamp: the
            // moment it is handed over, once the pixels are in shared memory
            // (rendering and the copy stand for exposure and readout).
            let cloud = config.cloud.then_some(frame.cloud.as_slice());
            let sent = output.send(frame_id, &camera, PixelFormat::Rgb8, frame.frame.image.as_raw(), cloud);
            match sent {
                Ok(stamp) => {
                    truth.send(truth_msg(frame, frame_id, stamp));
                    health.output(stamp, render_ms);
                }
                Err(e) => tracing::warn!(frame = frame_id, "publishing: {e}"),
            }
        }
        CallbackProgression::Continue
    };
    super::run_until_stopped(&waitset, on_event)?;
    rt.stopped(&health);
    Ok(())
}
