//! `dopslam convert`: a recording written as a TUM RGB-D or KITTI stereo folder.

use anyhow::{Context, Result};
use clap::Args;
use dopslam::config::Config;
use dopslam::io::recording::convert::{self, Layout};

use super::topics::TopicArgs;

/// The layouts `dopslam convert` writes.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum LayoutArg {
    /// TUM RGB-D (RGB-D recordings): rgb/ and depth/ PNGs (16-bit, 5000 per metre),
    /// rgb.txt, depth.txt, calibration.yaml.
    Tum,
    /// KITTI odometry (stereo recordings): image_0/, image_1/, times.txt, calib.txt.
    Kitti,
}

/// `dopslam convert`.
#[derive(Args, Debug)]
pub struct ConvertArgs {
    /// A recording (ROS 1 .bag, ROS 2 bag folder, .mcap, .db3) or any RGB-D sequence.
    input: std::path::PathBuf,
    /// The layout to write.
    #[arg(long, value_enum, default_value = "tum")]
    to: LayoutArg,
    /// The output folder: must not exist yet (or be empty).
    out: std::path::PathBuf,
    /// A TOML config ([dataset]: depth scale, tolerance, topics).
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Convert only the first N frames.
    #[arg(long)]
    frames: Option<usize>,
    #[command(flatten)]
    topics: TopicArgs,
}

/// Runs `dopslam convert`.
pub fn run_convert(args: ConvertArgs, mut config: Config) -> Result<()> {
    args.topics.apply(&mut config);
    let layout = match args.to {
        LayoutArg::Tum => Layout::Tum,
        LayoutArg::Kitti => Layout::Kitti,
    };
    // The output is checked before the recording is scanned (which can take a while).
    if dopslam::io::output::is_within(&args.out, &args.input) {
        anyhow::bail!(
            "{}: the output folder is inside the input {}: dopslam never writes into its inputs; choose a folder elsewhere",
            args.out.display(),
            args.input.display()
        );
    }
    let partial = convert::prepare(&args.out, layout)?;
    std::fs::remove_dir_all(&partial)?;
    let sequence = dopslam::run::open_sequence(&args.input, &config)?;
    let frames = args.frames.unwrap_or(usize::MAX).min(sequence.len());
    let written = convert::convert(sequence.as_ref(), &args.out, frames, layout, true)?;
    // What the reader found wrong and read past (a recording cut short, no index) stays
    // with the converted folder.
    if !sequence.warnings().is_empty() {
        let path = args.out.join("conversion_warnings.txt");
        std::fs::write(&path, sequence.warnings().join("\n") + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!(
            "what the reader found wrong with the recording is kept in {}",
            path.display()
        );
    }
    println!(
        "wrote {written} frames to {} ({layout:?} layout)",
        args.out.display()
    );
    Ok(())
}
