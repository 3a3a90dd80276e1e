//! A scene seen from a camera that moves: the arm's approach to the outlet. The
//! wall, the plates and the light stay where the scene put them; only the camera
//! (and the stereo pair on it) moves. Nothing here changes how a scene sampled
//! by [`crate::sample_scene`] renders.

use crate::RenderedFrame;
use crate::render::{Prepared, UndistortGrid};
use crate::scene::Scene;
use nalgebra::Isometry3;
use outlet_protocol::CameraModel;

/// `scene` seen by a camera at `camera_in_outlet` (the camera frame to the
/// outlet frame, metres), with `noise_seed` for the sensor noise and the cloud.
/// The light keeps its place relative to the wall as `scene` had it; a
/// realistic stereo bias keeps its error at the outlet.
pub fn seen_from(scene: &Scene, camera_in_outlet: &Isometry3<f64>, noise_seed: u64) -> Scene {
    let light_in_outlet = scene.pose.inverse_transform_point(&scene.light.position_cam_m);
    let pose = camera_in_outlet.inverse();
    let mut moved = scene.clone();
    moved.light.position_cam_m = pose * light_in_outlet;
    // A realistic pair's bias turns about the outlet, so that its offset alone
    // sets the error there (`StereoModel::realistic`): keep it about the outlet
    // wherever the camera goes. The default model's identity stays identity.
    let bias = &scene.stereo.bias;
    let (turn, old_about) = (bias.rotation, scene.pose.translation.vector);
    let offset = bias.translation.vector - (old_about - turn * old_about);
    let new_about = pose.translation.vector;
    moved.stereo.bias.translation.vector = new_about - turn * new_about + offset;
    moved.pose = pose;
    moved.noise_seed = noise_seed;
    moved
}

/// Renders frames of one camera again and again: the undistortion grid, which
/// depends on the camera alone, is computed once.
pub struct ApproachRenderer {
    camera: CameraModel,
    grid: UndistortGrid,
}

impl ApproachRenderer {
    pub fn new(camera: &CameraModel) -> Self {
        Self { camera: *camera, grid: UndistortGrid::new(camera) }
    }

    /// The image, the stereo cloud and the ground truth of `scene`, as
    /// [`crate::render_frame`] gives them; `None` when the scene's camera is
    /// not this renderer's.
    pub fn render(&self, scene: &Scene, image_name: &str) -> Option<RenderedFrame> {
        if scene.camera != self.camera {
            return None;
        }
        let prepared = Prepared::new(scene);
        Some(RenderedFrame {
            frame: crate::render::render_with(scene, &prepared, &self.grid),
            cloud: crate::cloud::stereo_cloud_with(scene, &prepared, &self.grid),
            truth: crate::ground_truth(scene, image_name),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scene_seen_from_its_own_camera_renders_the_same_bytes() {
        let camera = CameraModel::default_vga();
        let scene = crate::sample_scene("orange2x1", 3, 0, &camera).expect("scene");
        let same = seen_from(&scene, &scene.pose.inverse(), scene.noise_seed);
        let a = crate::render_frame(&scene, "a");
        let b = ApproachRenderer::new(&camera).render(&same, "a").expect("same camera");
        let diff = a
            .frame
            .image
            .pixels()
            .zip(b.frame.image.pixels())
            .filter(|(p, q)| p.0.iter().zip(q.0).any(|(x, y)| x.abs_diff(y) > 1));
        assert_eq!(diff.count(), 0);
    }

    #[test]
    fn a_closer_camera_sees_the_holes_further_apart() {
        let camera = CameraModel::default_vga();
        let scene = crate::sample_scene("fw_2x1white", 5, 0, &camera).expect("scene");
        let far = scene.pose.inverse();
        let near = far * nalgebra::Translation3::new(0.0, 0.0, 0.1);
        let renderer = ApproachRenderer::new(&camera);
        let spread = |s: &Scene| {
            let t = crate::ground_truth(s, "x");
            (t.holes[0].pixel[0] - t.holes[1].pixel[0]).hypot(t.holes[0].pixel[1] - t.holes[1].pixel[1])
        };
        let a = seen_from(&scene, &far, 1);
        let b = seen_from(&scene, &near, 1);
        assert!(spread(&b) > spread(&a) * 1.2, "{} vs {}", spread(&b), spread(&a));
        assert!(renderer.render(&b, "b").is_some());
    }

    #[test]
    fn a_realistic_stereo_bias_keeps_its_error_at_the_outlet_as_the_camera_moves() {
        let camera = CameraModel::default_vga();
        let scene = crate::sample_scene("rs_orange2x1", 2, 0, &camera).expect("scene");
        let error_at_outlet = |s: &Scene| {
            let outlet = nalgebra::Point3::from(s.pose.translation.vector);
            (s.stereo.bias * outlet - outlet).norm()
        };
        let near = scene.pose.inverse() * nalgebra::Translation3::new(0.02, 0.0, 0.12);
        let moved = seen_from(&scene, &near, 1);
        assert!((error_at_outlet(&moved) - error_at_outlet(&scene)).abs() < 1e-9);
        assert!(error_at_outlet(&scene) > 0.4e-3);
    }
}
