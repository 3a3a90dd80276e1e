//! `outlet eval --approach`: the arm's approach, from 60 cm to 10 cm, seen by a
//! VGA, a 1280x960 and a 1920x1080 camera (issue 21). Each approach takes a
//! rendered scene's outlet, wall and light, turns the camera to look at the
//! outlet and moves it along the line to the outlet's centre (the off-axis angle
//! stays the scene's), rendering at each distance with each camera. Reports
//! found, wrong, hole pixel error, plane-mode hole error and detection time by
//! distance and camera (`approach.md`, `approach.jsonl`, `approach.png` and `.svg`,
//! and `report.html` with them all).

use crate::eval_cmd::EvalArgs;
use crate::plot::{BLUE, DrawResult, Figure, GREEN, LIGHT_GREY, ORANGE};
use anyhow::{Context, Result};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};
use outlet_detector::detect::{Detector, DetectorParams};
use outlet_protocol::CameraModel;
use outlet_sim::approach::{ApproachRenderer, seen_from};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::collections::HashMap;
use std::fmt::Write as _;

/// Camera-to-outlet-centre distances of an approach (m).
const DISTANCES_M: [f64; 9] = [0.60, 0.50, 0.40, 0.30, 0.25, 0.20, 0.15, 0.12, 0.10];

/// The three cameras: name, size and focal length (the VGA one is the default
/// camera's; the others keep its field of view or, for 1080p, an HD webcam's).
const CAMERAS: [(&str, u32, u32, f64); 3] =
    [("640x480", 640, 480, 525.0), ("1280x960", 1280, 960, 1050.0), ("1920x1080", 1920, 1080, 1181.0)];

/// One rendered view of an approach.
#[derive(Debug, Clone, serde::Serialize)]
struct ApproachOutcome {
    scenario: String,
    approach: usize,
    camera: &'static str,
    distance_m: f64,
    off_axis_deg: f64,
    /// Slot pitch in the image (pixels): the hole scale the detector met.
    pitch_px: f64,
    found: bool,
    correct: bool,
    errors_px: Vec<f64>,
    /// Plane-mode hole position errors (mm), for correct detections.
    plane_mm: Vec<f64>,
    ms: f64,
    /// Candidates, classification, hashing, refinement (ms, all levels).
    stages_ms: [f64; 4],
}

fn camera_model(width: u32, height: u32, f: f64, distortion: [f64; 5]) -> Result<CameraModel> {
    CameraModel::new(width, height, [f, f, width as f64 / 2.0, height as f64 / 2.0], distortion)
        .with_context(|| format!("a {width}x{height} camera"))
}

/// The camera (camera frame to outlet frame) turned to look at the outlet's
/// centre and moved along the line to it to `distance` m.
fn approach_pose(camera_in_outlet: &Isometry3<f64>, distance: f64) -> Option<Isometry3<f64>> {
    let position = camera_in_outlet.translation.vector;
    let range = position.norm();
    if !(range.is_finite() && range > 0.0) {
        return None;
    }
    // The ray to the outlet's centre in the camera frame, turned onto the optical axis.
    let ray = camera_in_outlet.rotation.inverse() * (-position / range);
    let align = UnitQuaternion::rotation_between(&ray, &Vector3::z())?;
    let rotation = camera_in_outlet.rotation * align.inverse();
    Some(Isometry3::from_parts(Translation3::from(position / range * distance), rotation))
}

