//! `outlet record` and `outlet replay`: what crossed shared memory, kept in an
//! MCAP file (the format of ROS 2 bags and Foxglove; see
//! [`outlet::recording`]) and played back later with its original timing: a
//! field problem brought to the desk, or a ROS 2 bag of a real camera run
//! through the sidecar with no ROS installed.

use crate::serve::subscriber;
use anyhow::{Context, Result, bail};
use clap::Args;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use outlet::config::Config;
use outlet::recording::{self, Recorder, Sample, TopicChoice};
use outlet_protocol::shm;
use outlet_protocol::wire::{DetectionMsg, HolePosesMsg, WallPlaneMsg, service};
use std::io::BufWriter;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(Args, Debug)]
pub struct RecordArgs {
    /// The MCAP file to write.
    pub out: PathBuf,
    /// The sidecar's configuration: its domain, and the topics and frame id of `[ros2]`.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The shared-memory domain to record from (over the configuration's).
    #[arg(long)]
    pub domain: Option<String>,
    /// Stop after this many seconds (default: Ctrl-C).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Stop after this many frames.
    #[arg(long)]
    pub frames: Option<u64>,
}

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// An MCAP file: written by `outlet record`, or a ROS 2 bag with
    /// sensor_msgs/msg/Image, CameraInfo and (optionally) PointCloud2.
    pub input: PathBuf,
    /// The shared-memory domain to play into.
    #[arg(long, default_value = outlet_protocol::shm::DEFAULT_DOMAIN)]
    pub domain: String,
    /// Play this many times faster (2 = twice the original rate).
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Play the recording this many times.
    #[arg(long, default_value_t = 1)]
    pub repeat: u32,
    /// The image topic, when the file has several.
    #[arg(long)]
    pub image_topic: Option<String>,
    /// The point cloud topic, when the file has several.
    #[arg(long)]
    pub points_topic: Option<String>,
}

/// Takes every waiting sample of `sub` into `write`; stops at the first write error.
fn drain<T: std::fmt::Debug + ZeroCopySend + 'static>(
    sub: &Subscriber<ipc::Service, T, ()>,
    mut write: impl FnMut(&T) -> Result<()>,
) -> Result<()> {
    while let Ok(Some(s)) = sub.receive() {
        write(s.payload())?;
    }
    Ok(())
}

