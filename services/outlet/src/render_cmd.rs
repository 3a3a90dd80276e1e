//! `outlet render` and `outlet sheet`: the simulated camera on the command line.

use anyhow::{Context, Result, bail};
use clap::Args;
use image::RgbImage;
use outlet_protocol::CameraModel;
use outlet_protocol::camera_info::{read_camera_info, write_camera_info};
use outlet_protocol::ply::write_ply_binary;
use outlet_sim::{SCENARIOS, render_frame, sample_scene};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The camera of a rendering run: a camera_info file, or size and intrinsics.
#[derive(Args, Debug, Clone)]
pub struct CameraArgs {
    /// Image width in pixels.
    #[arg(long, default_value_t = 640)]
    pub width: u32,
    /// Image height in pixels.
    #[arg(long, default_value_t = 480)]
    pub height: u32,
    /// Focal length in pixels (default: 525 scaled with the width from 640).
    #[arg(long)]
    pub focal: Option<f64>,
    /// Principal point x (default: the image centre).
    #[arg(long)]
    pub cx: Option<f64>,
    /// Principal point y (default: the image centre).
    #[arg(long)]
    pub cy: Option<f64>,
    /// plumb_bob distortion "k1,k2,p1,p2,k3".
    #[arg(long, default_value = "-0.06,0.03,0,0,0", allow_hyphen_values = true)]
    pub distortion: String,
    /// A ROS camera_info YAML: overrides the size and intrinsics above.
    #[arg(long)]
    pub camera: Option<PathBuf>,
}

impl CameraArgs {
    pub fn camera(&self) -> Result<CameraModel> {
        if let Some(path) = &self.camera {
            return Ok(read_camera_info(path)?);
        }
        let f = self.focal.unwrap_or(525.0 * self.width as f64 / 640.0);
        let cx = self.cx.unwrap_or((self.width as f64 - 1.0) / 2.0);
        let cy = self.cy.unwrap_or((self.height as f64 - 1.0) / 2.0);
        let values: Vec<f64> = self
            .distortion
            .split(',')
            .map(|v| v.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .with_context(|| format!("--distortion {:?} is not numbers", self.distortion))?;
        let d: [f64; 5] = values.as_slice().try_into().map_err(|_| {
            anyhow::anyhow!("--distortion {:?} needs 5 values k1,k2,p1,p2,k3, got {}", self.distortion, values.len())
        })?;
        Ok(CameraModel::new(self.width, self.height, [f, f, cx, cy], d)?)
    }
}

#[derive(Args, Debug)]
pub struct RenderArgs {
    /// Scenario name (one of the paper's Table I, or `negative`), or `all`.
    #[arg(long)]
    pub scenario: String,
    /// Images per scenario (default: the paper's count; 300 negatives).
    #[arg(long)]
    pub count: Option<usize>,
    /// Seed: the same seed gives the same bytes.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Output folder (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Stereo cloud: one point every this many pixels.
    #[arg(long, default_value_t = 2)]
    pub cloud_step: u32,
    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    #[command(flatten)]
    pub camera: CameraArgs,
}

/// Renders one image of a scenario and writes its four files; returns the image's name.
fn render_one(
    scenario: &str,
    seed: u64,
    index: usize,
    camera: &CameraModel,
    cloud_step: u32,
    out: &Path,
) -> Result<String> {
    let mut scene = sample_scene(scenario, seed, index as u64, camera)?;
    scene.stereo.step = cloud_step.max(1);
    let stem = format!("{scenario}_{index:04}");
    let ext = if scene.sensor.jpeg_quality.is_some() { "jpg" } else { "png" };
    let image_name = format!("{stem}.{ext}");
    let rendered = render_frame(&scene, &image_name);
    let image_path = out.join(&image_name);
    match &rendered.frame.jpeg {
        Some(bytes) => std::fs::write(&image_path, bytes),
        None => encode_png(&rendered.frame.image, &image_path),
    }
    .with_context(|| format!("writing {}", image_path.display()))?;
    let json = serde_json::to_string_pretty(&rendered.truth)?;
    write(&out.join(format!("{stem}.json")), json.as_bytes())?;
    write(&out.join(format!("{stem}.camera.yaml")), write_camera_info(camera, "outlet_sim").as_bytes())?;
    write(&out.join(format!("{stem}.ply")), &write_ply_binary(&rendered.cloud))?;
    Ok(image_name)
}

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// PNG with the image crate's default (deterministic) settings.
pub fn encode_png(image: &RgbImage, path: &Path) -> std::io::Result<()> {
    image.save_with_format(path, image::ImageFormat::Png).map_err(std::io::Error::other)
}

fn scenarios_of(name: &str) -> Result<Vec<&'static str>> {
    match name {
        "all" => return Ok(SCENARIOS.to_vec()),
        "realistic" => return Ok(outlet_sim::REALISTIC_SCENARIOS.to_vec()),
        _ => {}
    }
    match outlet_sim::scenario_named(name) {
        Some(s) => Ok(vec![s]),
        None => bail!(
            "unknown scenario {name:?}; known: all, realistic, {}, each also as rs_NAME (realistic stereo)",
            SCENARIOS.join(", ")
        ),
    }
}