pub fn eval_approach(args: &EvalArgs) -> Result<()> {
    let distortion = args.camera.camera()?.distortion;
    let cameras: Vec<(&'static str, CameraModel)> = CAMERAS
        .iter()
        .map(|(name, w, h, f)| Ok((*name, camera_model(*w, *h, *f, distortion)?)))
        .collect::<Result<_>>()?;
    let vga = cameras[0].1;
    let scenarios: Vec<&str> = match args.scenario.as_str() {
        "all" => outlet_sim::SCENARIOS.iter().copied().filter(|s| *s != "negative").collect(),
        name => vec![outlet_sim::scenario_named(name).with_context(|| format!("unknown scenario {name:?}"))?],
    };
    let count = args.count.unwrap_or(5);
    let mut detectors = HashMap::new();
    for name in ["2x1", "2x2"] {
        detectors.insert(name, Detector::new(outlet::templates::builtin(name)?, DetectorParams::default()));
    }
    let renderers: Vec<ApproachRenderer> = cameras.iter().map(|(_, c)| ApproachRenderer::new(c)).collect();
    let mut jobs = Vec::new();
    for scenario in &scenarios {
        for approach in 0..count {
            let scene = outlet_sim::sample_scene(scenario, args.seed, approach as u64, &vga)?;
            if scene.template.is_none() {
                continue;
            }
            for (k, d) in DISTANCES_M.iter().enumerate() {
                for c in 0..cameras.len() {
                    jobs.push((scene.clone(), approach, *d, k, c));
                }
            }
        }
    }
    let bar = crate::progress::bar(jobs.len(), "approaching");
    let next = std::sync::atomic::AtomicUsize::new(0);
    let outcomes = std::sync::Mutex::new(Vec::new());
    std::thread::scope(|s| {
        for _ in 0..args.threads.max(1) {
            s.spawn(|| {
                loop {
                    let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                    let Some((scene, approach, distance, step, c)) = jobs.get(k) else { break };
                    let (name, camera) = &cameras[*c];
                    let seed = scene.noise_seed.wrapping_add(*step as u64 * 7919);
                    match view(scene, *approach, *distance, seed, name, camera, &renderers[*c], &detectors, args) {
                        Ok(Some(o)) => {
                            if let Ok(mut v) = outcomes.lock() {
                                v.push(o)
                            }
                        }
                        Ok(None) => {}
                        Err(e) => tracing::error!("{} #{approach} at {distance} m, {name}: {e:#}", scene.scenario),
                    }
                    bar.inc(1);
                }
            });
        }
    });
    bar.finish_and_clear();
    let mut outcomes = outcomes.into_inner().unwrap_or_default();
    outcomes.sort_by(|a, b| {
        (a.camera, a.scenario.as_str(), a.approach)
            .cmp(&(b.camera, b.scenario.as_str(), b.approach))
            .then(b.distance_m.total_cmp(&a.distance_m))
    });
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let table = table(&outcomes, args, &scenarios, count);
    std::fs::write(args.out.join("approach.md"), &table)?;
    let mut jsonl = String::new();
    for o in &outcomes {
        let _ = writeln!(jsonl, "{}", serde_json::to_string(o)?);
    }
    std::fs::write(args.out.join("approach.jsonl"), jsonl)?;
    crate::plot::write(&ApproachFigure(&outcomes), &args.out, "approach")?;
    let caption = "Found and detection time against distance, per camera";
    let plots = [crate::report_html::Plot { stem: "approach", caption }];
    crate::report_html::write(&args.out, "outlet eval --approach: from 60 to 10 cm", &table, &plots)?;
    println!("{table}");
    Ok(())
}

/// One distance of one approach with one camera; None where the outlet's
/// centre is not in the image.
#[allow(clippy::too_many_arguments)] // one view's coordinates; a struct would only rename them
fn view(
    scene: &outlet_sim::Scene,
    approach: usize,
    distance: f64,
    seed: u64,
    name: &'static str,
    camera: &CameraModel,
    renderer: &ApproachRenderer,
    detectors: &HashMap<&str, Detector>,
    args: &EvalArgs,
) -> Result<Option<ApproachOutcome>> {
    let pose = approach_pose(&scene.pose.inverse(), distance).context("the scene's camera is at the outlet")?;
    let mut moved = seen_from(scene, &pose, seed);
    moved.camera = *camera;
    // Occluders hang in front of the camera of the scene's view; on an approach
    // they would cover the outlet at every distance alike.
    moved.occluders.clear();
    let frame = renderer.render(&moved, "approach").context("rendering")?;
    let truth = &frame.truth;
    let detector = detectors.get(moved.search_template.as_str()).context("no detector for the sought template")?;
    let t = std::time::Instant::now();
    let report = detector.detect(&frame.frame.image, Some(camera));
    let ms = t.elapsed().as_secs_f64() * 1e3;
    let pitch_px = slot_pitch_px(&truth.holes);
    // The angle between the face normal (the outlet frame's z axis, either sign) and the line to the camera.
    let to_camera = pose.translation.vector / distance;
    let off_axis_deg = to_camera.z.abs().min(1.0).acos().to_degrees();
    let in_image =
        |p: &[f64; 2]| p[0] >= 0.0 && p[1] >= 0.0 && p[0] < camera.width as f64 && p[1] < camera.height as f64;
    if !truth.holes.iter().all(|h| in_image(&h.pixel)) {
        return Ok(None);
    }
    // The paper's 5 px at VGA, the same angle at the other cameras.
    let tolerance = args.tolerance_px * camera.fx / 525.0;
    let errors_px: Vec<f64> = report
        .detection
        .iter()
        .flat_map(|d| d.holes.iter().zip(&truth.holes))
        .map(|(h, t)| ((h.pixel.x - t.pixel[0]).powi(2) + (h.pixel.y - t.pixel[1]).powi(2)).sqrt())
        .collect();
    let found = report.detection.is_some();
    let correct = found && errors_px.iter().all(|e| *e <= tolerance);
    let mut plane_mm = Vec::new();
    if let (true, Some(d)) = (correct, &report.detection) {
        let geometry = &detector.template().geometry;
        let holes = outlet::DetectedHoles::new(d, geometry);
        let obs = holes.observations(camera, 0.25);
        if let Ok(plane) = outlet_normal::fit_wall_plane(&frame.cloud, &outlet_normal::PlaneParams::default())
            && let Ok((p, _)) = outlet::solve_plane_with_cloud(&obs, &plane, &frame.cloud, geometry, &args.model_error)
        {
            plane_mm = p
                .holes_cam_m
                .iter()
                .zip(&truth.holes)
                .filter_map(|(h, t)| Some((h - Point3::from(t.position_m?)).norm() * 1e3))
                .collect();
        }
    }
    // Wrong outlets and misses are kept to look at (`outlet detect --camera`
    // reruns them).
    if !correct {
        let dir = args.out.join(if found { "wrong" } else { "missed" });
        let stem = format!("{name}_{}_{approach}_{:.0}cm", scene.scenario, distance * 100.0);
        std::fs::create_dir_all(&dir)?;
        frame.frame.image.save_with_format(dir.join(format!("{stem}.png")), image::ImageFormat::Png)?;
        std::fs::write(
            dir.join(format!("{stem}.yaml")),
            outlet_protocol::camera_info::write_camera_info(camera, &stem),
        )?;
    }
    Ok(Some(ApproachOutcome {
        scenario: scene.scenario.clone(),
        approach,
        camera: name,
        distance_m: distance,
        off_axis_deg,
        pitch_px,
        found,
        correct,
        errors_px,
        plane_mm,
        ms,
        stages_ms: [report.times.candidates, report.times.classify, report.times.hash, report.times.refine],
    }))
}

/// The image distance between the first two holes (the first receptacle's
/// slots: the blade pitch, 12.7 mm).
fn slot_pitch_px(holes: &[outlet_protocol::truth::HoleJson]) -> f64 {
    match holes {
        [a, b, ..] => ((a.pixel[0] - b.pixel[0]).powi(2) + (a.pixel[1] - b.pixel[1]).powi(2)).sqrt(),
        _ => f64::NAN,
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    v.sort_by(f64::total_cmp);
    v.get(v.len() / 2).copied().unwrap_or(f64::NAN)
}

fn table(outcomes: &[ApproachOutcome], args: &EvalArgs, scenarios: &[&str], count: usize) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Approaches: {count} per scenario ({}), seed {}, the camera turned to the outlet and moved \
         along the line to it; correct = every hole within {} px at 640x480 (the same angle at the \
         other cameras); plane mode with model error {:?}.\n",
        scenarios.join(", "),
        args.seed,
        args.tolerance_px,
        args.model_error
    );
    let _ = writeln!(
        s,
        "| camera | distance (cm) | views | slot pitch (px) | found | wrong | median hole error (px) | plane RMS (mm) | median ms |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for (name, ..) in CAMERAS {
        for d in DISTANCES_M {
            let at: Vec<&ApproachOutcome> =
                outcomes.iter().filter(|o| o.camera == name && (o.distance_m - d).abs() < 1e-9).collect();
            if at.is_empty() {
                continue;
            }
            let correct = at.iter().filter(|o| o.correct).count();
            let wrong = at.iter().filter(|o| o.found && !o.correct).count();
            let errors: Vec<f64> = at.iter().filter(|o| o.correct).flat_map(|o| o.errors_px.clone()).collect();
            let plane: Vec<f64> = at.iter().flat_map(|o| o.plane_mm.clone()).collect();
            let rms = (plane.iter().map(|e| e * e).sum::<f64>() / plane.len().max(1) as f64).sqrt();
            let _ = writeln!(
                s,
                "| {name} | {:.0} | {} | {:.0} | {} ({:.0}%) | {wrong} | {:.3} | {} | {:.1} |",
                d * 100.0,
                at.len(),
                median(at.iter().map(|o| o.pitch_px).collect()),
                correct,
                100.0 * correct as f64 / at.len() as f64,
                median(errors),
                if plane.is_empty() { "-".to_string() } else { format!("{rms:.3}") },
                median(at.iter().map(|o| o.ms).collect()),
            );
        }
    }
    s
}

