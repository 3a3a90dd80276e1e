//! Frame transport latency between two processes, publish to receive: iceoryx2
//! zero-copy shared memory against a Unix-domain stream socket that copies the
//! frame.
//!
//! ```sh
//! cargo bench -p outlet-tests --bench transport
//! ```
//!
//! This process is the camera. It starts itself again as the receiver (the
//! [`ROLE_ENV`] variable says so) and sends rgb8 frames of each size, one every
//! [`PERIOD`], taking the transports in turn, so the receiver is idle-waiting
//! when a frame comes, as it would be behind a real camera. Three transports:
//!
//! - iceoryx2, WaitSet: the camera loans a slice, writes the pixels into it,
//!   stamps the header, sends and notifies an event; the receiver wakes on a
//!   WaitSet (as `outlet serve` does), receives the sample, checks its header and
//!   reads one byte of every 4 KiB page (the pixels are not copied).
//! - iceoryx2, listener: the same on a second service, but the receiver blocks
//!   in its listener's `timed_wait` (no WaitSet: the leanest way to wait).
//! - socket: the camera stamps the header and writes header and pixels; the
//!   receiver reads the whole frame into a buffer it reuses.
//!
//! The stamps are `CLOCK_MONOTONIC`, one clock for both processes: the camera's
//! goes in the header (`capture_time_ns`), the receiver takes its own once it
//! holds the complete frame and reports the differences back on its stdout.
//!
//! Without `--bench` (`cargo test --benches`) it runs a few frames only, as a
//! smoke test.

use anyhow::{Context, Result, anyhow, bail, ensure};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::waitset::WaitSetRunResult;
use nix::time::{ClockId, clock_gettime};
use outlet_protocol::CameraModel;
use outlet_protocol::wire::{FrameHeader, PixelFormat};
use std::collections::BTreeMap;
use std::fmt::Debug;
use std::io::{BufRead, BufReader, ErrorKind, Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

/// Set to [`RECEIVER`] in the receiver process.
const ROLE_ENV: &str = "OUTLET_BENCH_TRANSPORT_ROLE";
const RECEIVER: &str = "receiver";
/// The iceoryx2 service name prefix, for the receiver.
const SERVICE_ENV: &str = "OUTLET_BENCH_TRANSPORT_SERVICE";
/// The Unix socket's path, for the receiver.
const SOCKET_ENV: &str = "OUTLET_BENCH_TRANSPORT_SOCKET";

/// Frame sizes (rgb8, 3 bytes a pixel).
const SIZES: [(u32, u32); 3] = [(640, 480), (1280, 960), (1920, 1080)];
const CHANNELS: usize = 3;
/// Time between two frames (of any transport): each transport gets a frame
/// every three periods.
const PERIOD: Duration = Duration::from_millis(5);
/// Idle time the receiver gets at least between two frames, if a send overran.
const MIN_GAP: Duration = Duration::from_millis(2);
/// Frames per size and transport that are sent but not counted.
const WARMUP: u64 = 50;
/// Frames per size and transport that are counted.
const SAMPLES: u64 = 600;
/// The frame id that ends an iceoryx2 stream (the socket ends by closing).
const END_FRAME_ID: u64 = u64::MAX;
/// The receiver touches one byte of each page of a shared-memory frame.
const PAGE: usize = 4096;
/// The largest frame a receiver accepts from the socket.
const MAX_FRAME_BYTES: usize = 64 << 20;
/// The receiver gives up when no frame came for this long.
const IDLE_LIMIT: Duration = Duration::from_secs(30);
/// How long a receiver blocks before it checks [`IDLE_LIMIT`].
const WAKE_CHECK: Duration = Duration::from_secs(1);

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Transport {
    /// iceoryx2, the receiver waiting on a WaitSet.
    WaitSet,
    /// iceoryx2, the receiver blocking in its listener.
    Listener,
    /// A Unix-domain stream socket.
    Socket,
}

impl Transport {
    const ALL: [Self; 3] = [Self::WaitSet, Self::Listener, Self::Socket];

    /// The name in the receiver's report.
    fn key(self) -> &'static str {
        match self {
            Self::WaitSet => "iceoryx2-waitset",
            Self::Listener => "iceoryx2-listener",
            Self::Socket => "socket",
        }
    }

    /// The name in the table.
    fn label(self) -> &'static str {
        match self {
            Self::WaitSet => "iceoryx2, WaitSet",
            Self::Listener => "iceoryx2, listener",
            Self::Socket => "Unix socket",
        }
    }

    /// The iceoryx2 service of an iceoryx2 transport.
    fn service(self, prefix: &str) -> String {
        format!("{prefix}/{}", self.key())
    }
}

