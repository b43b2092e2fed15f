//! The dense-map commands: `dopslam fuse` and `dopslam compare-maps`.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;

use dopslam::config::Config;
use dopslam::dense::compare_maps::{compare_maps, run_alignment, CompareInputs, Comparison};
use dopslam::dense::map_figures::CompareSettings;
use dopslam::dense::{DenseReport, FrameChoice};
use dopslam::dop::Mode;
use dopslam::io::run_dir::{names, RunDir, RunSummary};
use dopslam::io::trajectory::TrajectoryFormat;
use dopslam::io::Trajectory;
use dopslam::run::{dense_pass, DenseSetup};

#[derive(Args)]
pub struct FuseArgs {
    /// A finished run's folder (written by `dopslam run`).
    pub run: PathBuf,
    /// The sequence folder (default: the one the run names in report.json).
    #[arg(long)]
    pub sequence: Option<PathBuf>,
    /// A TOML config whose [dense] section sets the fusion (default: built-in defaults).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Fuse everything (the baseline), whatever the run did.
    #[arg(long, conflicts_with_all = ["mask_boxes", "dop"])]
    pub no_dop: bool,
    /// Mask whole dynamic boxes of the nearest keyframe.
    #[arg(long, conflicts_with = "dop")]
    pub mask_boxes: bool,
    /// Mask the DOP model's objects and dynamic keypoints (default: as the run did).
    #[arg(long)]
    pub dop: bool,
    /// TSDF voxel edge in metres (overrides the config).
    #[arg(long)]
    pub voxel: Option<f64>,
    /// Fuse keyframes only into the TSDF.
    #[arg(long)]
    pub keyframes_only: bool,
    /// The ORB-SLAM2 settings file the run used (`run --settings`), if any.
    #[arg(long)]
    pub settings: Option<PathBuf>,
}

/// Applies an ORB-SLAM2 settings file (the one path: [`Config::apply_orbslam_settings`])
/// and prints once what it ignored.
pub fn apply_settings(config: &mut Config, path: &Path) -> Result<()> {
    config.apply_orbslam_settings(path)?;
    print_settings_notes(config);
    Ok(())
}

/// Prints the keys of the config's settings file that were not applied.
pub fn print_settings_notes(config: &Config) {
    if let Some(applied) = &config.dataset.settings_applied {
        for note in applied.notes() {
            eprintln!("{note}");
        }
    }
}

/// Refuses to fuse a run with a sequence it did not track: at least 90 % of the run's
/// poses must have a frame of the sequence at their timestamp (1 µs).
fn same_frames(
    run: &RunDir,
    sequence: &dyn dopslam::io::sequence::Sequence,
    dir: &Path,
) -> Result<()> {
    let trajectory = Trajectory::read(&run.trajectory(), TrajectoryFormat::Tum)?;
    let frames: std::collections::HashSet<i64> = (0..sequence.len())
        .map(|i| (sequence.timestamp(i) * 1e6).round() as i64)
        .collect();
    let found = trajectory
        .timestamps
        .iter()
        .filter(|t| frames.contains(&((**t * 1e6).round() as i64)))
        .count();
    if trajectory.is_empty() || (found as f64) < 0.9 * trajectory.len() as f64 {
        bail!(
            "{} is not the sequence {} tracked: {found} of its {} poses have a frame there; the dense map was left as it was (pass the sequence the run tracked, or none: report.json names it)",
            dir.display(),
            run.root().display(),
            trajectory.len()
        );
    }
    Ok(())
}

/// The masking a run used, from its report.json.
/// How the run in `run` treated movers, as its report says: the dense pass masks
/// the same way unless told otherwise.
fn run_masking(run: &RunDir, report: &RunSummary) -> Result<Mode> {
    match Mode::from_name(&report.mode) {
        Some(mode) => Ok(mode),
        None if report.mode.is_empty() => bail!(
            "{} does not say how the run treated moving objects: pass --dop, --mask-boxes or --no-dop",
            run.report().display()
        ),
        None => bail!(
            "{} says mode {:?}, which is none of off, mask-boxes and dop: pass --dop, --mask-boxes or --no-dop",
            run.report().display(),
            report.mode
        ),
    }
}

