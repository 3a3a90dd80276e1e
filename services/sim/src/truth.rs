//! The exact ground truth of a scene, as `CONTRACT.md` records it.

use crate::scene::Scene;
use nalgebra::{Point3, Vector3};
use outlet_protocol::truth::{CameraJson, GroundTruth, HoleJson, PlaneJson, PoseJson, ViewJson};

/// Ground truth of a scene whose image is written as `image_name`.
pub fn ground_truth(scene: &Scene, image_name: &str) -> GroundTruth {
    let (normal, distance) = scene.wall_plane_cam();
    let holes = scene
        .geometry()
        .map(|g| {
            g.holes
                .iter()
                .map(|h| {
                    let p = scene.pose * Point3::new(h.position_mm[0] / 1000.0, h.position_mm[1] / 1000.0, 0.0);
                    // Scenes are drawn with every hole in view, so the projection exists.
                    let px = scene.camera.project(&p).map_or([f64::NAN; 2], |q| [q.x, q.y]);
                    HoleJson { kind: h.kind, pixel: px, position_m: Some([p.x, p.y, p.z]) }
                })
                .collect()
        })
        .unwrap_or_default();
    let found = scene.template.is_some();
    GroundTruth {
        image: image_name.to_string(),
        scenario: scene.scenario.clone(),
        template: scene.template.clone(),
        search_template: scene.search_template.clone(),
        pose: found.then(|| PoseJson::from_isometry(&scene.pose)),
        holes,
        wall_plane: PlaneJson { normal: [normal.x, normal.y, normal.z], distance_m: distance },
        camera: CameraJson::from(&scene.camera),
        view: Some(view(scene)),
    }
}

/// Distance, obliquity and in-image roll of the outlet.
pub fn view(scene: &Scene) -> ViewJson {
    let t = scene.pose.translation.vector;
    let into_wall = scene.pose.rotation * Vector3::z();
    let off_axis = t.normalize().dot(&into_wall).clamp(-1.0, 1.0).acos().to_degrees();
    let origin = scene.pose * Point3::origin();
    let below = scene.pose * Point3::new(0.0, 0.01, 0.0);
    let roll_deg = match (scene.camera.project(&origin), scene.camera.project(&below)) {
        (Some(a), Some(b)) => (-(b.x - a.x)).atan2(b.y - a.y).to_degrees(),
        _ => 0.0,
    };
    ViewJson { distance_m: t.norm(), off_axis_deg: off_axis, roll_deg, ground_up: roll_deg.abs() > 90.0 }
}
