//! The Fast DDS test peer (`tests/fastdds/ros2_peer.cpp`): built here with the
//! system's C++ compiler against Debian's `libfastrtps-dev` and
//! `libfastcdr-dev`, once per version of its sources (cached in the target
//! directory), and fed scenes as raw files it can read without an image or
//! PLY library.

use outlet_protocol::truth::GroundTruth;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// What the peer needs, for error messages.
pub const PACKAGES: &str = "libfastrtps-dev libfastcdr-dev g++";

/// The Fast DDS XML profile that confines the peer to 127.0.0.1
/// (`FASTRTPS_DEFAULT_PROFILES_FILE`); the peer refuses to run without it.
pub fn loopback_profile() -> PathBuf {
    workspace().join("tests/dds/fastdds-loopback.xml")
}

fn workspace() -> PathBuf {
    let tests = Path::new(env!("CARGO_MANIFEST_DIR"));
    tests.parent().unwrap_or(tests).to_path_buf()
}

/// The peer executable, built when its sources changed since the last build.
/// `CXX` names the compiler (default `c++`); `FASTDDS_PREFIX` an install
/// prefix of Fast DDS 2.x other than /usr (its `include` and `lib`).
pub fn peer() -> Result<PathBuf, String> {
    static PEER: OnceLock<Result<PathBuf, String>> = OnceLock::new();
    PEER.get_or_init(build_peer).clone()
}

fn build_peer() -> Result<PathBuf, String> {
    let sources = workspace().join("tests/fastdds");
    let cxx = std::env::var("CXX").unwrap_or_else(|_| "c++".into());
    let mut flags: Vec<String> = ["-std=c++17", "-O2", "-Wall", "-Wextra"].map(String::from).to_vec();
    if let Ok(prefix) = std::env::var("FASTDDS_PREFIX") {
        flags.push(format!("-I{prefix}/include"));
        flags.push(format!("-L{prefix}/lib"));
        flags.push(format!("-Wl,-rpath,{prefix}/lib"));
    }
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    for name in ["ros2_peer.cpp", "ros2_msgs.hpp"] {
        let path = sources.join(name);
        std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?.hash(&mut hasher);
    }
    (&cxx, &flags).hash(&mut hasher);
    // target/<profile>/deps/<test> -> target/<profile>/fastdds-peer
    let test_exe = std::env::current_exe().map_err(|e| e.to_string())?;
    let profile_dir = test_exe.parent().and_then(|d| d.parent()).ok_or("no target directory")?;
    let dir = profile_dir.join("fastdds-peer");
    let exe = dir.join(format!("ros2_peer-{:016x}", hasher.finish()));
    if exe.is_file() {
        return Ok(exe);
    }
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    // Built under a name of this process, then renamed: test processes may build at once.
    let partial = dir.join(format!("ros2_peer.{}.partial", std::process::id()));
    let out = crate::builder(cxx.as_ref())
        .args(&flags)
        .arg(sources.join("ros2_peer.cpp"))
        .arg("-o")
        .arg(&partial)
        .args(["-lfastrtps", "-lfastcdr"])
        .output()
        .map_err(|e| {
            format!("the Fast DDS test peer needs a C++ compiler; running {cxx}: {e} (apt-get install {PACKAGES})")
        })?;
    if !out.status.success() {
        let stderr = String::from_utf8_lossy(&out.stderr);
        let lines: Vec<&str> = stderr.lines().collect();
        return Err(format!(
            "the Fast DDS test peer (tests/fastdds/ros2_peer.cpp) did not build with {cxx}: it needs eProsima \
             Fast DDS 2.x and Fast CDR 1.x, Debian's libfastrtps-dev and libfastcdr-dev, and a C++17 compiler \
             (apt-get install {PACKAGES}; another install: FASTDDS_PREFIX=<prefix>). The compiler said:\n{}",
            lines[..lines.len().min(20)].join("\n")
        ));
    }
    std::fs::rename(&partial, &exe).map_err(|e| format!("{}: {e}", exe.display()))?;
    Ok(exe)
}

