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
                    // OUTLET_TEST_LOGS=1 shows the services' logs when a test fails.
                    .stderr(if std::env::var_os("OUTLET_TEST_LOGS").is_some() {
                        Stdio::inherit()
                    } else {
                        Stdio::null()
                    })
                    .spawn()?,
            );
        }
        Ok(Self(children, domain.to_string()))
    }

    /// Detector, normal estimator and pose service of a 2x1 pipeline.
    #[allow(dead_code)] // not every test binary that shares this module uses it
    pub fn start_2x1_pipeline(domain: &str) -> std::io::Result<Self> {
        Self::start(domain, &[&["detector", "--template", "2x1"], &["normal"], &["pose", "--template", "2x1"]])
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

/// Publishes a frame and its stereo cloud (the cloud first, stamped alike: the
/// pose service joins a detection with the plane closest in time) into the
/// domain's shared memory, again with a new stamp every ~450 ms, until a hole
/// poses result that `accept` takes comes back; fails after `timeout` or when a
/// service dies.
#[allow(dead_code)] // not every test binary that shares this module uses it
pub fn feed_until(
    services: &mut Services,
    camera: &outlet_protocol::CameraModel,
    pixels: &[u8],
    cloud: &[f32],
    timeout: std::time::Duration,
    accept: impl Fn(&outlet_protocol::wire::HolePosesMsg) -> bool,
) -> Result<outlet_protocol::wire::HolePosesMsg, Box<dyn std::error::Error>> {
    use outlet_protocol::shm;
    use outlet_protocol::wire::{CloudHeader, FrameHeader, HolePosesMsg, PixelFormat, SCHEMA_VERSION, service};
    use std::time::{Duration, Instant};
    let node = shm::node(&services.1, "test")?;
    let frame_pub = shm::frames(&node)?.publisher_builder().initial_max_slice_len(pixels.len()).create()?;
    let cloud_pub = shm::clouds(&node)?.publisher_builder().initial_max_slice_len(cloud.len()).create()?;
    let frame_note = shm::events(&node, service::FRAMES)?.notifier_builder().create()?;
    let cloud_note = shm::events(&node, service::CLOUDS)?.notifier_builder().create()?;
    let pose_sub = shm::messages::<HolePosesMsg>(&node, service::HOLE_POSES)?.subscriber_builder().create()?;
    let started = Instant::now();
    let mut id = 0u64;
    loop {
        if started.elapsed() > timeout {
            return Err(format!("no accepted hole poses from the pipeline in {timeout:?}").into());
        }
        if !services.all_running() {
            return Err("a service died".into());
        }
        id += 1;
        let stamp = id * 1_000_000;
        let mut c = cloud_pub.loan_slice_uninit(cloud.len())?;
        *c.user_header_mut() = CloudHeader {
            schema_version: SCHEMA_VERSION,
            reserved: 0,
            frame_id: id,
            capture_time_ns: stamp,
            points: (cloud.len() / 3) as u64,
        };
        c.write_from_slice(cloud).send()?;
        cloud_note.notify()?;
        std::thread::sleep(Duration::from_millis(50));
        let mut f = frame_pub.loan_slice_uninit(pixels.len())?;
        *f.user_header_mut() = FrameHeader::new(id, stamp, PixelFormat::Rgb8, camera);
        f.write_from_slice(pixels).send()?;
        frame_note.notify()?;
        let wait = Instant::now();
        let mut got = None;
        while wait.elapsed() < Duration::from_millis(400) {
            if let Some(s) = pose_sub.receive()?
                && accept(s.payload())
            {
                got = Some(*s.payload());
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        if let Some(p) = got {
            return Ok(p);
        }
    }
}
