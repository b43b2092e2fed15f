//! `dopslam fuse`: a finished run's frames fused again into a dense map, with other
//! settings, without tracking again.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use clap::Args;
use dopslam::config::Config;
use dopslam::dense::{DenseReport, FrameChoice};
use dopslam::dop::Mode;
use dopslam::io::run_dir::RunDir;
use dopslam::io::trajectory::TrajectoryFormat;
use dopslam::io::Trajectory;
use dopslam::run::{dense_pass, DenseSetup};

use super::settings::apply_settings;

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
    /// Keep the fused volume and cloud in RUN/dense_state/ (as `run --keep-state`).
    /// A state kept there by an earlier pass is reused, without fusing again, whenever
    /// this pass would fuse the same (every setting but the outputs' and the memory
    /// budgets' the same, the same run and sequence): only the maps are written.
    #[arg(long)]
    pub keep_state: bool,
    /// An ORB-SLAM2 settings file (default: the one the run used, `run --settings`,
    /// as its report.json names it).
    #[arg(long)]
    pub settings: Option<PathBuf>,
}

/// Refuses to fuse a run with a sequence it did not track: at least 90 % of the run's
/// poses must have a frame of the sequence at their timestamp (1 µs).
pub fn same_frames(
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

/// A finished run opened again: its report, the config with the settings file it
/// used (or `settings`), and its sequence (or `sequence`), checked to be the one it
/// tracked.
pub struct OpenedRun {
    pub report: dopslam::run::RunReport,
    pub config: Config,
    pub sequence_dir: PathBuf,
    pub sequence: Box<dyn dopslam::io::sequence::Sequence>,
}

/// Opens the finished run `run` with `config` (see [`OpenedRun`]).
pub fn open_run(
    run_dir: &Path,
    mut config: Config,
    settings: Option<&Path>,
    sequence: Option<&Path>,
) -> Result<OpenedRun> {
    let run = RunDir::new(run_dir);
    let report = dopslam::records::read_report(&run)
        .with_context(|| format!("{} is not a finished run", run_dir.display()))?;
    // The settings file the run used unless another is named: the camera it tracked
    // with is the one its frames are fused with.
    let recorded = report.setup.settings.as_ref().map(|s| s.file.as_path());
    if let Some(path) = settings.or(recorded) {
        apply_settings(&mut config, path).with_context(|| match settings {
            Some(_) => format!("--settings {}", path.display()),
            None => format!(
                "the settings file {} names (pass --settings to use another)",
                run.report().display()
            ),
        })?;
    }
    let sequence_dir = match (sequence, &report.sequence_path) {
        (Some(dir), _) => dir.to_path_buf(),
        (None, Some(dir)) => dir.clone(),
        (None, None) => bail!(
            "{} does not say which sequence it tracked: pass --sequence",
            run.report().display()
        ),
    };
    let sequence = dopslam::run::open_sequence(&sequence_dir, &config)?;
    same_frames(&run, sequence.as_ref(), &sequence_dir)?;
    if let Some(recorded) = report.first_frame_hash() {
        if dopslam::run::first_frame_hash(sequence.as_ref()).as_deref() != Some(recorded) {
            bail!(
                "{} is not the sequence {} tracked: its first frame differs from the one the run recorded; the dense map was left as it was",
                sequence_dir.display(),
                run_dir.display()
            );
        }
    }
    Ok(OpenedRun {
        report,
        config,
        sequence_dir,
        sequence,
    })
}

pub fn run_fuse(args: FuseArgs) -> Result<()> {
    let mut config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::default(),
    };
    if let Some(voxel) = args.voxel {
        config.dense.tsdf.voxel = voxel;
        config.dense.tsdf.truncation = config.dense.tsdf.truncation.max(4.0 * voxel);
    }
    if args.keyframes_only {
        config.dense.frames.which = FrameChoice::Keyframes;
    }
    if args.keep_state {
        config.dense.outputs.keep_state = true;
    }
    let opened = open_run(
        &args.run,
        config,
        args.settings.as_deref(),
        args.sequence.as_deref(),
    )?;
    let OpenedRun {
        report,
        config,
        sequence_dir,
        sequence,
    } = opened;
    let masking = if args.no_dop {
        Mode::Off
    } else if args.mask_boxes {
        Mode::MaskBoxes
    } else if args.dop {
        Mode::Dop
    } else {
        // How the run treated movers, as its report says.
        report.mode
    };
    let dense = dense_pass(&dopslam::run::DensePass {
        sequence: sequence.as_ref(),
        setup: &DenseSetup::resolve(sequence.as_ref(), &config)?
            .with_disparity_offset(report.disparity_offset_px()),
        run_dir: &args.run,
        out_dir: &args.run,
        masking,
        sequence_dir: Some(&sequence_dir),
        progress: true,
    })?;
    print_dense(&dense);
    Ok(())
}

