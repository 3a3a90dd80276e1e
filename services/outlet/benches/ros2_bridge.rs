//! The ROS 2 bridge's cost: `outlet serve ros2-bridge` as a process, fed
//! 640x480 (or `--size WxH`, e.g. 1920x1080: 6 MB, fragmented) rgb8
//! `sensor_msgs/Image`s (each with its CameraInfo) at 30 frames per second by
//! a ROS 2 participant in this program. Measured:
//! - latency: the Image's header stamp (taken just before it is published on
//!   DDS) to the frame being readable on iceoryx2 here (woken by the frames'
//!   notification): serialisation, RTPS over loopback, the bridge's checks and
//!   copy into shared memory, the notification;
//! - the bridge process's CPU time (utime + stime from /proc/<pid>/stat) over
//!   the measured window, as % of one core, and its resident memory.
//!
//! `cargo bench -p outlet --bench ros2_bridge [-- --seconds 20 --fps 30 --size 640x480 --cloud --dds-only]`
//! (`--cloud` adds a PointCloud2 of one point per pixel with each image; `--dds-only`
//! measures DDS alone for comparison: no bridge, the Image deserialised by a
//! second participant in this program, woken as the bridge's input thread is).
//!
//! LOOPBACK ONLY: the bridge runs with `[ros2] interfaces = ["lo"]` and this
//! program's participant likewise (a rustdds DomainParticipant whose only
//! network is 127.0.0.1, no multicast); its DDS domain id is its own (from the
//! process id, in 1..=200).

use outlet_protocol::CameraModel;
use outlet_protocol::shm;
use outlet_protocol::wire::{PixelFormat, service};
use outlet_ros2_bridge::Ros2Config;
use outlet_ros2_bridge::bridge::{self, SENSOR_QOS};
use outlet_ros2_bridge::convert::{camera_info_of, cloud_of, image_of, ns_to_time};
use outlet_ros2_bridge::msgs::{CameraInfo, Header, Image, PointCloud2};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

type Result<T> = std::result::Result<T, Box<dyn std::error::Error>>;

fn now_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

struct Options {
    seconds: f64,
    fps: f64,
    cloud: bool,
    dds_only: bool,
    width: u32,
    height: u32,
}

fn options() -> Result<Options> {
    let mut o = Options { seconds: 20.0, fps: 30.0, cloud: false, dds_only: false, width: 640, height: 480 };
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--seconds" => o.seconds = args.next().ok_or("--seconds N")?.parse()?,
            "--fps" => o.fps = args.next().ok_or("--fps N")?.parse()?,
            "--size" => {
                let size = args.next().ok_or("--size WxH")?;
                let (w, h) = size.split_once('x').ok_or("--size WxH, e.g. 1920x1080")?;
                (o.width, o.height) = (w.parse()?, h.parse()?);
            }
            "--cloud" => o.cloud = true,
            "--dds-only" => o.dds_only = true,
            _ => {} // `--bench` and the like, from cargo
        }
    }
    Ok(o)
}

/// The bridge process; SIGTERM (then SIGKILL) when dropped.
struct BridgeProcess(Child, String);

impl Drop for BridgeProcess {
    fn drop(&mut self) {
        use nix::sys::signal::{Signal, kill};
        if let Ok(pid) = i32::try_from(self.0.id()) {
            let _ = kill(nix::unistd::Pid::from_raw(pid), Signal::SIGTERM);
        }
        let deadline = Instant::now() + Duration::from_secs(3);
        while matches!(self.0.try_wait(), Ok(None)) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
        shm::remove_node_counter(&self.1);
    }
}

/// utime + stime of a process, in clock ticks.
fn cpu_ticks(pid: u32) -> Result<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat"))?;
    // Fields after the command name, which is in parentheses and may hold spaces.
    let rest = stat.rsplit_once(')').ok_or("/proc/pid/stat")?.1;
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // utime and stime are fields 14 and 15 of the line, 12 and 13 after the name.
    Ok(fields.get(11).ok_or("utime")?.parse::<u64>()? + fields.get(12).ok_or("stime")?.parse::<u64>()?)
}

