//! `outlet detect` (CONTRACT.md) and `outlet train`.

use anyhow::{Context, Result, bail};
use clap::Args;
use nalgebra::Point2;
use nalgebra::Vector3;
use outlet::templates;
use outlet_detector::candidates::find_candidates;
use outlet_detector::descriptor::DescriptorParams;
use outlet_detector::detect::{Detection, Detector, DetectorParams};
use outlet_detector::grey_of;
use outlet_detector::template::{TrainingImage, TrainingOptions, train_template_with};
use outlet_detector::track::{Searched, TrackParams, Tracker};
use outlet_normal::{PlaneParams, fit_wall_plane};
use outlet_pose::{OutletPose, PoseError, solve_mono, solve_normal};
use outlet_protocol::camera_info::read_camera_info;
use outlet_protocol::ply::read_ply;
use outlet_protocol::truth::PoseJson;
use outlet_protocol::{CameraModel, OutletGeometry};
use serde_json::{Value, json};
use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Args, Debug)]
pub struct DetectArgs {
    /// Template: `2x1`, `2x2` or a template file written by `outlet train`.
    #[arg(long, default_value = "2x1")]
    pub template: String,
    /// ROS camera_info YAML of the camera (plumb_bob distortion honoured).
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Wall normal in the camera frame "NX,NY,NZ" (either sign).
    #[arg(long, allow_hyphen_values = true, conflicts_with = "points")]
    pub normal: Option<String>,
    /// Stereo cloud of the wall (PLY, camera frame, metres).
    #[arg(long)]
    pub points: Option<PathBuf>,
    /// With a cloud: what its plane cannot know, one sigma each, "FACE_MM,TILT_DEG,DISTANCE_MM":
    /// the receptacle face's offset from the nominal 5.0 mm and the stereo pair's bias on the
    /// wall's normal and distance. "0,0,0" trusts the cloud and the nominal face fully.
    #[arg(long, default_value = "1.15,0.48,1.32", value_parser = outlet::ModelError::parse)]
    pub model_error: outlet::ModelError,
    /// One JSON object per image on stdout.
    #[arg(long)]
    pub json: bool,
    /// JSON lines manifest: {"image": P, "camera": P, "template": T, "normal": [x,y,z] | "points": P}.
    #[arg(long, conflicts_with = "images")]
    pub batch: Option<PathBuf>,
    /// Draw the found holes and the classified candidates: a PNG file for one
    /// image, a folder for several.
    #[arg(long)]
    pub annotate: Option<PathBuf>,
    /// Take the images, in the order given, as consecutive frames of one camera
    /// at this many frames per second, tracked as `outlet serve detector` does:
    /// after a frame with an outlet, the next is searched first in a window
    /// around it. Each record then says where it was searched ("searched").
    #[arg(long, value_name = "FPS")]
    pub track: Option<f64>,
    /// Images to search.
    pub images: Vec<PathBuf>,
}

/// The trackers of `--track`, one per template, and the frame clock.
struct Tracking {
    fps: f64,
    frame: u64,
    trackers: HashMap<String, Tracker>,
}

/// One image to process, with what goes with it.
struct Job {
    image: PathBuf,
    camera: Option<PathBuf>,
    template: String,
    wall: Wall,
}

/// What is known of the wall for the pose.
#[derive(Debug, Clone)]
enum Wall {
    Unknown,
    Normal(Vector3<f64>),
    Points(PathBuf),
}

/// Templates are trained or read once per run, whatever the number of images.
#[derive(Default)]
struct Detectors {
    cache: HashMap<String, Detector>,
}

impl Detectors {
    fn get(&mut self, name: &str) -> Result<&Detector> {
        if !self.cache.contains_key(name) {
            let template = templates::load(name).with_context(|| format!("loading template {name}"))?;
            self.cache.insert(name.to_string(), Detector::new(template, DetectorParams::default()));
        }
        self.cache.get(name).context("template cache")
    }
}