/// One received frame, as the receiver reports it. Times are nanoseconds from
/// the camera's send stamp.
#[derive(Debug, Clone, Copy)]
struct Record {
    transport: Transport,
    width: u32,
    height: u32,
    frame_id: u64,
    /// The receiver woke: the WaitSet's callback began, the listener's wait
    /// returned, the socket's frame header had been read.
    woke_ns: u64,
    /// The frame was in hand: `receive()` returned the sample (iceoryx2), the
    /// last byte was read (socket).
    held_ns: u64,
    /// The receiver was done: header checked and, for iceoryx2, every page of
    /// the pixels touched. The latency the tables report.
    done_ns: u64,
}

impl Record {
    fn to_line(self) -> String {
        let Self { transport, width, height, frame_id, woke_ns, held_ns, done_ns } = self;
        format!("record {} {width} {height} {frame_id} {woke_ns} {held_ns} {done_ns}", transport.key())
    }

    fn from_line(line: &str) -> Result<Self> {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let ["record", transport, width, height, frame_id, woke_ns, held_ns, done_ns] = fields[..] else {
            bail!("the receiver said {line:?}, expected `record` and 7 fields");
        };
        let number =
            |s: &str| s.parse::<u64>().with_context(|| format!("the receiver said {line:?}: {s:?} is no number"));
        Ok(Self {
            transport: Transport::ALL
                .into_iter()
                .find(|t| t.key() == transport)
                .ok_or_else(|| anyhow!("the receiver said {line:?}: unknown transport"))?,
            width: u32::try_from(number(width)?)?,
            height: u32::try_from(number(height)?)?,
            frame_id: number(frame_id)?,
            woke_ns: number(woke_ns)?,
            held_ns: number(held_ns)?,
            done_ns: number(done_ns)?,
        })
    }
}

fn main() {
    let outcome = if std::env::var(ROLE_ENV).is_ok_and(|role| role == RECEIVER) {
        receiver()
    } else {
        // `cargo bench` passes `--bench`; `cargo test --benches` does not.
        let full = std::env::args().any(|a| a == "--bench");
        camera(if full { (WARMUP, SAMPLES) } else { (5, 20) })
    };
    if let Err(e) = outcome {
        eprintln!("transport bench: {e:#}");
        std::process::exit(1);
    }
}

