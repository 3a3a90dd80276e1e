//! Photographs as a camera: `outlet serve files` sends PNG and JPEG files (and,
//! with `--points`, a stereo cloud with each) at a rate on the services the
//! simulated camera uses ([`service::FRAMES`], [`service::CLOUDS`]), so that the
//! pipeline runs on logged images as on a live camera. On
//! [`service::FILES`] it says which file each frame was, which files it
//! skipped and why, and when the list is done.
//!
//! - The list: every file the `--images` patterns (globs, files, folders)
//!   name, PNG or JPEG by name, sorted by path, each once. Clouds go with
//!   images by file stem: `NAME.png` with `NAME.ply`.
//! - The camera: `--camera` for all, else per image `NAME.camera.yaml` (as
//!   `outlet render` writes), else `camera.yaml` in its folder; an image with
//!   neither stops the service at start, naming the image.
//! - A file that cannot be sent (unreadable, corrupt, not the camera's size,
//!   larger than [`MAX_FRAME_BYTES`], its cloud unreadable or missing) is
//!   logged with its name, counted as rejected and skipped, on every pass.
//!   The service stops only when a whole pass sent nothing.
//! - No frame goes out before something reads the frames (a detector starting
//!   up would miss the first files); without `--loop` the service keeps its
//!   heartbeat after the last file, until stopped.

use super::camera_out::CameraOutput;
use super::{Output, Runtime};
use anyhow::{Context, Result, bail};
use clap::Args;
use iceoryx2::prelude::*;
use outlet::health::Health;
use outlet_protocol::CameraModel;
use outlet_protocol::camera_info::read_camera_info;
use outlet_protocol::ply::read_ply;
use outlet_protocol::wire::{FileFrameMsg, MAX_FRAME_BYTES, PixelFormat, file_status, service};
use std::collections::{BTreeMap, HashMap, HashSet};
use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

#[derive(Args, Debug, Clone)]
pub struct FilesArgs {
    /// The photographs (PNG, JPEG): glob patterns (quoted: 'DIR/*.png'), files or
    /// folders (their PNG and JPEG files), sent in the sorted order of their paths.
    #[arg(long, required = true, num_args = 1..)]
    pub images: Vec<String>,
    /// The camera_info YAML of every image (read as `outlet detect --camera` reads it).
    /// Without it: each image's NAME.camera.yaml (as `outlet render` writes), else
    /// camera.yaml in its folder.
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Stereo clouds (PLY, camera frame, metres), patterns as for --images; an
    /// image goes with the cloud of its file stem (NAME.png with NAME.ply), and an
    /// image without one is skipped.
    #[arg(long, num_args = 1..)]
    pub points: Vec<String>,
    /// Frames per second.
    #[arg(long, default_value_t = 10.0)]
    pub rate: f64,
    /// After the last file, start again from the first, until stopped.
    #[arg(long = "loop")]
    pub repeat: bool,
}

/// One image of the list, with what goes with it.
#[derive(Debug, Clone, PartialEq)]
struct Photo {
    image: PathBuf,
    /// Its camera_info file; None: the `--camera` one.
    camera: Option<PathBuf>,
    cloud: Option<PathBuf>,
    /// Why it cannot be sent, known before it is read.
    problem: Option<String>,
}

fn has_extension(path: &Path, extensions: &[&str]) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| extensions.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

fn is_image(path: &Path) -> bool {
    has_extension(path, &["png", "jpg", "jpeg"])
}

fn is_ply(path: &Path) -> bool {
    has_extension(path, &["ply"])
}