/// Runs `work(i)` for i in 0..n on `threads` threads, ticking a progress bar.
fn parallel<F>(n: usize, threads: usize, label: &str, work: F) -> Vec<Result<()>>
where
    F: Fn(usize) -> Result<()> + Sync,
{
    let bar = crate::progress::bar(n, label);
    let next = AtomicUsize::new(0);
    let results: Vec<std::sync::Mutex<Option<Result<()>>>> = (0..n).map(|_| std::sync::Mutex::new(None)).collect();
    std::thread::scope(|s| {
        for _ in 0..threads.max(1) {
            s.spawn(|| {
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= n {
                        break;
                    }
                    let r = work(i);
                    if let Ok(mut slot) = results[i].lock() {
                        *slot = Some(r);
                    }
                    bar.inc(1);
                }
            });
        }
    });
    bar.finish_and_clear();
    results
        .into_iter()
        .map(|m| m.into_inner().ok().flatten().unwrap_or_else(|| Err(anyhow::anyhow!("worker lost"))))
        .collect()
}

fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

pub fn render(args: RenderArgs) -> Result<()> {
    let camera = args.camera.camera()?;
    let scenarios = scenarios_of(&args.scenario)?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let jobs: Vec<(&str, usize)> = scenarios
        .iter()
        .flat_map(|s| (0..args.count.unwrap_or_else(|| outlet_sim::paper_count(s))).map(move |i| (*s, i)))
        .collect();
    let results = parallel(jobs.len(), args.threads.unwrap_or_else(default_threads), "rendering", |k| {
        let (scenario, i) = jobs[k];
        render_one(scenario, args.seed, i, &camera, args.cloud_step, &args.out).map(|_| ())
    });
    let failed: Vec<String> = results.iter().filter_map(|r| r.as_ref().err().map(|e| format!("{e:#}"))).collect();
    for e in &failed {
        tracing::error!("{e}");
    }
    tracing::info!("rendered {} of {} images into {}", jobs.len() - failed.len(), jobs.len(), args.out.display());
    if failed.len() == jobs.len() && !jobs.is_empty() {
        bail!("no image could be rendered");
    }
    Ok(())
}

#[derive(Args, Debug)]
pub struct SheetArgs {
    /// Output PNG.
    #[arg(long, default_value = "docs/scenarios.png")]
    pub out: PathBuf,
    /// Images per scenario (one row each).
    #[arg(long, default_value_t = 4)]
    pub per_scenario: usize,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

pub fn sheet(args: SheetArgs) -> Result<()> {
    let camera = CameraModel::default_vga();
    let (tw, th, label_w) = (320u32, 240u32, 120u32);
    let n = args.per_scenario.max(1) as u32;
    let mut sheet =
        RgbImage::from_pixel(label_w + n * (tw + 4), SCENARIOS.len() as u32 * (th + 4), image::Rgb([24, 24, 24]));
    for (row, scenario) in SCENARIOS.iter().enumerate() {
        let y0 = row as u32 * (th + 4);
        let label = plotters::style::RGBColor(235, 235, 235);
        crate::plot::draw_label(&mut sheet, scenario, (6, (y0 + th / 2) as i32 - 8), 15.0, label)?;
        for col in 0..n {
            let scene = sample_scene(scenario, args.seed, col as u64, &camera)?;
            let frame = render_frame(&scene, "sheet");
            let thumb = image::imageops::resize(&frame.frame.image, tw, th, image::imageops::FilterType::Triangle);
            image::imageops::replace(&mut sheet, &thumb, (label_w + col * (tw + 4)) as i64, y0 as i64);
        }
    }
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    encode_png(&sheet, &args.out).with_context(|| format!("writing {}", args.out.display()))?;
    tracing::info!("wrote {}", args.out.display());
    Ok(())
}
