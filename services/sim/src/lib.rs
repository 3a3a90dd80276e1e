//! The simulated camera: renders a wall with an outlet (or without one) as a
//! camera image, a stereo point cloud and exact ground truth.
//!
//! ```
//! use outlet_sim::{sample_scene, render_frame};
//! let scene = sample_scene("orange2x1", 1, 0, &outlet_protocol::CameraModel::default_vga()).unwrap();
//! let frame = render_frame(&scene, "orange2x1_0000.png");
//! assert_eq!(frame.truth.holes.len(), 6);
//! ```

pub mod approach;
pub mod cloud;
pub mod render;
pub mod rng;
pub mod scenario;
pub mod scene;
pub mod shapes;
pub mod truth;

pub use cloud::stereo_cloud;
pub use render::{Frame, render};
pub use scenario::{
    REALISTIC_SCENARIOS, REALISTIC_STEREO_PREFIX, SCENARIOS, ScenarioError, paper_count, sample_scene, scenario_named,
};
pub use scene::Scene;
pub use truth::ground_truth;

use outlet_protocol::truth::GroundTruth;

/// Everything the simulated camera delivers for one scene.
#[derive(Debug, Clone)]
pub struct RenderedFrame {
    pub frame: Frame,
    /// Stereo cloud in the camera frame (metres), NaN where stereo fails.
    pub cloud: Vec<[f32; 3]>,
    pub truth: GroundTruth,
}

/// Renders the image, the cloud and the ground truth of a scene.
pub fn render_frame(scene: &Scene, image_name: &str) -> RenderedFrame {
    let prepared = render::Prepared::new(scene);
    let grid = render::UndistortGrid::new(&scene.camera);
    RenderedFrame {
        frame: render::render_with(scene, &prepared, &grid),
        cloud: cloud::stereo_cloud_with(scene, &prepared, &grid),
        truth: ground_truth(scene, image_name),
    }
}