/// The summary's lines on the frames the dense pass chose (none when it took them all).
fn print_frame_choice(dense: &DenseReport) {
    if dense.frames_fused_still > 0 {
        println!(
            "dense map: {} frames fused while the camera stood still, closer together: each shows what the movers hid before ([dense] frame_still_gap; 0: as when it moves)",
            dense.frames_fused_still
        );
    }
    if dense.frames_left_still > 0 {
        println!(
            "dense map: {} tracked frames not fused, taken from nearly where the last fused frame was ([dense] frame_min_translation, frame_min_rotation, frame_max_gap, frame_still_gap)",
            dense.frames_left_still
        );
    }
    if dense.other_segment_frames > 0 {
        println!(
            "dense map: {} tracked frames left out, in map segments that no loop merged with the largest",
            dense.other_segment_frames
        );
    }
}

/// Prints what the dense pass did.
pub fn print_dense(dense: &DenseReport) {
    println!(
        "dense map ({:?} masks, {:.1} % of pixels masked, {:.1} % of those with depth to fuse): {} frames fused, {} TSDF blocks ({:.0} MB), mesh {} vertices / {} triangles, cloud {} points from {} keyframes",
        dense.masking.unwrap_or(Mode::Off),
        dense.masked_percent,
        dense.masked_fusable_percent,
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
    if let Some(sgbm) = dense.sgbm.filter(|s| s.downscale > 1) {
        println!(
            "dense map: stereo depth matched at 1/{} size ([stereo] sgbm_downscale): faster, coarser",
            sgbm.downscale
        );
    }
    print_frame_choice(dense);
    println!(
        "dense time: integration median {:.1} ms a frame, marching cubes {:.0} ms, cloud {:.0} ms, total {:.1} s{}",
        dense.median_integration_ms,
        dense.marching_cubes_ms,
        dense.cloud_ms,
        dense.total_s,
        dense
            .real_time_factor
            .map_or(String::new(), |f| format!(" ({f:.2} x the recording)"))
    );
    let stages: Vec<String> = dense
        .stages
        .named()
        .iter()
        .filter(|(_, s)| *s >= 0.05)
        .map(|(name, s)| format!("{name} {s:.1}"))
        .collect();
    println!("dense stages (s): {}", stages.join(", "));
    print_dense_memory(&dense.memory);
    print_dense_spill(dense);
    if dense.released_on_map > 0 {
        println!(
            "dense masks: {} masked pixels lay on the static map fused so far and were fused ([dense] mask_map_min_weight)",
            dense.released_on_map
        );
    }
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

/// What the memory budgets made the volume and the cloud do, when they wrote to their
/// spill files.
fn print_dense_spill(dense: &DenseReport) {
    let fate = match dense.kept_state {
        Some(_) => "kept",
        None => "removed",
    };
    let tsdf = &dense.tsdf_spill;
    if tsdf.blocks_written > 0 {
        println!(
            "dense volume: at most {:.0} MB of voxels in memory ([dense] tsdf_memory_mb); {} blocks written to the spill file ({:.0} MB, {fate}), {} read back",
            tsdf.peak_resident_mb, tsdf.blocks_written, tsdf.file_mb, tsdf.blocks_reloaded
        );
    }
    let cloud = &dense.cloud_spill;
    if cloud.chunks_written > 0 {
        println!(
            "dense cloud: at most {:.0} MB of voxel sums in memory ([dense] cloud_memory_mb); {} chunks written to the spill file ({:.0} MB, {fate}), {} read back",
            cloud.peak_resident_mb, cloud.chunks_written, cloud.file_mb, cloud.chunks_reloaded
        );
    }
    if let Some(dir) = &dense.kept_state {
        println!(
            "dense state kept in {} ([dense] keep_state): `dopslam fuse` with other output settings reuses it",
            dir.display()
        );
    }
    if let Some(reused) = &dense.reused_state {
        println!(
            "dense state reused from {}: the frames were not fused again (fusion took {:.1} s when it was kept); the figures of the frames fused are that pass's",
            reused.from.display(),
            reused.fusion_s
        );
    }
}

/// Prints each part of the dense pass's peak memory, where it is known.
fn print_dense_memory(memory: &dopslam::dense::report::DenseMemory) {
    let peaks: Vec<String> = [
        ("fusion", memory.fusion_mib),
        ("mesh", memory.mesh_mib),
        ("cloud", memory.cloud_mib),
        ("files", memory.writing_mib),
    ]
    .iter()
    .filter_map(|&(name, mib)| Some(format!("{name} {:.0}", mib?)))
    .collect();
    if !peaks.is_empty() {
        println!("dense peak memory (MiB): {}", peaks.join(", "));
    }
}