fn rss_mib(pid: u32) -> Option<f64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kb: f64 = status.lines().find(|l| l.starts_with("VmRSS:"))?.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

fn clock_ticks_per_second() -> f64 {
    Command::new("getconf")
        .arg("CLK_TCK")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(100.0)
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() as f64 * q).ceil() as usize).clamp(1, sorted.len()) - 1]
}

fn main() -> Result<()> {
    let o = options()?;
    // Asked before any DDS participant exists: the SIGCHLD of `getconf` can
    // interrupt rustdds 0.15's event loop thread in epoll_wait, and that loop
    // ends on EINTR (the participant then neither sends nor receives).
    let ticks_per_s = clock_ticks_per_second();
    let domain = format!("ros2-bench-{}", std::process::id());
    let dds_domain = (1 + std::process::id() % 200) as u16;
    let dir = tempfile::tempdir()?;
    let config = dir.path().join("outlet.toml");
    std::fs::write(
        &config,
        format!("domain = \"{domain}\"\n[ros2]\ndomain_id = {dds_domain}\n# Loopback only.\ninterfaces = [\"lo\"]\n"),
    )?;
    let ros2 = Ros2Config { domain_id: dds_domain, interfaces: vec!["lo".into()], ..Ros2Config::default() };
    if o.dds_only {
        return dds_only(&o, &ros2);
    }
    let child = Command::new(env!("CARGO_BIN_EXE_outlet"))
        .args(["serve", "--config"])
        .arg(&config)
        .arg("ros2-bridge")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()?;
    let bridge = BridgeProcess(child, domain.clone());
    let pid = bridge.0.id();
    let node = shm::node(&domain, "bench-main")?;
    let beats = shm::heartbeats(&node)?.subscriber_builder().create()?;

    // What a camera driver would publish: a rendered view, its camera info
    // (focal length 525 px at 640 wide, scaled with the width).
    let (w, h) = (o.width, o.height);
    let f = 525.0 * f64::from(w) / 640.0;
    let camera = CameraModel::new(
        w,
        h,
        [f, f, (f64::from(w) - 1.0) / 2.0, (f64::from(h) - 1.0) / 2.0],
        [-0.06, 0.03, 0.0, 0.0, 0.0],
    )?;
    let scene = outlet_sim::sample_scene("fw_2x1white", 1, 0, &camera)?;
    let frame = outlet_sim::render_frame(&scene, "bench");
    let image =
        image_of(Header::default(), w, h, frame.frame.image.as_raw(), PixelFormat::Rgb8, 3 * w).ok_or("image")?;
    // A depth camera's full-resolution cloud: one point per pixel, a wall 0.5 m away.
    let wall: Vec<[f32; 3]> = (0..w * h)
        .map(|k| {
            let (u, v) = ((k % w) as f64, (k / w) as f64);
            let z = 0.5;
            [((u - camera.cx) / camera.fx * z) as f32, ((v - camera.cy) / camera.fy * z) as f32, z as f32]
        })
        .collect();
    let cloud = cloud_of(Header::default(), &wall);
    let context = bridge::context(&ros2)?;
    let mut node = bridge::node(&context, "outlet_bench_camera")?;
    let image_pub = bridge::publisher::<Image>(&mut node, &ros2.topics.image, &SENSOR_QOS)?;
    let info_pub = bridge::publisher::<CameraInfo>(&mut node, &ros2.topics.camera_info, &SENSOR_QOS)?;
    let cloud_pub = bridge::publisher::<PointCloud2>(&mut node, &ros2.topics.points, &SENSOR_QOS)?;
    let points = u64::from(w * h);

    // The reader on iceoryx2, woken by the frames' notifications, on its own thread.
    let latencies_ms = Arc::new(Mutex::new(Vec::<f64>::new()));
    let (measuring, done) = (Arc::new(AtomicBool::new(false)), Arc::new(AtomicBool::new(false)));
    let reader = {
        let (latencies_ms, measuring, done, domain) =
            (Arc::clone(&latencies_ms), Arc::clone(&measuring), Arc::clone(&done), domain.clone());
        std::thread::spawn(move || -> std::result::Result<(u64, u64), String> {
            let e = |e: &dyn std::fmt::Debug| format!("{e:?}");
            let node = shm::node(&domain, "bench").map_err(|x| e(&x))?;
            let frames = shm::frames(&node).map_err(|x| e(&x))?.subscriber_builder().create().map_err(|x| e(&x))?;
            let clouds = shm::clouds(&node).map_err(|x| e(&x))?.subscriber_builder().create().map_err(|x| e(&x))?;
            let listener = shm::events(&node, service::FRAMES)
                .map_err(|x| e(&x))?
                .listener_builder()
                .create()
                .map_err(|x| e(&x))?;
            let (mut received, mut received_clouds) = (0u64, 0u64);
            while !done.load(Ordering::Relaxed) {
                if listener.timed_wait(|_| {}, Duration::from_millis(100)).is_err() {
                    break;
                }
                while let Ok(Some(cloud)) = clouds.receive() {
                    if measuring.load(Ordering::Relaxed) && cloud.user_header().points == points {
                        received_clouds += 1;
                    }
                }
                while let Ok(Some(sample)) = frames.receive() {
                    let latency_ms = now_ns().saturating_sub(sample.user_header().capture_time_ns) as f64 / 1e6;
                    if measuring.load(Ordering::Relaxed) {
                        received += 1;
                        latencies_ms.lock().map_err(|x| e(&x))?.push(latency_ms);
                    }
                }
            }
            Ok((received, received_clouds))
        })
    };

    let period = Duration::from_secs_f64(1.0 / o.fps);
    let warmup = (3.0 * o.fps) as u64;
    let frames = (o.seconds * o.fps) as u64;
    let (mut cpu_start, mut wall_start) = (0, Instant::now());
    let mut next = Instant::now();
    for k in 0..warmup + frames {
        if k == warmup {
            // Discovery and the first allocations are done: measure from here.
            std::thread::sleep(Duration::from_millis(200));
            latencies_ms.lock().map_err(|e| format!("{e:?}"))?.clear();
            measuring.store(true, Ordering::Relaxed);
            cpu_start = cpu_ticks(pid)?;
            wall_start = Instant::now();
            next = Instant::now();
        }
        next += period;
        let header = Header { stamp: ns_to_time(now_ns()), frame_id: "camera_optical_frame".into() };
        info_pub.publish(camera_info_of(&camera, header.clone())).map_err(|e| format!("{e:?}"))?;
        if o.cloud {
            cloud_pub.publish(PointCloud2 { header: header.clone(), ..cloud.clone() }).map_err(|e| format!("{e:?}"))?;
        }
        let header = Header { stamp: ns_to_time(now_ns()), ..header };
        image_pub.publish(Image { header, ..image.clone() }).map_err(|e| format!("{e:?}"))?;
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    std::thread::sleep(Duration::from_millis(300));
    let cpu_end = cpu_ticks(pid)?;
    let wall = wall_start.elapsed().as_secs_f64();
    let rss = rss_mib(pid);
    let mut beat = None;
    while let Ok(Some(b)) = beats.receive() {
        if b.payload().service_name() == "ros2-bridge" {
            beat = Some(*b.payload());
        }
    }
    done.store(true, Ordering::Relaxed);
    let (received, received_clouds) = reader.join().map_err(|_| "the reader panicked")??;
    drop(bridge);

    let mut l = latencies_ms.lock().map_err(|e| format!("{e:?}"))?.clone();
    l.sort_by(f64::total_cmp);
    let cpu_percent = (cpu_end - cpu_start) as f64 / ticks_per_s / wall * 100.0;
    let model = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|c| {
            c.lines()
                .find(|l| l.starts_with("model name"))
                .map(|l| l.split(':').nth(1).unwrap_or("").trim().to_string())
        })
        .unwrap_or_default();
    println!(
        "ros2-bridge: {} x {w}x{h} rgb8 Image + CameraInfo{} at {} fps over DDS on loopback, {:.1} s measured ({} cores, {model})",
        frames,
        if o.cloud { format!(" + {points}-point PointCloud2") } else { String::new() },
        o.fps,
        wall,
        std::thread::available_parallelism().map_or(0, |n| n.get()),
    );
    println!("  frames readable on iceoryx2: {received} of {frames}");
    if o.cloud {
        println!(
            "  clouds readable on iceoryx2: {received_clouds} of {frames} (only the newest two are kept for a reader)"
        );
    }
    println!(
        "  latency, Image publish -> frame readable (ms): p50 {:.2}  p90 {:.2}  p99 {:.2}  max {:.2}",
        quantile(&l, 0.5),
        quantile(&l, 0.9),
        quantile(&l, 0.99),
        l.last().copied().unwrap_or(f64::NAN)
    );
    println!(
        "  bridge process CPU: {cpu_percent:.1} % of one core; resident memory {}",
        rss.map_or("?".into(), |m| format!("{m:.0} MiB"))
    );
    if let Some(b) = beat {
        println!(
            "  bridge heartbeat, last second: work per message p50 {:.3} ms p99 {:.3} ms (checks, conversion, copy \
             into shared memory); rejected {}",
            b.work_p50_ms, b.work_p99_ms, b.rejected
        );
    }
    Ok(())
}