/// The files that `patterns` name (glob patterns, files, or folders for their
/// own files) and that `keep` accepts: sorted by path, each once. Matches that
/// `keep` refuses are logged once; entries that cannot be read are logged and
/// left out.
fn expand(flag: &str, patterns: &[String], keep: impl Fn(&Path) -> bool) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let mut left_out = Vec::new();
    for pattern in patterns {
        let matches = glob::glob(pattern).with_context(|| format!("{flag} {pattern:?} is not a glob pattern"))?;
        let before = files.len() + left_out.len();
        for entry in matches {
            let path = match entry {
                Ok(p) => p,
                Err(e) => {
                    tracing::warn!("{flag} {pattern:?}: {e}: left out");
                    continue;
                }
            };
            if path.is_dir() {
                let listing = std::fs::read_dir(&path).with_context(|| format!("reading folder {}", path.display()))?;
                files.extend(listing.flatten().map(|e| e.path()).filter(|p| p.is_file() && keep(p)));
            } else if keep(&path) {
                files.push(path);
            } else {
                left_out.push(path);
            }
        }
        if files.len() + left_out.len() == before {
            tracing::warn!("{flag} {pattern:?} names no file");
        }
    }
    if !left_out.is_empty() {
        let shown: Vec<String> = left_out.iter().take(5).map(|p| p.display().to_string()).collect();
        tracing::warn!(
            "{flag}: {} files are left out by their names' extension: {}{}",
            left_out.len(),
            shown.join(", "),
            if left_out.len() > shown.len() { ", ..." } else { "" }
        );
    }
    files.sort();
    files.dedup();
    Ok(files)
}

/// The camera_info file of `image` without `--camera`: `NAME.camera.yaml`
/// beside it, else `camera.yaml` in its folder.
fn camera_file(image: &Path) -> Option<PathBuf> {
    let folder = image.parent().unwrap_or(Path::new("."));
    let stem = image.file_stem()?.to_string_lossy();
    [folder.join(format!("{stem}.camera.yaml")), folder.join("camera.yaml")].into_iter().find(|p| p.is_file())
}

/// The list of photographs in the order they go out.
fn plan(args: &FilesArgs) -> Result<Vec<Photo>> {
    let images = expand("--images", &args.images, is_image)?;
    if images.is_empty() {
        bail!("--images {:?}: no PNG or JPEG file", args.images);
    }
    let mut clouds: BTreeMap<OsString, PathBuf> = BTreeMap::new();
    if !args.points.is_empty() {
        for cloud in expand("--points", &args.points, is_ply)? {
            let stem = cloud.file_stem().map(OsString::from).unwrap_or_default();
            if let Some(other) = clouds.insert(stem, cloud.clone()) {
                bail!(
                    "--points: two clouds of one name, {} and {}: an image goes with the cloud of its file stem",
                    other.display(),
                    cloud.display()
                );
            }
        }
        if clouds.is_empty() {
            bail!("--points {:?}: no PLY file", args.points);
        }
    }
    let mut photos = Vec::with_capacity(images.len());
    for image in images {
        let camera = match &args.camera {
            Some(_) => None,
            None => Some(camera_file(&image).with_context(|| {
                let stem = image.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
                format!(
                    "no camera for {}: give --camera CAMERA.yaml, or put {stem}.camera.yaml (as `outlet render` \
                     writes) or camera.yaml beside it",
                    image.display()
                )
            })?),
        };
        let stem = image.file_stem().map(OsString::from).unwrap_or_default();
        let cloud = clouds.get(&stem).cloned();
        let problem = (!args.points.is_empty() && cloud.is_none())
            .then(|| format!("no cloud named {}.ply among --points", stem.to_string_lossy()));
        photos.push(Photo { image, camera, cloud, problem });
    }
    let used: HashSet<&PathBuf> = photos.iter().filter_map(|p| p.cloud.as_ref()).collect();
    if used.len() < clouds.len() {
        tracing::warn!("--points: {} clouds go with no image", clouds.len() - used.len());
    }
    Ok(photos)
}

/// One photograph, ready to go out.
struct Frame {
    camera: CameraModel,
    image: image::RgbImage,
    cloud: Option<Vec<[f32; 3]>>,
}

