//! The debug image: a frame with what the sidecar found in it drawn on top,
//! for a person watching in rviz, rqt_image_view or Foxglove. What is drawn:
//!
//! - each hole of the frame's detection ([`annotate::draw_hole`], as `outlet
//!   detect --annotate` draws it): a circle in its class's colour (yellow
//!   power, blue ground) of radius [`HOLE_SIGMAS`] x its pixel sigma (at
//!   least [`annotate::HOLE_RADIUS_PX`], so a well-placed hole stays visible),
//!   a black ring, a green cross on its centre;
//! - with a pose: the plate's outline ([`crate::markers::plate_of`], the
//!   rviz marker's plate) projected into the image with the frame's camera and
//!   its distortion, and the outlet's axes (x red, y green, z blue, as rviz
//!   draws frames), [`AXIS_LENGTH_M`] long;
//! - a label: the detector's score or "no outlet", the pose's mode or why
//!   there is none, the frame id.
//!
//! The detection on the wire carries the found holes only, not the
//! candidates, so the candidates are not drawn (`outlet detect --annotate`
//! draws them).
//!
//! [`DebugImages`] joins the three inputs of a debug image, which come
//! separately: the frame (from the frames service), its detection, and
//! (later, when the detection found an outlet) its hole poses.

use crate::convert::{Rejection, ns_to_time};
use crate::markers::plate_of;
use crate::msgs::{CompressedImage, Header, Image};
use image::{Rgb, RgbImage};
use nalgebra::{Point2, Point3, Vector3};
use outlet_detector::annotate;
use outlet_protocol::wire::{DetectionMsg, FrameHeader, HolePosesMsg, MAX_HOLES, PixelFormat, pose_status};
use outlet_protocol::{CameraModel, HoleKind};
use std::collections::VecDeque;

/// A hole's circle has this many of its pixel sigmas as its radius.
pub const HOLE_SIGMAS: f64 = 3.0;
/// The plate's outline.
pub const OUTLINE: Rgb<u8> = Rgb([255, 0, 255]);
/// The outlet's axes drawn, each this long (m).
pub const AXIS_LENGTH_M: f64 = 0.02;
/// JPEG quality of the compressed debug image (image_transport's default is 95;
/// 85 is a third of the bytes and still shows every mark).
pub const JPEG_QUALITY: u8 = 85;
/// The `format` of the compressed debug image, as image_transport's
/// `compressed` publisher writes it for an rgb8 image.
pub const JPEG_FORMAT: &str = "rgb8; jpeg compressed bgr8";

/// A frame's pixels (any stride; mono8, rgb8 or bgr8) as an RGB image.
pub fn rgb_of_frame(header: &FrameHeader, pixels: &[u8]) -> Result<(RgbImage, CameraModel), Rejection> {
    let (format, camera) = header.validate(pixels.len()).map_err(|e| Rejection::Frame(e.to_string()))?;
    let (width, height, stride) = (header.width as usize, header.height as usize, header.stride as usize);
    let row_bytes = width * format.channels();
    let mut rgb = Vec::with_capacity(width * height * 3);
    for row in pixels.chunks(stride).take(height) {
        let row = row.get(..row_bytes).ok_or_else(|| Rejection::Frame(format!("a row of {} bytes", row.len())))?;
        match format {
            PixelFormat::Rgb8 => rgb.extend_from_slice(row),
            PixelFormat::Bgr8 => row.chunks_exact(3).for_each(|p| rgb.extend_from_slice(&[p[2], p[1], p[0]])),
            PixelFormat::Mono8 => row.iter().for_each(|&g| rgb.extend_from_slice(&[g, g, g])),
        }
    }
    let image = RgbImage::from_raw(header.width, header.height, rgb)
        .ok_or_else(|| Rejection::Frame(format!("{}x{} pixels do not fit the frame", header.width, header.height)))?;
    Ok((image, camera))
}

/// The radius of a hole's circle (pixels) for its pixel sigma.
pub fn hole_radius_px(sigma_px: f64) -> f64 {
    if sigma_px.is_finite() { (HOLE_SIGMAS * sigma_px).max(annotate::HOLE_RADIUS_PX) } else { annotate::HOLE_RADIUS_PX }
}

/// The name of a pose mode on the wire.
fn mode_name(mode: u32) -> &'static str {
    match mode {
        1 => "mono",
        2 => "normal",
        3 => "plane",
        _ => "unknown",
    }
}