/// One scene as the peer publishes it.
#[derive(Debug, Clone)]
pub struct PeerScene {
    pub stem: String,
    pub truth: GroundTruth,
    pub width: u32,
    pub height: u32,
    /// `rgb8`, `bgr8` or `mono8`.
    pub encoding: &'static str,
    /// Bytes per row, `width` x channels plus padding.
    pub step: u32,
    /// height x step bytes, as the Image's data.
    pub pixels: Vec<u8>,
    pub points: usize,
}

/// Writes the scene `stem` of `scenes` (rendered by `outlet render`) for the
/// peer into `out`: `STEM.txt` (size, encoding, step, K, D), `STEM.pixels`
/// (the image in `encoding`, rows of `step` bytes, the padding 0xA5) and
/// `STEM.cloud` (16-byte points: float32 x, y, z and an `intensity` of 1e6,
/// which breaks the wall plane if read as a coordinate), and appends the stem
/// to `out/scenes.txt`.
pub fn write_peer_scene(
    scenes: &Path,
    stem: &str,
    encoding: &'static str,
    padding: u32,
    out: &Path,
) -> Result<PeerScene, String> {
    let path = scenes.join(format!("{stem}.json"));
    let text = std::fs::read(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let truth: GroundTruth = serde_json::from_slice(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let image_path = scenes.join(&truth.image);
    let rgb = image::open(&image_path).map_err(|e| format!("{}: {e}", image_path.display()))?.to_rgb8();
    let (width, height) = rgb.dimensions();
    let channels = if encoding == "mono8" { 1 } else { 3 };
    let step = width * channels + padding;
    let mut pixels = vec![0xA5u8; (step * height) as usize];
    for (y, row) in pixels.chunks_exact_mut(step as usize).enumerate() {
        for x in 0..width {
            let [r, g, b] = rgb.get_pixel(x, y as u32).0;
            let at = (x * channels) as usize;
            match encoding {
                "rgb8" => row[at..at + 3].copy_from_slice(&[r, g, b]),
                "bgr8" => row[at..at + 3].copy_from_slice(&[b, g, r]),
                "mono8" => {
                    // ITU-R BT.601 luma, as OpenCV's BGR2GRAY.
                    row[at] = (0.299 * f64::from(r) + 0.587 * f64::from(g) + 0.114 * f64::from(b)).round() as u8
                }
                other => return Err(format!("encoding {other} is not rgb8, bgr8 or mono8")),
            }
        }
    }
    let ply = scenes.join(format!("{stem}.ply"));
    let cloud = outlet_protocol::ply::read_ply(&ply).map_err(|e| format!("{}: {e}", ply.display()))?;
    let mut points = Vec::with_capacity(cloud.len() * 16);
    for p in &cloud {
        for v in [p[0], p[1], p[2], 1e6] {
            points.extend_from_slice(&v.to_le_bytes());
        }
    }
    let c = &truth.camera;
    let numbers = |v: &[f64]| v.iter().map(|x| format!("{x:?}")).collect::<Vec<_>>().join(" ");
    let description = format!(
        "width {width}\nheight {height}\nencoding {encoding}\nstep {step}\nk {}\nd {}\n",
        numbers(&c.camera_matrix),
        numbers(&c.distortion_coefficients)
    );
    let write = |name: String, bytes: &[u8]| std::fs::write(out.join(&name), bytes).map_err(|e| format!("{name}: {e}"));
    std::fs::create_dir_all(out).map_err(|e| format!("{}: {e}", out.display()))?;
    write(format!("{stem}.txt"), description.as_bytes())?;
    write(format!("{stem}.pixels"), &pixels)?;
    write(format!("{stem}.cloud"), &points)?;
    let list = out.join("scenes.txt");
    let mut stems = std::fs::read_to_string(&list).unwrap_or_default();
    stems.push_str(stem);
    stems.push('\n');
    std::fs::write(&list, stems).map_err(|e| format!("{}: {e}", list.display()))?;
    Ok(PeerScene { stem: stem.into(), truth, width, height, encoding, step, pixels, points: cloud.len() })
}
