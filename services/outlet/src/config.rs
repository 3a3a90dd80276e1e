//! The sidecar's configuration: one TOML file for every service, each key with a
//! default, command-line flags over the file. A running service publishes the
//! configuration it resolved as a postcard snapshot, so `outlet status --config`
//! shows what each process really runs with.

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// The shared-memory domain: processes see each other only within one.
    pub domain: String,
    /// How often each service publishes its heartbeat (ms).
    pub heartbeat_ms: u64,
    pub detector: DetectorConfig,
    pub normal: NormalConfig,
    pub pose: PoseConfig,
    pub sim_camera: SimCameraConfig,
    /// `outlet serve ros2-bridge`: DDS domain, interfaces, frame id and topics.
    pub ros2: outlet_ros2_bridge::Ros2Config,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct DetectorConfig {
    /// `2x1`, `2x2` or a template file written by `outlet train`.
    pub template: String,
    /// Look for the outlet first in a window around where the last frame had
    /// it (the whole frame when that fails); every result is verified as a
    /// whole-frame one. `false`: every frame searched whole.
    pub tracking: bool,
    /// With tracking: the whole frame is searched at least every this many
    /// frames (a second outlet, a better view elsewhere).
    pub full_frame_every: u32,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NormalConfig {
    /// The stereo camera's depth noise at 1 m (m); it grows as z².
    pub sigma_at_1m: f64,
    /// Estimate the noise scale from each cloud rather than trusting `sigma_at_1m`.
    pub estimate_noise_scale: bool,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PoseConfig {
    /// The detector's template, for its hole geometry.
    pub template: String,
    /// A plane further than this in time from a detection is not used (ms).
    pub max_plane_age_ms: f64,
    /// How long a detection waits for the plane of its own frame (ms) before
    /// it is joined with the closest plane there is. A moving camera's closest
    /// other plane is of another place: at 50 ms, 1000 realistic plug-in trials
    /// on a loaded machine joined some detections with the frame before's
    /// plane or solved them in mono (14 `ambiguous` frames), and 1-2 poses per
    /// run came out 7-18 mm off beyond 5 sigma; at 250 ms, 8 `ambiguous` and
    /// none beyond 5 sigma (BENCHMARKS.md, session 14). A plane on time costs
    /// no wait.
    pub plane_wait_ms: f64,
    /// Standard deviation of a detected hole's pixel (px), for holes the detector
    /// gives no `sigma_px` of their own.
    pub pixel_sigma: f64,
    /// A plane whose pose leaves a larger RMS reprojection error (px) over the
    /// holes it kept cannot explain the detection (another wall, a wrong hole):
    /// the result says `plane_mismatch` and carries no pose.
    pub max_rms_px: f64,
    /// How far a receptacle face may stand from the template's nominal face
    /// offset (mm, one sigma; CONTRACT: 5.0 nominal, real faces differ by a few
    /// mm). It widens the plane's distance in the covariance. 0: the nominal
    /// is exact (true only of simulated scenes). Default: [`crate::ModelError::REAL_STEREO`].
    pub face_offset_sigma_mm: f64,
    /// A calibration bias of the stereo pair not in the plane fit's own
    /// covariance: on the wall normal (degrees, one sigma) ...
    pub plane_tilt_sigma_deg: f64,
    /// ... and on the wall distance (mm, one sigma). 0: none.
    pub plane_distance_sigma_mm: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimCameraConfig {
    /// Frames per second.
    pub rate_hz: f64,
    /// A scenario of `outlet render` (`fw_2x1white`, ..., `negative`).
    pub scenario: String,
    pub seed: u64,
    pub width: u32,
    pub height: u32,
    /// Publish a stereo cloud with each frame.
    pub cloud: bool,
    /// Render this many views once and replay them (0: render every frame).
    pub views: u32,
    /// Rendering every frame: each scene is seen for this many frames by a
    /// camera moving towards the outlet (5 mm per frame, as an arm approaching
    /// at 5 cm/s at 10 Hz), then the next scene: a video that tracking can
    /// follow, with a jump every so often. 1: a new scene every frame.
    pub frames_per_scene: u32,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            domain: outlet_protocol::shm::DEFAULT_DOMAIN.into(),
            heartbeat_ms: 1000,
            detector: DetectorConfig::default(),
            normal: NormalConfig::default(),
            pose: PoseConfig::default(),
            sim_camera: SimCameraConfig::default(),
            ros2: outlet_ros2_bridge::Ros2Config::default(),
        }
    }
}

impl Default for DetectorConfig {
    fn default() -> Self {
        let track = outlet_detector::track::TrackParams::default();
        Self { template: "2x1".into(), tracking: true, full_frame_every: track.full_frame_every }
    }
}

impl Default for NormalConfig {
    fn default() -> Self {
        let p = outlet_normal::PlaneParams::default();
        Self { sigma_at_1m: p.sigma_at_1m, estimate_noise_scale: p.estimate_noise_scale }
    }
}

impl Default for PoseConfig {
    fn default() -> Self {
        Self {
            template: "2x1".into(),
            max_plane_age_ms: 200.0,
            plane_wait_ms: 250.0,
            pixel_sigma: 0.25,
            max_rms_px: 2.0,
            face_offset_sigma_mm: crate::ModelError::REAL_STEREO.face_offset_sigma_mm,
            plane_tilt_sigma_deg: crate::ModelError::REAL_STEREO.plane_tilt_sigma_deg,
            plane_distance_sigma_mm: crate::ModelError::REAL_STEREO.plane_distance_sigma_mm,
        }
    }
}

impl Default for SimCameraConfig {
    fn default() -> Self {
        Self {
            rate_hz: 10.0,
            scenario: "fw_2x1white".into(),
            seed: 1,
            width: 640,
            height: 480,
            cloud: true,
            views: 0,
            frames_per_scene: 10,
        }
    }
}

impl Config {
    /// The file's configuration, or the defaults without a file.
    pub fn load(path: Option<&Path>) -> Result<Self> {
        let config = match path {
            None => Self::default(),
            Some(p) => {
                let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
                Self::parse(&text).with_context(|| format!("configuration {}", p.display()))?
            }
        };
        Ok(config)
    }

    pub fn parse(text: &str) -> Result<Self> {
        let config: Self = toml::from_str(text)?;
        config.check()?;
        Ok(config)
    }

    /// Refuses values no service can run with, naming the key.
    pub fn check(&self) -> Result<()> {
        outlet_protocol::shm::prefix(&self.domain).context("key `domain`")?;
        if self.heartbeat_ms == 0 || self.heartbeat_ms > 60_000 {
            bail!("key `heartbeat_ms`: {} is not in 1..=60000", self.heartbeat_ms);
        }
        if self.detector.tracking && !(2..=10_000).contains(&self.detector.full_frame_every) {
            bail!("key `detector.full_frame_every`: {} is not in 2..=10000", self.detector.full_frame_every);
        }
        if !(self.normal.sigma_at_1m > 0.0 && self.normal.sigma_at_1m < 1.0) {
            bail!("key `normal.sigma_at_1m`: {} is not in (0, 1) m", self.normal.sigma_at_1m);
        }
        if !(self.pose.max_plane_age_ms >= 0.0 && self.pose.max_plane_age_ms.is_finite()) {
            bail!("key `pose.max_plane_age_ms`: {} is not a duration", self.pose.max_plane_age_ms);
        }
        if !(self.pose.plane_wait_ms >= 0.0 && self.pose.plane_wait_ms <= 10_000.0) {
            bail!("key `pose.plane_wait_ms`: {} is not in 0..=10000", self.pose.plane_wait_ms);
        }
        for (key, v) in [
            ("face_offset_sigma_mm", self.pose.face_offset_sigma_mm),
            ("plane_tilt_sigma_deg", self.pose.plane_tilt_sigma_deg),
            ("plane_distance_sigma_mm", self.pose.plane_distance_sigma_mm),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                bail!("key `pose.{key}`: {v} is not a standard deviation");
            }
        }
        if !(self.pose.max_rms_px > 0.0 && self.pose.max_rms_px.is_finite()) {
            bail!("key `pose.max_rms_px`: {} is not positive", self.pose.max_rms_px);
        }
        if !(self.pose.pixel_sigma > 0.0 && self.pose.pixel_sigma.is_finite()) {
            bail!("key `pose.pixel_sigma`: {} is not positive", self.pose.pixel_sigma);
        }
        let sim = &self.sim_camera;
        if !(sim.rate_hz > 0.0 && sim.rate_hz <= 1000.0) {
            bail!("key `sim_camera.rate_hz`: {} is not in (0, 1000]", sim.rate_hz);
        }
        if outlet_sim::scenario_named(&sim.scenario).is_none() {
            bail!(
                "key `sim_camera.scenario`: {:?} is not one of {} (or rs_NAME, realistic stereo)",
                sim.scenario,
                outlet_sim::SCENARIOS.join(", ")
            );
        }
        if !(1..=10_000).contains(&sim.frames_per_scene) {
            bail!("key `sim_camera.frames_per_scene`: {} is not in 1..=10000", sim.frames_per_scene);
        }
        if !(64..=4096).contains(&sim.width) || !(48..=4096).contains(&sim.height) {
            bail!("keys `sim_camera.width`/`height`: {}x{} is not a camera size", sim.width, sim.height);
        }
        self.ros2.check().map_err(anyhow::Error::msg)?;
        Ok(())
    }

    /// The configuration as TOML, as a file would hold it.
    pub fn to_toml(&self) -> Result<String> {
        Ok(toml::to_string_pretty(self)?)
    }

    /// The compact snapshot a service publishes.
    pub fn snapshot(&self) -> Result<Vec<u8>> {
        Ok(postcard::to_allocvec(self)?)
    }

    pub fn from_snapshot(bytes: &[u8]) -> Result<Self> {
        Ok(postcard::from_bytes(bytes)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_partial_file_keeps_the_other_defaults() {
        let c = Config::parse("domain = \"robot1\"\n[pose]\nmax_plane_age_ms = 50\n").expect("parses");
        assert_eq!(c.domain, "robot1");
        assert_eq!(c.pose.max_plane_age_ms, 50.0);
        assert_eq!(c.pose.template, "2x1");
        assert_eq!(c.sim_camera, SimCameraConfig::default());
    }

    #[test]
    fn unknown_keys_and_bad_values_are_named() {
        let e = format!("{:#}", Config::parse("[pose]\nmax_plane_age = 5\n").expect_err("unknown key"));
        assert!(e.contains("max_plane_age"), "{e}");
        let e = format!("{:#}", Config::parse("heartbeat_ms = 0\n").expect_err("zero period"));
        assert!(e.contains("heartbeat_ms"), "{e}");
        let e = format!("{:#}", Config::parse("domain = \"a/b\"\n").expect_err("bad domain"));
        assert!(e.contains("domain"), "{e}");
        let e = format!("{:#}", Config::parse("[sim_camera]\nscenario = \"moon\"\n").expect_err("bad scenario"));
        assert!(e.contains("sim_camera.scenario"), "{e}");
    }

    #[test]
    fn the_ros2_table_is_read_and_checked() {
        let c = Config::parse("[ros2]\ndomain_id = 42\ninterfaces = [\"lo\"]\n[ros2.topics]\nimage = \"/cam/image\"\n")
            .expect("parses");
        assert_eq!(c.ros2.domain_id, 42);
        assert_eq!(c.ros2.interfaces, ["lo"]);
        assert_eq!(c.ros2.topics.image, "/cam/image");
        assert_eq!(c.ros2.topics.holes, "/outlet/holes", "the other topics keep their defaults");
        assert_eq!(c.ros2.frame_id, "camera_optical_frame");
        let e = format!("{:#}", Config::parse("[ros2]\ndomain_id = 300\n").expect_err("domain"));
        assert!(e.contains("ros2.domain_id"), "{e}");
        let e = format!("{:#}", Config::parse("[ros2.topics]\nholes = \"/a//b\"\n").expect_err("topic"));
        assert!(e.contains("ros2.topics.holes"), "{e}");
        let e = format!("{:#}", Config::parse("[ros2]\nnetworks = []\n").expect_err("unknown key"));
        assert!(e.contains("networks"), "{e}");
    }

    #[test]
    fn the_example_file_holds_the_defaults() {
        let text = include_str!("../../../outlet.example.toml");
        assert_eq!(Config::parse(text).expect("the example parses"), Config::default());
    }

    #[test]
    fn toml_and_snapshots_round_trip() {
        let mut c = Config::default();
        c.sim_camera.rate_hz = 12.5;
        c.detector.template = "my.template".into();
        assert_eq!(Config::parse(&c.to_toml().expect("toml")).expect("parses"), c);
        assert_eq!(Config::from_snapshot(&c.snapshot().expect("snapshot")).expect("decodes"), c);
    }
}