/// `CLOCK_MONOTONIC` in nanoseconds: the same clock in every process.
fn now_ns() -> Result<u64> {
    let t = clock_gettime(ClockId::CLOCK_MONOTONIC).context("clock_gettime(CLOCK_MONOTONIC)")?;
    Ok(t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
}

/// iceoryx2's errors, with what was being done.
fn iox<T, E: Debug>(result: Result<T, E>, what: &str) -> Result<T> {
    result.map_err(|e| anyhow!("iceoryx2: {what}: {e:?}"))
}

fn service_name(name: &str) -> Result<ServiceName> {
    iox(ServiceName::new(name), &format!("service name {name:?}"))
}

fn camera_of(width: u32, height: u32) -> Result<CameraModel> {
    let f = 0.82 * width as f64;
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    Ok(CameraModel::new(width, height, [f, f, cx, cy], [0.0; 5])?)
}

/// The camera's end of an iceoryx2 transport: frames and the event that wakes
/// the receiver.
struct ShmSender {
    publisher: Publisher<ipc::Service, [u8], FrameHeader>,
    notifier: Notifier<ipc::Service>,
}

impl ShmSender {
    fn create(node: &Node<ipc::Service>, name: &str, max_len: usize) -> Result<Self> {
        let frames = iox(
            node.service_builder(&service_name(name)?)
                .publish_subscribe::<[u8]>()
                .user_header::<FrameHeader>()
                .max_publishers(1)
                .max_subscribers(1)
                .history_size(0)
                .subscriber_max_buffer_size(2)
                // A full reader buffer loses its oldest frame; the camera never waits.
                .enable_safe_overflow(true)
                .create(),
            &format!("creating {name}"),
        )?;
        let events = iox(node.service_builder(&service_name(name)?).event().create(), "creating an event service")?;
        Ok(Self {
            publisher: iox(frames.publisher_builder().initial_max_slice_len(max_len).create(), "publisher")?,
            notifier: iox(events.notifier_builder().create(), "notifier")?,
        })
    }

    /// Loans, writes the pixels, stamps the header just before `send()`, sends
    /// and notifies.
    fn send(&self, frame_id: u64, pixels: &[u8], camera: &CameraModel) -> Result<()> {
        let sample = iox(self.publisher.loan_slice_uninit(pixels.len()), "loaning a frame")?;
        let mut sample = sample.write_from_slice(pixels);
        *sample.user_header_mut() = FrameHeader::new(frame_id, now_ns()?, PixelFormat::Rgb8, camera);
        iox(sample.send(), "sending a frame")?;
        iox(self.notifier.notify(), "notifying the receiver")?;
        Ok(())
    }

    fn send_end(&self) -> Result<()> {
        let end = iox(self.publisher.loan_slice_uninit(1), "loaning the end marker")?;
        let mut end = end.write_from_fn(|_| 0);
        end.user_header_mut().frame_id = END_FRAME_ID;
        iox(end.send(), "sending the end marker")?;
        iox(self.notifier.notify(), "notifying the receiver")?;
        Ok(())
    }
}

/// The camera process: sends the frames, collects the receiver's records,
/// prints the tables.
fn camera((warmup, samples): (u64, u64)) -> Result<()> {
    let pid = std::process::id();
    let prefix = format!("outlet/bench/transport/{pid}");
    let socket_path = std::env::temp_dir().join(format!("outlet-bench-transport-{pid}.sock"));
    let max_len = SIZES.iter().map(|&(w, h)| w as usize * h as usize * CHANNELS).max().unwrap_or(0);

    let node = iox(NodeBuilder::new().create::<ipc::Service>(), "node")?;
    let waitset_link = ShmSender::create(&node, &Transport::WaitSet.service(&prefix), max_len)?;
    let listener_link = ShmSender::create(&node, &Transport::Listener.service(&prefix), max_len)?;
    let socket = SocketFile::bind(socket_path)?;

    let mut receiver = Receiver::spawn(&prefix, &socket.path)?;
    receiver.wait_until_ready()?;
    let (mut stream, _) = socket.listener.accept().context("accepting the receiver's connection")?;

    let mut source: Vec<u8> = (0..max_len).map(|i| (i % 251) as u8).collect();
    let mut next = Instant::now() + PERIOD;
    for (width, height) in SIZES {
        let camera = camera_of(width, height)?;
        let len = width as usize * height as usize * CHANNELS;
        let pixels = &mut source[..len];
        for frame_id in 0..warmup + samples {
            // The first and last byte say which frame this is: the receiver checks them.
            pixels[0] = frame_id as u8;
            pixels[len - 1] = frame_id as u8;
            for transport in Transport::ALL {
                let now = Instant::now();
                if next > now {
                    std::thread::sleep(next - now);
                }
                match transport {
                    Transport::WaitSet => waitset_link.send(frame_id, pixels, &camera)?,
                    Transport::Listener => listener_link.send(frame_id, pixels, &camera)?,
                    Transport::Socket => {
                        let header = FrameHeader::new(frame_id, now_ns()?, PixelFormat::Rgb8, &camera);
                        stream.write_all(&encode_header(&header)).context("writing a frame header to the socket")?;
                        stream.write_all(pixels).context("writing a frame to the socket")?;
                    }
                }
                next = (next + PERIOD).max(Instant::now() + MIN_GAP);
            }
        }
    }
    waitset_link.send_end()?;
    listener_link.send_end()?;
    drop(stream);

    let records = receiver.finish()?;
    print_tables(&records, warmup, samples);
    Ok(())
}

/// The socket file, removed again when done.
struct SocketFile {
    path: PathBuf,
    listener: UnixListener,
}

impl SocketFile {
    fn bind(path: PathBuf) -> Result<Self> {
        match std::fs::remove_file(&path) {
            Ok(()) => {}
            Err(e) if e.kind() == ErrorKind::NotFound => {}
            Err(e) => return Err(e).with_context(|| format!("removing the stale socket {}", path.display())),
        }
        let listener = UnixListener::bind(&path).with_context(|| format!("binding {}", path.display()))?;
        Ok(Self { path, listener })
    }
}

impl Drop for SocketFile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// The receiver process, seen from the camera; ended if the camera stops early.
struct Receiver {
    child: Child,
    lines: std::io::Lines<BufReader<ChildStdout>>,
}

impl Receiver {
    fn spawn(service_prefix: &str, socket: &Path) -> Result<Self> {
        let exe = std::env::current_exe().context("finding this benchmark's executable")?;
        let mut child = Command::new(&exe)
            .env(ROLE_ENV, RECEIVER)
            .env(SERVICE_ENV, service_prefix)
            .env(SOCKET_ENV, socket)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .with_context(|| format!("starting the receiver {}", exe.display()))?;
        let stdout = child.stdout.take().ok_or_else(|| anyhow!("the receiver has no stdout"))?;
        Ok(Self { child, lines: BufReader::new(stdout).lines() })
    }

    fn next_line(&mut self) -> Result<Option<String>> {
        self.lines.next().transpose().context("reading the receiver's output")
    }

    fn wait_until_ready(&mut self) -> Result<()> {
        match self.next_line()? {
            Some(line) if line == "ready" => Ok(()),
            Some(line) => bail!("the receiver said {line:?} instead of \"ready\""),
            None => bail!("the receiver stopped before it was ready"),
        }
    }

    fn finish(mut self) -> Result<Vec<Record>> {
        let mut records = Vec::new();
        while let Some(line) = self.next_line()? {
            records.push(Record::from_line(&line)?);
        }
        let status = self.child.wait().context("waiting for the receiver")?;
        ensure!(status.success(), "the receiver failed: {status}");
        Ok(records)
    }
}

impl Drop for Receiver {
    fn drop(&mut self) {
        // Ends the receiver if the camera gave up early; after `wait` this does nothing.
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The receiver process: the WaitSet on the main thread, the listener and the
/// socket on threads of their own.
fn receiver() -> Result<()> {
    let prefix = std::env::var(SERVICE_ENV).with_context(|| format!("{SERVICE_ENV} is not set"))?;
    let socket_path = std::env::var(SOCKET_ENV).with_context(|| format!("{SOCKET_ENV} is not set"))?;

    let (ready_tx, ready_rx) = mpsc::channel::<Result<()>>();
    let listener_thread = {
        let (name, ready) = (Transport::Listener.service(&prefix), ready_tx.clone());
        std::thread::spawn(move || receive_with_listener(&name, &ready))
    };
    let socket_thread = {
        let ready = ready_tx.clone();
        std::thread::spawn(move || receive_socket(&socket_path, &ready))
    };
    drop(ready_tx);

    let node = iox(NodeBuilder::new().create::<ipc::Service>(), "node")?;
    let (subscriber, listener) = open_shm(&node, &Transport::WaitSet.service(&prefix))?;
    let waitset = iox(WaitSetBuilder::new().create::<ipc::Service>(), "waitset")?;
    let guard = iox(waitset.attach_notification(&listener), "attaching the listener")?;
    for _ in 0..2 {
        ready_rx.recv().map_err(|_| anyhow!("a receiver thread stopped before it was ready"))??;
    }
    let mut stdout = std::io::stdout().lock();
    writeln!(stdout, "ready")?;
    stdout.flush()?;

    let mut records = Vec::new();
    let mut failure = None;
    let mut ended = false;
    let mut last_frame = Instant::now();
    while !ended {
        let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
            let woke = now_ns();
            if id.has_event_from(&guard) {
                let received = woke.and_then(|woke| {
                    iox(listener.try_wait(|_| {}), "clearing notifications")?;
                    receive_all(&subscriber, Transport::WaitSet, woke, &mut records)
                });
                match received {
                    Ok(end) => {
                        ended |= end;
                        last_frame = Instant::now();
                    }
                    Err(e) => {
                        failure = Some(e);
                        return CallbackProgression::Stop;
                    }
                }
            }
            CallbackProgression::Continue
        };
        let result = iox(waitset.wait_and_process_once_with_timeout(on_event, WAKE_CHECK), "waiting")?;
        if let Some(e) = failure.take() {
            return Err(e);
        }
        if let WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest = result {
            bail!("interrupted");
        }
        ensure!(last_frame.elapsed() < IDLE_LIMIT, "no frame on the WaitSet for {IDLE_LIMIT:?}");
    }
    for thread in [listener_thread, socket_thread] {
        records.extend(thread.join().map_err(|_| anyhow!("a receiver thread panicked"))??);
    }
    for record in records {
        writeln!(stdout, "{}", record.to_line())?;
    }
    stdout.flush()?;
    Ok(())
}

type FrameSubscriber = Subscriber<ipc::Service, [u8], FrameHeader>;

/// The receiver's end of an iceoryx2 transport.
fn open_shm(node: &Node<ipc::Service>, name: &str) -> Result<(FrameSubscriber, Listener<ipc::Service>)> {
    let frames = iox(
        node.service_builder(&service_name(name)?).publish_subscribe::<[u8]>().user_header::<FrameHeader>().open(),
        &format!("opening {name}"),
    )?;
    let events = iox(node.service_builder(&service_name(name)?).event().open(), "opening the event service")?;
    Ok((iox(frames.subscriber_builder().create(), "subscriber")?, iox(events.listener_builder().create(), "listener")?))
}

/// Tells the receiver's main thread whether set-up worked; on failure the
/// thread's own result is only a pointer to that report.
fn report_ready<T>(setup: Result<T>, ready: &mpsc::Sender<Result<()>>) -> Result<T> {
    match setup {
        Ok(v) => {
            let _ = ready.send(Ok(()));
            Ok(v)
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            bail!("set-up failed (reported)")
        }
    }
}

/// The listener transport: blocks in the listener, no WaitSet.
fn receive_with_listener(name: &str, ready: &mpsc::Sender<Result<()>>) -> Result<Vec<Record>> {
    let (_node, subscriber, listener) = report_ready(
        iox(NodeBuilder::new().create::<ipc::Service>(), "node")
            .and_then(|node| open_shm(&node, name).map(|(s, l)| (node, s, l))),
        ready,
    )?;
    let mut records = Vec::new();
    let mut last_frame = Instant::now();
    loop {
        let notifications = iox(listener.timed_wait(|_| {}, WAKE_CHECK), "waiting on the listener")?;
        let woke = now_ns()?;
        if notifications > 0 {
            last_frame = Instant::now();
        }
        if receive_all(&subscriber, Transport::Listener, woke, &mut records)? {
            return Ok(records);
        }
        ensure!(last_frame.elapsed() < IDLE_LIMIT, "no frame on the listener for {IDLE_LIMIT:?}");
    }
}

/// Every sample waiting in `subscriber`; true once the end marker came.
fn receive_all(
    subscriber: &FrameSubscriber,
    transport: Transport,
    woke: u64,
    records: &mut Vec<Record>,
) -> Result<bool> {
    let mut ended = false;
    while let Some(sample) = iox(subscriber.receive(), "receiving a frame")? {
        let held = now_ns()?;
        let header = *sample.user_header();
        if header.frame_id == END_FRAME_ID {
            ended = true;
            continue;
        }
        let pixels = sample.payload();
        header.validate(pixels.len())?;
        let touched = pixels.iter().step_by(PAGE).fold(0u8, |sum, &b| sum.wrapping_add(b));
        std::hint::black_box(touched);
        let done = now_ns()?;
        check_frame_marks(&header, pixels)?;
        records.push(record(transport, &header, [woke, held, done]));
    }
    Ok(ended)
}

/// The socket's frames until the camera closes it.
fn receive_socket(path: &str, ready: &mpsc::Sender<Result<()>>) -> Result<Vec<Record>> {
    let mut stream =
        report_ready(UnixStream::connect(path).with_context(|| format!("connecting to the socket {path}")), ready)?;
    let mut records = Vec::new();
    let mut header_bytes = [0u8; HEADER_BYTES];
    let mut pixels = Vec::new();
    loop {
        match stream.read_exact(&mut header_bytes) {
            Ok(()) => {}
            Err(e) if e.kind() == ErrorKind::UnexpectedEof => return Ok(records),
            Err(e) => return Err(e).context("reading a frame header from the socket"),
        }
        let woke = now_ns()?;
        let header = decode_header(&header_bytes);
        let len =
            (header.stride as usize).checked_mul(header.height as usize).filter(|&n| n <= MAX_FRAME_BYTES).ok_or_else(
                || anyhow!("frame {}: {} rows of {} bytes is too large", header.frame_id, header.height, header.stride),
            )?;
        pixels.resize(len, 0);
        stream.read_exact(&mut pixels).with_context(|| format!("reading frame {} from the socket", header.frame_id))?;
        let done = now_ns()?;
        header.validate(pixels.len())?;
        check_frame_marks(&header, &pixels)?;
        records.push(record(Transport::Socket, &header, [woke, done, done]));
    }
}

/// A frame's record from the receiver's stamps: woke, held, done.
fn record(transport: Transport, header: &FrameHeader, [woke, held, done]: [u64; 3]) -> Record {
    let since_sent = |t: u64| t.saturating_sub(header.capture_time_ns);
    Record {
        transport,
        width: header.width,
        height: header.height,
        frame_id: header.frame_id,
        woke_ns: since_sent(woke),
        held_ns: since_sent(held),
        done_ns: since_sent(done),
    }
}

/// The camera marks the first and last byte with the frame id.
fn check_frame_marks(header: &FrameHeader, pixels: &[u8]) -> Result<()> {
    let mark = header.frame_id as u8;
    let (first, last) = (pixels.first().copied(), pixels.last().copied());
    ensure!(
        first == Some(mark) && last == Some(mark),
        "frame {}: pixels marked {first:?} .. {last:?}, not {mark}: a stale or torn frame",
        header.frame_id
    );
    Ok(())
}

/// Bytes of a [`FrameHeader`] on the socket, little-endian, field by field (a
/// field added to the header stops [`decode_header`] compiling until it is here).
const HEADER_BYTES: usize = 4 + 4 + 8 + 8 + 4 * 4 + 4 * 8 + 5 * 8;

fn encode_header(h: &FrameHeader) -> [u8; HEADER_BYTES] {
    let mut out = [0u8; HEADER_BYTES];
    let mut at = 0;
    let mut put = |field: &[u8]| {
        out[at..at + field.len()].copy_from_slice(field);
        at += field.len();
    };
    put(&h.schema_version.to_le_bytes());
    put(&h.pixel_format.to_le_bytes());
    put(&h.frame_id.to_le_bytes());
    put(&h.capture_time_ns.to_le_bytes());
    for v in [h.width, h.height, h.stride, h.reserved] {
        put(&v.to_le_bytes());
    }
    for v in h.intrinsics.iter().chain(&h.distortion) {
        put(&v.to_le_bytes());
    }
    out
}

fn decode_header(bytes: &[u8; HEADER_BYTES]) -> FrameHeader {
    let mut rest: &[u8] = bytes;
    let mut take = |n: usize| {
        let (field, tail) = rest.split_at(n);
        rest = tail;
        field
    };
    // The sizes below add up to HEADER_BYTES, so every conversion succeeds.
    let mut u32_ = || u32::from_le_bytes(take(4).try_into().unwrap());
    let (schema_version, pixel_format) = (u32_(), u32_());
    let mut u64_ = || u64::from_le_bytes(take(8).try_into().unwrap());
    let (frame_id, capture_time_ns) = (u64_(), u64_());
    let mut u32_ = || u32::from_le_bytes(take(4).try_into().unwrap());
    let (width, height, stride, reserved) = (u32_(), u32_(), u32_(), u32_());
    let mut f64_ = || f64::from_le_bytes(take(8).try_into().unwrap());
    let intrinsics = [f64_(), f64_(), f64_(), f64_()];
    let distortion = [f64_(), f64_(), f64_(), f64_(), f64_()];
    FrameHeader {
        schema_version,
        pixel_format,
        frame_id,
        capture_time_ns,
        width,
        height,
        stride,
        reserved,
        intrinsics,
        distortion,
    }
}

/// Median, 99th percentile and maximum, microseconds (nearest rank).
fn summary(mut ns: Vec<u64>) -> Option<[f64; 3]> {
    ns.sort_unstable();
    let n = ns.len();
    let rank = |q: f64| ns[((q * n as f64).ceil() as usize).clamp(1, n) - 1] as f64 / 1e3;
    (n > 0).then(|| [rank(0.5), rank(0.99), ns[n - 1] as f64 / 1e3])
}

fn print_tables(records: &[Record], warmup: u64, samples: u64) {
    let mut by_key: BTreeMap<((u32, u32), Transport), Vec<Record>> = BTreeMap::new();
    for r in records.iter().filter(|r| r.frame_id >= warmup) {
        by_key.entry(((r.width, r.height), r.transport)).or_default().push(*r);
    }
    let stats = |size: (u32, u32), t: Transport, stamp: fn(&Record) -> u64| {
        summary(by_key.get(&(size, t)).map_or_else(Vec::new, |rs| rs.iter().map(stamp).collect()))
    };
    let cell = |v: Option<f64>| v.map_or("-".to_string(), |v| format!("{v:.1}"));

    println!(
        "\nFrame transport latency, publish to receive, between two processes: {samples} frames per size and \
         transport after {warmup} warm-up frames, one frame every {} ms, transports in turn. Microseconds.\n",
        PERIOD.as_millis()
    );
    println!("| frame (rgb8) | MB | transport | median | p99 | max | socket / this, median |");
    println!("|---|---:|---|---:|---:|---:|---:|");
    for size @ (w, h) in SIZES {
        let socket = stats(size, Transport::Socket, |r| r.done_ns);
        for t in Transport::ALL {
            let s = stats(size, t, |r| r.done_ns);
            let ratio = match (s, socket) {
                (Some(s), Some(k)) if s[0] > 0.0 => format!("{:.1}", k[0] / s[0]),
                _ => "-".to_string(),
            };
            println!(
                "| {w}x{h} | {:.2} | {} | {} | {} | {} | {ratio} |",
                (w as usize * h as usize * CHANNELS) as f64 / 1e6,
                t.label(),
                cell(s.map(|s| s[0])),
                cell(s.map(|s| s[1])),
                cell(s.map(|s| s[2])),
            );
        }
    }

    println!("\nWhere the time goes: medians from the send stamp, microseconds.\n");
    println!("| frame (rgb8) | transport | woke | frame in hand | done |");
    println!("|---|---|---:|---:|---:|");
    for size @ (w, h) in SIZES {
        for t in Transport::ALL {
            let median = |stamp: fn(&Record) -> u64| cell(stats(size, t, stamp).map(|s| s[0]));
            let (woke, held, done) = (median(|r| r.woke_ns), median(|r| r.held_ns), median(|r| r.done_ns));
            println!("| {w}x{h} | {} | {woke} | {held} | {done} |", t.label());
        }
    }
    println!(
        "\nwoke: the WaitSet's callback began, the listener's wait returned, the socket's header was read; \
         frame in hand: `receive()` returned, the last byte was read; done: header checked, one byte per 4 KiB \
         page read (iceoryx2)."
    );

    for size @ (w, h) in SIZES {
        for t in Transport::ALL {
            let n = by_key.get(&(size, t)).map_or(0, Vec::len);
            if n as u64 != samples {
                println!("\n{w}x{h} {}: {n} of {samples} frames arrived", t.label());
            }
        }
    }
}
