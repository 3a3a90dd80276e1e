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
    // The grey image's pixels, handed back after each frame: no allocation per frame.
    let mut spare: Vec<u8> = Vec::new();
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
                        grey_of_frame(&header, format, sample.payload(), std::mem::take(&mut spare))
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
                        spare = grey.into_raw();
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
/// channel) straight from a frame's pixels (any stride), without a colour copy,
/// into `grey`'s memory (the last frame's); None when the payload is shorter than
/// the header says.
fn grey_of_frame(
    header: &FrameHeader,
    format: PixelFormat,
    pixels: &[u8],
    mut grey: Vec<u8>,
) -> Option<image::GrayImage> {
    let (w, h, stride) = (header.width as usize, header.height as usize, header.stride as usize);
    let row_bytes = w * format.channels();
    grey.clear();
    grey.reserve(w * h);
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grey_of_a_padded_frame_is_its_brightest_channel_whatever_the_buffer_held() {
        let camera = outlet_protocol::CameraModel::new(3, 2, [3.0, 3.0, 1.0, 0.5], [0.0; 5]).expect("camera");
        let mut header = FrameHeader::new(1, 0, PixelFormat::Bgr8, &camera);
        header.stride = 12; // 9 bytes of pixels and 3 of padding per row
        let pixels: Vec<u8> = (0..24u8).map(|i| if i % 12 >= 9 { 255 } else { i * 10 % 97 }).collect();
        let expected: Vec<u8> = pixels
            .chunks(12)
            .flat_map(|row| row[..9].chunks_exact(3).map(|p| *p.iter().max().unwrap_or(&0)).collect::<Vec<_>>())
            .collect();
        let fresh = grey_of_frame(&header, PixelFormat::Bgr8, &pixels, Vec::new()).expect("grey");
        assert_eq!(fresh.as_raw(), &expected);
        // The last frame's memory, larger and full of other values, gives the same.
        let reused = grey_of_frame(&header, PixelFormat::Bgr8, &pixels, vec![7; 100]).expect("grey");
        assert_eq!(reused.as_raw(), &expected);
        assert_eq!(grey_of_frame(&header, PixelFormat::Bgr8, &pixels[..20], Vec::new()), None, "a short payload");
    }
}
