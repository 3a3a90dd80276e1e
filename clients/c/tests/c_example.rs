//! `examples/follow.c`, compiled with `cc` against the static library and the
//! committed header, follows results this test publishes.

mod common;

use common::{POSITIONS_M, PoseService, poses, unique_domain};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

const LIB: &str = "liboutlet_client_c.a";

/// `target/<profile>/` of this test run: the test executable is in its `deps/`.
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("the test executable's path");
    let deps = exe.parent().expect("the test executable's folder");
    deps.parent().expect("target/<profile>/").to_path_buf()
}

/// The static library of this build. `cargo test` compiles it into `deps/`
/// along with the rlib the tests link; if it is missing (another runner, an
/// older cargo), build it with the same profile.
fn static_library() -> PathBuf {
    let profile_dir = profile_dir();
    for candidate in [profile_dir.join("deps").join(LIB), profile_dir.join(LIB)] {
        if candidate.is_file() {
            return candidate;
        }
    }
    let profile = match profile_dir.file_name().and_then(|n| n.to_str()) {
        Some("debug") | None => "dev".to_string(),
        Some(name) => name.to_string(),
    };
    let target_dir = profile_dir.parent().expect("the target folder");
    let status = Command::new(env!("CARGO"))
        .args(["build", "-p", "outlet-client-c", "--lib", "--profile", &profile, "--target-dir"])
        .arg(target_dir)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .status()
        .expect("running cargo build");
    assert!(status.success(), "cargo build -p outlet-client-c --profile {profile} failed");
    let built = profile_dir.join(LIB);
    assert!(built.is_file(), "cargo build did not make {}", built.display());
    built
}

/// Compiles `examples/follow.c` into the target folder.
fn compile_follow() -> PathBuf {
    let crate_dir = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out_dir = profile_dir().join("outlet-client-c-tests");
    std::fs::create_dir_all(&out_dir).expect("creating the output folder");
    let exe = out_dir.join(format!("follow-{}", std::process::id()));
    let output = Command::new(std::env::var_os("CC").unwrap_or_else(|| "cc".into()))
        .args(["-std=c11", "-Wall", "-Wextra", "-Werror", "-I"])
        .arg(crate_dir.join("include"))
        .arg(crate_dir.join("examples/follow.c"))
        .arg(static_library())
        .args(["-lpthread", "-ldl", "-lm", "-lrt", "-o"])
        .arg(&exe)
        .output()
        .expect("running cc (a C compiler is needed for this test)");
    assert!(output.status.success(), "cc failed:\n{}", String::from_utf8_lossy(&output.stderr));
    exe
}

#[test]
fn follow_c_prints_the_published_hole_positions() {
    let domain = unique_domain();
    let follow = compile_follow();
    let pose = PoseService::open(&domain);
    let mut child = Command::new(&follow)
        .args([domain.0.as_str(), "3"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("starting follow");

    // The program sees only what is published after it has connected: publish
    // until it has had its three results and exits.
    let deadline = Instant::now() + Duration::from_secs(30);
    let mut frame = 0;
    let status = loop {
        if let Some(status) = child.try_wait().expect("polling follow") {
            break status;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            panic!("follow did not finish within 30 s");
        }
        frame += 1;
        pose.send(poses(frame));
        std::thread::sleep(Duration::from_millis(50));
    };
    let output = child.wait_with_output().expect("follow's output");
    let _ = std::fs::remove_file(&follow);
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(status.success(), "follow failed: {status}\n{stdout}\n{}", String::from_utf8_lossy(&output.stderr));

    assert_eq!(stdout.lines().filter(|l| l.starts_with("frame ")).count(), 3, "{stdout}");
    assert!(stdout.contains("(plane): 3 holes"), "{stdout}");
    for (kind, [x, y, z]) in ["power", "power", "ground"].into_iter().zip(POSITIONS_M) {
        let line = format!("  {kind:<6} {x:.6} {y:.6} {z:.6} m");
        assert_eq!(stdout.matches(&line).count(), 3, "no {line:?} three times in:\n{stdout}");
    }
}