pub fn run_fuse(args: FuseArgs) -> Result<()> {
    let mut config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::default(),
    };
    if let Some(voxel) = args.voxel {
        config.dense.voxel = voxel;
        config.dense.truncation = config.dense.truncation.max(4.0 * voxel);
    }
    if args.keyframes_only {
        config.dense.frames = FrameChoice::Keyframes;
    }
    if let Some(path) = &args.settings {
        apply_settings(&mut config, path)?;
    }
    let run = RunDir::new(&args.run);
    let report = run
        .read_summary()
        .with_context(|| format!("{} is not a finished run", args.run.display()))?;
    let sequence_dir = match (&args.sequence, &report.sequence_path) {
        (Some(dir), _) | (None, Some(dir)) => dir.clone(),
        (None, None) => bail!(
            "{} does not say which sequence it tracked: pass --sequence",
            run.report().display()
        ),
    };
    let masking = if args.no_dop {
        Mode::Off
    } else if args.mask_boxes {
        Mode::MaskBoxes
    } else if args.dop {
        Mode::Dop
    } else {
        run_masking(&run, &report)?
    };
    let sequence = dopslam::run::open_sequence(&sequence_dir, &config)?;
    same_frames(&run, sequence.as_ref(), &sequence_dir)?;
    if let Some(recorded) = report.first_frame_hash() {
        if dopslam::run::first_frame_hash(sequence.as_ref()).as_deref() != Some(recorded) {
            bail!(
                "{} is not the sequence {} tracked: its first frame differs from the one the run recorded; the dense map was left as it was",
                sequence_dir.display(),
                args.run.display()
            );
        }
    }
    let dense = dense_pass(
        sequence.as_ref(),
        &DenseSetup::resolve(sequence.as_ref(), &config)?
            .with_disparity_offset(report.disparity_offset_px()),
        (&args.run, &args.run),
        masking,
        Some(&sequence_dir),
        true,
    )?;
    print_dense(&dense);
    Ok(())
}

/// Prints what the dense pass did.
pub fn print_dense(dense: &DenseReport) {
    println!(
        "dense map ({:?} masks, {:.1} % of pixels masked): {} frames fused, {} TSDF blocks ({:.0} MB), mesh {} vertices / {} triangles, cloud {} points from {} keyframes",
        dense.masking.unwrap_or(Mode::Off),
        dense.masked_percent,
        dense.frames_fused,
        dense.tsdf_blocks,
        dense.tsdf_memory_mb,
        dense.mesh_vertices,
        dense.mesh_triangles,
        dense.cloud_points,
        dense.keyframes_in_cloud
    );
    if dense.mesh_pieces_dropped > 0 {
        println!(
            "dense map: {} small pieces of the mesh dropped ({} vertices; [dense] mesh_min_piece_area)",
            dense.mesh_pieces_dropped, dense.mesh_vertices_dropped
        );
    }
    if dense.other_segment_frames > 0 {
        println!(
            "dense map: {} tracked frames left out, in map segments that no loop merged with the largest",
            dense.other_segment_frames
        );
    }
    println!(
        "dense time: integration median {:.1} ms a frame, marching cubes {:.0} ms, cloud {:.0} ms, total {:.1} s",
        dense.median_integration_ms, dense.marching_cubes_ms, dense.cloud_ms, dense.total_s
    );
    if let Some(t) = &dense.truth {
        println!(
            "against the ground-truth masks: {:.2} % of mover pixels kept out, {:.2} % of static pixels fused",
            100.0 * t.dynamic_removed,
            100.0 * t.static_kept
        );
        if let Some(l) = t.leaks.first() {
            println!(
                "largest leak: mover {} at {:.3}-{:.3} s, {} frames, {} of its {} pixels fused (dense.json lists the {} largest)",
                l.instance, l.first, l.last, l.frames, l.pixels_fused, l.pixels, t.leaks.len()
            );
        }
    }
    for path in &dense.outputs {
        println!("wrote {}", path.display());
    }
}

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
    /// report.json beside the map, or one folder up) fitted to the ground truth of the
    /// sequence the run names. Needed against a synthetic static_scene.ply.
    #[arg(long)]
    pub align: bool,
    /// Precision/recall threshold, metres.
    #[arg(long, default_value_t = CompareSettings::default().threshold)]
    pub threshold: f64,
    /// Ghost distance: map points farther than this from the reference, metres.
    #[arg(long, default_value_t = CompareSettings::default().ghost_distance)]
    pub ghost_distance: f64,
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
            match run_alignment(dir).or_else(|| run_alignment(dir.parent()?)) {
                Some(pose) => Ok(Some(pose)),
                None => bail!(
                    "--align: no run beside {} (or one folder up) whose trajectory.txt and report.json lead to a sequence with groundtruth.txt",
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
            ..CompareSettings::default()
        },
        out: &args.out,
    })?;
    print_comparison(&comparison, args.json)
}

/// Prints a comparison as a table or JSON.
pub fn print_comparison(comparison: &Comparison, json: bool) -> Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(comparison)?);
    } else {
        print!("{}", comparison.table);
        for path in &comparison.outputs {
            eprintln!("wrote {}", path.display());
        }
    }
    Ok(())
}

