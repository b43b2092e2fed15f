//! `dopslam synth`: a synthetic sequence with exact ground truth.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

#[derive(Args)]
pub struct SynthArgs {
    /// A synth preset, e.g. configs/synth/static_room.toml.
    #[arg(long)]
    config: PathBuf,
    /// Output folder (must be empty or absent unless --force).
    #[arg(long)]
    out: PathBuf,
    /// Overrides the preset's seed.
    #[arg(long)]
    seed: Option<u64>,
    /// Overrides the preset's number of frames.
    #[arg(long, value_parser = super::values::at_least_one)]
    frames: Option<usize>,
    /// Overwrite a non-empty output folder.
    #[arg(long)]
    force: bool,
    /// The same room and camera path without the movers (a control: what the movers
    /// cost the tracker).
    #[arg(long)]
    without_movers: bool,
    /// Also write preview.png: a contact sheet of 4 frames (colour, depth, mask).
    #[arg(long)]
    preview: bool,
}

pub fn run_synth(args: SynthArgs) -> Result<()> {
    let mut config = dopslam::synth::SynthConfig::load(&args.config)?;
    if let Some(seed) = args.seed {
        config.sequence.seed = seed;
    }
    if let Some(frames) = args.frames {
        config.sequence.frames = frames;
    }
    config.sequence.without_movers |= args.without_movers;
    let summary = dopslam::synth::generate(&config, &args.out, args.force)?;
    println!(
        "wrote {} frames to {} in {:.1} s ({:.1} frames/s)",
        summary.frames,
        summary.out.display(),
        summary.seconds,
        summary.frames as f64 / summary.seconds
    );
    if args.preview {
        let path = args.out.join("preview.png");
        dopslam::synth::preview::contact_sheet(&args.out, 4)?
            .save(&path)
            .with_context(|| format!("writing {}", path.display()))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
