//! `outlet eval --photos DIR`: detection on labelled photographs, and on new views
//! of each made by turning and zooming the camera about its centre.
//!
//! A camera that only rotates (and changes focal length) sees every scene through
//! the homography K' R K^-1 of the undistorted image, whatever the scene's depth:
//! the views are exact, and so are their labels. They change where the outlet
//! appears, its roll and its size in pixels, not the angle it is seen at (that
//! needs the camera to move; `scripts/photo_views.py` does it for a planar wall).
//! Each view also gets the photometric changes of another camera: gain, gamma,
//! noise, blur, JPEG.

use anyhow::{Context, Result, bail};
use image::{Rgb, RgbImage};
use nalgebra::{Matrix3, Point2, Rotation3, Unit, Vector3};
use outlet_detector::Class;
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_protocol::camera_info::{read_camera_info, write_camera_info};
use outlet_protocol::{CameraModel, OutletGeometry};
use outlet_sim::rng::SimRng as Rng;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// What `--photos` needs from `outlet eval`'s arguments.
pub struct PhotoEvalArgs<'a> {
    /// Folders of `*.labels.json`; an image or camera not beside its labels is
    /// looked for in the other folders (labels kept apart from the photographs).
    pub dirs: &'a [PathBuf],
    pub out: &'a Path,
    pub views: usize,
    pub seed: u64,
    /// A built-in template name or a template file; None: each label file's own.
    pub template: Option<&'a str>,
    /// The largest turn of the view's optical axis from the photo's (degrees).
    pub max_turn_deg: f64,
    /// Slot lengths (px) the zoomed views are drawn between.
    pub slot_px: [f64; 2],
    /// Views of each photograph written to `out/views` (PNG and camera_info YAML).
    pub save_views: usize,
}

/// One labelled photograph.
struct Photo {
    name: String,
    image: RgbImage,
    camera: CameraModel,
    /// Whether the camera came from a camera_info file (else a guessed pinhole).
    calibrated: bool,
    template: String,
    holes: Vec<Point2<f64>>,
}

#[derive(serde::Deserialize)]
struct LabelFile {
    image: String,
    template: Option<String>,
    holes: Vec<LabelHole>,
}

#[derive(serde::Deserialize)]
struct LabelHole {
    kind: String,
    pixel: [f64; 2],
}

/// The outcome of one view.
#[derive(Debug, Clone, serde::Serialize)]
struct ViewOutcome {
    photo: String,
    /// 0 is the photograph itself.
    view: usize,
    turn_deg: f64,
    /// The outlet's angle in the view, neutral to hot slot (degrees).
    outlet_angle_deg: f64,
    /// The neutral slot's length in the view (px), from the labels.
    slot_px: f64,
    /// The angle between the face's normal and the ray to the outlet (degrees),
    /// from the labels' homography: how obliquely the outlet is seen.
    off_axis_deg: f64,
    #[serde(flatten)]
    result: Evaluated,
}

/// What one image gave.
#[derive(Debug, Clone, serde::Serialize)]
struct Evaluated {
    found: bool,
    correct: bool,
    /// Per-hole distance from the label (px), template order, of a found outlet.
    errors_px: Vec<f64>,
    tolerance_px: f64,
    ms: f64,
    /// Of `ms`: candidates, classification, hashing, refinement and verification.
    stages_ms: [f64; 4],
    /// Per-hole reported standard deviation (px), template order, of a found outlet.
    sigma_px: Vec<f64>,
    /// Labelled holes with a candidate of their class within the tolerance: how
    /// many holes the descriptor handed to the hashing.
    holes_classed: usize,
    /// Why the outlet that hashing found was refused, if it was.
    rejected: Option<String>,
    /// The labelled holes in this view (px), template order.
    truth_px: Vec<[f64; 2]>,
    /// The found outlet's holes (px), template order; empty when none.
    found_px: Vec<[f64; 2]>,
    /// Per found hole: its centre fitted (true) or taken from the other holes'
    /// homography where its outline shows (false).
    fitted: Vec<bool>,
    /// Per found hole: the evidence that it was seen ([`outlet_detector::DetectedHole::score`]).
    scores: Vec<f64>,
}

