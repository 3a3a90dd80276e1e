//! The sidecar as it runs on a robot, for the trials: `outlet serve` detector,
//! normal and pose as child processes on a shared-memory domain of their own,
//! each rendered frame and its cloud published into it, and the hole poses read
//! back through the client library. One frame at a time: the arm moves only
//! after it has the result of the frame it took.

use anyhow::{Context, Result, bail};
use iceoryx2::prelude::*;
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use outlet::health::now_ns;
use outlet_client::{Client, HolePoses};
use outlet_protocol::CameraModel;
use outlet_protocol::shm;
use outlet_protocol::wire::{CloudHeader, DetectionMsg, FrameHeader, PixelFormat, SCHEMA_VERSION, service};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Longest wait for the detector's answer to a frame (it trains its template at
/// start; a loaded machine may be slow), and for the pose after a detection.
const DETECTION_WAIT: Duration = Duration::from_secs(10);
const POSE_WAIT: Duration = Duration::from_millis(500);

/// What the sidecar said about one frame.
#[derive(Debug, Clone)]
pub struct FrameResult {
    /// `ok`, `ambiguous`, `plane_mismatch`, `not_found` (the detector found no
    /// outlet) or `missing` (no answer in time).
    pub status: &'static str,
    pub poses: Option<HolePoses>,
    /// The detector's time for the frame (ms).
    pub detect_ms: Option<f64>,
    /// From the frame's stamp to the pose service's publication (ms).
    pub sidecar_ms: Option<f64>,
}

type FramePublisher = iceoryx2::port::publisher::Publisher<ipc::Service, [u8], FrameHeader>;
type CloudPublisher = iceoryx2::port::publisher::Publisher<ipc::Service, [f32], CloudHeader>;

/// A running sidecar for one template.
pub struct Pipeline {
    pub template: String,
    domain: String,
    children: Vec<Child>,
    frames: FramePublisher,
    clouds: CloudPublisher,
    frame_note: iceoryx2::port::notifier::Notifier<ipc::Service>,
    cloud_note: iceoryx2::port::notifier::Notifier<ipc::Service>,
    detections: iceoryx2::port::subscriber::Subscriber<ipc::Service, DetectionMsg, ()>,
    client: Client,
    next_id: u64,
    // Declared last: the ports above drop before their node.
    node: Node<ipc::Service>,
}

