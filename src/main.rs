//! The `dopslam` command line: parses the arguments and hands each command to its
//! module under `cli/`.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use cli::load_config;

mod cli;

#[derive(Parser)]
#[command(
    name = "dopslam",
    version,
    about = "Dynamic-object-probability SLAM for RGB-D and stereo sequences"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Evaluate an estimated trajectory against a reference: ATE/APE and RPE as evo and TUM's scripts define them.
    Eval(cli::eval::EvalArgs),
    /// Generate the bundled example (ground truth + drifting estimate) and evaluate it.
    Demo(cli::demo::DemoArgs),
    /// Generate a synthetic RGB-D sequence in the TUM layout with exact ground truth.
    Synth(cli::synth::SynthArgs),
    /// Run a sequence: the tracking pass (trajectory, keyframes, sparse map, report), then the dense map (mesh, point cloud, pictures).
    Run(cli::run::RunArgs),
    /// Fuse a finished run's frames again into a dense map, with other settings, without tracking again.
    Fuse(cli::fuse::FuseArgs),
    /// One dense static map of several recordings of one place tracked in one map (`run --map`), free space carved across them.
    Merge(cli::merge::MergeArgs),
    /// Compare dense maps (PLY) against a static reference and each other: accuracy, completion, ghosts, SA/DA.
    CompareMaps(cli::compare_maps::CompareArgs),
    /// Describe a sequence folder (TUM/Bonn RGB-D or KITTI stereo layout) or a recording (ROS bag, MCAP): frames, pairing, topics, calibration, ground truth.
    Info(cli::info::InfoArgs),
    /// Write a recording (ROS bag, MCAP, RealSense) as a TUM RGB-D or KITTI stereo folder that every tool reads.
    Convert(cli::convert::ConvertArgs),
    /// Detect objects (COCO) in an image or a sequence: prints them and draws boxes onto PNGs.
    Detect(cli::detect::DetectArgs),
    /// Train or inspect the place-recognition vocabulary (bag of binary words) of the global pass.
    Vocab(cli::vocab::VocabArgs),
    /// Show where the runtime data (ONNX Runtime, detector models, vocabulary) was found and what is missing.
    Doctor(cli::doctor::DoctorArgs),
    /// Make and optimise 3-D pose graphs in g2o's format (VERTEX_SE3:QUAT / EDGE_SE3:QUAT).
    Graph(cli::graph::GraphArgs),
    /// Run many sequences in several modes, repeated, and write the tables, plots and HTML report (resumable).
    Batch(cli::batch::BatchArgs),
    /// Match one rectified stereo pair as tracking does and compare with OpenCV's SGBM disparities.
    Stereo(cli::stereo::StereoArgs),
    /// Build the Rerun recording of a finished run folder (trajectories, events, boxes, removed keypoints, images, dense map) without tracking again.
    View(cli::view::ViewArgs),
}

fn main() -> ExitCode {
    // Die quietly on a closed pipe (`dopslam eval --json | head`), as Unix tools do,
    // instead of panicking in println!.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    dopslam::memory::keep_freed_memory();
    let cli = Cli::parse();
    if matches!(
        cli.command,
        Command::Run(_) | Command::Fuse(_) | Command::Merge(_) | Command::Batch(_)
    ) {
        dopslam::interrupt::install();
    }
    let result = match cli.command {
        Command::Eval(args) => cli::eval::run_eval(args),
        Command::Demo(args) => cli::demo::run_demo(args),
        Command::Synth(args) => cli::synth::run_synth(args),
        Command::Info(args) => cli::info::run_info(args),
        Command::Convert(args) => load_config(args.config.as_deref())
            .and_then(|config| cli::convert::run_convert(args, config)),
        Command::Run(args) => cli::run::run_run(args),
        Command::Fuse(args) => cli::fuse::run_fuse(args),
        Command::Merge(args) => cli::merge::run_merge(args),
        Command::CompareMaps(args) => cli::compare_maps::run_compare(args),
        Command::Detect(args) => cli::detect::run_detect(args),
        Command::Vocab(args) => cli::vocab::run_vocab(args),
        Command::Graph(args) => cli::graph::run_graph(args),
        Command::Doctor(args) => cli::doctor::run_doctor(args),
        Command::Batch(args) => cli::batch::run_batch(args),
        Command::Stereo(args) => cli::stereo::run_stereo(args),
        Command::View(args) => {
            load_config(args.config.as_deref()).and_then(|config| cli::view::run_view(args, config))
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {}", error_sentence(&error));
            ExitCode::FAILURE
        }
    }
}

/// The error and its causes in one line, each cause once: typed errors that name
/// their cause in their own message (`cannot create X: Not a directory`) are not
/// followed by it again.
fn error_sentence(error: &anyhow::Error) -> String {
    let mut sentence = error.to_string();
    for cause in error.chain().skip(1) {
        let text = cause.to_string();
        if !sentence.contains(&text) {
            sentence.push_str(": ");
            sentence.push_str(&text);
        }
    }
    sentence
}