/// The first of `dirs` (the labels' own folder first) that holds `name`.
fn find_in(own: &Path, dirs: &[PathBuf], name: &str) -> Option<PathBuf> {
    std::iter::once(own).chain(dirs.iter().map(PathBuf::as_path)).map(|d| d.join(name)).find(|p| p.exists())
}

/// Reads every `*.labels.json` of `dirs` with its image and camera
/// (`STEM.camera.yaml`, else `camera.yaml`, else a pinhole guess).
fn read_photos(dirs: &[PathBuf], template_override: Option<&str>) -> Result<Vec<Photo>> {
    let mut paths: Vec<PathBuf> = Vec::new();
    for dir in dirs {
        let listing = std::fs::read_dir(dir).with_context(|| format!("reading photo folder {}", dir.display()))?;
        paths.extend(
            listing
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.file_name().and_then(|n| n.to_str()).is_some_and(|n| n.ends_with(".labels.json"))),
        );
    }
    paths.sort_by_key(|p| p.file_name().map(|n| n.to_os_string()));
    if paths.is_empty() {
        bail!("no *.labels.json (labels as `outlet train` takes them) in {dirs:?}");
    }
    let mut photos = Vec::new();
    for path in paths {
        let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
        let labels: LabelFile = serde_json::from_str(&text)
            .with_context(|| format!("labels {}: not the format of `outlet train`", path.display()))?;
        let template = match (template_override, &labels.template) {
            (Some(t), _) => t.to_string(),
            (None, Some(t)) => t.clone(),
            (None, None) => bail!("labels {}: no \"template\", and no --template given", path.display()),
        };
        let here = path.parent().unwrap_or(Path::new("."));
        let image_path = find_in(here, dirs, &labels.image)
            .with_context(|| format!("labels {}: image {} not found in {dirs:?}", path.display(), labels.image))?;
        let image =
            image::open(&image_path).with_context(|| format!("reading image {}", image_path.display()))?.to_rgb8();
        let name = labels.image.rsplit_once('.').map_or(labels.image.as_str(), |(stem, _)| stem).to_string();
        let camera_path =
            find_in(here, dirs, &format!("{name}.camera.yaml")).or_else(|| find_in(here, dirs, "camera.yaml"));
        let (camera, calibrated) = match camera_path {
            Some(p) => (read_camera_info(&p).with_context(|| format!("camera of {}", path.display()))?, true),
            None => (guessed_pinhole(image.width(), image.height())?, false),
        };
        if (camera.width, camera.height) != (image.width(), image.height()) {
            bail!(
                "{}: the camera is {}x{} but the image {}x{}",
                path.display(),
                camera.width,
                camera.height,
                image.width(),
                image.height()
            );
        }
        let geometry = OutletGeometry::builtin_or_file(&template).ok();
        if let Some(g) = &geometry {
            if g.holes.len() != labels.holes.len() {
                bail!(
                    "labels {}: {} holes, the template `{template}` has {}",
                    path.display(),
                    labels.holes.len(),
                    g.holes.len()
                );
            }
            for (i, (h, m)) in labels.holes.iter().zip(&g.holes).enumerate() {
                if h.kind != m.kind.as_str() {
                    bail!(
                        "labels {}: hole {i} is {:?} but the template's hole {i} is {}",
                        path.display(),
                        h.kind,
                        m.kind.as_str()
                    );
                }
            }
        }
        let holes: Vec<Point2<f64>> = labels.holes.iter().map(|h| Point2::new(h.pixel[0], h.pixel[1])).collect();
        if holes.iter().any(|p| !p.coords.iter().all(|v| v.is_finite())) {
            bail!("labels {}: a hole pixel is not finite", path.display());
        }
        photos.push(Photo { name, image, camera, calibrated, template, holes });
    }
    Ok(photos)
}

/// A camera for a photograph without calibration: a pinhole with the focal
/// length of a 60-degree horizontal field of view, centred, no distortion.
fn guessed_pinhole(width: u32, height: u32) -> Result<CameraModel> {
    let f = f64::from(width) / (2.0 * 30f64.to_radians().tan());
    Ok(CameraModel::new(width, height, [f, f, f64::from(width) / 2.0 - 0.5, f64::from(height) / 2.0 - 0.5], [0.0; 5])?)
}