/// The image as RGB, its size checked before anything is decoded.
fn decode(path: &Path) -> Result<image::RgbImage, String> {
    let open = || {
        image::ImageReader::open(path).and_then(|r| r.with_guessed_format()).map_err(|e| format!("cannot read it: {e}"))
    };
    let (width, height) = open()?.into_dimensions().map_err(|e| format!("not a readable PNG or JPEG: {e}"))?;
    if width == 0 || height == 0 {
        return Err(format!("the image is empty ({width}x{height})"));
    }
    let bytes = u64::from(width) * u64::from(height) * 3;
    if bytes > MAX_FRAME_BYTES as u64 {
        return Err(format!(
            "{width}x{height} is {:.1} MiB of RGB, more than a frame may have ({} MiB)",
            bytes as f64 / (1 << 20) as f64,
            MAX_FRAME_BYTES >> 20
        ));
    }
    let mut reader = open()?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(width);
    limits.max_image_height = Some(height);
    reader.limits(limits);
    let image = reader.decode().map_err(|e| format!("not a readable PNG or JPEG: {e}"))?;
    Ok(image.into_rgb8())
}

/// Reads a photograph with its camera and cloud; why it cannot be sent otherwise.
fn load(
    photo: &Photo,
    given: Option<&CameraModel>,
    cameras: &HashMap<PathBuf, Result<CameraModel, String>>,
) -> Result<Frame, String> {
    if let Some(problem) = &photo.problem {
        return Err(problem.clone());
    }
    let camera = match (&photo.camera, given) {
        (Some(path), _) => match cameras.get(path) {
            Some(Ok(c)) => *c,
            Some(Err(e)) => return Err(e.clone()),
            None => return Err(format!("camera {} was not read", path.display())),
        },
        (None, Some(c)) => *c,
        (None, None) => return Err("no camera".into()),
    };
    let image = decode(&photo.image)?;
    if image.dimensions() != (camera.width, camera.height) {
        return Err(format!(
            "the image is {}x{} but its camera_info says {}x{}",
            image.width(),
            image.height(),
            camera.width,
            camera.height
        ));
    }
    let cloud = match &photo.cloud {
        Some(path) => Some(read_ply(path).map_err(|e| format!("cloud {}: {e}", path.display()))?),
        None => None,
    };
    Ok(Frame { camera, image, cloud })
}

/// Where the feed is in its list.
struct Feed {
    photos: Vec<Photo>,
    next: usize,
    pass: u32,
    sent_this_pass: usize,
    /// Files found bad: skipped without reading them again.
    bad: HashSet<usize>,
    frame_id: u64,
    done: bool,
}

impl Feed {
    fn msg(&self, status: u32, index: usize) -> FileFrameMsg {
        let image = self.photos.get(index).map_or(String::new(), |p| p.image.display().to_string());
        FileFrameMsg::new(status, index as u32, self.pass, self.photos.len() as u32, &image)
    }
}

