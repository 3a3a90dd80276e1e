//! `outlet`: the command line of the outlet perception sidecar.

mod approach_cmd;
mod demo;
mod demo_photos;
mod detect_cmd;
mod eval_cmd;
mod eval_plots;
mod nees;
mod photos_cmd;
mod plot;
mod progress;
mod record;
mod render_cmd;
mod report_html;
mod serve;
mod soak;
mod status;
mod trials;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(name = "outlet", version, about = "Finds wall outlets' holes in camera images and gives their 3D positions")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Render simulated outlet images with exact ground truth (image, JSON, camera_info YAML, PLY cloud).
    Render(render_cmd::RenderArgs),
    /// Render a contact sheet: a few images of every scenario in one PNG.
    Sheet(render_cmd::SheetArgs),
    /// Find the outlet's holes in images (CONTRACT.md).
    Detect(detect_cmd::DetectArgs),
    /// Train a template from one labelled photograph.
    Train(detect_cmd::TrainArgs),
    /// Detection over rendered scenarios: the paper's Table I, timings, rates by view.
    Eval(eval_cmd::EvalArgs),
    /// Run one of the sidecar's services on iceoryx2 shared memory.
    Serve(serve::ServeArgs),
    /// Record the camera's frames and clouds and the services' results from shared memory into an MCAP file.
    Record(record::RecordArgs),
    /// Play an MCAP recording (ours, or a ROS 2 bag of a camera) into shared memory with its original timing.
    Replay(record::ReplayArgs),
    /// The whole sidecar on the simulated camera (each result with its error and latency), or on photographs.
    Demo(demo::DemoArgs),
    /// A live view of the running services: channel rates, latencies, rejected inputs.
    Status(status::StatusArgs),
    /// Plug-in success over simulated approaches: the sidecar, a controller and a strict judge.
    Trials(trials::TrialsArgs),
}

fn main() -> ExitCode {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .init();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Render(args) => render_cmd::render(args),
        Command::Sheet(args) => render_cmd::sheet(args),
        Command::Detect(args) => detect_cmd::detect(args),
        Command::Train(args) => detect_cmd::train(args),
        Command::Eval(args) => eval_cmd::eval(args),
        Command::Serve(args) => serve::serve(args),
        Command::Status(args) => status::status(args),
        Command::Demo(args) => demo::demo(args),
        Command::Record(args) => record::record(args),
        Command::Replay(args) => record::replay(args),
        Command::Trials(args) => trials::trials(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("outlet: {e:#}");
            ExitCode::FAILURE
        }
    }
}