/// A new view: a pinhole camera (no distortion) turned by `rotation` (photo
/// camera frame to view camera frame) with focal length `focal_px`, same image size.
struct View {
    camera: CameraModel,
    rotation: Rotation3<f64>,
}

impl View {
    fn pixel_of(&self, photo: &CameraModel, pixel: Point2<f64>) -> Option<Point2<f64>> {
        let ray = photo.ray(pixel);
        let p = self.rotation * ray;
        if p.z <= 1e-9 {
            return None;
        }
        self.camera.project(&nalgebra::Point3::from(p))
    }

    /// The view's image: every pixel's ray turned back into the photo's camera and
    /// sampled there (bilinear, supersampled where the view shrinks the photo).
    fn render(&self, photo: &Photo, zoom: f64) -> RgbImage {
        let (w, h) = (self.camera.width, self.camera.height);
        let n = (1.0 / zoom).ceil().clamp(1.0, 4.0) as u32;
        let k_inv = {
            let [fx, fy, cx, cy] = [self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy];
            Matrix3::new(1.0 / fx, 0.0, -cx / fx, 0.0, 1.0 / fy, -cy / fy, 0.0, 0.0, 1.0)
        };
        let back = self.rotation.inverse();
        let mut out = RgbImage::new(w, h);
        for v in 0..h {
            for u in 0..w {
                let mut acc = [0.0f64; 3];
                let mut hits = 0.0;
                for sy in 0..n {
                    for sx in 0..n {
                        let q = Vector3::new(
                            f64::from(u) + (f64::from(sx) + 0.5) / f64::from(n) - 0.5,
                            f64::from(v) + (f64::from(sy) + 0.5) / f64::from(n) - 0.5,
                            1.0,
                        );
                        let ray = back * (k_inv * q);
                        if ray.z <= 1e-9 {
                            continue;
                        }
                        if let Some(p) = photo.camera.project(&nalgebra::Point3::from(ray))
                            && let Some(c) = bilinear(&photo.image, p)
                        {
                            for k in 0..3 {
                                acc[k] += c[k];
                            }
                            hits += 1.0;
                        }
                    }
                }
                if hits > 0.0 {
                    let total = f64::from(n * n);
                    // Outside the photo is black, as a camera's dark surround would be.
                    out.put_pixel(u, v, Rgb(acc.map(|a| (a / total).round().clamp(0.0, 255.0) as u8)));
                }
            }
        }
        out
    }
}

fn bilinear(image: &RgbImage, p: Point2<f64>) -> Option<[f64; 3]> {
    let (w, h) = (f64::from(image.width()), f64::from(image.height()));
    if !(p.x >= 0.0 && p.y >= 0.0 && p.x <= w - 1.0 && p.y <= h - 1.0) {
        return None;
    }
    let (x0, y0) = (p.x.floor() as u32, p.y.floor() as u32);
    let (x1, y1) = ((x0 + 1).min(image.width() - 1), (y0 + 1).min(image.height() - 1));
    let (fx, fy) = (p.x - f64::from(x0), p.y - f64::from(y0));
    let px = |x: u32, y: u32| image.get_pixel(x, y).0.map(f64::from);
    let (a, b, c, d) = (px(x0, y0), px(x1, y0), px(x0, y1), px(x1, y1));
    Some(std::array::from_fn(|k| (a[k] * (1.0 - fx) + b[k] * fx) * (1.0 - fy) + (c[k] * (1.0 - fx) + d[k] * fx) * fy))
}

