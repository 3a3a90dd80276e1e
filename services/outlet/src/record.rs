//! `outlet record` and `outlet replay`: the camera's frames and stereo clouds
//! as they crossed shared memory, kept in a file (postcard records) and played
//! back later with their original timing: a field problem brought to the desk.
//!
//! File: the magic `OUTLETREC`, a format version byte, then records, each a
//! little-endian u32 length and a postcard-encoded [`Record`].

use anyhow::{Context, Result, bail};
use clap::Args;
use iceoryx2::prelude::*;
use outlet_protocol::shm;
use outlet_protocol::wire::{CloudHeader, FrameHeader, SCHEMA_VERSION, service};
use serde::{Deserialize, Serialize};
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

const MAGIC: &[u8; 9] = b"OUTLETREC";
const FORMAT_VERSION: u8 = 1;
/// A record larger than this is not one we wrote (a 4K rgb8 frame is 25 MB).
const MAX_RECORD_BYTES: u32 = 64 << 20;

/// One sample as it crossed shared memory, `offset_ns` after the first.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Record {
    Frame {
        offset_ns: u64,
        frame_id: u64,
        capture_time_ns: u64,
        pixel_format: u32,
        width: u32,
        height: u32,
        stride: u32,
        intrinsics: [f64; 4],
        distortion: [f64; 5],
        pixels: Vec<u8>,
    },
    Cloud {
        offset_ns: u64,
        frame_id: u64,
        capture_time_ns: u64,
        xyz: Vec<f32>,
    },
}

impl Record {
    fn offset_ns(&self) -> u64 {
        match self {
            Self::Frame { offset_ns, .. } | Self::Cloud { offset_ns, .. } => *offset_ns,
        }
    }
}

/// Writes records to a file.
pub struct Recorder<W: Write> {
    out: W,
}

impl<W: Write> Recorder<W> {
    pub fn new(mut out: W) -> std::io::Result<Self> {
        out.write_all(MAGIC)?;
        out.write_all(&[FORMAT_VERSION])?;
        Ok(Self { out })
    }

    pub fn write(&mut self, record: &Record) -> Result<()> {
        let bytes = postcard::to_allocvec(record)?;
        let len = u32::try_from(bytes.len()).ok().filter(|&n| n <= MAX_RECORD_BYTES).context("record too large")?;
        self.out.write_all(&len.to_le_bytes())?;
        self.out.write_all(&bytes)?;
        Ok(())
    }

    pub fn finish(mut self) -> std::io::Result<()> {
        self.out.flush()
    }
}

/// Reads the records of a file, checking its magic and version first.
pub struct Player<R: Read> {
    input: R,
    name: String,
}

impl<R: Read> Player<R> {
    pub fn new(mut input: R, name: &str) -> Result<Self> {
        let mut head = [0u8; 10];
        input.read_exact(&mut head).with_context(|| format!("{name}: too short for a recording"))?;
        if &head[..9] != MAGIC {
            bail!("{name}: not a recording of `outlet record`");
        }
        if head[9] != FORMAT_VERSION {
            bail!("{name}: recording format {} (this build reads {FORMAT_VERSION})", head[9]);
        }
        Ok(Self { input, name: name.into() })
    }

    /// The next record; None at the end of the file.
    pub fn next_record(&mut self) -> Result<Option<Record>> {
        let mut len = [0u8; 4];
        match self.input.read_exact(&mut len) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(None),
            Err(e) => return Err(e).with_context(|| format!("{}: reading", self.name)),
        }
        let len = u32::from_le_bytes(len);
        if len > MAX_RECORD_BYTES {
            bail!("{}: a record claims {len} bytes; the file is corrupt", self.name);
        }
        let mut bytes = vec![0u8; len as usize];
        self.input.read_exact(&mut bytes).with_context(|| format!("{}: truncated record", self.name))?;
        let record = postcard::from_bytes(&bytes).with_context(|| format!("{}: corrupt record", self.name))?;
        Ok(Some(record))
    }
}

#[derive(Args, Debug)]
pub struct RecordArgs {
    /// The recording to write.
    pub out: PathBuf,
    /// The shared-memory domain to record from.
    #[arg(long, default_value = outlet_protocol::shm::DEFAULT_DOMAIN)]
    pub domain: String,
    /// Stop after this many seconds (default: Ctrl-C).
    #[arg(long)]
    pub duration: Option<f64>,
    /// Stop after this many frames.
    #[arg(long)]
    pub frames: Option<u64>,
}

