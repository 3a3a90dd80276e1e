//! Helpers for the tests that span crates and processes: the `outlet`
//! executable, and a sidecar of service processes that a test can kill and
//! restart one by one; rendered scenes the detector finds ([`scenes`]); the
//! Fast DDS test peer ([`fastdds`]).

pub mod fastdds;
pub mod scenes;

use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

/// A command that runs `program` with umask 022, for the tests' builds (cargo, the
/// C++ peer). iceoryx2 narrows the process's umask for a moment while it binds
/// an event socket, and a child forked by another test thread in that moment
/// inherits it: a cargo build under umask 0177 writes build scripts it cannot
/// execute (seen here: every test that needed the rebuild failed with
/// "Permission denied").
pub fn builder(program: &std::ffi::OsStr) -> Command {
    let mut command = Command::new("sh");
    command.args(["-c", "umask 022 && exec \"$0\" \"$@\""]).arg(program);
    command
}

/// The newest modification time of the workspace's sources and manifests.
fn newest_source(dir: &std::path::Path) -> Option<std::time::SystemTime> {
    let mut newest = None;
    for entry in std::fs::read_dir(dir).ok()?.flatten() {
        let path = entry.path();
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if name.starts_with('.') || name == "target" {
            continue;
        }
        let t = if path.is_dir() {
            newest_source(&path)
        } else if name.ends_with(".rs") || name.ends_with(".toml") || name == "Cargo.lock" {
            entry.metadata().ok()?.modified().ok()
        } else {
            None
        };
        newest = newest.max(t);
    }
    newest
}

/// The `outlet` executable of this build profile. `cargo test --workspace`
/// has built it already (the `outlet` package's own tests need it); built here
/// when it is older than the sources, as with `cargo test -p outlet-tests`.
pub fn outlet_exe() -> Result<PathBuf, String> {
    static EXE: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    EXE.get_or_init(|| {
        let test_exe = std::env::current_exe().map_err(|e| e.to_string())?;
        // target/<profile>/deps/<test> -> target/<profile>
        let profile_dir = test_exe.parent().and_then(|d| d.parent()).ok_or("no target directory")?.to_path_buf();
        let target_dir = profile_dir.parent().ok_or("no target directory")?;
        let profile = profile_dir.file_name().and_then(|n| n.to_str()).ok_or("no profile")?;
        let exe = profile_dir.join("outlet");
        let workspace = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).parent().ok_or("no workspace")?;
        let built = std::fs::metadata(&exe).and_then(|m| m.modified()).ok();
        if built.is_some() && built >= newest_source(workspace) {
            return Ok(exe);
        }
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut build = builder(cargo.as_ref());
        build.args(["build", "--quiet", "-p", "outlet", "--bin", "outlet", "--target-dir"]).arg(target_dir);
        if profile != "debug" {
            build.args(["--profile", if profile == "release" { "release" } else { profile }]);
        }
        let status = build.status().map_err(|e| format!("running cargo build: {e}"))?;
        if !status.success() {
            return Err(format!("cargo build -p outlet failed: {status}"));
        }
        Ok(exe)
    })
    .clone()
}

/// A shared-memory domain for one test alone.
pub fn domain(test: &str) -> String {
    format!("{test}-{}", std::process::id())
}

/// Service processes of one domain, by name; killed when dropped.
pub struct Sidecar {
    pub domain: String,
    pub logs: PathBuf,
    children: Vec<(String, Vec<String>, Child)>,
}

impl Sidecar {
    pub fn new(domain: &str) -> std::io::Result<Self> {
        let logs = std::env::temp_dir().join(format!("outlet-test-{domain}"));
        std::fs::create_dir_all(&logs)?;
        Ok(Self { domain: domain.into(), logs, children: Vec::new() })
    }

    /// Starts `outlet serve --domain D <service> <args>`; its log goes to `logs/<service>.log`.
    pub fn start(&mut self, service: &str, args: &[&str]) -> Result<(), String> {
        let domain = self.domain.clone();
        self.spawn(&["--domain", &domain, "--heartbeat-ms", "200"], service, args)
    }

    /// Starts `outlet serve --config FILE <service> <args>`: everything, the
    /// domain too, from the file (whose `domain` should be this sidecar's); its
    /// log goes to `logs/<service>.log`.
    pub fn start_with_config(&mut self, config: &std::path::Path, service: &str, args: &[&str]) -> Result<(), String> {
        let config = config.to_str().ok_or_else(|| format!("configuration path {} is not UTF-8", config.display()))?;
        self.spawn(&["--config", config], service, args)
    }