fn read_manifest(path: &Path, default_template: &str) -> Result<Vec<Result<Job, String>>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading manifest {}", path.display()))?;
    let base = path.parent().unwrap_or(Path::new("."));
    let resolve = |p: &str| {
        let p = Path::new(p);
        if p.is_absolute() { p.to_path_buf() } else { base.join(p) }
    };
    Ok(text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(n, line)| {
            let v: Value = serde_json::from_str(line).map_err(|e| format!("manifest line {}: {e}", n + 1))?;
            let image = v["image"].as_str().ok_or_else(|| format!("manifest line {}: no \"image\"", n + 1))?;
            let wall = match (v["normal"].as_array(), v["points"].as_str()) {
                (Some(values), _) => {
                    let v: Vec<f64> = values.iter().filter_map(Value::as_f64).collect();
                    let [x, y, z] = v[..] else {
                        return Err(format!("manifest line {}: \"normal\" needs 3 numbers", n + 1));
                    };
                    Wall::Normal(Vector3::new(x, y, z))
                }
                (None, Some(p)) => Wall::Points(resolve(p)),
                (None, None) => Wall::Unknown,
            };
            Ok(Job {
                image: resolve(image),
                camera: v["camera"].as_str().map(resolve),
                template: v["template"].as_str().unwrap_or(default_template).to_string(),
                wall,
            })
        })
        .collect())
}

pub fn detect(args: DetectArgs) -> Result<()> {
    let wall = match (&args.normal, &args.points) {
        (Some(n), _) => Wall::Normal(parse_normal(n)?),
        (None, Some(p)) => Wall::Points(p.clone()),
        (None, None) => Wall::Unknown,
    };
    let jobs: Vec<Result<Job, String>> = match &args.batch {
        Some(manifest) => read_manifest(manifest, &args.template)?,
        None if args.images.is_empty() => bail!("no image given: name images or --batch MANIFEST.jsonl"),
        None => args
            .images
            .iter()
            .map(|p| {
                Ok(Job {
                    image: p.clone(),
                    camera: args.camera.clone(),
                    template: args.template.clone(),
                    wall: wall.clone(),
                })
            })
            .collect(),
    };
    let mut tracking = match args.track {
        Some(fps) if !(fps.is_finite() && fps > 0.0) => bail!("--track {fps}: frames per second must be positive"),
        Some(fps) => Some(Tracking { fps, frame: 0, trackers: HashMap::new() }),
        None => None,
    };
    let mut detectors = Detectors::default();
    let mut processed = 0;
    let stdout = std::io::stdout();
    let several = jobs.len() > 1;
    for job in &jobs {
        let record = match job {
            Ok(job) => match run_one(
                job,
                &mut detectors,
                tracking.as_mut(),
                args.annotate.as_deref(),
                several,
                &args.model_error,
            ) {
                Ok(record) => {
                    processed += 1;
                    record
                }
                Err(e) => json!({"image": job.image.display().to_string(), "found": false, "error": format!("{e:#}")}),
            },
            Err(e) => json!({"image": null, "found": false, "error": e}),
        };
        let mut out = stdout.lock();
        if args.json {
            writeln!(out, "{record}")?;
        } else {
            writeln!(out, "{}", human(&record))?;
        }
    }
    if processed == 0 {
        bail!("no input could be processed");
    }
    Ok(())
}