/// A camera's line: (distance in cm, found share, median ms) at each distance it has views of.
type CameraLine = (&'static str, Vec<(f64, f64, f64)>);

/// Found (%) and median detection time against distance, one line per camera.
struct ApproachFigure<'a>(&'a [ApproachOutcome]);

impl ApproachFigure<'_> {
    /// Per camera, its line.
    fn lines(&self) -> Vec<CameraLine> {
        CAMERAS
            .iter()
            .map(|(name, ..)| {
                let points = DISTANCES_M
                    .iter()
                    .rev()
                    .filter_map(|d| {
                        let at: Vec<&ApproachOutcome> =
                            self.0.iter().filter(|o| o.camera == *name && (o.distance_m - d).abs() < 1e-9).collect();
                        let found = at.iter().filter(|o| o.correct).count() as f64 / at.len().max(1) as f64;
                        (!at.is_empty()).then(|| (d * 100.0, found, median(at.iter().map(|o| o.ms).collect())))
                    })
                    .collect();
                (*name, points)
            })
            .collect()
    }
}

impl Figure for ApproachFigure<'_> {
    fn size(&self) -> (u32, u32) {
        (960, 400)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        const FONT: &str = crate::plot::FONT;
        let lines = self.lines();
        let colours = [BLUE, ORANGE, GREEN];
        let panels = root.split_evenly((1, 2));
        let ms_max =
            lines.iter().flat_map(|(_, p)| p.iter().map(|q| q.2)).filter(|v| v.is_finite()).fold(1.0, f64::max);
        for (k, panel) in panels.iter().enumerate() {
            let (title, y_desc, y_range) = if k == 0 {
                ("Found vs distance", "found (every hole right)", 0.0..105.0)
            } else {
                ("Detection time vs distance", "median ms per image", 0.0..ms_max * 1.15)
            };
            let mut chart = ChartBuilder::on(panel)
                .caption(title, (FONT, 18))
                .margin(8)
                .x_label_area_size(44)
                .y_label_area_size(56)
                .build_cartesian_2d(8.0..62.0f64, y_range)?;
            let percent = |v: &f64| format!("{v:.0}%");
            let plain = |v: &f64| format!("{v:.0}");
            chart
                .configure_mesh()
                .x_desc("distance to the outlet (cm)")
                .x_label_formatter(&plain)
                .y_desc(y_desc)
                .axis_desc_style((FONT, 14))
                .y_label_formatter(if k == 0 { &percent } else { &plain })
                .light_line_style(WHITE)
                .bold_line_style(LIGHT_GREY.mix(0.6))
                .draw()?;
            for ((name, points), colour) in lines.iter().zip(colours) {
                let xy: Vec<(f64, f64)> =
                    points.iter().map(|(d, found, ms)| (*d, if k == 0 { 100.0 * found } else { *ms })).collect();
                chart
                    .draw_series(LineSeries::new(xy.clone(), colour.stroke_width(2)))?
                    .label(*name)
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
                chart.draw_series(xy.into_iter().map(|p| Circle::new(p, 3, colour.filled())))?;
            }
            chart
                .configure_series_labels()
                .label_font((FONT, 13))
                .position(if k == 0 { SeriesLabelPosition::LowerRight } else { SeriesLabelPosition::UpperRight })
                .background_style(WHITE.mix(0.85))
                .border_style(LIGHT_GREY)
                .draw()?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_approach_keeps_the_outlet_on_the_optical_axis_at_the_asked_distance() {
        let start = Isometry3::from_parts(
            Translation3::new(0.1, -0.05, 0.35),
            UnitQuaternion::from_euler_angles(3.0f64.to_radians(), 170.0f64.to_radians(), 0.4),
        );
        for d in DISTANCES_M {
            let pose = approach_pose(&start, d).expect("pose");
            // The outlet's centre in the camera frame lies on +z at distance d.
            let centre = pose.inverse() * Point3::origin();
            assert!((centre.coords - Vector3::new(0.0, 0.0, d)).norm() < 1e-9, "{centre:?}");
            // The line of approach is the scene's: the camera stays on it.
            let dir = pose.translation.vector.normalize();
            assert!((dir - start.translation.vector.normalize()).norm() < 1e-9);
        }
        assert!(approach_pose(&Isometry3::identity(), 0.3).is_none());
    }

    #[test]
    fn the_approach_plot_has_a_line_per_camera_with_its_found_share() {
        let outcome = |camera: &'static str, distance_m: f64, correct: bool| ApproachOutcome {
            scenario: "orange2x1".into(),
            approach: 0,
            camera,
            distance_m,
            off_axis_deg: 10.0,
            pitch_px: 20.0,
            found: correct,
            correct,
            errors_px: Vec::new(),
            plane_mm: Vec::new(),
            ms: if camera == "640x480" { 3.0 } else { 20.0 },
            stages_ms: [0.0; 4],
        };
        let outcomes = vec![
            outcome("640x480", 0.6, true),
            outcome("640x480", 0.6, false),
            outcome("640x480", 0.3, true),
            outcome("1920x1080", 0.3, true),
        ];
        let figure = ApproachFigure(&outcomes);
        let lines = figure.lines();
        assert_eq!(lines[0], ("640x480", vec![(30.0, 1.0, 3.0), (60.0, 0.5, 3.0)]));
        assert!(lines[1].1.is_empty());
        assert_eq!(lines[2], ("1920x1080", vec![(30.0, 1.0, 20.0)]));
        let img = crate::plot::render_png(&figure).expect("png");
        assert_eq!(img.dimensions(), (960, 400));
        let svg = crate::plot::render_svg(&figure).expect("svg");
        for text in
            ["Found vs distance", "Detection time vs distance", "640x480", "1280x960", "distance to the outlet (cm)"]
        {
            assert!(svg.contains(text), "{text} missing");
        }
    }
}