    /// `outlet serve <serve_args> <service> <args>`, remembered for restarts.
    fn spawn(&mut self, serve_args: &[&str], service: &str, args: &[&str]) -> Result<(), String> {
        let exe = outlet_exe()?;
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(self.log_path(service))
            .map_err(|e| e.to_string())?;
        let child = Command::new(exe)
            .arg("serve")
            .args(serve_args)
            .arg(service)
            .args(args)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(log)
            .spawn()
            .map_err(|e| format!("starting {service}: {e}"))?;
        let args = args.iter().map(|a| a.to_string()).collect();
        self.children.push((service.into(), args, child));
        Ok(())
    }

    pub fn log_path(&self, service: &str) -> PathBuf {
        self.logs.join(format!("{service}.log"))
    }

    pub fn pid(&self, service: &str) -> Option<u32> {
        self.children.iter().find(|c| c.0 == service).map(|c| c.2.id())
    }

    /// SIGKILL: the service gets no chance to clean up after itself.
    pub fn kill9(&mut self, service: &str) -> Result<Vec<String>, String> {
        let k = self.children.iter().position(|c| c.0 == service).ok_or(format!("no {service}"))?;
        let (_, args, mut child) = self.children.remove(k);
        child.kill().map_err(|e| e.to_string())?;
        child.wait().map_err(|e| e.to_string())?;
        Ok(args)
    }

    /// `outlet.toml` in the logs folder for a 2x1 pipeline with the ROS 2 bridge
    /// on the loopback interface only, in DDS domain `dds_domain`, the camera
    /// frame `frame_id`: what the ROS 2 interop tests run with.
    pub fn write_ros2_loopback_config(&self, dds_domain: u32, frame_id: &str) -> std::io::Result<PathBuf> {
        let config = self.logs.join("outlet.toml");
        std::fs::write(
            &config,
            format!(
                r#"domain = "{}"
heartbeat_ms = 200

[detector]
template = "2x1"

[pose]
template = "2x1"
# A detection waits for the wall plane of its own frame.
plane_wait_ms = 2000.0

[ros2]
domain_id = {dds_domain}
interfaces = ["lo"]
frame_id = "{frame_id}"
"#,
                self.domain
            ),
        )?;
        Ok(config)
    }

    /// SIGTERM, as a robot's supervisor stops a service, and waits (at most
    /// 5 s) for it to end.
    pub fn terminate(&mut self, service: &str) -> Result<(), String> {
        use nix::sys::signal::{Signal, kill};
        let k = self.children.iter().position(|c| c.0 == service).ok_or(format!("no {service}"))?;
        let (_, _, mut child) = self.children.remove(k);
        let pid = i32::try_from(child.id()).map_err(|e| e.to_string())?;
        kill(nix::unistd::Pid::from_raw(pid), Signal::SIGTERM).map_err(|e| e.to_string())?;
        let deadline = Instant::now() + Duration::from_secs(5);
        while matches!(child.try_wait(), Ok(None)) {
            if Instant::now() > deadline {
                let _ = child.kill();
                let _ = child.wait();
                return Err(format!("{service} did not end within 5 s of SIGTERM"));
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(())
    }

    /// The name of a service that is no longer running, if any.
    pub fn dead(&mut self) -> Option<String> {
        self.children.iter_mut().find_map(|c| (!matches!(c.2.try_wait(), Ok(None))).then(|| c.0.clone()))
    }
}

impl Drop for Sidecar {
    /// SIGTERM, so that each service removes its shared memory; SIGKILL after 3 s.
    fn drop(&mut self) {
        use nix::sys::signal::{Signal, kill};
        for (_, _, c) in &self.children {
            if let Ok(pid) = i32::try_from(c.id()) {
                let _ = kill(nix::unistd::Pid::from_raw(pid), Signal::SIGTERM);
            }
        }
        let deadline = Instant::now() + Duration::from_secs(3);
        for (_, _, c) in &mut self.children {
            while matches!(c.try_wait(), Ok(None)) && Instant::now() < deadline {
                std::thread::sleep(Duration::from_millis(10));
            }
            let _ = c.kill();
            let _ = c.wait();
        }
        outlet_protocol::shm::remove_node_counter(&self.domain);
    }
}

/// The shared-memory files of a domain, with their permission bits.
pub fn shm_files(domain: &str) -> Vec<(String, u32)> {
    use std::os::unix::fs::PermissionsExt;
    let prefix = format!("{domain}_");
    let Ok(entries) = std::fs::read_dir("/dev/shm") else { return Vec::new() };
    let mut files: Vec<(String, u32)> = entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_string_lossy().to_string();
            let mode = e.metadata().ok()?.permissions().mode() & 0o777;
            name.starts_with(&prefix).then_some((name, mode))
        })
        .collect();
    files.sort();
    files
}

/// Polls `f` until it gives a value or `timeout` passes.
pub fn wait_for<T>(timeout: Duration, mut f: impl FnMut() -> Option<T>) -> Option<T> {
    let start = Instant::now();
    loop {
        if let Some(v) = f() {
            return Some(v);
        }
        if start.elapsed() > timeout {
            return None;
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}
