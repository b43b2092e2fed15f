//! `dopslam merge`: one dense static map of several recordings of one place, tracked
//! in one map's frame (`dopslam run --map`), with free space carved across them.

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use clap::Args;
use dopslam::config::Config;
use dopslam::run::{DensePass, DenseSetup};

use super::fuse::{open_run, OpenedRun};

#[derive(Args)]
pub struct MergeArgs {
    /// The run folders, each a recording of the same place tracked in one map: the
    /// first run, and runs made with `dopslam run --map` on it (or on each other).
    #[arg(required = true, num_args = 2..)]
    pub runs: Vec<PathBuf>,
    /// Output folder: dense_mesh.ply/.obj, dense_points.ply, dense.json, merge.json.
    #[arg(long)]
    pub out: PathBuf,
    /// A TOML config whose [dense] section sets the fusion (default: built-in defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
}

pub fn run_merge(args: MergeArgs) -> Result<()> {
    let config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::default(),
    };
    let opened = args
        .runs
        .iter()
        .map(|run| open_run(run, config.clone(), None, None))
        .collect::<Result<Vec<_>>>()?;
    check_one_place(&args.runs, &opened)?;
    let _lock = prepare_output(&args.out, &args.runs, &opened)?;
    let setups = opened
        .iter()
        .map(|o| {
            Ok(DenseSetup::resolve(o.sequence.as_ref(), &o.config)?
                .with_disparity_offset(o.report.disparity_offset_px()))
        })
        .collect::<Result<Vec<_>>>()?;
    let sides: Vec<PathBuf> = opened
        .iter()
        .enumerate()
        .map(|(i, o)| {
            let name = format!("{}_{}", i + 1, o.report.sequence);
            args.out
                .join(dopslam::io::run_dir::names::MERGED_RECORDINGS)
                .join(name)
        })
        .collect();
    let passes: Vec<DensePass> = opened
        .iter()
        .zip(&setups)
        .zip(&args.runs)
        .zip(&sides)
        .map(|(((o, setup), run), side)| DensePass {
            sequence: o.sequence.as_ref(),
            setup,
            run_dir: run,
            out_dir: side,
            masking: o.report.mode,
            sequence_dir: Some(&o.sequence_dir),
            progress: true,
        })
        .collect();
    let report = dopslam::run::merge_pass(&passes, &args.out)?;
    for (part, o) in report.recordings.iter().zip(&opened) {
        println!(
            "{}: {} frames fused ({:.1} % of pixels masked), {} carved free space",
            o.report.sequence, part.frames_fused, part.masked_percent, part.carving_frames
        );
    }
    super::fuse::print_dense(&report.dense);
    println!("wrote {}", args.out.display());
    Ok(())
}

/// The runs share one world frame (each was tracked in a map holding the first
/// recording of the place, or is it) and one sensor and camera.
fn check_one_place(runs: &[PathBuf], opened: &[OpenedRun]) -> Result<()> {
    let root = |o: &OpenedRun| {
        o.report
            .slam_map
            .as_ref()
            .and_then(|m| m.loaded.as_ref())
            .and_then(|l| l.recordings.first().cloned())
            .unwrap_or_else(|| o.report.sequence.clone())
    };
    let (first, first_root) = (&opened[0], root(&opened[0]));
    for (run, o) in runs.iter().zip(opened).skip(1) {
        if root(o) != first_root {
            bail!(
                "{} was not tracked in the same map as {} (its map starts with recording {:?}, the other's with {:?}): merge runs made with `dopslam run --map` on one first run",
                run.display(),
                runs[0].display(),
                root(o),
                first_root
            );
        }
        if o.sequence.sensor() != first.sequence.sensor()
            || o.report.setup.calibration.camera != first.report.setup.calibration.camera
        {
            bail!(
                "{} and {} come from different sensors or cameras: a merged map needs one",
                run.display(),
                runs[0].display()
            );
        }
    }
    Ok(())
}

/// The output folder checked (writable, not inside a sequence or a run folder),
/// locked, and an earlier merge's or run's outputs there moved aside.
fn prepare_output(
    out: &Path,
    runs: &[PathBuf],
    opened: &[OpenedRun],
) -> Result<dopslam::io::output::DirLock> {
    use dopslam::io::output;
    let mut inputs: Vec<&Path> = opened.iter().map(|o| o.sequence_dir.as_path()).collect();
    inputs.extend(runs.iter().map(PathBuf::as_path));
    // A run folder is an input: the output may not be one, nor lie inside one.
    output::prepare_dir(out, "output", &inputs)?;
    let lock = output::DirLock::take(out)?;
    let (moved, to) = output::move_previous_outputs(out, &[])?;
    if let Some(to) = to {
        eprintln!(
            "{} held earlier outputs: moved into {} ({})",
            out.display(),
            to.display(),
            moved.join(", ")
        );
    }
    Ok(lock)
}