#[derive(Args, Debug)]
pub struct ReplayArgs {
    /// A recording written by `outlet record`.
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
}

pub fn record(args: RecordArgs) -> Result<()> {
    let node = shm::node(&args.domain, "record")?;
    let frames = shm::frames(&node)?.subscriber_builder().create().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let clouds = shm::clouds(&node)?.subscriber_builder().create().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let frame_events =
        shm::events(&node, service::FRAMES)?.listener_builder().create().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let cloud_events =
        shm::events(&node, service::CLOUDS)?.listener_builder().create().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let file = std::fs::File::create(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mut recorder = Recorder::new(BufWriter::new(file))?;
    let waitset = WaitSetBuilder::new().create::<ipc::Service>().map_err(|e| anyhow::anyhow!("waitset: {e:?}"))?;
    let frame_guard = waitset.attach_notification(&frame_events).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let cloud_guard = waitset.attach_notification(&cloud_events).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let _tick = waitset.attach_interval(Duration::from_millis(200)).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let started = Instant::now();
    let (mut n_frames, mut n_clouds) = (0u64, 0u64);
    let mut failure = None;
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        let offset_ns = started.elapsed().as_nanos() as u64;
        if id.has_event_from(&frame_guard) {
            let _ = frame_events.try_wait(|_| {});
            while let Ok(Some(s)) = frames.receive() {
                let h = *s.user_header();
                let record = Record::Frame {
                    offset_ns,
                    frame_id: h.frame_id,
                    capture_time_ns: h.capture_time_ns,
                    pixel_format: h.pixel_format,
                    width: h.width,
                    height: h.height,
                    stride: h.stride,
                    intrinsics: h.intrinsics,
                    distortion: h.distortion,
                    pixels: s.payload().to_vec(),
                };
                if let Err(e) = recorder.write(&record) {
                    failure = Some(e);
                    return CallbackProgression::Stop;
                }
                n_frames += 1;
            }
        }
        if id.has_event_from(&cloud_guard) {
            let _ = cloud_events.try_wait(|_| {});
            while let Ok(Some(s)) = clouds.receive() {
                let h = *s.user_header();
                let record = Record::Cloud {
                    offset_ns,
                    frame_id: h.frame_id,
                    capture_time_ns: h.capture_time_ns,
                    xyz: s.payload().to_vec(),
                };
                if let Err(e) = recorder.write(&record) {
                    failure = Some(e);
                    return CallbackProgression::Stop;
                }
                n_clouds += 1;
            }
        }
        let done = args.duration.is_some_and(|d| started.elapsed().as_secs_f64() >= d)
            || args.frames.is_some_and(|n| n_frames >= n);
        if done { CallbackProgression::Stop } else { CallbackProgression::Continue }
    };
    waitset.wait_and_process(on_event).map_err(|e| anyhow::anyhow!("waiting: {e:?}"))?;
    if let Some(e) = failure {
        return Err(e).with_context(|| format!("writing {}", args.out.display()));
    }
    recorder.finish()?;
    eprintln!("outlet record: {n_frames} frames and {n_clouds} clouds in {}", args.out.display());
    Ok(())
}

fn open(path: &Path) -> Result<Player<BufReader<std::fs::File>>> {
    let file = std::fs::File::open(path).with_context(|| format!("opening {}", path.display()))?;
    Player::new(BufReader::new(file), &path.display().to_string())
}

