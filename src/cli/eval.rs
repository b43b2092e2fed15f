//! `dopslam eval`: ATE/APE and RPE of an estimate against a reference, as evo and TUM's
//! scripts define them.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use dopslam::eval::associate::AssociationRule;
use dopslam::eval::ate::PoseRelation;
use dopslam::eval::plot::write_plots;
use dopslam::eval::report::{AlignMode, RpeSpec};
use dopslam::eval::rpe::DeltaUnit;
use dopslam::eval::{evaluate_with_series, EvalOptions};
use dopslam::io::atomic::write_atomic;
use dopslam::io::trajectory::TrajectoryFormat;
use dopslam::io::Trajectory;

use super::load_config;

#[derive(Args)]
pub struct EvalArgs {
    /// The reference (ground-truth) trajectory file.
    pub reference: PathBuf,
    /// The estimated trajectory file.
    pub estimate: PathBuf,
    /// Format of both files (tum: `t tx ty tz qx qy qz qw`; kitti: 12 numbers a line).
    #[arg(long, value_enum, default_value = "tum")]
    pub format: TrajectoryFormat,
    /// A KITTI times.txt giving both KITTI trajectories timestamps (else poses pair by index).
    #[arg(long)]
    pub times: Option<PathBuf>,
    /// A TOML config whose [eval] section sets the defaults below.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// How poses are paired: evo (nearest timestamp), tum-greedy (associate.py) or by-index.
    #[arg(long, value_enum)]
    pub association: Option<AssociationRule>,
    /// Association tolerance in seconds (default: evo 0.01, tum-greedy 0.02).
    #[arg(long, value_parser = super::values::non_negative)]
    pub max_diff: Option<f64>,
    /// Time offset added to the estimate's timestamps, in seconds.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = super::values::finite)]
    pub offset: f64,
    /// Alignment of the estimate to the reference.
    #[arg(long, value_enum)]
    pub align: Option<AlignMode>,
    /// Align using only the first N matched poses.
    #[arg(long)]
    pub n_align: Option<usize>,
    /// Pose relation of the APE.
    #[arg(long, value_enum, default_value = "trans_part")]
    pub pose_relation: PoseRelation,
    /// RPE deltas, each a number and a unit: f (frames), m (metres), d (degrees), r (radians), s (seconds, reported per second). Repeat for several.
    #[arg(long = "rpe", default_values_t = vec!["1f".to_string()])]
    pub rpe: Vec<String>,
    /// Pose relation of the RPE.
    #[arg(long, value_enum, default_value = "trans_part")]
    pub rpe_relation: PoseRelation,
    /// Fail when fewer than this fraction of the shorter trajectory's poses are matched.
    #[arg(long, value_parser = super::values::fraction)]
    pub min_coverage: Option<f64>,
    /// Print the report as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Write SVG plots (trajectory top view, errors over time) into this folder.
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Also write the JSON report to this file.
    #[arg(long)]
    pub save_report: Option<PathBuf>,
}

pub fn parse_rpe(text: &str) -> Result<RpeSpec> {
    let split = text
        .find(|c: char| c.is_ascii_alphabetic())
        .with_context(|| {
            format!("--rpe {text:?}: expected a number and a unit, e.g. 1f, 1s, 0.5m")
        })?;
    let (number, unit) = text.split_at(split);
    let delta: f64 = number
        .parse()
        .with_context(|| format!("--rpe {text:?}: {number:?} is not a number"))?;
    if delta.is_nan() || delta <= 0.0 {
        bail!("--rpe {text:?}: the delta must be positive");
    }
    let unit = match unit {
        "f" => DeltaUnit::Frames,
        "m" => DeltaUnit::Metres,
        "d" => DeltaUnit::Degrees,
        "r" => DeltaUnit::Radians,
        "s" => DeltaUnit::Seconds,
        other => bail!("--rpe {text:?}: unknown unit {other:?} (f, m, d, r or s)"),
    };
    Ok(RpeSpec { delta, unit })
}

pub fn read_trajectory(
    path: &Path,
    format: TrajectoryFormat,
    times: Option<&Path>,
) -> Result<Trajectory> {
    let trajectory = Trajectory::read(path, format)?;
    Ok(match times {
        Some(times) => trajectory.with_times_file(times)?,
        None => trajectory,
    })
}

pub fn run_eval(args: EvalArgs) -> Result<()> {
    let config = load_config(args.config.as_deref())?;
    let reference = read_trajectory(&args.reference, args.format, args.times.as_deref())?;
    let estimate = read_trajectory(&args.estimate, args.format, args.times.as_deref())?;
    if let Some((t, first, second)) = estimate.repeated_timestamp() {
        bail!(
            "{}: timestamp {t} is given twice (poses {first} and {second}): an estimate gives one pose per time",
            args.estimate.display()
        );
    }
    let default_rule = if args.format == TrajectoryFormat::Kitti && args.times.is_none() {
        AssociationRule::ByIndex
    } else {
        config.eval.association
    };
    let options = EvalOptions {
        association: args.association.unwrap_or(default_rule),
        max_diff: args.max_diff.or(config.eval.max_diff),
        offset: args.offset,
        align: args.align.unwrap_or(config.eval.align),
        n_align: args.n_align,
        ape_relation: args.pose_relation,
        rpe: args
            .rpe
            .iter()
            .map(|s| parse_rpe(s))
            .collect::<Result<_>>()?,
        rpe_relation: args.rpe_relation,
        min_coverage: args.min_coverage.unwrap_or(config.eval.min_coverage),
    };
    let dopslam::eval::Evaluation { report, series } =
        evaluate_with_series(&reference, &estimate, &options).with_context(|| {
            format!(
                "evaluating {} against {}",
                args.estimate.display(),
                args.reference.display()
            )
        })?;
    let json = serde_json::to_string_pretty(&report)?;
    if args.json {
        println!("{json}");
    } else {
        print!("{}", report.to_table());
    }
    if let Some(path) = &args.save_report {
        write_atomic(path, json.as_bytes())?;
    }
    if let Some(dir) = &args.plot {
        for path in write_plots(&report, &series, dir)? {
            eprintln!("wrote {}", path.display());
        }
    }
    Ok(())
}