impl Pipeline {
    /// Starts the three services for `template` on `domain`, their logs in `logs`.
    pub fn start(domain: &str, template: &str, camera: &CameraModel, logs: &Path) -> Result<Self> {
        let node = shm::node(domain, "trials")?;
        let bytes = (camera.width * camera.height * 3) as usize;
        let frames = shm::frames(&node)?
            .publisher_builder()
            .initial_max_slice_len(bytes)
            .create()
            .map_err(|e| anyhow::anyhow!("frame publisher: {e:?}"))?;
        let clouds = shm::clouds(&node)?
            .publisher_builder()
            .initial_max_slice_len(bytes)
            .create()
            .map_err(|e| anyhow::anyhow!("cloud publisher: {e:?}"))?;
        let frame_note = shm::events(&node, service::FRAMES)?
            .notifier_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("frame notifier: {e:?}"))?;
        let cloud_note = shm::events(&node, service::CLOUDS)?
            .notifier_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("cloud notifier: {e:?}"))?;
        let detections = shm::messages::<DetectionMsg>(&node, service::DETECTIONS)?
            .subscriber_builder()
            .create()
            .map_err(|e| anyhow::anyhow!("detection subscriber: {e:?}"))?;
        let client = Client::builder().domain(domain).node_name("trials-client").connect().context("the client")?;
        let exe = std::env::current_exe().context("locating the outlet executable")?;
        let mut pipeline = Self {
            template: template.to_string(),
            domain: domain.to_string(),
            children: Vec::new(),
            frames,
            clouds,
            frame_note,
            cloud_note,
            detections,
            client,
            next_id: 0,
            node,
        };
        let services: [&[&str]; 3] =
            [&["normal"], &["pose", "--template", template], &["detector", "--template", template]];
        for args in services {
            let log_path = logs.join(format!("{}-{}.log", args[0], template));
            let log = std::fs::File::create(&log_path).with_context(|| format!("creating {}", log_path.display()))?;
            let child = Command::new(&exe)
                .arg("serve")
                .args(["--domain", domain])
                .args(args)
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(log)
                .spawn()
                .with_context(|| format!("starting {}", args[0]))?;
            pipeline.children.push(child);
        }
        Ok(pipeline)
    }

    /// Publishes the cloud and then the frame (one stamp, the pose service joins
    /// them by it) and waits for what the sidecar makes of them.
    pub fn process(&mut self, camera: &CameraModel, pixels: &[u8], cloud: &[[f32; 3]]) -> Result<FrameResult> {
        self.process_within(camera, pixels, cloud, DETECTION_WAIT)
    }

    /// Feeds `pixels` until the detector answers (it subscribes and trains its
    /// template after start), for at most a minute.
    pub fn warm_up(&mut self, camera: &CameraModel, pixels: &[u8], cloud: &[[f32; 3]]) -> Result<()> {
        let started = Instant::now();
        while started.elapsed() < Duration::from_secs(60) {
            let r = self.process_within(camera, pixels, cloud, Duration::from_millis(300))?;
            if r.detect_ms.is_some() {
                return Ok(());
            }
        }
        bail!("the {} pipeline gave no detection in 60 s", self.template)
    }

    fn process_within(
        &mut self,
        camera: &CameraModel,
        pixels: &[u8],
        cloud: &[[f32; 3]],
        detection_wait: Duration,
    ) -> Result<FrameResult> {
        self.next_id += 1;
        let id = self.next_id;
        let stamp = now_ns();
        let values: Vec<f32> = cloud.iter().flatten().copied().collect();
        let mut c = self.clouds.loan_slice_uninit(values.len()).map_err(|e| anyhow::anyhow!("cloud loan: {e:?}"))?;
        *c.user_header_mut() = CloudHeader {
            schema_version: SCHEMA_VERSION,
            reserved: 0,
            frame_id: id,
            capture_time_ns: stamp,
            points: cloud.len() as u64,
        };
        c.write_from_slice(&values).send().map_err(|e| anyhow::anyhow!("cloud send: {e:?}"))?;
        self.cloud_note.notify().map_err(|e| anyhow::anyhow!("cloud notify: {e:?}"))?;
        let mut f = self.frames.loan_slice_uninit(pixels.len()).map_err(|e| anyhow::anyhow!("frame loan: {e:?}"))?;
        *f.user_header_mut() = FrameHeader::new(id, stamp, PixelFormat::Rgb8, camera);
        f.write_from_slice(pixels).send().map_err(|e| anyhow::anyhow!("frame send: {e:?}"))?;
        self.frame_note.notify().map_err(|e| anyhow::anyhow!("frame notify: {e:?}"))?;

        let started = Instant::now();
        let mut detected: Option<(DetectionMsg, Instant)> = None;
        loop {
            while let Some(d) = self.detections.receive().map_err(|e| anyhow::anyhow!("detections: {e:?}"))? {
                if d.payload().frame_id == id {
                    detected = Some((*d.payload(), Instant::now()));
                }
            }
            if let Some((d, _)) = &detected
                && d.hole_count == 0
            {
                return Ok(FrameResult {
                    status: "not_found",
                    poses: None,
                    detect_ms: Some(d.detect_ms),
                    sidecar_ms: None,
                });
            }
            let waited_out = match &detected {
                Some((_, at)) => at.elapsed() > POSE_WAIT,
                None => started.elapsed() > detection_wait,
            };
            if waited_out {
                if let Some(why) = self.exited() {
                    bail!("{why}");
                }
                if detected.is_some() {
                    tracing::warn!(frame = id, template = %self.template, "no pose in time after a detection");
                }
                return Ok(FrameResult {
                    status: "missing",
                    poses: None,
                    detect_ms: detected.map(|(d, _)| d.detect_ms),
                    sidecar_ms: None,
                });
            }
            match self.client.wait_next(Duration::from_millis(20)) {
                Ok(Some(p)) if p.frame_id == id => {
                    let sidecar_ms = p.published.duration_since(p.capture_time).map_or(0.0, |d| d.as_secs_f64() * 1e3);
                    let detect_ms = detected.map(|(d, _)| d.detect_ms).or_else(|| self.detect_ms_of(id));
                    return Ok(FrameResult {
                        status: p.status.as_str(),
                        poses: Some(p),
                        detect_ms,
                        sidecar_ms: Some(sidecar_ms),
                    });
                }
                Ok(_) => {}
                Err(e) => tracing::warn!("client: {e}"),
            }
        }
    }

    /// Ctrl-C or SIGTERM arrived (iceoryx2's handler records it).
    pub fn interrupted(&self) -> bool {
        self.node.wait(Duration::ZERO).is_err()
    }

    fn detect_ms_of(&mut self, id: u64) -> Option<f64> {
        let mut found = None;
        while let Ok(Some(d)) = self.detections.receive() {
            if d.payload().frame_id == id {
                found = Some(d.payload().detect_ms);
            }
        }
        found
    }

    /// The first service that has exited, with its status.
    fn exited(&mut self) -> Option<String> {
        self.children.iter_mut().find_map(|c| match c.try_wait() {
            Ok(Some(status)) => Some(format!("a service of template {} exited ({status})", self.template)),
            _ => None,
        })
    }
}

impl Drop for Pipeline {
    /// SIGTERM, so that each service removes its shared memory; SIGKILL after 3 s.
    fn drop(&mut self) {
        for c in &self.children {
            if let Ok(pid) = i32::try_from(c.id()) {
                let _ = kill(Pid::from_raw(pid), Signal::SIGTERM);
            }
        }
        let deadline = Instant::now() + Duration::from_secs(3);
        for c in &mut self.children {
            while matches!(c.try_wait(), Ok(None)) && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = c.kill();
            let _ = c.wait();
        }
        shm::remove_node_counter(&self.domain);
    }
}