/// DDS alone: the same Images, received and deserialised by a second
/// participant in this process (the bridge's own input code, woken the same
/// way), stamp to message in hand.
fn dds_only(o: &Options, ros2: &Ros2Config) -> Result<()> {
    let mut receiver = outlet_ros2_bridge::Bridge::new(ros2)?;
    let inputs = receiver.take_inputs().ok_or("inputs")?;
    let (stop_handle, stop) = outlet_ros2_bridge::Stop::new();
    let latencies_ms = Arc::new(Mutex::new(Vec::<f64>::new()));
    let measuring = Arc::new(AtomicBool::new(false));
    let runner = {
        let (latencies_ms, measuring) = (Arc::clone(&latencies_ms), Arc::clone(&measuring));
        std::thread::spawn(move || {
            inputs.run(stop, |input| {
                if let outlet_ros2_bridge::Input::Image(m) = input
                    && measuring.load(Ordering::Relaxed)
                    && let (Some(stamp), Ok(mut l)) =
                        (outlet_ros2_bridge::convert::time_to_ns(m.header.stamp), latencies_ms.lock())
                {
                    l.push(now_ns().saturating_sub(stamp) as f64 / 1e6);
                }
            })
        })
    };
    let context = bridge::context(ros2)?;
    let mut node = bridge::node(&context, "outlet_bench_camera")?;
    let image_pub = bridge::publisher::<Image>(&mut node, &ros2.topics.image, &SENSOR_QOS)?;
    let (w, h) = (o.width, o.height);
    let rgb = vec![100u8; (w * h * 3) as usize];
    let image = image_of(Header::default(), w, h, &rgb, PixelFormat::Rgb8, 3 * w).ok_or("image")?;
    let period = Duration::from_secs_f64(1.0 / o.fps);
    let (warmup, frames) = ((3.0 * o.fps) as u64, (o.seconds * o.fps) as u64);
    let mut next = Instant::now();
    for k in 0..warmup + frames {
        if k == warmup {
            std::thread::sleep(Duration::from_millis(200));
            measuring.store(true, Ordering::Relaxed);
            next = Instant::now();
        }
        next += period;
        let header = Header { stamp: ns_to_time(now_ns()), frame_id: "camera_optical_frame".into() };
        image_pub.publish(Image { header, ..image.clone() }).map_err(|e| format!("{e:?}"))?;
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    std::thread::sleep(Duration::from_millis(300));
    stop_handle.stop();
    runner.join().map_err(|_| "the receiver panicked")?;
    let mut l = latencies_ms.lock().map_err(|e| format!("{e:?}"))?.clone();
    l.sort_by(f64::total_cmp);
    println!("DDS alone: {frames} x {w}x{h} rgb8 Image at {} fps, rustdds to rustdds on loopback", o.fps);
    println!(
        "  received {} of {frames}; latency, Image publish -> deserialised Image in hand (ms): p50 {:.2}  p90 {:.2}  \
         p99 {:.2}  max {:.2}",
        l.len(),
        quantile(&l, 0.5),
        quantile(&l, 0.9),
        quantile(&l, 0.99),
        l.last().copied().unwrap_or(f64::NAN)
    );
    Ok(())
}
