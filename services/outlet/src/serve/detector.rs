//! The detector: frames in ([`service::FRAMES`]), detections out
//! ([`service::DETECTIONS`]); a frame without the outlet gives a detection with
//! no holes, so that readers can tell "looked, found nothing" from silence.

use super::{Output, Runtime, clear, newest};
use anyhow::Result;
use iceoryx2::prelude::*;
use outlet::health::Health;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_detector::track::{TrackParams, Tracker};
use outlet_protocol::wire::{DetectionMsg, FrameHeader, HoleMsg, MAX_HOLES, PixelFormat, SCHEMA_VERSION, service};
use outlet_protocol::{HoleKind, shm};
use std::time::Instant;

pub fn run(rt: &Runtime) -> Result<()> {
    let template = &rt.config.detector.template;
    let detector = Detector::new(outlet::templates::load(template)?, DetectorParams::default());
    let config = &rt.config.detector;
    let full_frame_every = if config.tracking { config.full_frame_every } else { 0 };
    let mut tracker = Tracker::new(TrackParams { full_frame_every, ..TrackParams::default() });
    let subscriber =
        shm::frames(&rt.node)?.subscriber_builder().create().map_err(|e| anyhow::anyhow!("frame subscriber: {e:?}"))?;
    let listener = rt.listener(service::FRAMES)?;
    let output = Output::<DetectionMsg>::open(rt, service::DETECTIONS)?;
    let waitset = rt.waitset()?;
    let frames = waitset.attach_notification(&listener).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let tick = waitset.attach_interval(rt.heartbeat_period()).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let mut health = Health::new(rt.name);
    tracing::info!("detector ready ({template}): {} -> {}", service::FRAMES, service::DETECTIONS);
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        if id.has_event_from(&tick) {
            rt.beat(&mut health);
        }
        if id.has_event_from(&frames) {
            clear(&listener);
            // Detection takes longer than a frame period on a slow machine: work
            // on the newest frame, drop the older ones waiting.
            if let Some(sample) = newest(&subscriber, &mut health) {
                let started = Instant::now();
                let header = *sample.user_header();
                let checked =
                    header.validate(sample.payload().len()).map_err(|e| e.to_string()).and_then(|(format, camera)| {
                        grey_of_frame(&header, format, sample.payload())
                            .map(|grey| (grey, camera))
                            .ok_or_else(|| format!("frame {}: pixels do not fill the image", header.frame_id))
                    });
                // The grey image is all the detector reads: give the shared
                // memory back before detecting.
                drop(sample);
                match checked {
                    Ok((grey, camera)) => {
                        let time_s = header.capture_time_ns as f64 * 1e-9;
                        let report = tracker.detect_grey(&detector, &grey, Some(&camera), time_s).report;
                        let detect_ms = started.elapsed().as_secs_f64() * 1e3;
                        let msg = detection_msg(&header, &camera, report.detection.as_ref(), detect_ms);
                        if output.send(msg) {
                            health.output(header.capture_time_ns, detect_ms);
                        }
                    }
                    Err(reason) => {
                        health.rejected(&reason);
                        tracing::warn!(frame = header.frame_id, "frame rejected: {reason}");
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

/// The detector's grey image ([`outlet_detector::grey_of`]: the brightest
/// channel) straight from a frame's pixels (any stride), without a colour copy;
/// None when the payload is shorter than the header says.
fn grey_of_frame(header: &FrameHeader, format: PixelFormat, pixels: &[u8]) -> Option<image::GrayImage> {
    let (w, h, stride) = (header.width as usize, header.height as usize, header.stride as usize);
    let row_bytes = w * format.channels();
    let mut grey = Vec::with_capacity(w * h);
    for row in pixels.chunks(stride.max(1)).take(h) {
        let row = row.get(..row_bytes)?;
        match format {
            PixelFormat::Mono8 => grey.extend_from_slice(row),
            PixelFormat::Rgb8 | PixelFormat::Bgr8 => {
                grey.extend(row.chunks_exact(3).map(outlet_detector::grey_of_pixel))
            }
        }
    }
    image::GrayImage::from_raw(header.width, header.height, grey)
}

fn detection_msg(
    header: &FrameHeader,
    camera: &outlet_protocol::CameraModel,
    detection: Option<&outlet_detector::detect::Detection>,
    detect_ms: f64,
) -> DetectionMsg {
    let mut msg = DetectionMsg {
        schema_version: SCHEMA_VERSION,
        hole_count: 0,
        frame_id: header.frame_id,
        capture_time_ns: header.capture_time_ns,
        score: 0,
        reserved: 0,
        detect_ms,
        width: camera.width,
        height: camera.height,
        intrinsics: [camera.fx, camera.fy, camera.cx, camera.cy],
        distortion: camera.distortion,
        holes: [HoleMsg::default(); MAX_HOLES],
    };
    if let Some(d) = detection {
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
                score: h.score,
                sigma_px: h.sigma_px,
            };
        }
    }
    msg
}
