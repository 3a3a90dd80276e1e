//! Service processes for the tests: started from the built `outlet`, ended
//! however the test ends.

use std::process::{Child, Command, Stdio};

pub struct Services(pub Vec<Child>, String);

impl Services {
    /// Starts `outlet serve --domain DOMAIN ...` once per argument list.
    pub fn start(domain: &str, args: &[&[&str]]) -> std::io::Result<Self> {
        let mut children = Vec::new();
        for a in args {
            children.push(
                Command::new(env!("CARGO_BIN_EXE_outlet"))
                    .arg("serve")
                    .args(["--domain", domain])
                    .args(*a)
                    .stdout(Stdio::null())
                    .stderr(Stdio::null())
                    .spawn()?,
            );
        }
        Ok(Self(children, domain.to_string()))
    }

    /// True while every service is running.
    pub fn all_running(&mut self) -> bool {
        self.0.iter_mut().all(|c| matches!(c.try_wait(), Ok(None)))
    }
}

impl Drop for Services {
    /// SIGTERM, so that each service removes its shared memory; SIGKILL after 3 s.
    fn drop(&mut self) {
        use nix::sys::signal::{Signal, kill};
        for c in &self.0 {
            if let Ok(pid) = i32::try_from(c.id()) {
                let _ = kill(nix::unistd::Pid::from_raw(pid), Signal::SIGTERM);
            }
        }
        let deadline = std::time::Instant::now() + std::time::Duration::from_secs(3);
        for c in &mut self.0 {
            while matches!(c.try_wait(), Ok(None)) && std::time::Instant::now() < deadline {
                std::thread::sleep(std::time::Duration::from_millis(10));
            }
            let _ = c.kill();
            let _ = c.wait();
        }
        outlet_protocol::shm::remove_node_counter(&self.1);
    }
}

/// A shared-memory domain of this test process alone.
pub fn domain(test: &str) -> String {
    format!("{test}-{}", std::process::id())
}

/// The first scene of `scenario` (seeds 0..100) seen within `max_off_axis_deg`
/// of frontal: one the detector finds every hole of.
#[allow(dead_code)] // not every test binary that shares this module uses it
pub fn frontal_scene(
    scenario: &str,
    camera: &outlet_protocol::CameraModel,
    max_off_axis_deg: f64,
) -> Result<outlet_sim::Scene, String> {
    (0..100)
        .filter_map(|s| outlet_sim::sample_scene(scenario, s, 0, camera).ok())
        .find(|scene| outlet_sim::truth::view(scene).off_axis_deg < max_off_axis_deg)
        .ok_or_else(|| format!("no scene of {scenario} within {max_off_axis_deg} degrees of frontal"))
}