/// The segment from `a` to `b` (camera frame) projected, as a polyline of
/// `steps` pieces so that distortion bends it as the lens does.
fn draw_projected(
    image: &mut RgbImage,
    camera: &CameraModel,
    a: Point3<f64>,
    b: Point3<f64>,
    steps: usize,
    colour: Rgb<u8>,
) {
    let points: Vec<Option<Point2<f64>>> =
        (0..=steps).map(|k| camera.project(&(a + (b - a) * (k as f64 / steps as f64)))).collect();
    for pair in points.windows(2) {
        if let [Some(p), Some(q)] = pair {
            annotate::draw_line(image, *p, *q, 2, colour);
        }
    }
}

/// The frame with the detection's holes, and with `poses` (when its status is
/// OK) the plate's outline and the outlet's axes, and a label; see the module's
/// documentation. `camera` is the frame's.
pub fn draw(frame: &RgbImage, camera: &CameraModel, d: &DetectionMsg, poses: Option<&HolePosesMsg>) -> RgbImage {
    let mut out = frame.clone();
    let posed = poses.filter(|p| p.status == pose_status::OK);
    if let Some(plate) = posed.and_then(plate_of) {
        let corners = plate.corners_cam_m();
        for k in 0..4 {
            draw_projected(&mut out, camera, corners[k], corners[(k + 1) % 4], 24, OUTLINE);
        }
        let origin = plate.face_centre_cam_m;
        for (axis, colour) in [(0, Rgb([255, 40, 40])), (1, Rgb([40, 255, 40])), (2, Rgb([40, 40, 255]))] {
            let end = origin + plate.rotation * Vector3::from_fn(|i, _| if i == axis { AXIS_LENGTH_M } else { 0.0 });
            draw_projected(&mut out, camera, origin, end, 8, colour);
        }
    }
    let holes = &d.holes[..(d.hole_count as usize).min(MAX_HOLES)];
    for h in holes {
        let kind = match h.kind {
            1 => HoleKind::Power,
            2 => HoleKind::Ground,
            _ => continue,
        };
        annotate::draw_hole(&mut out, Point2::new(h.pixel[0], h.pixel[1]), kind, hole_radius_px(h.sigma_px));
    }
    let scale = (out.width() / 320).clamp(1, 4);
    let mut label = |k: u32, text: &str, colour: Rgb<u8>| {
        // A dark shadow, so that the label reads on a white wall too.
        annotate::draw_text(&mut out, text, 6 + scale, 6 + k * 10 * scale + scale, scale, annotate::RING);
        annotate::draw_text(&mut out, text, 6, 6 + k * 10 * scale, scale, colour);
    };
    if holes.is_empty() {
        label(0, "no outlet", annotate::NOT_FOUND);
    } else {
        label(0, &format!("outlet: score {}", d.score), annotate::CENTRE);
        let (pose, colour) = match poses {
            Some(p) if p.status == pose_status::OK => (format!("pose: {}", mode_name(p.mode)), annotate::CENTRE),
            Some(p) if p.status == pose_status::AMBIGUOUS => ("no pose: ambiguous".into(), annotate::NOT_FOUND),
            Some(_) => ("no pose: plane_mismatch".into(), annotate::NOT_FOUND),
            None => ("no pose".into(), annotate::NOT_FOUND),
        };
        label(1, &pose, colour);
    }
    label(2, &format!("frame {}", d.frame_id), Rgb([255, 255, 255]));
    out
}

/// A drawn debug image and the frame it shows.
#[derive(Debug, Clone, PartialEq)]
pub struct DebugImage {
    pub frame_id: u64,
    pub capture_time_ns: u64,
    pub rgb: RgbImage,
}

impl DebugImage {
    /// Its header: stamped with the frame's capture time, in `frame_id`.
    pub fn header(&self, frame_id: &str) -> Header {
        Header { stamp: ns_to_time(self.capture_time_ns), frame_id: frame_id.to_string() }
    }

    /// As an rgb8 `sensor_msgs/Image` (the pixels move into the message).
    pub fn into_image(self, frame_id: &str) -> Image {
        let header = self.header(frame_id);
        let (width, height) = self.rgb.dimensions();
        Image {
            header,
            height,
            width,
            encoding: "rgb8".into(),
            is_bigendian: 0,
            step: width * 3,
            data: self.rgb.into_raw(),
        }
    }

