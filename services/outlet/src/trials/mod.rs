//! `outlet trials`: plug-in success over simulated approaches (issue 18). A
//! robot parks in front of a rendered wall, the camera on its arm moves in as
//! the controller commands, each frame and its stereo cloud go through the
//! sidecar's services over shared memory, and the controller reads the hole
//! poses with the client library; the judge holds the push against the
//! renderer's truth.

mod controller;
mod judge;
mod park;
mod pipeline;
mod report;

use anyhow::{Context, Result, bail};
use clap::Args;
use controller::{Action, Controller, Estimate};
use judge::{Class, Ending, Truth};
use outlet_protocol::CameraModel;
use outlet_sim::approach::{ApproachRenderer, seen_from};
use outlet_sim::rng::SimRng;
use pipeline::Pipeline;
use report::TrialRecord;
use std::collections::BTreeMap;
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

#[derive(Args, Debug)]
pub struct TrialsArgs {
    /// Number of trials.
    #[arg(long, default_value_t = 100)]
    pub count: u64,
    /// Trial index to start at: `--first 17 --count 1` repeats trial 17 alone.
    #[arg(long, default_value_t = 0)]
    pub first: u64,
    /// `default` (every outlet scenario), `hard` (specular, ground up, dim,
    /// oblique), `realistic` (real stereo), or a scenario name; several are
    /// taken in turn.
    #[arg(long, default_values_t = vec!["default".to_string()])]
    pub scenario: Vec<String>,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// One JSON line per trial on stdout; the summary goes to stderr.
    #[arg(long)]
    pub json: bool,
    /// Most frames of one approach before it times out.
    #[arg(long, default_value_t = 30)]
    pub max_frames: u32,
    /// Write the success-rate plot here (PNG; its SVG beside it, same stem).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Write every frame (PNG) and its truth (JSON) here, to look at a trial
    /// repeated alone with `--first`.
    #[arg(long)]
    pub save_frames: Option<PathBuf>,
    /// Where the services' logs go (default: a folder in the temp dir).
    #[arg(long)]
    pub logs: Option<PathBuf>,
}

/// The robot's clock: the camera's frame period, the arm's speeds, the push.
const FRAME_PERIOD_S: f64 = 1.0 / 15.0;
const ARM_SPEED_M_S: f64 = 0.15;
const ARM_TURN_DEG_S: f64 = 45.0;
const PUSH_SPEED_M_S: f64 = 0.03;

pub fn trials(args: TrialsArgs) -> Result<()> {
    if args.count == 0 {
        bail!("--count 0: nothing to run");
    }
    if args.max_frames == 0 {
        bail!("--max-frames 0: an approach needs a frame");
    }
    for s in &args.scenario {
        park::check_mix(s)?;
    }
    let camera = CameraModel::default_vga();
    let renderer = ApproachRenderer::new(&camera);
    let run = format!("trials-{}", std::process::id());
    if let Some(dir) = &args.save_frames {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let logs = args.logs.clone().unwrap_or_else(|| std::env::temp_dir().join(&run));
    std::fs::create_dir_all(&logs).with_context(|| format!("creating {}", logs.display()))?;
    eprintln!(
        "outlet trials: {} trials of {} from seed {}; services' logs in {}",
        args.count,
        args.scenario.join("+"),
        args.seed,
        logs.display()
    );

    let started = Instant::now();
    let mut pipelines: BTreeMap<String, Pipeline> = BTreeMap::new();
    let mut records = Vec::new();
    let stdout = std::io::stdout();
    for index in args.first..args.first + args.count {
        let mix = &args.scenario[(index % args.scenario.len() as u64) as usize];
        let setup = park::draw(mix, args.seed, index, &camera)?;
        let template = setup.scene.search_template.clone();
        if !pipelines.contains_key(&template) {
            let domain = format!("{run}-{template}");
            let mut p = Pipeline::start(&domain, &template, &camera, &logs)?;
            let first = renderer
                .render(&seen_from(&setup.scene, &setup.start, 0), "warm-up")
                .context("the renderer's camera")?;
            p.warm_up(&camera, first.frame.image.as_raw(), &first.cloud)?;
            pipelines.insert(template.clone(), p);
        }
        let Some(pipeline) = pipelines.get_mut(&template) else { bail!("no pipeline for {template}") };
        if pipeline.interrupted() {
            // Stop the services cleanly and report what was run.
            eprintln!("outlet trials: interrupted after {} trials", records.len());
            break;
        }
        let trial = Trial {
            index,
            seed: args.seed,
            setup: &setup,
            max_frames: args.max_frames,
            save: args.save_frames.as_deref(),
        };
        let record = run_trial(&trial, pipeline, &renderer, &camera)?;
        if args.json {
            let mut out = stdout.lock();
            writeln!(out, "{}", serde_json::to_string(&record)?)?;
        }
        records.push(record);
    }
    let wall_s = started.elapsed().as_secs_f64();
    drop(pipelines);
    eprint!("{}", report::summary(&records, wall_s));
    if let Some(path) = &args.plot {
        let [png, svg] = crate::plot::write_at(&report::TrialsFigure(&records), path)?;
        eprintln!("outlet trials: wrote {} and {}", png.display(), svg.display());
    }
    Ok(())
}

/// What one approach is given.
struct Trial<'a> {
    index: u64,
    seed: u64,
    setup: &'a park::Setup,
    max_frames: u32,
    save: Option<&'a std::path::Path>,
}