pub fn replay(args: ReplayArgs) -> Result<()> {
    if !(args.speed > 0.0 && args.speed.is_finite()) {
        bail!("--speed {}: not a positive number", args.speed);
    }
    // Check the whole file before anything goes out.
    let mut player = open(&args.input)?;
    let mut count = 0usize;
    while player.next_record()?.is_some() {
        count += 1;
    }
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
        let mut player = open(&args.input)?;
        let start = Instant::now();
        // Capture times move to now, keeping their spacing: the pose service joins by time.
        let base_ns = outlet::health::now_ns();
        let mut first_capture = None;
        while let Some(record) = player.next_record()? {
            let due = Duration::from_nanos((record.offset_ns() as f64 / args.speed) as u64);
            if let Some(wait) = due.checked_sub(start.elapsed()) {
                // Ctrl-C: iceoryx2's handler records it, the node reports it.
                if node.wait(wait).is_err() {
                    eprintln!("outlet replay: interrupted after {sent} records");
                    return Ok(());
                }
            }
            let restamp = |capture: u64, first: &mut Option<u64>| {
                let first = *first.get_or_insert(capture);
                base_ns + ((capture.saturating_sub(first)) as f64 / args.speed) as u64
            };
            let id_offset = pass as u64 * 1_000_000_000;
            match record {
                Record::Frame {
                    frame_id,
                    capture_time_ns,
                    pixel_format,
                    width,
                    height,
                    stride,
                    intrinsics,
                    distortion,
                    pixels,
                    ..
                } => {
                    let header = FrameHeader {
                        schema_version: SCHEMA_VERSION,
                        pixel_format,
                        frame_id: frame_id + id_offset,
                        capture_time_ns: restamp(capture_time_ns, &mut first_capture),
                        width,
                        height,
                        stride,
                        reserved: 0,
                        intrinsics,
                        distortion,
                    };
                    let mut s = frames.loan_slice_uninit(pixels.len()).map_err(|e| anyhow::anyhow!("frame: {e:?}"))?;
                    *s.user_header_mut() = header;
                    s.write_from_slice(&pixels).send().map_err(|e| anyhow::anyhow!("frame: {e:?}"))?;
                    let _ = frame_note.notify();
                }
                Record::Cloud { frame_id, capture_time_ns, xyz, .. } => {
                    let header = CloudHeader {
                        schema_version: SCHEMA_VERSION,
                        reserved: 0,
                        frame_id: frame_id + id_offset,
                        capture_time_ns: restamp(capture_time_ns, &mut first_capture),
                        points: (xyz.len() / 3) as u64,
                    };
                    let mut s = clouds.loan_slice_uninit(xyz.len()).map_err(|e| anyhow::anyhow!("cloud: {e:?}"))?;
                    *s.user_header_mut() = header;
                    s.write_from_slice(&xyz).send().map_err(|e| anyhow::anyhow!("cloud: {e:?}"))?;
                    let _ = cloud_note.notify();
                }
            }
            sent += 1;
        }
    }
    eprintln!("outlet replay: {sent} records ({count} per pass) into domain {}", args.domain);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn records() -> Vec<Record> {
        vec![
            Record::Frame {
                offset_ns: 0,
                frame_id: 1,
                capture_time_ns: 10,
                pixel_format: 2,
                width: 2,
                height: 1,
                stride: 6,
                intrinsics: [1.0, 1.0, 0.5, 0.0],
                distortion: [0.0; 5],
                pixels: vec![1, 2, 3, 4, 5, 6],
            },
            Record::Cloud { offset_ns: 5, frame_id: 1, capture_time_ns: 10, xyz: vec![0.0, 1.0, f32::NAN] },
        ]
    }

    fn written() -> Vec<u8> {
        let mut bytes = Vec::new();
        let mut r = Recorder::new(&mut bytes).expect("header");
        for rec in records() {
            r.write(&rec).expect("record");
        }
        r.finish().expect("flush");
        bytes
    }

    #[test]
    fn records_round_trip() {
        let bytes = written();
        let mut p = Player::new(bytes.as_slice(), "mem").expect("valid");
        let Some(Record::Frame { pixels, .. }) = p.next_record().expect("frame") else { panic!("no frame") };
        assert_eq!(pixels, vec![1, 2, 3, 4, 5, 6]);
        let Some(Record::Cloud { xyz, .. }) = p.next_record().expect("cloud") else { panic!("no cloud") };
        assert!(xyz[2].is_nan() && xyz[1] == 1.0);
        assert!(p.next_record().expect("end").is_none());
    }

    #[test]
    fn bad_files_are_named_and_refused() {
        let e = Player::new(&b"PNG..."[..], "a.png").err().expect("not a recording");
        assert!(format!("{e:#}").contains("a.png"));
        let mut newer = written();
        newer[9] = 9;
        assert!(format!("{:#}", Player::new(newer.as_slice(), "new.rec").err().expect("too new")).contains("format 9"));
        let bytes = written();
        let mut truncated = Player::new(&bytes[..bytes.len() - 3], "cut.rec").expect("header fine");
        assert!(truncated.next_record().is_ok());
        let e = truncated.next_record().expect_err("truncated");
        assert!(format!("{e:#}").contains("cut.rec: truncated"), "{e:#}");
        let mut huge = bytes[..10].to_vec();
        huge.extend_from_slice(&u32::MAX.to_le_bytes());
        let e = Player::new(huge.as_slice(), "huge.rec").expect("header").next_record().expect_err("huge");
        assert!(format!("{e:#}").contains("corrupt"));
    }
}