pub fn run(rt: &Runtime, args: &FilesArgs) -> Result<()> {
    if !(args.rate > 0.0 && args.rate.is_finite()) {
        bail!("--rate {}: not a positive number of frames per second", args.rate);
    }
    let given = match &args.camera {
        Some(p) => Some(read_camera_info(p).with_context(|| format!("--camera {}", p.display()))?),
        None => None,
    };
    let photos = plan(args)?;
    // Each camera file once; a bad one makes its images bad files.
    let mut cameras = HashMap::new();
    for path in photos.iter().filter_map(|p| p.camera.as_ref()) {
        if !cameras.contains_key(path) {
            let read = read_camera_info(path).map_err(|e| format!("camera {}: {e}", path.display()));
            cameras.insert(path.clone(), read);
        }
    }
    let output = CameraOutput::open_vga(rt)?;
    let files_out = Output::<FileFrameMsg>::open(rt, service::FILES)?;
    let waitset = rt.waitset()?;
    let shutter = waitset
        .attach_interval(Duration::from_secs_f64(1.0 / args.rate))
        .map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let tick = waitset.attach_interval(rt.heartbeat_period()).map_err(|e| anyhow::anyhow!("attach: {e:?}"))?;
    let mut health = Health::new(rt.name);
    let mut feed = Feed { photos, next: 0, pass: 0, sent_this_pass: 0, bad: HashSet::new(), frame_id: 0, done: false };
    let (mut reading, mut waiting_told) = (false, false);
    let mut failure = None;
    tracing::info!(
        "files ready: {} images{}{} at {} Hz{} -> {}{}, {}",
        feed.photos.len(),
        args.camera.as_ref().map_or(String::new(), |c| format!(", camera {}", c.display())),
        if args.points.is_empty() { "" } else { " with their clouds" },
        args.rate,
        if args.repeat { ", looping" } else { "" },
        service::FRAMES,
        if args.points.is_empty() { String::new() } else { format!(", {}", service::CLOUDS) },
        service::FILES
    );
    let on_event = |id: WaitSetAttachmentId<ipc::Service>| {
        if id.has_event_from(&tick) {
            rt.beat(&mut health);
        }
        if !id.has_event_from(&shutter) || feed.done {
            return CallbackProgression::Continue;
        }
        if !reading {
            if output.frame_readers() == 0 {
                if !waiting_told {
                    tracing::info!("waiting for a reader of {} (the detector) before the first frame", service::FRAMES);
                    waiting_told = true;
                }
                return CallbackProgression::Continue;
            }
            reading = true;
        }
        // The next file that goes out; bad files on the way are skipped.
        for _ in 0..feed.photos.len() {
            let index = feed.next;
            let mut sent = false;
            if !feed.bad.contains(&index) {
                health.input();
                let started = Instant::now();
                let photo = feed.photos[index].clone();
                match load(&photo, given.as_ref(), &cameras) {
                    Ok(frame) => {
                        let work_ms = started.elapsed().as_secs_f64() * 1e3;
                        feed.frame_id += 1;
                        let pixels = frame.image.as_raw();
                        match output.send(
                            feed.frame_id,
                            &frame.camera,
                            PixelFormat::Rgb8,
                            pixels,
                            frame.cloud.as_deref(),
                        ) {
                            Ok(stamp) => {
                                let mut msg = feed.msg(file_status::SENT, index);
                                msg.frame_id = feed.frame_id;
                                msg.capture_time_ns = stamp;
                                files_out.send(msg);
                                health.output(stamp, work_ms);
                                feed.sent_this_pass += 1;
                            }
                            // Shared memory, not the file: it is tried again on the next pass.
                            Err(e) => {
                                tracing::warn!(frame = feed.frame_id, "{}: publishing: {e}", photo.image.display())
                            }
                        }
                        sent = true;
                    }
                    Err(reason) => {
                        tracing::warn!("{}: skipped: {reason}", photo.image.display());
                        health.rejected(&format!("{}: {reason}", photo.image.display()));
                        feed.bad.insert(index);
                        let mut msg = feed.msg(file_status::SKIPPED, index);
                        msg.set_reason(&reason);
                        files_out.send(msg);
                    }
                }
            }
            feed.next += 1;
            if feed.next == feed.photos.len() {
                if feed.sent_this_pass == 0 {
                    failure = Some(anyhow::anyhow!(
                        "none of the {} images could be sent (each one's reason is logged above)",
                        feed.photos.len()
                    ));
                    return CallbackProgression::Stop;
                }
                if args.repeat {
                    feed.next = 0;
                    feed.pass += 1;
                    feed.sent_this_pass = 0;
                } else {
                    feed.done = true;
                    files_out.send(feed.msg(file_status::END, feed.photos.len()));
                    tracing::info!(
                        "all {} images gone through: {} sent, {} skipped; serving until stopped (--loop repeats them)",
                        feed.photos.len(),
                        feed.sent_this_pass,
                        feed.bad.len()
                    );
                }
            }
            if sent || feed.done {
                break;
            }
        }
        CallbackProgression::Continue
    };
    let waited = super::run_until_stopped(&waitset, on_event);
    rt.stopped(&health);
    if let Some(e) = failure {
        return Err(e);
    }
    waited?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(images: &[&str], points: &[&str], camera: Option<&Path>) -> FilesArgs {
        FilesArgs {
            images: images.iter().map(|s| s.to_string()).collect(),
            camera: camera.map(Path::to_path_buf),
            points: points.iter().map(|s| s.to_string()).collect(),
            rate: 10.0,
            repeat: false,
        }
    }

    fn touch(dir: &Path, name: &str) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, b"x").expect("write");
        p
    }

    #[test]
    fn images_are_sorted_each_once_with_the_cloud_and_camera_of_their_stem() {
        let dir = tempfile::tempdir().expect("tmp");
        let d = dir.path();
        for n in ["b.png", "a.jpg", "c.JPEG", "a.camera.yaml", "camera.yaml", "a.ply", "b.ply", "c.ply", "a.json"] {
            touch(d, n);
        }
        let pattern = format!("{}/*", d.display());
        let both = format!("{}/*.png", d.display());
        let points = format!("{}/*.ply", d.display());
        let photos = plan(&args(&[&pattern, &both], &[&points], None)).expect("plan");
        let names: Vec<_> = photos.iter().map(|p| p.image.file_name().expect("name").to_owned()).collect();
        assert_eq!(names, ["a.jpg", "b.png", "c.JPEG"]);
        assert_eq!(photos[0].camera.as_deref(), Some(d.join("a.camera.yaml").as_path()));
        assert_eq!(photos[1].camera.as_deref(), Some(d.join("camera.yaml").as_path()));
        assert_eq!(photos[1].cloud.as_deref(), Some(d.join("b.ply").as_path()));
        assert!(photos.iter().all(|p| p.problem.is_none()));
        // A folder names its images; an image without a cloud of its stem has a problem.
        let folder = d.display().to_string();
        std::fs::remove_file(d.join("c.ply")).expect("rm");
        let photos = plan(&args(&[&folder], &[&points], None)).expect("plan");
        assert_eq!(photos.len(), 3);
        assert_eq!(photos[2].problem.as_deref(), Some("no cloud named c.ply among --points"));
    }

    #[test]
    fn an_image_without_a_camera_is_named_unless_one_is_given() {
        let dir = tempfile::tempdir().expect("tmp");
        let image = touch(dir.path(), "photo.png");
        let pattern = image.display().to_string();
        let e = plan(&args(&[&pattern], &[], None)).expect_err("no camera");
        let text = format!("{e:#}");
        assert!(text.contains("photo.png") && text.contains("photo.camera.yaml"), "{text}");
        let given = dir.path().join("elsewhere.yaml");
        let photos = plan(&args(&[&pattern], &[], Some(&given))).expect("camera given");
        assert_eq!(photos[0].camera, None);
        let e = plan(&args(&[&format!("{}/*.png", dir.path().join("none").display())], &[], Some(&given)));
        assert!(format!("{:#}", e.expect_err("no images")).contains("no PNG or JPEG"));
    }

    #[test]
    fn a_corrupt_or_oversized_image_says_why_before_decoding() {
        let dir = tempfile::tempdir().expect("tmp");
        let garbage = touch(dir.path(), "garbage.png");
        assert!(decode(&garbage).expect_err("garbage").contains("not a readable PNG or JPEG"));
        // 5000 x 5000 RGB is 71.5 MiB: refused from the header alone.
        let big = dir.path().join("big.png");
        image::GrayImage::new(5000, 5000).save(&big).expect("save");
        let e = decode(&big).expect_err("too large");
        assert!(e.contains("5000x5000") && e.contains("64 MiB"), "{e}");
        let small = dir.path().join("small.png");
        image::RgbImage::from_pixel(4, 3, image::Rgb([1, 2, 3])).save(&small).expect("save");
        let rgb = decode(&small).expect("decodes");
        assert_eq!((rgb.dimensions(), rgb.get_pixel(3, 2).0), ((4, 3), [1, 2, 3]));
        assert!(decode(&dir.path().join("missing.png")).expect_err("missing").contains("cannot read it"));
    }
}