/// One approach: frames until the controller pushes or the budget runs out.
fn run_trial(
    trial: &Trial,
    pipeline: &mut Pipeline,
    renderer: &ApproachRenderer,
    camera: &CameraModel,
) -> Result<TrialRecord> {
    let Trial { index, seed, setup, max_frames, save } = *trial;
    let started = Instant::now();
    let mut arm = SimRng::new(outlet_sim::scenario::image_seed(seed, "trials-arm", index));
    let mut controller = Controller::new();
    let mut tool = setup.start;
    let mut record = TrialRecord::new(index, seed, setup, &pipeline.template);
    let mut ending = None;
    for frame in 0..max_frames {
        let t = Instant::now();
        let noise_seed = setup.scene.noise_seed ^ (u64::from(frame) + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15);
        let scene = seen_from(&setup.scene, &tool, noise_seed);
        let rendered = renderer.render(&scene, "trial").context("the renderer's camera")?;
        record.render_ms += t.elapsed().as_secs_f64() * 1e3;
        if let Some(dir) = save {
            let stem = dir.join(format!("trial{index:05}_frame{frame:02}"));
            rendered.frame.image.save(stem.with_extension("png"))?;
            std::fs::write(stem.with_extension("json"), serde_json::to_string(&rendered.truth)?)?;
        }
        let result = pipeline.process(camera, rendered.frame.image.as_raw(), &rendered.cloud)?;
        record.frames += 1;
        record.count_status(result.status);
        record.detect_ms += result.detect_ms.unwrap_or(0.0);
        if let Some(s) = result.sidecar_ms {
            record.pose_ms += (s - result.detect_ms.unwrap_or(0.0)).max(0.0);
        }
        if let Some(poses) = &result.poses {
            let truth: Vec<Option<[f64; 3]>> = rendered.truth.holes.iter().map(|h| h.position_m).collect();
            record.check_pose(poses, &truth);
        }
        let estimate = result.poses.as_ref().and_then(Estimate::of);
        let action = controller.step(estimate.as_ref());
        record.sim_time_s += FRAME_PERIOD_S;
        match action {
            Action::Hold => {}
            Action::Move(command) => {
                let (length, angle) = controller::size(&command);
                record.sim_time_s += (length / ARM_SPEED_M_S).max(angle.to_degrees() / ARM_TURN_DEG_S);
                tool *= controller::execute(&command, &mut arm);
            }
            Action::Insert(command) => {
                let (length, angle) = controller::size(&command);
                record.sim_time_s += (length / PUSH_SPEED_M_S).max(angle.to_degrees() / ARM_TURN_DEG_S);
                tool *= controller::execute(&command, &mut arm);
                ending = Some(Ending::Inserted { tool, target: controller.target.unwrap_or(0) });
                break;
            }
        }
    }
    let ending = ending.unwrap_or(if controller.found() {
        Ending::TimedOut { tool, target: controller.target }
    } else {
        Ending::NeverFound
    });
    let truth = Truth { geometry: setup.scene.geometry(), plate_size_mm: setup.scene.plates[0].size };
    let (class, landing) = judge::classify(&truth, &ending);
    record.finish(class, landing, controller.target, controller.last_prediction_mm, started.elapsed().as_secs_f64());
    if class != Class::Success && class != Class::CorrectlyRefused {
        tracing::info!(trial = index, seed, scenario = %setup.scenario, "{}", class.as_str());
    }
    Ok(record)
}