pub fn record(args: RecordArgs) -> Result<()> {
    let config = Config::load(args.config.as_deref())?;
    let domain = args.domain.unwrap_or(config.domain);
    let node = shm::node(&domain, "record")?;
    let err = |e: &dyn std::fmt::Debug| anyhow::anyhow!("{e:?}");
    let frames = shm::frames(&node)?.subscriber_builder().create().map_err(|e| err(&e))?;
    let clouds = shm::clouds(&node)?.subscriber_builder().create().map_err(|e| err(&e))?;
    let detections = subscriber::<DetectionMsg>(&node, service::DETECTIONS)?;
    let poses = subscriber::<HolePosesMsg>(&node, service::HOLE_POSES)?;
    let planes = subscriber::<WallPlaneMsg>(&node, service::PLANES)?;
    let beats = shm::heartbeats(&node)?.subscriber_builder().create().map_err(|e| err(&e))?;
    let listen = |name| -> Result<_> { shm::events(&node, name)?.listener_builder().create().map_err(|e| err(&e)) };
    let frame_events = listen(service::FRAMES)?;
    let cloud_events = listen(service::CLOUDS)?;
    let result_events = [listen(service::DETECTIONS)?, listen(service::HOLE_POSES)?, listen(service::PLANES)?];

    let file = std::fs::File::create(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mut recorder = Recorder::new(BufWriter::new(file), &config.ros2)?;
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
        .create::<ipc::Service>()
        .map_err(|e| anyhow::anyhow!("waitset: {e:?}"))?;
    let mut guards = Vec::new();
    for listener in [&frame_events, &cloud_events].into_iter().chain(&result_events) {
        guards.push(waitset.attach_notification(listener).map_err(|e| err(&e))?);
    }
    // Heartbeats carry no notification: they are taken on this tick.
    let _tick = waitset.attach_interval(Duration::from_millis(200)).map_err(|e| err(&e))?;
    let started = Instant::now();
    let mut failure = None;
    let step = |recorder: &mut Recorder<_>| -> Result<()> {
        for listener in [&frame_events, &cloud_events].into_iter().chain(&result_events) {
            let _ = listener.try_wait(|_| {});
        }
        while let Ok(Some(s)) = clouds.receive() {
            recorder.cloud(s.user_header(), s.payload())?;
        }
        while let Ok(Some(s)) = frames.receive() {
            recorder.frame(s.user_header(), s.payload())?;
        }
        drain(&planes, |p| recorder.plane(p))?;
        drain(&detections, |d| recorder.detection(d))?;
        drain(&poses, |p| recorder.hole_poses(p))?;
        while let Ok(Some(b)) = beats.receive() {
            recorder.heartbeat(b.payload())?;
        }
        Ok(())
    };
    let on_event = |_: WaitSetAttachmentId<ipc::Service>| {
        if let Err(e) = step(&mut recorder) {
            failure = Some(e);
            return CallbackProgression::Stop;
        }
        let done = args.duration.is_some_and(|d| started.elapsed().as_secs_f64() >= d)
            || args.frames.is_some_and(|n| recorder.counts[0] >= n);
        if done { CallbackProgression::Stop } else { CallbackProgression::Continue }
    };
    // Recording to the end of a file must survive Ctrl-Z and `fg` (SIGCONT) too.
    let waited = crate::serve::run_until_stopped(&waitset, on_event);
    if let Some(e) = failure {
        return Err(e).with_context(|| format!("writing {}", args.out.display()));
    }
    // Interrupted or not, the file is closed so that it is a complete MCAP file.
    let counts = recorder.counts;
    recorder.finish().with_context(|| format!("finishing {}", args.out.display()))?;
    waited?;
    let [frames, clouds, detections, poses, planes, beats] = counts;
    eprintln!(
        "outlet record: {frames} frames, {clouds} clouds, {detections} detections, {poses} hole poses, {planes} \
         planes, {beats} heartbeats in {}",
        args.out.display()
    );
    Ok(())
}

pub fn replay(args: ReplayArgs) -> Result<()> {
    if !(args.speed > 0.0 && args.speed.is_finite()) {
        bail!("--speed {}: not a positive number", args.speed);
    }
    // Check the whole file before anything goes out: its channels, then every message.
    let choice = TopicChoice { image: args.image_topic.clone(), points: args.points_topic.clone() };
    let channels = recording::channels_of_file(&args.input, &choice)?;
    let mut player = recording::play_file(&args.input, &channels)?;
    let (mut count, mut first_capture, mut first_log) = (0usize, u64::MAX, u64::MAX);
    while let Some((log_time, sample)) = player.next_sample()? {
        count += 1;
        first_capture = first_capture.min(sample.capture_time_ns());
        first_log = first_log.min(log_time);
    }
    if count == 0 {
        bail!("{}: no frame or cloud to replay on {} and {:?}", args.input.display(), channels.image, channels.points);
    }
    if player.without_camera > 0 {
        eprintln!(
            "outlet replay: {} images before the first CameraInfo on {} are left out",
            player.without_camera, channels.camera_info
        );
    }
    eprintln!(
        "outlet replay: {} (camera info {}) and {} into domain {}",
        channels.image,
        channels.camera_info,
        channels.points.as_deref().unwrap_or("no cloud"),
        args.domain
    );

    let node = shm::node(&args.domain, "replay")?;
    let frames = shm::frames(&node)?
        .publisher_builder()
        .initial_max_slice_len(640 * 480 * 3)
        .allocation_strategy(AllocationStrategy::PowerOfTwo)
        .create()
        .map_err(|e| anyhow::anyhow!("frame publisher: {e:?}"))?;
    let clouds = shm::clouds(&node)?
        .publisher_builder()
        .initial_max_slice_len(3 * 76_800)
        .allocation_strategy(AllocationStrategy::PowerOfTwo)
        .create()
        .map_err(|e| anyhow::anyhow!("cloud publisher: {e:?}"))?;
    let frame_note =
        shm::events(&node, service::FRAMES)?.notifier_builder().create().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let cloud_note =
        shm::events(&node, service::CLOUDS)?.notifier_builder().create().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let mut sent = 0usize;
    for pass in 0..args.repeat {
        let mut player = recording::play_file(&args.input, &channels)?;
        let start = Instant::now();
        // Capture times move to now, keeping their spacing: the pose service joins by time.
        let base_ns = outlet::health::now_ns();
        let restamp = |capture: u64| base_ns + (capture.saturating_sub(first_capture) as f64 / args.speed) as u64;
        let id_offset = u64::from(pass) * 1_000_000_000;
        while let Some((log_time, sample)) = player.next_sample()? {
            let due = Duration::from_nanos((log_time.saturating_sub(first_log) as f64 / args.speed) as u64);
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                // Ctrl-C: iceoryx2's handler records it, the node reports it.
                if node.wait(wait).is_err() {
                    eprintln!("outlet replay: interrupted after {sent} frames and clouds");
                    return Ok(());
                }
            }
            match sample {
                Sample::Frame { mut header, pixels } => {
                    header.frame_id += id_offset;
                    header.capture_time_ns = restamp(header.capture_time_ns);
                    let mut s = frames.loan_slice_uninit(pixels.len()).map_err(|e| anyhow::anyhow!("frame: {e:?}"))?;
                    *s.user_header_mut() = header;
                    s.write_from_slice(&pixels).send().map_err(|e| anyhow::anyhow!("frame: {e:?}"))?;
                    let _ = frame_note.notify();
                }
                Sample::Cloud { mut header, xyz } => {
                    header.frame_id += id_offset;
                    header.capture_time_ns = restamp(header.capture_time_ns);
                    let mut s = clouds.loan_slice_uninit(xyz.len()).map_err(|e| anyhow::anyhow!("cloud: {e:?}"))?;
                    *s.user_header_mut() = header;
                    s.write_from_slice(&xyz).send().map_err(|e| anyhow::anyhow!("cloud: {e:?}"))?;
                    let _ = cloud_note.notify();
                }
            }
            sent += 1;
        }
    }
    eprintln!("outlet replay: {sent} frames and clouds ({count} per pass) into domain {}", args.domain);
    Ok(())
}
