//! `dopslam compare-maps`: dense maps against a static reference and each other.

use std::path::{Path, PathBuf};

use anyhow::{bail, Result};
use clap::Args;
use dopslam::dense::compare_maps::{compare_maps, CompareInputs, Comparison};
use dopslam::dense::map_figures::CompareSettings;
use dopslam::io::trajectory::TrajectoryFormat;
use dopslam::io::Trajectory;
use dopslam::records::run_alignment;

#[derive(Args)]
pub struct CompareArgs {
    /// The maps to judge (PLY: a mesh's vertices or a point cloud). With two or more,
    /// the last is the baseline for SA (e.g. fused without DOP), and the reference
    /// when --reference is not given.
    #[arg(required = true)]
    pub maps: Vec<PathBuf>,
    /// The static reference (a mesh or point cloud), e.g. a synthetic sequence's
    /// static_scene.ply.
    #[arg(long)]
    pub reference: Option<PathBuf>,
    /// The movers' ground truth (points), e.g. a synthetic sequence's movers.ply: mover
    /// points in the maps and DA.
    #[arg(long)]
    pub movers: Option<PathBuf>,
    /// A trajectory (TUM format) to orient the pictures.
    #[arg(long)]
    pub trajectory: Option<PathBuf>,
    /// Move each map into the reference's frame: its run's poses (trajectory.txt and
    /// report.json beside the map, or one folder up; for a merged map, the first run
    /// its merge.json names) fitted to the ground truth of the
    /// sequence the run names. Needed against a synthetic static_scene.ply.
    #[arg(long)]
    pub align: bool,
    /// Precision/recall threshold, metres.
    #[arg(long, default_value_t = CompareSettings::default().threshold)]
    pub threshold: f64,
    /// Ghost distance: map points farther than this from the reference, metres.
    #[arg(long, default_value_t = CompareSettings::default().ghost_distance)]
    pub ghost_distance: f64,
    /// The reference surface is sampled this far apart for completion and recall,
    /// metres; wider where that would give more than 10 million samples (a street's
    /// scene), which the run says.
    #[arg(long, default_value_t = CompareSettings::default().sample_spacing)]
    pub sample_spacing: f64,
    /// Output folder: compare.md, compare.json, coloured PLYs, pictures.
    #[arg(long, default_value = "outputs/compare")]
    pub out: PathBuf,
    /// Print the figures as JSON instead of the table.
    #[arg(long)]
    pub json: bool,
}

pub fn run_compare(args: CompareArgs) -> Result<()> {
    for (name, value) in [
        ("--threshold", args.threshold),
        ("--ghost-distance", args.ghost_distance),
        ("--sample-spacing", args.sample_spacing),
    ] {
        if !(value.is_finite() && value > 0.0) {
            bail!("{name} must be a positive distance in metres, not {value}");
        }
    }
    let reference = match (&args.reference, args.maps.len()) {
        (Some(r), _) => r.clone(),
        (None, n) if n >= 2 => args.maps[n - 1].clone(),
        _ => bail!("nothing to compare against: give a second map or --reference"),
    };
    let mut maps: Vec<(String, PathBuf)> = Vec::new();
    for path in &args.maps {
        let mut name = name_of(path);
        while maps.iter().any(|(n, _)| *n == name) {
            name += "_";
        }
        maps.push((name, path.clone()));
    }
    let cameras = match &args.trajectory {
        Some(path) => Some(Trajectory::read(path, TrajectoryFormat::Tum)?.poses),
        None => None,
    };
    let alignments: Vec<Option<dopslam::geometry::se3::Se3>> = maps
        .iter()
        .map(|(_, path)| {
            if !args.align {
                return Ok(None);
            }
            let dir = path.parent().unwrap_or(Path::new("."));
            let merged = || run_alignment(&first_merged_run(dir)?);
            match run_alignment(dir)
                .or_else(merged)
                .or_else(|| run_alignment(dir.parent()?))
            {
                Some(pose) => Ok(Some(pose)),
                None => bail!(
                    "--align: no run beside {} (or one folder up, or the first run its merge.json names) whose trajectory.txt and report.json lead to a sequence with groundtruth.txt",
                    path.display()
                ),
            }
        })
        .collect::<Result<_>>()?;
    let comparison = compare_maps(&CompareInputs {
        maps: &maps,
        alignments: &alignments,
        reference: &reference,
        movers: args.movers.as_deref(),
        cameras: cameras.as_deref(),
        settings: CompareSettings {
            threshold: args.threshold,
            ghost_distance: args.ghost_distance,
            sample_spacing: args.sample_spacing,
            ..CompareSettings::default()
        },
        out: &args.out,
    })?;
    if comparison.settings.sample_spacing > args.sample_spacing {
        eprintln!(
            "the reference's surface sampled every {:.3} m, not {} m: at that spacing it would give more than {} million samples (--sample-spacing)",
            comparison.settings.sample_spacing,
            args.sample_spacing,
            dopslam::dense::compare_maps::MAX_REFERENCE_SAMPLES / 1e6
        );
    }
    print_comparison(&comparison, args.json)
}

/// The first run a merged map's `merge.json` in `dir` names: the merged map lies in
/// its world frame (`dopslam merge`).
fn first_merged_run(dir: &Path) -> Option<PathBuf> {
    let report = dopslam::records::read_merge(&dopslam::io::run_dir::RunDir::new(dir)).ok()?;
    report.recordings.first().map(|r| r.run.clone())
}

/// Prints a comparison as a table or JSON.
pub fn print_comparison(comparison: &Comparison, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(comparison)?);
    } else {
        print!("{}", comparison.table());
        for path in &comparison.outputs {
            eprintln!("wrote {}", path.display());
        }
    }
    Ok(())
}

/// A map's name from its path: the folder's name for `dense_*.ply` files of a run.
pub fn name_of(path: &Path) -> String {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    match path.parent().and_then(|p| p.file_name()) {
        Some(dir) if stem.starts_with("dense_") => dir.to_string_lossy().into_owned(),
        _ => stem,
    }
}