    /// As a JPEG `sensor_msgs/CompressedImage` of `quality` (1..=100).
    pub fn to_jpeg(&self, frame_id: &str, quality: u8) -> Result<CompressedImage, image::ImageError> {
        let mut data = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut data, quality.clamp(1, 100)).encode_image(&self.rgb)?;
        Ok(CompressedImage { header: self.header(frame_id), format: JPEG_FORMAT.into(), data })
    }
}

#[derive(Debug, Clone)]
struct KeptFrame {
    frame_id: u64,
    capture_time_ns: u64,
    rgb: RgbImage,
    camera: CameraModel,
}

impl KeptFrame {
    fn shows(&self, frame_id: u64, capture_time_ns: u64) -> bool {
        self.frame_id == frame_id && self.capture_time_ns == capture_time_ns
    }

    fn drawn(self, d: &DetectionMsg, poses: Option<&HolePosesMsg>) -> DebugImage {
        let rgb = draw(&self.rgb, &self.camera, d, poses);
        DebugImage { frame_id: self.frame_id, capture_time_ns: self.capture_time_ns, rgb }
    }
}

/// Joins each detection with its frame (same frame id and capture time) and,
/// when it found an outlet, with its hole poses, and draws the debug image
/// once all are in: at once for a detection without an outlet, at its poses
/// otherwise, or without a pose when none came (the next detection came
/// first, or a heartbeat period passed: [`DebugImages::tick`]).
///
/// Frames are kept only as they are handed in: hand them in only while
/// someone subscribes to the debug image, and [`DebugImages::clear`] when
/// nobody does any more.
#[derive(Debug, Clone, Default)]
pub struct DebugImages {
    frames: VecDeque<KeptFrame>,
    /// A detection with holes and its frame, waiting for the poses.
    pending: Option<(DetectionMsg, KeptFrame)>,
    /// Whether `pending` has been there at a tick already.
    pending_ticked: bool,
}

impl DebugImages {
    /// Frames kept for their detections (frames readers keep 2; the detector
    /// answers the newest).
    pub const FRAMES_KEPT: usize = 4;

    /// Keeps a frame (as RGB) for its detection.
    pub fn add_frame(&mut self, header: &FrameHeader, pixels: &[u8]) -> Result<(), Rejection> {
        let (rgb, camera) = rgb_of_frame(header, pixels)?;
        if self.frames.len() == Self::FRAMES_KEPT {
            self.frames.pop_front();
        }
        let (frame_id, capture_time_ns) = (header.frame_id, header.capture_time_ns);
        self.frames.push_back(KeptFrame { frame_id, capture_time_ns, rgb, camera });
        Ok(())
    }

    /// Takes a detection: the debug images now complete, oldest first (the
    /// previous detection's, still without poses, and this one's if it found
    /// no outlet). A detection whose frame is not kept gives none.
    pub fn detection(&mut self, d: &DetectionMsg) -> Vec<DebugImage> {
        let mut done: Vec<DebugImage> = self.flush().into_iter().collect();
        let Some(at) = self.frames.iter().position(|f| f.shows(d.frame_id, d.capture_time_ns)) else {
            return done;
        };
        // Frames before it will not be detected any more (the detector goes forward).
        let Some(frame) = self.frames.drain(..=at).next_back() else { return done };
        if d.hole_count == 0 {
            done.push(frame.drawn(d, None));
        } else {
            self.pending = Some((*d, frame));
            self.pending_ticked = false;
        }
        done
    }

    /// Takes hole poses: the debug image of their detection, if it waits for them.
    pub fn poses(&mut self, p: &HolePosesMsg) -> Option<DebugImage> {
        let (d, _) = self.pending.as_ref().filter(|(_, f)| f.shows(p.frame_id, p.capture_time_ns))?;
        let d = *d;
        let (_, frame) = self.pending.take()?;
        Some(frame.drawn(&d, Some(p)))
    }

    /// The waiting detection's image without a pose.
    pub fn flush(&mut self) -> Option<DebugImage> {
        let (d, frame) = self.pending.take()?;
        Some(frame.drawn(&d, None))
    }

