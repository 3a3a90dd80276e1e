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
                let frame_id = header.frame_id;
                let not_filled = || format!("frame {frame_id}: pixels do not fill the image");
                let valid = header.validate(sample.payload().len()).map_err(|e| e.to_string());
                let outcome = valid.and_then(|(format, camera)| {
                    let time_s = header.capture_time_ns as f64 * 1e-9;
                    let size = [header.width, header.height];
                    let grey = |region, spare| grey_of_frame(&header, format, sample.payload(), region, spare);
                    // While tracking, only the window's pixels are made grey, and the
                    // frame is held for that search alone (about a millisecond).
                    let mut tried = None;
                    if let Some(window) = tracker.window_for(size, time_s) {
                        let crop = grey(window, std::mem::take(&mut spare)).ok_or_else(not_filled)?;
                        let found = tracker.search_window(&detector, &crop, window, size, Some(&camera), time_s);
                        spare = crop.into_raw();
                        match found {
                            Ok(tracked) => return Ok((tracked.report, camera)),
                            Err(times) => tried = Some(times),
                        }
                    }
                    let whole = grey([0, 0, size[0], size[1]], std::mem::take(&mut spare)).ok_or_else(not_filled)?;
                    // The grey image is all the detector reads: give the shared
                    // memory back before the whole frame's search.
                    drop(sample);
                    let tracked = tracker.search_full_frame(&detector, &whole, Some(&camera), time_s, tried);
                    spare = whole.into_raw();
                    Ok((tracked.report, camera))
                });
                match outcome {
                    Ok((report, camera)) => {
                        let detect_ms = started.elapsed().as_secs_f64() * 1e3;
                        let msg = detection_msg(&header, &camera, report.detection.as_ref(), detect_ms);
                        if output.send(msg) {
                            health.output(header.capture_time_ns, detect_ms);
                        }
                    }
                    Err(reason) => {
                        health.rejected(&reason);
                        tracing::warn!(frame = frame_id, "frame rejected: {reason}");
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
/// channel) of `region` (`[x, y, width, height]`, clipped to the frame) straight
/// from a frame's pixels (any stride), without a colour copy, into `grey`'s
/// memory (the last frame's); None when the payload is shorter than the header
/// says or the region is empty.
fn grey_of_frame(
    header: &FrameHeader,
    format: PixelFormat,
    pixels: &[u8],
    region: [u32; 4],
    mut grey: Vec<u8>,
) -> Option<image::GrayImage> {
    let (w, h, stride) = (header.width as usize, header.height as usize, header.stride as usize);
    let channels = format.channels();
    let [x, y] = [(region[0] as usize).min(w), (region[1] as usize).min(h)];
    let [rw, rh] = [(region[2] as usize).min(w - x), (region[3] as usize).min(h - y)];
    if rw == 0 || rh == 0 {
        return None;
    }
    grey.clear();
    grey.resize(rw * rh, 0);
    for (out, row) in grey.chunks_exact_mut(rw).zip(pixels.chunks(stride.max(1)).skip(y).take(rh)) {
        let row = row.get(x * channels..(x + rw) * channels)?;
        match format {
            PixelFormat::Mono8 => out.copy_from_slice(row),
            PixelFormat::Rgb8 | PixelFormat::Bgr8 => {
                for (g, p) in out.iter_mut().zip(row.chunks_exact(3)) {
                    *g = outlet_detector::grey_of_pixel(p);
                }
            }
        }
    }
    // Fewer rows than the region: the payload ended early.
    if pixels.len() < (y + rh - 1) * stride + (x + rw) * channels {
        return None;
    }
    image::GrayImage::from_raw(rw as u32, rh as u32, grey)
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
                shape: [h.shape[(0, 0)], h.shape[(0, 1)], h.shape[(1, 1)]],
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
        let whole = [0, 0, 3, 2];
        let fresh = grey_of_frame(&header, PixelFormat::Bgr8, &pixels, whole, Vec::new()).expect("grey");
        assert_eq!(fresh.as_raw(), &expected);
        // The last frame's memory, larger and full of other values, gives the same.
        let reused = grey_of_frame(&header, PixelFormat::Bgr8, &pixels, whole, vec![7; 100]).expect("grey");
        assert_eq!(reused.as_raw(), &expected);
        // A tracking window: the same grey values, of its pixels only.
        let window = grey_of_frame(&header, PixelFormat::Bgr8, &pixels, [1, 1, 5, 5], Vec::new()).expect("grey");
        assert_eq!(window.dimensions(), (2, 1), "clipped to the frame");
        assert_eq!(window.as_raw(), &expected[4..6]);
        assert_eq!(grey_of_frame(&header, PixelFormat::Bgr8, &pixels, [3, 0, 2, 2], Vec::new()), None, "empty");
        assert_eq!(
            grey_of_frame(&header, PixelFormat::Bgr8, &pixels[..20], whole, Vec::new()),
            None,
            "a short payload"
        );
    }
}