/// Gain, gamma, sensor noise, defocus blur and (sometimes) JPEG: another camera's look.
fn photometric(image: &RgbImage, rng: &mut Rng) -> Result<RgbImage> {
    let gain = rng.range(0.6, 1.4);
    let gamma = rng.range(0.7, 1.4);
    let noise = rng.range(0.0, 4.0);
    let blur = if rng.chance(0.5) { rng.range(0.3, 1.2) } else { 0.0 };
    let mut out = image.clone();
    for p in out.pixels_mut() {
        p.0 = p.0.map(|c| {
            let x = (f64::from(c) / 255.0 * gain).clamp(0.0, 1.0).powf(gamma) * 255.0 + noise * rng.normal();
            x.round().clamp(0.0, 255.0) as u8
        });
    }
    if blur > 0.0 {
        out = image::imageops::blur(&out, blur as f32);
    }
    if rng.chance(0.4) {
        let quality = rng.range(60.0, 95.0) as u8;
        let mut bytes = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut bytes, quality)
            .encode_image(&out)
            .context("JPEG-compressing a view")?;
        out = image::load_from_memory(&bytes).context("decoding a JPEG view")?.to_rgb8();
    }
    Ok(out)
}

/// The neutral slot's length (px) about a labelled outlet in a pinhole view: 8.7 mm
/// at the scale of the slot pitch (12.7 mm) between the first neutral and hot labels.
fn slot_length_px(holes: &[Point2<f64>]) -> f64 {
    match holes {
        [n, h, ..] => (n - h).norm() * 8.7 / 12.7,
        _ => f64::NAN,
    }
}

/// How obliquely the labelled outlet is seen (degrees; NaN where the labels fix no
/// plane): the camera turned to look straight at the outlet's centre, the
/// foreshortening of the labels' homography there, acos of the ratio of its
/// singular values. (A normal from the homography's perspective terms would be
/// noise: a 3 cm outlet barely shows perspective.)
fn off_axis_deg(model: &[Point2<f64>], camera: &CameraModel, labels: &[Point2<f64>]) -> f64 {
    let pairs: Vec<(Point2<f64>, Point2<f64>)> =
        model.iter().zip(labels).map(|(m, p)| (*m, Point2::from(camera.undistort_pixel(*p)))).collect();
    let Some(h) = outlet_protocol::math::fit_homography(&pairs) else { return f64::NAN };
    let n = model.len().max(1) as f64;
    let centre = model.iter().fold(Vector3::zeros(), |a, m| a + Vector3::new(m.x, m.y, 1.0)) / n;
    let ray = h * centre;
    let Some(look) = Rotation3::rotation_between(&ray, &Vector3::z()) else { return f64::NAN };
    let h = look.matrix() * h;
    // Jacobian of (x/z, y/z) at the centre.
    let q = h * centre;
    let mut j = nalgebra::Matrix2::zeros();
    for col in 0..2 {
        let (dx, dy, dz) = (h[(0, col)], h[(1, col)], h[(2, col)]);
        j[(0, col)] = (dx * q.z - q.x * dz) / (q.z * q.z);
        j[(1, col)] = (dy * q.z - q.y * dz) / (q.z * q.z);
    }
    let sv = j.singular_values();
    let ratio = sv.min() / sv.max();
    if ratio.is_finite() { ratio.min(1.0).acos().to_degrees() } else { f64::NAN }
}

