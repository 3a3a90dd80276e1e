//! What the fuzz targets share: a 2x1 template trained once, a rendered outlet
//! to mutate, template headers with a valid checksum, and wire types read from
//! raw bytes as they arrive from shared memory.

use image::RgbImage;
use nalgebra::{Point2, Vector3};
use outlet_detector::candidates::{CandidateParams, find_candidates};
use outlet_detector::descriptor::DescriptorParams;
use outlet_detector::grey_of;
use outlet_detector::template::{TEMPLATE_FORMAT_VERSION, Template, TrainingImage, train_template};
use outlet_protocol::{CameraModel, OutletGeometry};
use outlet_sim::scenario::pose_looking;
use outlet_sim::{render_frame, sample_scene};
use std::sync::OnceLock;

/// The camera of the rendered images: 256x192, so that the detector target's
/// images stay within 256x256.
pub fn small_camera() -> CameraModel {
    CameraModel { width: 256, height: 192, fx: 210.0, fy: 210.0, cx: 127.5, cy: 95.5, distortion: [0.0; 5] }
}

/// A white 2x1 outlet seen from `distance` m, `off_axis` degrees.
fn rendered_2x1(camera: &CameraModel, distance: f64, off_axis_deg: f64) -> (RgbImage, Vec<Point2<f64>>) {
    let mut scene = sample_scene("fw_2x1white", 2010, 0, camera).expect("built-in scenario");
    scene.pose = pose_looking(Vector3::z(), distance, off_axis_deg.to_radians(), 0.0, 0.0);
    scene.spots.clear();
    scene.occluders.clear();
    scene.sensor.jpeg_quality = None;
    let frame = render_frame(&scene, "fuzz");
    let holes = frame.truth.holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect();
    (frame.frame.image, holes)
}

/// A 2x1 template trained once per process, from one rendered frontal view and
/// one rendered background, as `outlet train` trains from one photograph.
pub fn template_2x1() -> &'static Template {
    static TEMPLATE: OnceLock<Template> = OnceLock::new();
    TEMPLATE.get_or_init(|| {
        let camera = CameraModel { distortion: [0.0; 5], ..CameraModel::default_vga() };
        let (image, holes) = rendered_2x1(&camera, 0.30, 0.0);
        let grey = grey_of(&image);
        let params = CandidateParams::high_recall();
        let candidates = find_candidates(&grey, &params);
        let background = sample_scene("negative", 2010, 0, &camera).expect("built-in scenario");
        let background = grey_of(&render_frame(&background, "background").frame.image);
        let background_candidates = find_candidates(&background, &params);
        train_template(
            "2x1",
            OutletGeometry::us_2x1(),
            &[TrainingImage { grey: &grey, holes, candidates }],
            &[(&background, background_candidates)],
            &DescriptorParams::default(),
            false,
        )
        .expect("training on a rendered outlet")
    })
}

/// A 2x1 outlet rendered by [`small_camera`] at 35 cm, 20 degrees off axis: an
/// image the detector finds the outlet in, for the fuzzer to damage.
pub fn outlet_image() -> &'static RgbImage {
    &outlet_view().0
}

fn outlet_view() -> &'static (RgbImage, Vec<Point2<f64>>) {
    static VIEW: OnceLock<(RgbImage, Vec<Point2<f64>>)> = OnceLock::new();
    VIEW.get_or_init(|| rendered_2x1(&small_camera(), 0.35, 20.0))
}

/// The postcard payload of a tiny but real template (4x4 crops, 2 PCA
/// dimensions, 2 poses): a few hundred bytes for the fuzzer to damage behind a
/// valid header, so that decoding gets past the first field.
pub fn tiny_template_payload() -> &'static [u8] {
    static PAYLOAD: OnceLock<Vec<u8>> = OnceLock::new();
    PAYLOAD.get_or_init(|| {
        let (image, holes) = outlet_view();
        let grey = grey_of(image);
        let candidates = find_candidates(&grey, &CandidateParams::high_recall());
        let params =
            DescriptorParams { crop_size: 4, poses_per_feature: 2, noisy_copies: 1, pca_dims: 2, ..Default::default() };
        let view = TrainingImage { grey: &grey, holes: holes.clone(), candidates };
        let template = train_template("tiny", OutletGeometry::us_2x1(), &[view], &[], &params, false)
            .expect("training on a rendered outlet");
        let file = template.to_bytes().expect("a trained template encodes");
        file[24..].to_vec()
    })
}

/// A template file around `payload`: the magic, this build's version, the
/// payload's length and its CRC-32, so that the fuzzer reaches the decoder.
pub fn template_file(payload: &[u8]) -> Vec<u8> {
    let mut out = b"OUTLETTP".to_vec();
    out.extend_from_slice(&TEMPLATE_FORMAT_VERSION.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&crc32fast_hash(payload).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// CRC-32 (IEEE), bitwise: the fuzz crate needs no more than this.
fn crc32fast_hash(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

/// Types made of integers and floats only: every bit pattern is a value.
///
/// # Safety
/// Implement only for `repr(C)` types without padding-sensitive invariants,
/// references, `bool`s or enums.
pub unsafe trait Plain: Copy {}

unsafe impl Plain for outlet_protocol::wire::FrameHeader {}
unsafe impl Plain for outlet_protocol::wire::CloudHeader {}
unsafe impl Plain for outlet_protocol::wire::HolePosesMsg {}
unsafe impl Plain for outlet_protocol::wire::DetectionMsg {}
unsafe impl Plain for outlet_protocol::wire::WallPlaneMsg {}
unsafe impl Plain for outlet_protocol::wire::HeartbeatMsg {}
unsafe impl Plain for outlet_protocol::wire::TruthMsg {}

/// A value read from the front of `bytes` as a subscriber finds it in shared
/// memory (missing bytes read as zero), and the bytes after it.
pub fn read_plain<T: Plain>(bytes: &[u8]) -> (T, &[u8]) {
    let size = std::mem::size_of::<T>();
    let mut buffer = vec![0u8; size];
    let n = bytes.len().min(size);
    buffer[..n].copy_from_slice(&bytes[..n]);
    // SAFETY: `buffer` holds size_of::<T>() bytes and T accepts any bit pattern (Plain).
    let value = unsafe { std::ptr::read_unaligned(buffer.as_ptr().cast::<T>()) };
    (value, &bytes[n..])
}