/// A map's name from its path: the folder's name for `dense_*.ply` files of a run.
fn name_of(path: &Path) -> String {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    match path.parent().and_then(|p| p.file_name()) {
        Some(dir) if stem.starts_with("dense_") => dir.to_string_lossy().into_owned(),
        _ => stem,
    }
}

/// `run --compare-no-dop`: the dense maps of the run (`dop_mesh`, `dop_cloud`), the
/// run's keyframes fused with its own poses but no masks (`no_masks_cloud`: what the
/// masks keep out, apart from tracking), and the baseline run's cloud (`no_dop_cloud`:
/// tracked and fused without DOP, as ORB-SLAM2 users get it; the baseline for SA),
/// each that exists. In the ground truth's frame when the runs were evaluated,
/// against the sequence's `static_scene.ply` (else the baseline map) and its
/// `movers.ply` when it has them. Pictures: side by side, ghosts in red.
pub fn compare_with_baseline(
    (run, baseline): (&Path, &Path),
    sequence: &dyn dopslam::io::sequence::Sequence,
    sequence_dir: &Path,
    config: &Config,
) -> Result<Comparison> {
    let (mesh, cloud) = (names::DENSE_MESH_PLY, names::DENSE_POINTS);
    let no_masks = run.join(names::NO_MASKS);
    let mut points_only = config.clone();
    points_only.dense.fusion = dopslam::dense::Fusion::Points;
    points_only.dense.frames = FrameChoice::Keyframes;
    points_only.dense.pictures = false;
    let setup = DenseSetup::resolve(sequence, &points_only)?;
    dense_pass(sequence, &setup, (run, &no_masks), Mode::Off, None, true)?;
    let baseline_map = if baseline.join(cloud).exists() {
        ("no_dop_cloud", baseline.join(cloud))
    } else {
        ("no_dop_mesh", baseline.join(mesh))
    };
    let run_aligned = run_alignment(run);
    let mut maps = Vec::new();
    let mut alignments = Vec::new();
    for (name, path) in [
        ("dop_mesh", run.join(mesh)),
        ("dop_cloud", run.join(cloud)),
        ("no_masks_cloud", no_masks.join(cloud)),
    ] {
        if path.exists() {
            maps.push((name.to_string(), path));
            alignments.push(run_aligned);
        }
    }
    maps.push((baseline_map.0.to_string(), baseline_map.1));
    alignments.push(run_alignment(baseline));
    let static_scene = sequence_dir.join("static_scene.ply");
    let movers = sequence_dir.join("movers.ply");
    let mut cameras =
        Trajectory::read(&RunDir::new(run).trajectory(), TrajectoryFormat::Tum)?.poses;
    if let Some(align) = &alignments[0] {
        cameras.iter_mut().for_each(|pose| *pose = align * *pose);
    }
    let reference = if static_scene.exists() {
        static_scene
    } else {
        maps[maps.len() - 1].1.clone()
    };
    let comparison = compare_maps(&CompareInputs {
        maps: &maps,
        alignments: &alignments,
        reference: &reference,
        movers: movers.exists().then_some(movers.as_path()),
        cameras: Some(&cameras),
        settings: CompareSettings::default(),
        out: &run.join(names::COMPARE_NO_DOP),
    })?;
    print_comparison(&comparison, false)?;
    Ok(comparison)
}

/// The few lines that say what DOP did in a `--compare-no-dop` run: ATE with and
/// without it, the movers left in each map, where the pictures are.
pub fn print_summary(
    dop: &dopslam::run::RunReport,
    no_dop: &dopslam::run::RunReport,
    comparison: &Comparison,
) {
    let ate = |r: &dopslam::run::RunReport| {
        r.ate
            .as_ref()
            .map_or("- (no ground truth)".to_string(), |a| {
                format!("{:.4} m", a.ape.statistics.rmse)
            })
    };
    let movers: Vec<String> = comparison
        .names
        .iter()
        .zip(&comparison.maps)
        .map(|(name, m)| {
            let count = m.mover_points.unwrap_or(m.ghost_points);
            format!("{name} {count} of {}", m.points)
        })
        .collect();
    let what = if comparison.movers.is_some() {
        "mover points"
    } else {
        "ghost points"
    };
    println!("summary:");
    println!(
        "  ATE RMSE with DOP {}, without DOP (ORB-SLAM2 behaviour) {}",
        ate(dop),
        ate(no_dop)
    );
    println!("  {what} in each map: {}", movers.join(", "));
    if let Some(picture) = comparison
        .outputs
        .iter()
        .find(|p| p.ends_with("compare_perspective.png"))
    {
        println!(
            "  picture (left to right as listed, ghosts in red): {}",
            picture.display()
        );
    }
    if let Some(table) = comparison.outputs.first().and_then(|p| p.parent()) {
        println!("  table: {}", table.join("compare.md").display());
    }
}