fn run_one(
    job: &Job,
    detectors: &mut Detectors,
    tracking: Option<&mut Tracking>,
    annotate: Option<&Path>,
    several: bool,
    model_error: &outlet::ModelError,
) -> Result<Value> {
    let camera: Option<CameraModel> = job.camera.as_deref().map(read_camera_info).transpose()?;
    let decoded = image::open(&job.image).with_context(|| format!("reading image {}", job.image.display()))?;
    if decoded.width() == 0 || decoded.height() == 0 {
        bail!("image {} is empty", job.image.display());
    }
    // A grey image (mono8 PNG, PGM) is what the detector works on: used as it is.
    let (image, luma) = match decoded {
        image::DynamicImage::ImageLuma8(grey) => (None, Some(grey)),
        other => (Some(other.into_rgb8()), None),
    };
    let size = image.as_ref().map(|i| i.dimensions()).or(luma.as_ref().map(|g| g.dimensions())).unwrap_or_default();
    if let Some(c) = &camera
        && (c.width, c.height) != size
    {
        bail!("image {} is {}x{} but camera_info says {}x{}", job.image.display(), size.0, size.1, c.width, c.height);
    }
    let detector = detectors.get(&job.template)?;
    let t = Instant::now();
    // The timing starts before a colour frame is made grey, as `Detector::detect` times it.
    let grey = match (luma, &image) {
        (Some(grey), _) => grey,
        (None, Some(rgb)) => grey_of(rgb),
        (None, None) => bail!("image {} has no pixels", job.image.display()),
    };
    let (report, searched) = match tracking {
        Some(tracking) => {
            let time_s = tracking.frame as f64 / tracking.fps;
            tracking.frame += 1;
            let tracker =
                tracking.trackers.entry(job.template.clone()).or_insert_with(|| Tracker::new(TrackParams::default()));
            let tracked = tracker.detect_grey(detector, &grey, camera.as_ref(), time_s);
            let searched = match tracked.searched {
                Searched::Window(_) => "window",
                Searched::Followed(_) => "followed",
                Searched::FullFrame { after_window: false } => "full_frame",
                Searched::FullFrame { after_window: true } => "full_frame_after_window",
            };
            (tracked.report, Some(searched))
        }
        None => (detector.detect_grey(&grey, camera.as_ref()), None),
    };
    let detect_ms = t.elapsed().as_secs_f64() * 1e3;
    if let Some(path) = annotate {
        let out = if several {
            std::fs::create_dir_all(path)?;
            let stem = job.image.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
            path.join(format!("{stem}.annotated.png"))
        } else {
            path.to_path_buf()
        };
        let image = image.unwrap_or_else(|| image::DynamicImage::ImageLuma8(grey).to_rgb8());
        outlet_detector::annotate::draw_report(&image, &report)
            .save_with_format(&out, image::ImageFormat::Png)
            .with_context(|| format!("writing {}", out.display()))?;
    }
    let t = Instant::now();
    // An ambiguous mono pose, or a plane that cannot explain the holes, is no
    // pose: positions and pose null, and why.
    let mut pose_status = None;
    let pose = match (&report.detection, &camera) {
        (Some(d), Some(camera)) => match solve_pose(d, detector, camera, &job.wall, model_error) {
            Ok(p) => Some(p),
            Err(e) if matches!(e.downcast_ref::<PoseError>(), Some(PoseError::Ambiguous { .. })) => {
                pose_status = Some("ambiguous");
                None
            }
            // The stereo plane cannot explain the holes: no pose, as the sidecar says.
            Err(e) if matches!(e.downcast_ref::<PoseError>(), Some(PoseError::PlaneDisagrees { .. })) => {
                pose_status = Some("plane_mismatch");
                None
            }
            Err(e) => return Err(e),
        },
        _ => None,
    };
    let pose_ms = pose.as_ref().map(|_| t.elapsed().as_secs_f64() * 1e3);
    let holes: Vec<Value> = report
        .detection
        .iter()
        .flat_map(|d| d.holes.iter().enumerate())
        .map(|(i, h)| {
            let position = pose.as_ref().map(|p| {
                let x = p.holes_cam_m[i];
                [x.x, x.y, x.z]
            });
            let covariance = pose.as_ref().map(|p| {
                let c = p.covariances[i];
                [
                    [c[(0, 0)], c[(0, 1)], c[(0, 2)]],
                    [c[(1, 0)], c[(1, 1)], c[(1, 2)]],
                    [c[(2, 0)], c[(2, 1)], c[(2, 2)]],
                ]
            });
            let c = h.covariance_px();
            let covariance_px = [[c[(0, 0)], c[(0, 1)]], [c[(1, 0)], c[(1, 1)]]];
            json!({
                "kind": h.kind.as_str(),
                "pixel": [h.pixel.x, h.pixel.y],
                "position_m": position,
                "covariance_m2": covariance,
                "score": h.score,
                "sigma_px": h.sigma_px,
                "covariance_px": covariance_px,
            })
        })
        .collect();
    let pose_json = pose.as_ref().map(|p| {
        let mut v = serde_json::to_value(PoseJson::from_isometry(&p.pose)).unwrap_or(Value::Null);
        v["mode"] = json!(p.mode.as_str());
        v
    });
    let mut record = json!({
        "image": job.image.display().to_string(),
        "found": report.detection.is_some(),
        "template": job.template,
        "holes": holes,
        "pose": pose_json,
        "pose_status": pose_status.or(pose.as_ref().map(|_| "ok")),
        "timing_ms": {"detect": detect_ms, "pose": pose_ms},
    });
    if let Some(searched) = searched {
        record["searched"] = json!(searched);
    }
    Ok(record)
}

