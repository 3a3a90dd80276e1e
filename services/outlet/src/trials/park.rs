//! Where a trial starts: the scene (outlet kind, colour, plate, light,
//! distractors, drawn as the simulator's scenarios draw them) and the pose the
//! robot parks the camera at, 30-60 cm from the outlet, up to 40 degrees to one
//! side, above or below it, the outlet somewhere in the image.

use anyhow::{Result, bail};
use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};
use outlet_protocol::CameraModel;
use outlet_protocol::geometry::OutletGeometry;
use outlet_sim::rng::SimRng;
use outlet_sim::scenario::image_seed;
use outlet_sim::{REALISTIC_STEREO_PREFIX, SCENARIOS, Scene, sample_scene, scenario_named};

/// The mixes `--scenario` knows besides the simulator's scenario names.
pub const MIXES: [&str; 3] = ["default", "hard", "realistic"];

/// The scenarios with an outlet in them (all but the negatives).
fn positives() -> Vec<&'static str> {
    SCENARIOS.iter().copied().filter(|s| *s != "negative").collect()
}

/// The start of one trial.
#[derive(Debug, Clone)]
pub struct Setup {
    /// The mix or scenario name it was drawn from, and the scenario drawn.
    pub mix: String,
    pub scenario: String,
    pub scene: Scene,
    /// The camera (tool) frame to the outlet frame at the start (m).
    pub start: Isometry3<f64>,
    pub range_m: f64,
    /// Turned this far to the side of the wall's normal (signed, degrees).
    pub yaw_deg: f64,
    pub pitch_deg: f64,
    pub ground_up: bool,
    /// The sensor's exposure multiplier: `dim` below 0.6, `bright` above 1.4.
    pub exposure: f64,
}

impl Setup {
    pub fn light(&self) -> &'static str {
        if self.exposure < 0.6 {
            "dim"
        } else if self.exposure > 1.4 {
            "bright"
        } else {
            "normal"
        }
    }
}

/// Checks `--scenario` names: a mix or a scenario of the simulator.
pub fn check_mix(name: &str) -> Result<()> {
    if MIXES.contains(&name) || scenario_named(name).is_some() {
        return Ok(());
    }
    bail!(
        "unknown --scenario {name:?}: one of {} or a scenario ({}, each also with rs_)",
        MIXES.join(", "),
        SCENARIOS.join(", ")
    )
}

/// Trial `index` of a run seeded `seed` on `mix`: the same whatever the count.
pub fn draw(mix: &str, seed: u64, index: u64, camera: &CameraModel) -> Result<Setup> {
    let mut rng = SimRng::new(image_seed(seed, "trials", index));
    let hard = mix == "hard";
    let scenario = match mix {
        "default" => rng.pick(&positives()).to_string(),
        "realistic" => format!("{REALISTIC_STEREO_PREFIX}{}", rng.pick(&positives())),
        // Specular plates half the time, any outlet the other half.
        "hard" if rng.chance(0.5) => "specular2x2".to_string(),
        "hard" => rng.pick(&positives()).to_string(),
        named => named.to_string(),
    };
    let mut scene = None;
    for attempt in 0..5u64 {
        if let Ok(s) = sample_scene(&scenario, seed, index + attempt * 1_000_000_007, camera) {
            scene = Some(s);
            break;
        }
    }
    let Some(mut scene) = scene else { bail!("trial {index}: no scene of {scenario} could be drawn") };
    let ground_up = hard || outlet_sim::truth::view(&scene).ground_up;
    if hard {
        scene.sensor.exposure = rng.range(0.2, 0.5) as f32;
    }
    let geometry = scene.geometry().unwrap_or_else(OutletGeometry::us_2x1);
    for _ in 0..100 {
        let range_m = rng.range(0.30, 0.60);
        let yaw =
            if hard { rng.range(25.0, 40.0) } else { rng.range(0.0, 40.0) } * if rng.chance(0.5) { -1.0 } else { 1.0 };
        let pitch = rng.range(-15.0, 15.0);
        let roll = rng.range(-5.0, 5.0);
        // Where in the image the robot's parking puts the outlet.
        let target = Point2::new(
            camera.cx + rng.range(-0.2, 0.2) * camera.width as f64,
            camera.cy + rng.range(-0.2, 0.2) * camera.height as f64,
        );
        // The camera in the upright wall frame (x right, y down, z into the wall).
        let turn = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), yaw.to_radians())
            * UnitQuaternion::from_axis_angle(&Vector3::x_axis(), pitch.to_radians())
            * UnitQuaternion::from_axis_angle(&Vector3::z_axis(), roll.to_radians());
        let sight = turn * camera.ray(target).normalize();
        let upright = Isometry3::from_parts(Translation3::from(-sight * range_m), turn);
        // A receptacle mounted ground up: its outlet frame is half a turn from upright.
        let mounting =
            if ground_up { Isometry3::rotation(Vector3::z() * std::f64::consts::PI) } else { Isometry3::identity() };
        let start = mounting * upright;
        let to_camera = start.inverse();
        let inside = geometry.holes.iter().all(|h| {
            camera
                .project(&(to_camera * Point3::new(h.position_mm[0] / 1e3, h.position_mm[1] / 1e3, 0.0)))
                .is_some_and(|px| camera.contains(px, 12.0))
        });
        if inside {
            return Ok(Setup {
                mix: mix.to_string(),
                scenario,
                exposure: scene.sensor.exposure as f64,
                scene,
                start,
                range_m,
                yaw_deg: yaw,
                pitch_deg: pitch,
                ground_up,
            });
        }
    }
    bail!("trial {index}: no parking pose with the outlet in view")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parked_camera_sees_the_outlet_from_30_to_60_cm() {
        let camera = CameraModel::default_vga();
        for i in 0..20 {
            let s = draw("default", 3, i, &camera).expect("setup");
            let outlet = s.start.inverse() * Point3::origin();
            assert!((0.25..0.65).contains(&outlet.coords.norm()), "{}", outlet.coords.norm());
            assert!(outlet.z > 0.0);
            assert!(s.yaw_deg.abs() <= 40.0);
        }
    }

    #[test]
    fn the_hard_mix_is_ground_up_dim_and_oblique() {
        let camera = CameraModel::default_vga();
        for i in 0..10 {
            let s = draw("hard", 3, i, &camera).expect("setup");
            assert!(s.ground_up && s.yaw_deg.abs() >= 25.0 && s.light() == "dim", "{s:?}");
            assert!(outlet_sim::truth::view(&outlet_sim::approach::seen_from(&s.scene, &s.start, 1)).ground_up);
        }
        assert!(check_mix("hard").is_ok() && check_mix("rs_orange2x1").is_ok() && check_mix("nope").is_err());
    }
}