    /// Called every heartbeat period: the waiting detection's image without a
    /// pose if it has waited a whole period.
    pub fn tick(&mut self) -> Option<DebugImage> {
        if self.pending.is_some() && self.pending_ticked {
            return self.flush();
        }
        self.pending_ticked = self.pending.is_some();
        None
    }

    /// Forgets every frame and the waiting detection (nobody watches any more).
    pub fn clear(&mut self) {
        self.frames.clear();
        self.pending = None;
    }

    /// Frames kept, and whether a detection waits.
    pub fn len(&self) -> usize {
        self.frames.len() + usize::from(self.pending.is_some())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::convert::image_of_compressed;
    use outlet_protocol::OutletGeometry;
    use outlet_protocol::wire::{HoleMsg, SCHEMA_VERSION};

    const GREY: Rgb<u8> = Rgb([128, 128, 128]);

    fn camera() -> CameraModel {
        CameraModel::new(320, 240, [800.0, 800.0, 160.0, 120.0], [-0.05, 0.01, 0.0, 0.0, 0.0]).expect("camera")
    }

    /// A 2x1 facing the camera 0.5 m away, and where the camera sees its
    /// holes (the slots 20 px apart).
    fn outlet() -> (HolePosesMsg, Vec<Point2<f64>>) {
        let geometry = OutletGeometry::us_2x1();
        let t = Vector3::new(0.0, 0.0, 0.5);
        let mut p = HolePosesMsg {
            schema_version: SCHEMA_VERSION,
            hole_count: 6,
            frame_id: 5,
            capture_time_ns: 1_700_000_000_123_000_000,
            published_ns: 0,
            mode: 3,
            status: pose_status::OK,
            outlier_mask: 0,
            reserved: 0,
            rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            translation_m: t.into(),
            kinds: [0; MAX_HOLES],
            positions_m: [[0.0; 3]; MAX_HOLES],
            covariances_m2: [[0.0; 9]; MAX_HOLES],
        };
        let mut pixels = Vec::new();
        for (k, h) in geometry.holes.iter().enumerate() {
            let x = Point3::from(Vector3::new(h.position_mm[0] / 1e3, h.position_mm[1] / 1e3, 0.0) + t);
            p.positions_m[k] = x.coords.into();
            p.kinds[k] = if h.kind == HoleKind::Power { 1 } else { 2 };
            pixels.push(camera().project(&x).expect("in front"));
        }
        (p, pixels)
    }

    fn detection(p: &HolePosesMsg, pixels: &[Point2<f64>], sigma_px: f64) -> DetectionMsg {
        let mut holes = [HoleMsg::default(); MAX_HOLES];
        for (k, (h, px)) in holes.iter_mut().zip(pixels).enumerate() {
            *h = HoleMsg { kind: p.kinds[k], refined: 1, pixel: [px.x, px.y], score: 0.9, sigma_px, shape: [0.0; 3] };
        }
        let c = camera();
        DetectionMsg {
            schema_version: SCHEMA_VERSION,
            hole_count: pixels.len() as u32,
            frame_id: p.frame_id,
            capture_time_ns: p.capture_time_ns,
            score: 6,
            reserved: 0,
            detect_ms: 2.0,
            width: c.width,
            height: c.height,
            intrinsics: [c.fx, c.fy, c.cx, c.cy],
            distortion: c.distortion,
            holes,
        }
    }

    fn frame(frame_id: u64, capture_time_ns: u64, format: PixelFormat) -> (FrameHeader, Vec<u8>) {
        let mut header = FrameHeader::new(frame_id, capture_time_ns, format, &camera());
        header.stride += 5;
        let row = vec![128u8; header.stride as usize];
        (header, row.repeat(header.height as usize))
    }

    fn colour_near(image: &RgbImage, c: Point2<f64>, r: f64, colour: Rgb<u8>) -> usize {
        (0..64)
            .filter(|k| {
                let a = *k as f64 * std::f64::consts::TAU / 64.0;
                let (x, y) = ((c.x + r * a.cos()).round(), (c.y + r * a.sin()).round());
                *image.get_pixel(x as u32, y as u32) == colour
            })
            .count()
    }

    #[test]
    fn frames_of_every_format_and_stride_become_rgb() {
        let c = camera();
        let mut header = FrameHeader::new(1, 2, PixelFormat::Bgr8, &c);
        header.stride = 320 * 3 + 4;
        let mut pixels = vec![0u8; header.stride as usize * 240];
        pixels[..3].copy_from_slice(&[1, 2, 3]);
        let (rgb, cam) = rgb_of_frame(&header, &pixels).expect("bgr8");
        assert_eq!((rgb.dimensions(), rgb.get_pixel(0, 0).0, cam), ((320, 240), [3, 2, 1], c));
        let mut mono = FrameHeader::new(1, 2, PixelFormat::Mono8, &c);
        mono.stride = 321;
        let mut pixels = vec![0u8; 321 * 240];
        pixels[321] = 77;
        let (rgb, _) = rgb_of_frame(&mono, &pixels).expect("mono8");
        assert_eq!(rgb.get_pixel(0, 1).0, [77, 77, 77]);
        assert!(rgb_of_frame(&mono, &pixels[..1000]).is_err(), "short");
    }

    #[test]
    fn the_holes_are_drawn_where_they_are_in_their_class_colours() {
        let (p, pixels) = outlet();
        let (header, data) = frame(p.frame_id, p.capture_time_ns, PixelFormat::Rgb8);
        let (rgb, cam) = rgb_of_frame(&header, &data).expect("frame");
        // Hole 2 (ground) is poorly placed: sigma 4 px, a 12 px circle.
        let mut d = detection(&p, &pixels, 0.2);
        d.holes[2].sigma_px = 4.0;
        let drawn = draw(&rgb, &cam, &d, Some(&p));
        for (k, px) in pixels.iter().enumerate() {
            let colour = if p.kinds[k] == 1 { annotate::POWER } else { annotate::GROUND };
            let r = if k == 2 { 12.0 } else { annotate::HOLE_RADIUS_PX };
            assert!(colour_near(&drawn, *px, r, colour) >= 48, "hole {k}: its circle at {r} px in its colour");
            assert_eq!(colour_near(&drawn, *px, r + 3.0, colour), 0, "hole {k}: nothing beyond it");
            let centre = drawn.get_pixel(px.x.floor() as u32, px.y.floor() as u32);
            assert_eq!(*centre, annotate::CENTRE, "hole {k}: the cross on its centre");
        }
        // The plate's outline: its top edge's middle, projected, is drawn.
        let plate = plate_of(&p).expect("plate");
        let c = plate.corners_cam_m();
        let top = cam.project(&Point3::from((c[0].coords + c[1].coords) / 2.0)).expect("in front");
        let near_top = (-2..=2).any(|dy| *drawn.get_pixel(top.x as u32, (top.y as i64 + dy) as u32) == OUTLINE);
        assert!(near_top, "the outline at {top:?}");
        // Away from everything the frame is as it was.
        assert_eq!(*drawn.get_pixel(300, 230), GREY);
        assert_eq!(*rgb.get_pixel(pixels[0].x as u32, pixels[0].y as u32), GREY, "the frame itself untouched");
        // Without a pose: holes, no outline.
        let unposed = draw(&rgb, &cam, &d, None);
        assert!(colour_near(&unposed, pixels[0], annotate::HOLE_RADIUS_PX, annotate::POWER) >= 48);
        assert!(!unposed.pixels().any(|px| *px == OUTLINE));
        let ambiguous = HolePosesMsg { status: pose_status::AMBIGUOUS, ..p };
        assert!(!draw(&rgb, &cam, &d, Some(&ambiguous)).pixels().any(|px| *px == OUTLINE));
    }

    #[test]
    fn detections_meet_their_frames_and_poses() {
        let (p, pixels) = outlet();
        let d = detection(&p, &pixels, 0.2);
        let mut debug = DebugImages::default();
        assert!(debug.detection(&d).is_empty(), "no frame kept: nothing");
        for k in 0..6u64 {
            let (header, data) = frame(p.frame_id - 3 + k, p.capture_time_ns - 3 + k, PixelFormat::Bgr8);
            debug.add_frame(&header, &data).expect("frame");
        }
        assert_eq!(debug.len(), DebugImages::FRAMES_KEPT);
        // Another capture with the same frame id (a restarted camera) is not this frame.
        let restarted = DetectionMsg { capture_time_ns: 1, ..d };
        assert!(debug.detection(&restarted).is_empty());
        assert!(debug.detection(&d).is_empty(), "it waits for its poses");
        assert_eq!(debug.len(), 2 + 1, "the frames after it, and it");
        let other = HolePosesMsg { frame_id: 99, ..p };
        assert!(debug.poses(&other).is_none());
        let image = debug.poses(&p).expect("joined");
        assert_eq!((image.frame_id, image.capture_time_ns), (p.frame_id, p.capture_time_ns));
        assert!(image.rgb.pixels().any(|px| *px == OUTLINE), "drawn with the pose");
        assert!(debug.poses(&p).is_none(), "once");
        // A detection without an outlet is drawn at once; one with holes whose
        // poses never come, at the next detection or after a whole tick.
        let next = DetectionMsg { frame_id: p.frame_id + 1, capture_time_ns: p.capture_time_ns + 1, ..d };
        assert!(debug.detection(&next).is_empty());
        let empty =
            DetectionMsg { frame_id: p.frame_id + 2, capture_time_ns: p.capture_time_ns + 2, hole_count: 0, ..d };
        let done = debug.detection(&empty);
        assert_eq!(done.iter().map(|i| i.frame_id).collect::<Vec<_>>(), [p.frame_id + 1, p.frame_id + 2]);
        assert!(!done[0].rgb.pixels().any(|px| *px == OUTLINE));
        assert!(debug.is_empty());
        for k in 3..5 {
            let (header, data) = frame(p.frame_id + k, p.capture_time_ns + k, PixelFormat::Mono8);
            debug.add_frame(&header, &data).expect("frame");
        }
        let late = DetectionMsg { frame_id: p.frame_id + 3, capture_time_ns: p.capture_time_ns + 3, ..d };
        assert!(debug.detection(&late).is_empty());
        assert!(debug.tick().is_none(), "not a whole period yet");
        assert_eq!(debug.tick().map(|i| i.frame_id), Some(p.frame_id + 3));
        debug.clear();
        assert!(debug.is_empty());
    }

    #[test]
    fn the_debug_image_goes_out_as_rgb8_and_as_jpeg() {
        let (p, pixels) = outlet();
        let (header, data) = frame(p.frame_id, p.capture_time_ns, PixelFormat::Rgb8);
        let (rgb, cam) = rgb_of_frame(&header, &data).expect("frame");
        let image = DebugImage {
            frame_id: p.frame_id,
            capture_time_ns: p.capture_time_ns,
            rgb: draw(&rgb, &cam, &detection(&p, &pixels, 0.2), Some(&p)),
        };
        let jpeg = image.to_jpeg("cam", JPEG_QUALITY).expect("jpeg");
        assert_eq!(jpeg.format, JPEG_FORMAT);
        assert_eq!(&jpeg.data[..2], &[0xFF, 0xD8], "a JPEG");
        assert_eq!(jpeg.header.stamp, ns_to_time(p.capture_time_ns));
        let decoded = image_of_compressed(&jpeg).expect("decodes");
        let raw = image.clone().into_image("cam");
        assert_eq!((raw.width, raw.height, raw.step, raw.encoding.as_str()), (320, 240, 960, "rgb8"));
        assert_eq!(raw.data, image.rgb.as_raw().clone());
        assert_eq!(raw.header, jpeg.header);
        assert_eq!((decoded.width, decoded.height), (320, 240));
        // The JPEG is the drawn image within its loss: a few levels on average.
        let error: u64 = decoded.data.iter().zip(&raw.data).map(|(a, b)| u64::from(a.abs_diff(*b))).sum();
        let mean = error as f64 / raw.data.len() as f64;
        assert!(mean < 3.0, "mean error {mean}");
        let undrawn = DebugImage { rgb: rgb.clone(), ..image.clone() }.to_jpeg("cam", JPEG_QUALITY).expect("jpeg");
        let undrawn = image_of_compressed(&undrawn).expect("decodes");
        // About the first hole the marks survive compression.
        let (cx, cy) = (pixels[0].x.round() as usize, pixels[0].y.round() as usize);
        let mut difference = 0u64;
        for y in cy - 10..=cy + 10 {
            for x in cx - 10..=cx + 10 {
                let at = (y * 320 + x) * 3;
                difference +=
                    (0..3).map(|c| u64::from(decoded.data[at + c].abs_diff(undrawn.data[at + c]))).sum::<u64>();
            }
        }
        let near_hole = difference as f64 / (21.0 * 21.0 * 3.0);
        assert!(near_hole > 10.0 * mean, "about the hole {near_hole}, everywhere {mean}");
    }
}