/// The wall normal given on the command line, "NX,NY,NZ".
fn parse_normal(text: &str) -> Result<Vector3<f64>> {
    let v: Vec<f64> = text
        .split(',')
        .map(|t| t.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("--normal {text:?} is not numbers"))?;
    let [x, y, z] = v[..] else { bail!("--normal {text:?} needs 3 numbers NX,NY,NZ") };
    let n = Vector3::new(x, y, z);
    if !n.iter().all(|c| c.is_finite()) || n.norm() < 1e-9 {
        bail!("--normal {text:?} is not a usable direction");
    }
    Ok(n)
}

/// Pixel noise of the detector's hole centres (px): the median error measured on
/// rendered scenarios is 0.15 px; a little more for real images.
const HOLE_PIXEL_SIGMA: f64 = 0.25;
/// Uncertainty of a wall normal given without one (radians): 1 degree.
const GIVEN_NORMAL_SIGMA_RAD: f64 = 0.017;

fn solve_pose(
    detection: &Detection,
    detector: &Detector,
    camera: &CameraModel,
    wall: &Wall,
    model_error: &outlet::ModelError,
) -> Result<OutletPose> {
    let geometry = &detector.template().geometry;
    // Each hole's own sigma from the detector's fit (HOLE_PIXEL_SIGMA where it has none).
    let holes = outlet::DetectedHoles::new(detection, geometry);
    let obs = holes.observations(camera, HOLE_PIXEL_SIGMA);
    let pose = match wall {
        Wall::Normal(n) => solve_normal(&obs, n, GIVEN_NORMAL_SIGMA_RAD)?,
        Wall::Points(path) => {
            let cloud = read_ply(path)?;
            let plane = fit_wall_plane(&cloud, &PlaneParams::default())
                .with_context(|| format!("fitting the wall to {}", path.display()))?;
            outlet::solve_plane_with_cloud(&obs, &plane, &cloud, geometry, model_error)?.0
        }
        Wall::Unknown => solve_mono(&obs)?,
    };
    Ok(pose)
}

fn human(record: &Value) -> String {
    let image = record["image"].as_str().unwrap_or("?");
    if let Some(e) = record["error"].as_str() {
        return format!("{image}: error: {e}");
    }
    let ms = record["timing_ms"]["detect"].as_f64().unwrap_or(f64::NAN);
    match record["holes"].as_array() {
        Some(holes) if !holes.is_empty() => {
            let list: Vec<String> = holes
                .iter()
                .map(|h| {
                    format!(
                        "{} ({:.2}, {:.2})",
                        h["kind"].as_str().unwrap_or("?"),
                        h["pixel"][0].as_f64().unwrap_or(f64::NAN),
                        h["pixel"][1].as_f64().unwrap_or(f64::NAN)
                    )
                })
                .collect();
            format!(
                "{image}: outlet {} found in {ms:.1} ms: {}",
                record["template"].as_str().unwrap_or("?"),
                list.join(", ")
            )
        }
        _ => format!("{image}: no outlet ({ms:.1} ms)"),
    }
}