/// A random view of the photo: turned by at most `max_turn_deg` (any roll about
/// the optical axis), zoomed so that the slots are `slot_px` long, with the
/// outlet kept inside the image. None when no such view keeps it inside.
fn random_view(photo: &Photo, rng: &mut Rng, args: &PhotoEvalArgs) -> Result<Option<(View, f64, f64)>> {
    let cam = &photo.camera;
    // The slot length at the photo's own focal length, in a pinhole of the same focal length.
    // A view that shrinks the photo gets a smaller image (not below VGA), so that
    // it is mostly photo rather than the black beyond the photo's edges.
    let pinhole = |f: f64, rotation: Rotation3<f64>| -> Result<View> {
        let shrink = (f / cam.fx).min(1.0);
        let size = |full: u32, least: u32| ((f64::from(full) * shrink).round() as u32).clamp(least.min(full), full);
        let (w, h) = (size(cam.width, 640), size(cam.height, 480));
        let camera = CameraModel::new(w, h, [f, f, f64::from(w) / 2.0 - 0.5, f64::from(h) / 2.0 - 0.5], [0.0; 5])?;
        Ok(View { camera, rotation })
    };
    let base = pinhole(cam.fx, Rotation3::identity())?;
    let base_holes: Option<Vec<_>> = photo.holes.iter().map(|p| base.pixel_of(cam, *p)).collect();
    let Some(base_holes) = base_holes else { return Ok(None) };
    let base_slot = slot_length_px(&base_holes);
    for _ in 0..400 {
        let target_slot = (rng.range(args.slot_px[0].ln(), args.slot_px[1].ln())).exp();
        let zoom = target_slot / base_slot;
        let f = cam.fx * zoom;
        // Any roll about the photo's optical axis, then its axis tilted by at most
        // the allowed turn in a random direction: pan and tilt together.
        let roll = Rotation3::from_axis_angle(&Vector3::z_axis(), rng.range(0.0, std::f64::consts::TAU));
        let direction = rng.range(0.0, std::f64::consts::TAU);
        let tilt_axis = Unit::new_normalize(Vector3::new(direction.cos(), direction.sin(), 0.0));
        let tilt = Rotation3::from_axis_angle(&tilt_axis, rng.range(0.0, args.max_turn_deg).to_radians());
        let rotation = tilt * roll;
        let view = pinhole(f, rotation)?;
        let holes: Option<Vec<_>> = photo.holes.iter().map(|p| view.pixel_of(cam, *p)).collect();
        let Some(holes) = holes else { continue };
        // The plate reaches about 3 slot pitches beyond the holes: keep it inside.
        let margin = 2.5 * slot_length_px(&holes);
        if holes.iter().all(|p| view.camera.contains(*p, margin)) {
            let axis_turn = (rotation.inverse() * Vector3::z()).angle(&Vector3::z()).to_degrees();
            return Ok(Some((view, zoom, axis_turn)));
        }
    }
    Ok(None)
}

/// How a found outlet's holes (template order) compare with the labels:
/// (correct, per-hole errors px, tolerance px).
fn judge(found: &[Point2<f64>], truth: &[Point2<f64>]) -> (bool, Vec<f64>, f64) {
    let slot = slot_length_px(truth);
    // The paper's 5 px, but never more than a fifth of the slot pitch: at small
    // scales a hole one place over must not count as found.
    let tolerance = (0.2 * slot * 12.7 / 8.7).min(5.0);
    let errors: Vec<f64> = found.iter().zip(truth).map(|(h, t)| (h - t).norm()).collect();
    let correct = found.len() == truth.len() && errors.iter().all(|e| *e <= tolerance);
    (correct, errors, tolerance)
}

/// The outcome of one image.
fn evaluate(detector: &Detector, image: &RgbImage, camera: &CameraModel, truth: &[Point2<f64>]) -> Evaluated {
    let t = std::time::Instant::now();
    let report = detector.detect(image, Some(camera));
    let ms = t.elapsed().as_secs_f64() * 1e3;
    // Per found hole (template order); all empty when none was found.
    let holes = report.detection.as_ref().map_or(&[][..], |d| &d.holes[..]);
    let sigma_px = holes.iter().map(|h| h.sigma_px).collect();
    let scores = holes.iter().map(|h| h.score).collect();
    let fitted = holes.iter().map(|h| h.refined).collect();
    let found_px = holes.iter().map(|h| [h.pixel.x, h.pixel.y]).collect();
    let found: Option<Vec<Point2<f64>>> = report.detection.as_ref().map(|d| d.holes.iter().map(|h| h.pixel).collect());
    let (correct, errors_px, tolerance_px) = judge(found.as_deref().unwrap_or(&[]), truth);
    let kinds = detector.template().geometry.holes.iter().map(|h| Class::from(h.kind));
    let holes_classed = truth
        .iter()
        .zip(kinds)
        .filter(|(t, kind)| {
            report.candidates.iter().any(|(c, class)| class == kind && (c.centre - **t).norm() <= tolerance_px)
        })
        .count();
    Evaluated {
        found: found.is_some(),
        correct: correct && found.is_some(),
        errors_px,
        tolerance_px,
        ms,
        stages_ms: [report.times.candidates, report.times.classify, report.times.hash, report.times.refine],
        sigma_px,
        holes_classed,
        rejected: report.rejected,
        truth_px: truth.iter().map(|p| [p.x, p.y]).collect(),
        found_px,
        fitted,
        scores,
    }
}

