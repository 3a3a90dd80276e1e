//! What the detector's integration tests share: a plain rendered 2x1 scene and
//! the 2x1 template trained as the built-in one is.
#![allow(dead_code)] // each test file uses its own part

use nalgebra::{Matrix2, Point2, Point3, Vector3};
use outlet_detector::candidates::{CandidateParams, find_candidates};
use outlet_detector::descriptor::DescriptorParams;
use outlet_detector::detect::{Detection, Detector, DetectorParams};
use outlet_detector::grey_of;
use outlet_detector::refine::HoleShape;
use outlet_detector::template::{Template, TrainingImage, TrainingOptions, train_template_with};
use outlet_protocol::{CameraModel, OutletGeometry};
use outlet_sim::scenario::pose_looking;
use outlet_sim::scene::Scene;
use outlet_sim::{render_frame, sample_scene};
use std::sync::OnceLock;

pub fn camera() -> CameraModel {
    CameraModel { distortion: [0.0; 5], ..CameraModel::default_vga() }
}

/// A plain white 2x1 scene (no spots, cracks or occluders) seen from `distance`
/// m, `off_axis` and `azimuth` degrees, turned by `roll` degrees in the image.
pub fn plain_scene(index: u64, distance: f64, off_axis: f64, azimuth: f64, roll: f64) -> Scene {
    plain_scene_seen_by(&camera(), index, distance, off_axis, azimuth, roll)
}

/// [`plain_scene`] seen by another camera.
pub fn plain_scene_seen_by(
    camera: &CameraModel,
    index: u64,
    distance: f64,
    off_axis: f64,
    azimuth: f64,
    roll: f64,
) -> Scene {
    let mut scene = sample_scene("fw_2x1white", 4242, index, camera).expect("scene");
    scene.pose = pose_looking(Vector3::z(), distance, off_axis.to_radians(), azimuth.to_radians(), roll.to_radians());
    scene.plates.truncate(1);
    scene.plates[0].cracks.clear();
    scene.spots.clear();
    scene.occluders.clear();
    scene.sensor.jpeg_quality = None;
    scene
}

/// A 2x1 template trained as the built-in one is (outlet::templates), from four
/// rendered views and three backgrounds, once per test process.
pub fn template() -> &'static Template {
    static TEMPLATE: OnceLock<Template> = OnceLock::new();
    TEMPLATE.get_or_init(|| train_2x1(false))
}

/// [`template`] with far samples (`TrainingOptions::far_samples`).
pub fn template_with_far_samples() -> &'static Template {
    static TEMPLATE: OnceLock<Template> = OnceLock::new();
    TEMPLATE.get_or_init(|| train_2x1(true))
}

fn train_2x1(far_samples: bool) -> Template {
    let views = [(0.30, 0.0, 0.0), (0.35, 30.0, 0.0), (0.35, 30.0, 90.0), (0.45, 20.0, 225.0)];
    let params = CandidateParams::high_recall();
    let mut greys = Vec::new();
    let mut labels = Vec::new();
    for (k, &(d, a, z)) in views.iter().enumerate() {
        let mut scene = plain_scene(100 + k as u64, d, a, z, 0.0);
        scene.hole_glint = 0.0;
        scene.sensor.exposure = 1.0;
        scene.sensor.blur_sigma = 0.0;
        let frame = render_frame(&scene, "training");
        greys.push(grey_of(&frame.frame.image));
        labels.push(frame.truth.holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect::<Vec<_>>());
    }
    let training: Vec<TrainingImage> = greys
        .iter()
        .zip(labels)
        .map(|(g, holes)| TrainingImage { grey: g, holes, candidates: find_candidates(g, &params) })
        .collect();
    let backgrounds: Vec<_> = (0..3)
        .map(|i| {
            let scene = sample_scene("negative", 4242, i, &camera()).expect("scene");
            let g = grey_of(&render_frame(&scene, "background").frame.image);
            let c = find_candidates(&g, &params);
            (g, c)
        })
        .collect();
    let refs: Vec<_> = backgrounds.iter().map(|(g, c)| (g, c.clone())).collect();
    let geometry = OutletGeometry::builtin("2x1").expect("geometry");
    let options = TrainingOptions { far_samples, ..TrainingOptions::default() };
    train_template_with("2x1", geometry, &training, &refs, &DescriptorParams::default(), &options).expect("training")
}

pub fn detector() -> Detector {
    Detector::new(template().clone(), DetectorParams::default())
}

/// The largest distance of a reported hole from its true place (template order).
pub fn worst_error(d: &Detection, truth: &[Point2<f64>]) -> f64 {
    d.holes.iter().zip(truth).map(|(h, t)| (h.pixel - t).norm()).fold(0.0, f64::max)
}

pub fn truth_pixels(frame: &outlet_sim::RenderedFrame) -> Vec<Point2<f64>> {
    frame.truth.holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect()
}

/// The outlet-plane mm to image px Jacobian at a hole, from the true pose.
pub fn jacobian(scene: &outlet_sim::Scene, hole_mm: [f64; 2]) -> Matrix2<f64> {
    let project = |x: f64, y: f64| {
        scene.camera.project(&(scene.pose * Point3::new(x / 1000.0, y / 1000.0, 0.0))).expect("in front")
    };
    let c = project(hole_mm[0], hole_mm[1]);
    let dx = project(hole_mm[0] + 0.5, hole_mm[1]) - c;
    let dy = project(hole_mm[0], hole_mm[1] + 0.5) - c;
    Matrix2::new(dx.x, dy.x, dx.y, dy.y) * 2.0
}

/// Every hole of views `0..count` of `scenario` (seed `seed`, the default VGA
/// camera): the grey frame, the hole's true pixel, its mm-to-px Jacobian and
/// its outline, in template order.
pub fn each_rendered_hole(
    scenario: &str,
    seed: u64,
    count: u64,
    mut visit: impl FnMut(&image::GrayImage, Point2<f64>, &Matrix2<f64>, HoleShape),
) {
    let camera = CameraModel::default_vga();
    for index in 0..count {
        let scene = sample_scene(scenario, seed, index, &camera).expect("scene");
        let frame = render_frame(&scene, "x");
        let grey = grey_of(&frame.frame.image);
        let geometry = scene.geometry().expect("outlet");
        let outlines = HoleShape::us_outlines(&geometry);
        for ((hole, truth), outline) in geometry.holes.iter().zip(&frame.truth.holes).zip(outlines) {
            let j = jacobian(&scene, hole.position_mm);
            visit(&grey, Point2::new(truth.pixel[0], truth.pixel[1]), &j, outline);
        }
    }
}
