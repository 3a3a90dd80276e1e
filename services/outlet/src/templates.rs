//! The built-in templates `2x1` and `2x2`, trained as the paper trains: from ONE
//! image of an outlet (here rendered: white, frontal, 30 cm, even light) and
//! background images (rendered walls, plates and switches without an outlet).

use anyhow::{Context, Result};
use nalgebra::{Point2, Vector3};
use outlet_detector::candidates::{CandidateParams, find_candidates};
use outlet_detector::descriptor::DescriptorParams;
use outlet_detector::grey_of;
use outlet_detector::template::{Template, TrainingImage, train_template};
use outlet_protocol::{CameraModel, OutletGeometry};
use outlet_sim::scenario::pose_looking;
use outlet_sim::{render_frame, sample_scene};

/// The seed of the built-in training scenes: fixed, so templates are reproducible.
const TRAINING_SEED: u64 = 2010;

/// A built-in template by name, or a template file.
pub fn load(name_or_path: &str) -> Result<Template> {
    match name_or_path {
        "2x1" | "2x2" => builtin(name_or_path),
        path => Template::read(std::path::Path::new(path)).map_err(Into::into),
    }
}

/// Trains a built-in template.
pub fn builtin(name: &str) -> Result<Template> {
    let geometry = OutletGeometry::builtin(name)?;
    let camera = CameraModel { distortion: [0.0; 5], ..CameraModel::default_vga() };
    let scenario = if name == "2x1" { "fw_2x1white" } else { "white2x2" };
    let mut scene = sample_scene(scenario, TRAINING_SEED, 0, &camera)?;
    scene.pose = pose_looking(Vector3::z(), 0.30, 0.0, 0.0, 0.0);
    scene.plates.truncate(1);
    scene.spots.clear();
    scene.occluders.clear();
    scene.hole_glint = 0.0;
    scene.light.position_cam_m = nalgebra::Point3::new(0.1, -0.3, -0.1);
    scene.sensor.exposure = 1.0;
    scene.sensor.blur_sigma = 0.0;
    scene.sensor.jpeg_quality = None;
    scene.plates[0].cracks.clear();
    let frame = render_frame(&scene, "training");
    let grey = grey_of(&frame.frame.image);
    let holes: Vec<Point2<f64>> = frame.truth.holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect();
    let params = CandidateParams::default();
    let candidates = find_candidates(&grey, &params);
    let backgrounds: Vec<_> = (0..3)
        .map(|i| {
            let scene = sample_scene("negative", TRAINING_SEED, i, &camera)?;
            let g = grey_of(&render_frame(&scene, "background").frame.image);
            let c = find_candidates(&g, &params);
            Ok((g, c))
        })
        .collect::<Result<_>>()?;
    let refs: Vec<_> = backgrounds.iter().map(|(g, c)| (g, c.clone())).collect();
    train_template(
        name,
        geometry,
        &TrainingImage { grey: &grey, holes },
        &candidates,
        &refs,
        &DescriptorParams::default(),
        false,
    )
    .with_context(|| format!("training the built-in {name} template"))
}