/// The outlet's angle in the image (degrees): from the first neutral slot to its hot slot.
fn outlet_angle_deg(holes: &[Point2<f64>]) -> f64 {
    match holes {
        [n, h, ..] => (h.y - n.y).atan2(h.x - n.x).to_degrees(),
        _ => f64::NAN,
    }
}

pub fn eval_photos(args: &PhotoEvalArgs) -> Result<()> {
    let photos = read_photos(args.dirs, args.template)?;
    let mut detectors: Vec<(String, Detector)> = Vec::new();
    let mut rng = Rng::new(args.seed);
    let mut outcomes = Vec::new();
    let bar = crate::progress::bar(photos.len() * (args.views + 1), "photos and views");
    for photo in &photos {
        if !detectors.iter().any(|(n, _)| *n == photo.template) {
            let template = outlet::templates::load(&photo.template)?;
            detectors.push((photo.template.clone(), Detector::new(template, DetectorParams::default())));
        }
        let Some((_, detector)) = detectors.iter().find(|(n, _)| *n == photo.template) else { continue };
        if !photo.calibrated {
            tracing::warn!("{}: no camera_info; views assume a 60-degree pinhole", photo.name);
        }
        let model: Vec<Point2<f64>> = detector.template().geometry.holes.iter().map(|h| h.position()).collect();
        let e = evaluate(detector, &photo.image, &photo.camera, &photo.holes);
        let base_slot = {
            let und: Vec<_> = photo
                .holes
                .iter()
                .map(|p| {
                    let n = photo.camera.undistort_pixel(*p);
                    Point2::new(n.x * photo.camera.fx, n.y * photo.camera.fy)
                })
                .collect();
            slot_length_px(&und)
        };
        outcomes.push(ViewOutcome {
            photo: photo.name.clone(),
            view: 0,
            turn_deg: 0.0,
            outlet_angle_deg: outlet_angle_deg(&photo.holes),
            slot_px: base_slot,
            off_axis_deg: off_axis_deg(&model, &photo.camera, &photo.holes),
            result: e,
        });
        bar.inc(1);
        let mut photo_rng = rng.fork(outcomes.len() as u64);
        let mut made = 0;
        while made < args.views {
            let Some((view, zoom, turn_deg)) = random_view(photo, &mut photo_rng, args)? else {
                bail!("{}: no view keeps the outlet inside the image", photo.name);
            };
            made += 1;
            let image = photometric(&view.render(photo, zoom), &mut photo_rng)?;
            let truth: Vec<Point2<f64>> = photo.holes.iter().filter_map(|p| view.pixel_of(&photo.camera, *p)).collect();
            let e = evaluate(detector, &image, &view.camera, &truth);
            outcomes.push(ViewOutcome {
                photo: photo.name.clone(),
                view: made,
                turn_deg,
                outlet_angle_deg: outlet_angle_deg(&truth),
                slot_px: slot_length_px(&truth),
                off_axis_deg: off_axis_deg(&model, &view.camera, &truth),
                result: e,
            });
            bar.inc(1);
            if made <= args.save_views {
                let dir = args.out.join("views");
                std::fs::create_dir_all(&dir)?;
                let name = format!("{}_{made:03}", photo.name);
                image.save(dir.join(format!("{name}.png")))?;
                let yaml = write_camera_info(&view.camera, &name);
                std::fs::write(dir.join(format!("{name}.yaml")), yaml)?;
            }
        }
        bar.suspend(|| tracing::info!("{}: {} views", photo.name, made + 1));
    }
    bar.finish_and_clear();
    std::fs::create_dir_all(args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let mut jsonl = String::new();
    for o in &outcomes {
        jsonl += &serde_json::to_string(o)?;
        jsonl.push('\n');
    }
    std::fs::write(args.out.join("photos.jsonl"), jsonl)?;
    let table = photo_table(&outcomes);
    std::fs::write(args.out.join("photos.md"), &table)?;
    print!("{table}");
    Ok(())
}

fn photo_table(outcomes: &[ViewOutcome]) -> String {
    let mut s = String::new();
    let row = |s: &mut String, label: &str, set: &[&ViewOutcome]| {
        let found = set.iter().filter(|o| o.result.correct).count();
        let wrong = set.iter().filter(|o| o.result.found && !o.result.correct).count();
        let pct = if set.is_empty() { f64::NAN } else { 100.0 * found as f64 / set.len() as f64 };
        let _ = writeln!(s, "| {label} | {} | {found} ({pct:.0}%) | {wrong} |", set.len());
    };
    let _ = writeln!(s, "| views | count | found | wrong outlets |\n|---|---|---|---|");
    let mut names: Vec<&str> = outcomes.iter().map(|o| o.photo.as_str()).collect();
    names.dedup();
    for name in names {
        let own: Vec<_> = outcomes.iter().filter(|o| o.photo == name).collect();
        row(
            &mut s,
            &format!("{name}: the photograph"),
            &own.iter().copied().filter(|o| o.view == 0).collect::<Vec<_>>(),
        );
        row(&mut s, &format!("{name}: turned views"), &own.iter().copied().filter(|o| o.view > 0).collect::<Vec<_>>());
    }
    for (lo, hi) in [(0.0, 12.0), (12.0, 18.0), (18.0, 24.0), (24.0, 1e9)] {
        let set: Vec<_> = outcomes.iter().filter(|o| o.view > 0 && o.slot_px >= lo && o.slot_px < hi).collect();
        let label = if hi > 1e8 { format!("slots from {lo:.0} px") } else { format!("slots {lo:.0}-{hi:.0} px") };
        row(&mut s, &label, &set);
    }
    for (lo, hi) in [(0.0, 40.0), (40.0, 55.0), (55.0, 65.0), (65.0, 1e9)] {
        let set: Vec<_> = outcomes.iter().filter(|o| o.off_axis_deg >= lo && o.off_axis_deg < hi).collect();
        let label =
            if hi > 1e8 { format!("off-axis from {lo:.0} deg") } else { format!("off-axis {lo:.0}-{hi:.0} deg") };
        row(&mut s, &label, &set);
    }
    for (lo, hi) in [(0.0, 10.0), (10.0, 20.0), (20.0, 1e9)] {
        let set: Vec<_> = outcomes.iter().filter(|o| o.view > 0 && o.turn_deg >= lo && o.turn_deg < hi).collect();
        let label = if hi > 1e8 { format!("turned from {lo:.0} deg") } else { format!("turned {lo:.0}-{hi:.0} deg") };
        row(&mut s, &label, &set);
    }
    row(&mut s, "all", &outcomes.iter().collect::<Vec<_>>());
    let mut ms: Vec<f64> = outcomes.iter().map(|o| o.result.ms).collect();
    ms.sort_by(f64::total_cmp);
    if let Some(median) = ms.get(ms.len() / 2) {
        let _ = writeln!(s, "\nmedian detection time {median:.1} ms");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn photo_with(holes: Vec<Point2<f64>>) -> Photo {
        let camera =
            CameraModel::new(640, 480, [500.0, 500.0, 319.5, 239.5], [-0.2, 0.05, 0.0, 0.0, 0.0]).expect("camera");
        Photo {
            name: "t".into(),
            image: RgbImage::new(640, 480),
            camera,
            calibrated: true,
            template: "2x1".into(),
            holes,
        }
    }

    #[test]
    fn the_off_axis_angle_is_the_one_the_outlet_was_seen_at() {
        // A 2x1 outlet 0.4 m away, off the optical axis, its face turned by a known
        // angle from the ray to it, seen through a distorting lens.
        let photo = photo_with(Vec::new());
        let model: Vec<Point2<f64>> =
            OutletGeometry::builtin("2x1").expect("2x1").holes.iter().map(|h| h.position()).collect();
        let centre = Vector3::new(0.06, -0.03, 0.4);
        for degrees in [0.0f64, 30.0, 50.0, 64.0] {
            // Turned about an axis across the ray, from facing the camera.
            let ray = centre.normalize();
            let facing = Rotation3::rotation_between(&Vector3::z(), &-ray).expect("rotation");
            let across = Unit::new_normalize(ray.cross(&Vector3::y()));
            let pose = Rotation3::from_axis_angle(&across, degrees.to_radians()) * facing;
            let labels: Vec<Point2<f64>> = model
                .iter()
                .map(|m| {
                    let p = centre + pose * Vector3::new(m.x, m.y, 0.0) * 1e-3;
                    photo.camera.project(&nalgebra::Point3::from(p)).expect("in front")
                })
                .collect();
            let got = off_axis_deg(&model, &photo.camera, &labels);
            assert!((got - degrees).abs() < 1.0, "{degrees} degrees measured as {got:.2}");
        }
    }

    #[test]
    fn a_view_maps_a_photo_pixel_where_its_ray_goes() {
        // A ray turned by the view's rotation lands on the view's pixel of that ray.
        let photo = photo_with(vec![Point2::new(300.0, 200.0), Point2::new(340.0, 202.0), Point2::new(320.0, 240.0)]);
        let rotation = Rotation3::from_euler_angles(0.1, -0.2, 0.7);
        let camera = CameraModel::new(640, 480, [800.0, 800.0, 319.5, 239.5], [0.0; 5]).expect("camera");
        let view = View { camera, rotation };
        for p in &photo.holes {
            let q = view.pixel_of(&photo.camera, *p).expect("in front");
            let back = rotation.inverse() * view.camera.ray(q);
            let again = photo.camera.project(&nalgebra::Point3::from(back)).expect("in front");
            assert!((again - p).norm() < 1e-6, "{again} vs {p}");
        }
    }

    #[test]
    fn random_views_keep_the_outlet_inside_and_the_slots_in_range() {
        let photo = photo_with(vec![Point2::new(300.0, 200.0), Point2::new(330.0, 200.0), Point2::new(315.0, 228.0)]);
        let dir = std::env::temp_dir();
        let dirs = [dir.clone()];
        let args = PhotoEvalArgs {
            dirs: &dirs,
            out: &dir,
            views: 1,
            seed: 1,
            template: None,
            max_turn_deg: 25.0,
            slot_px: [8.0, 30.0],
            save_views: 0,
        };
        let mut rng = Rng::new(7);
        for _ in 0..20 {
            let (view, _, turn) = random_view(&photo, &mut rng, &args).expect("views").expect("a view");
            let holes: Vec<_> =
                photo.holes.iter().map(|p| view.pixel_of(&photo.camera, *p).expect("in front")).collect();
            let slot = slot_length_px(&holes);
            assert!((7.5..=31.0).contains(&slot), "slot {slot} px");
            assert!(turn <= 25.0 + 1e-6, "turned {turn} degrees");
            assert!(holes.iter().all(|p| view.camera.contains(*p, 0.0)));
        }
    }

    #[test]
    fn a_hole_off_by_more_than_the_tolerance_is_not_correct() {
        // Slot pitch 30 px: the paper's 5 px holds. Pitch 15 px: a fifth of it, 3 px.
        let truth = [Point2::new(100.0, 100.0), Point2::new(130.0, 100.0), Point2::new(115.0, 128.0)];
        let near = [Point2::new(104.0, 100.0), Point2::new(130.0, 103.0), Point2::new(115.0, 128.0)];
        assert!(judge(&near, &truth).0);
        let far = [Point2::new(105.5, 100.0), Point2::new(130.0, 100.0), Point2::new(115.0, 128.0)];
        assert!(!judge(&far, &truth).0);
        let small = truth.map(|p| Point2::new(p.x / 2.0, p.y / 2.0));
        let shifted = [Point2::new(53.5, 50.0), small[1], small[2]];
        let (correct, errors, tolerance) = judge(&shifted, &small);
        assert!(!correct && (tolerance - 3.0).abs() < 1e-9 && (errors[0] - 3.5).abs() < 1e-9);
        // A found outlet with fewer holes than the labels is never correct.
        assert!(!judge(&truth[..2], &truth).0);
    }
}