#[derive(Args, Debug)]
pub struct TrainArgs {
    /// The one labelled image of the outlet.
    #[arg(long)]
    pub image: PathBuf,
    /// LABELS.json: {"holes": [{"kind": "power"|"ground", "pixel": [u, v]}, ...]} in the geometry's order.
    #[arg(long)]
    pub labels: PathBuf,
    /// `2x1`, `2x2` or a GEOMETRY.json.
    #[arg(long)]
    pub geometry: String,
    /// Images (or regions of them) without an outlet; without any, the training
    /// image's candidates away from the holes serve.
    #[arg(long)]
    pub background: Vec<PathBuf>,
    /// Template file to write.
    #[arg(long)]
    pub output: PathBuf,
    /// Also train each hole foreshortened by this factor (1/cos of an off-axis
    /// angle: 2.0 is 60 degrees), about three axes; repeat for several. None by
    /// default (see `TrainingOptions::tilts`).
    #[arg(long = "tilt")]
    pub tilts: Vec<f64>,
    /// Also train every other pose from the image at half resolution, as far
    /// holes look (off by default: BENCHMARKS.md, "Session 9: far samples
    /// withdrawn").
    #[arg(long)]
    pub far_samples: bool,
}

pub fn train(args: TrainArgs) -> Result<()> {
    let t = Instant::now();
    let geometry = OutletGeometry::builtin_or_file(&args.geometry)?;
    let image = image::open(&args.image).with_context(|| format!("reading image {}", args.image.display()))?.to_rgb8();
    let labels: Value = serde_json::from_str(
        &std::fs::read_to_string(&args.labels).with_context(|| format!("reading labels {}", args.labels.display()))?,
    )
    .with_context(|| format!("labels {} are not JSON", args.labels.display()))?;
    let holes =
        labels["holes"].as_array().with_context(|| format!("labels {}: no \"holes\" list", args.labels.display()))?;
    let mut pixels = Vec::with_capacity(holes.len());
    for (i, h) in holes.iter().enumerate() {
        let (Some(u), Some(v)) = (h["pixel"][0].as_f64(), h["pixel"][1].as_f64()) else {
            bail!("labels {}: hole {i} has no numeric \"pixel\": [u, v]", args.labels.display());
        };
        let kind = h["kind"].as_str().unwrap_or("");
        if let Some(model) = geometry.holes.get(i)
            && kind != model.kind.as_str()
        {
            bail!(
                "labels {}: hole {i} is {kind:?} but the geometry's hole {i} is {}",
                args.labels.display(),
                model.kind.as_str()
            );
        }
        pixels.push(Point2::new(u, v));
    }
    let progress = crate::progress::spinner("finding candidates");
    let grey = grey_of(&image);
    let params = outlet_detector::candidates::CandidateParams::default();
    let candidates = find_candidates(&grey, &params);
    let backgrounds: Vec<_> = args
        .background
        .iter()
        .map(|p| {
            let g = grey_of(&image::open(p).with_context(|| format!("reading background {}", p.display()))?.to_rgb8());
            let c = find_candidates(&g, &params);
            Ok((g, c))
        })
        .collect::<Result<_>>()?;
    let refs: Vec<_> = backgrounds.iter().map(|(g, c)| (g, c.clone())).collect();
    let name = args.output.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "template".into());
    progress.set_message("training the descriptor (affine views of every hole and background feature)");
    let options = TrainingOptions { calibrate_sizes: true, tilts: &args.tilts, far_samples: args.far_samples };
    let template = train_template_with(
        &name,
        geometry,
        &[TrainingImage { grey: &grey, holes: pixels, candidates }],
        &refs,
        &DescriptorParams::default(),
        &options,
    )?;
    template.write(&args.output)?;
    progress.finish_and_clear();
    let counts = template.descriptor.sample_counts();
    tracing::info!(
        "wrote {} ({} power, {} ground, {} background samples) in {:.0} ms",
        args.output.display(),
        counts[0],
        counts[1],
        counts[2],
        t.elapsed().as_secs_f64() * 1e3
    );
    Ok(())
}
