//! `dopslam run`: a sequence through the passes, its summary printed.

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;
use dopslam::io::sequence::Sequence;
use dopslam::run::RunPlan;

use super::load_config;

#[derive(Args)]
pub struct RunArgs {
    /// The sequence folder (TUM/Bonn RGB-D layout, KITTI stereo, or one written by `dopslam
    /// synth`), or a recording (ROS 1 .bag, ROS 2 bag folder, .mcap, .db3).
    sequence: PathBuf,
    #[command(flatten)]
    topics: super::topics::TopicArgs,
    /// A TOML config (configs/default.toml lists every key).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output folder: trajectory.txt, keyframes.txt, report.json, map.ply.
    #[arg(long, default_value = "outputs/run")]
    out: PathBuf,
    /// Track only the first N frames.
    #[arg(long, value_parser = super::values::at_least_one)]
    frames: Option<usize>,
    /// ORB-SLAM2 behaviour: detections are not used against moving objects.
    #[arg(long, conflicts_with_all = ["mask_boxes", "dop"])]
    no_dop: bool,
    /// The naive method: map points seen inside dynamic boxes of detected keyframes go.
    #[arg(long, conflicts_with = "dop")]
    mask_boxes: bool,
    /// The DOP model (the default when there are detections).
    #[arg(long)]
    dop: bool,
    /// Run local mapping and detection after each keyframe in the tracking thread
    /// instead of beside it, so that a run repeats exactly (tests use this; slower).
    #[arg(long)]
    deterministic: bool,
    /// Real-time mode: hand frames to the tracker as fast as tracking goes (free, the
    /// default), or at the recording's rate as the camera delivered them (recording: a
    /// live run, as ORB-SLAM2's examples play sequences; the detector and local mapping
    /// get the time per frame they would have live, and the run takes the recording's
    /// duration).
    #[arg(long, value_enum, default_value = "free")]
    pace: dopslam::pacing::Pace,
    /// Keyframe detections: auto (the ONNX model, none with --no-dop), none (no
    /// detector: the DOP model on its geometric check alone), onnx (the [detector]
    /// model), cache ([detector] cache_dir) or oracle (a synthetic sequence's
    /// ground-truth boxes). Default: the config's [detector] source (auto). A missing
    /// model or ONNX Runtime is an error (`dopslam doctor`).
    #[arg(long, value_enum)]
    detections: Option<dopslam::detect::Source>,
    /// Write every frame with its keypoints coloured by DOP state into this folder.
    #[arg(long)]
    debug_frames: Option<PathBuf>,
    /// An ORB-SLAM2 settings file with the calibration (e.g. configs/calibration/RGB-D_TUM1.yaml);
    /// its DepthMapFactor sets the depth scale unless the config sets one.
    #[arg(long)]
    settings: Option<PathBuf>,
    /// Camera intrinsics `fx,fy,cx,cy` (image size from the first frame) or
    /// `fx,fy,cx,cy,width,height`, no distortion; overrides the settings' intrinsics.
    #[arg(long)]
    camera: Option<String>,
    /// Skip the dense map (the config's [dense] enabled = false does the same).
    #[arg(long)]
    no_dense: bool,
    /// Keep the dense pass's fused volume and cloud in OUT/dense_state/ (the config's
    /// [dense] keep_state = true does the same), so that `dopslam fuse` with other
    /// output settings (mesh_min_piece_area, the cloud's filters, obj, ply_encoding)
    /// writes the maps again without fusing again. GBs on long routes.
    #[arg(long, conflicts_with = "no_dense")]
    keep_state: bool,
    /// Skip the global pass (loop closing, essential graph, full BA): trajectory.txt is then the tracking pass's.
    #[arg(long)]
    no_global: bool,
    /// Run the global pass without loop closing (no vocabulary needed): full BA and the
    /// frames' refinement only.
    #[arg(long)]
    no_loops: bool,
    /// Also run with --no-dop into OUT/no_dop and compare the two dense maps
    /// (OUT/compare_no_dop/: table, distance-coloured PLYs, pictures with ghosts in red).
    #[arg(long, conflicts_with = "no_dense")]
    compare_no_dop: bool,
    /// Track the sequence in the map an earlier run left: RUN is its folder (or its
    /// slam_map.bin). Frames wait until one is placed in that map by relocalisation
    /// ([tracking] place_within_frames); trajectory.txt is then in the map's world
    /// frame, new keyframes and points join the map, the global pass runs over both
    /// recordings, and OUT/slam_map.bin holds the combined map. RUN is never written.
    #[arg(long, value_name = "RUN", conflicts_with = "compare_no_dop")]
    map: Option<PathBuf>,
    /// With --map: localisation only. The loaded map does not change (no keyframes,
    /// no points, no loop closing or full BA; each frame is still refined on it), and
    /// OUT has no slam_map.bin.
    #[arg(long, requires = "map")]
    map_frozen: bool,
    #[command(flatten)]
    rerun: super::view::RerunArgs,
}

/// `--camera fx,fy,cx,cy[,width,height]`; without a size, the first frame's.
pub fn parse_camera(
    text: &str,
    sequence: &dyn Sequence,
) -> Result<dopslam::geometry::camera::PinholeCamera> {
    let numbers: Vec<f64> = text
        .split(',')
        .map(|v| {
            v.trim()
                .parse::<f64>()
                .with_context(|| format!("--camera {text:?}: {v:?} is not a number"))
        })
        .collect::<Result<_>>()?;
    let (width, height) = match numbers.len() {
        6 => (numbers[4] as u32, numbers[5] as u32),
        4 => {
            if sequence.is_empty() {
                bail!("--camera {text:?}: the sequence has no frame to take the image size from; give fx,fy,cx,cy,width,height");
            }
            match sequence.load(0)?.images {
                dopslam::io::sequence::FrameImages::Rgbd { rgb, .. } => rgb.dimensions(),
                dopslam::io::sequence::FrameImages::Stereo { left, .. } => left.dimensions(),
            }
        }
        n => bail!(
            "--camera {text:?}: expected fx,fy,cx,cy or fx,fy,cx,cy,width,height, got {n} numbers"
        ),
    };
    let camera = dopslam::geometry::camera::PinholeCamera {
        fx: numbers[0],
        fy: numbers[1],
        cx: numbers[2],
        cy: numbers[3],
        width,
        height,
        distortion: [0.0; 5],
        rational: [0.0; 3],
    };
    camera
        .validate()
        .map_err(|m| anyhow::anyhow!("--camera {text:?}: {m}"))?;
    Ok(camera)
}

pub fn run_run(args: RunArgs) -> Result<()> {
    let mut config = run_config(&args)?;
    let sequence = dopslam::run::open_sequence(&args.sequence, &config)?;
    if let Some(text) = &args.camera {
        config.dataset.camera = Some(parse_camera(text, sequence.as_ref())?);
    }
    // --rerun's file or --rerun-connect's viewer, opened before any work.
    let given = super::view::open_for_run(&args.rerun, &config, &args.sequence)?;
    let options = dopslam::run::RunOptions {
        max_frames: args.frames,
        progress: true,
        deterministic: args.deterministic,
        sequence_dir: Some(args.sequence.clone()),
        debug_frames: args.debug_frames.clone(),
        dense: !args.no_dense && config.dense.enabled,
        pace: args.pace,
        rerun: given.as_ref().map(|l| l.handle()),
        base_map: args
            .map
            .as_deref()
            .map(|run| dopslam::run::base_map(run, args.map_frozen))
            .transpose()?,
    };
    let plan = RunPlan::resolve(sequence.as_ref(), &config, &args.out, options)?;
    print_plan(&plan);
    // On an error the recordings close as they drop: what was logged stays readable.
    let report = dopslam::run::execute(&plan)?;
    print_run_summary(&report);
    println!("wrote {}", args.out.display());
    let errors = &report.detection.errors;
    if !errors.is_empty() {
        bail!(
            "the run finished and its outputs are written, but {} keyframe detection(s) failed (report.json lists them), the first: {}",
            errors.len(),
            errors[0]
        );
    }
    if args.compare_no_dop {
        compare_no_dop(&args, &plan, &report)?;
    }
    plan.finish()?;
    if let Some(logger) = given {
        dopslam::run::finish_recording(logger, true)?;
    }
    Ok(())
}

/// What the plan resolved that a user checks first: the detection source and how
/// moving objects are treated.
fn print_plan(plan: &RunPlan) {
    use clap::ValueEnum;
    let name = |v: Option<clap::builder::PossibleValue>| {
        v.map_or("?".into(), |v| v.get_name().to_string())
    };
    eprintln!(
        "detections: {}; moving objects: {}",
        name(plan.setup.config.detector.source.to_possible_value()),
        name(plan.setup.mode.to_possible_value())
    );
}

/// The configuration of `dopslam run`: the file, then ORB-SLAM2's settings, then the
/// command line's options over both.
pub fn run_config(args: &RunArgs) -> Result<dopslam::config::Config> {
    let mut config = load_config(args.config.as_deref())?;
    args.topics.apply(&mut config);
    if let Some(source) = args.detections {
        config.detector.source = source;
    }
    match &args.settings {
        Some(path) => super::settings::apply_settings(&mut config, path)?,
        None => super::settings::print_settings_notes(&config),
    }
    if args.no_loops {
        config.global.loops.enabled = false;
    }
    if args.no_global {
        config.global.enabled = false;
    }
    if args.keep_state {
        config.dense.outputs.keep_state = true;
    }
    if args.no_dop {
        config.dop.mode = dopslam::dop::Mode::Off;
    } else if args.mask_boxes {
        config.dop.mode = dopslam::dop::Mode::MaskBoxes;
    } else if args.dop {
        config.dop.mode = dopslam::dop::Mode::Dop;
    }
    Ok(config)
}

/// What `dopslam run` prints of its report: tracking, map segments, times, the
/// global pass, ATE and the dense map.
/// The map a run loaded (`--map`) and the one it saved.
fn print_slam_map(maps: &dopslam::records::SlamMapReport) {
    if let Some(loaded) = &maps.loaded {
        let placed = loaded
            .placed_at_frame
            .map_or("no frame was placed in it".to_string(), |f| {
                format!("placed at frame {f}")
            });
        println!(
            "map {} ({}{} keyframes, {} points, read in {:.2} s): {placed}",
            loaded.file.display(),
            if loaded.frozen { "frozen, " } else { "" },
            loaded.keyframes,
            loaded.points,
            loaded.load_s
        );
    }
    if let Some(saved) = &maps.saved {
        println!(
            "saved the map of {} recording(s) ({} keyframes, {} points, {:.1} MB) to {}",
            saved.recordings.len(),
            saved.keyframes,
            saved.points,
            saved.bytes as f64 / 1e6,
            saved.file.display()
        );
    }
}

pub fn print_run_summary(report: &dopslam::run::RunReport) {
    let t = &report.totals;
    println!(
        "{}: tracked {} of {} frames ({:.1} %), lost {}, {} keyframes, {} map points",
        report.sequence, t.tracked, t.frames, t.coverage_percent, t.lost, t.keyframes, t.map_points
    );
    if t.segments.len() > 1 {
        let spans: Vec<String> = t
            .segments
            .iter()
            .map(|s| {
                let merged = s
                    .merged_into
                    .map_or(String::new(), |m| format!(", merged into {m}"));
                format!(
                    "{} (frames {}-{}, {} tracked{merged})",
                    s.segment, s.first_frame, s.last_frame, s.tracked_frames
                )
            })
            .collect();
        println!(
            "map segments (tracking stayed lost in between): {}; the largest holds {:.1} % of the frames",
            spans.join("; "),
            t.largest_segment_percent
        );
    }
    println!(
        "tracking time per frame: median {:.1} ms, mean {:.1} ms (ORB {:.1} ms, matching {:.1} ms, optimisation {:.1} ms, medians)",
        t.median_tracking_ms,
        t.mean_tracking_ms,
        t.median_extraction_ms,
        t.median_matching_ms,
        t.median_optimisation_ms
    );
    if let Some(offset) = &report.setup.disparity_offset {
        println!("{}", offset.summary());
    }
    if let Some(maps) = &report.slam_map {
        print_slam_map(maps);
    }
    if let Some(global) = &report.global {
        print_global(global);
    }
    if let Some(ate) = &report.ate_tracking {
        println!(
            "ATE RMSE {:.4} m after the tracking pass (trajectory_tracking.txt)",
            ate.ape.statistics.rmse
        );
    }
    if let Some(ate) = &report.ate {
        println!(
            "ATE RMSE {:.4} m (SE(3) alignment, {} poses matched)",
            ate.ape.statistics.rmse, ate.matched_poses
        );
    }
    if let Some(dense) = &report.dense {
        super::fuse::print_dense(dense);
    }
    if let Some(times) = &report.times {
        println!("{}", times.summary());
    }
}

/// `run --compare-no-dop`: the same run with --no-dop into OUT/no_dop, the two dense
/// maps compared, and the baseline's trajectory and dense map in the run's recording.
fn compare_no_dop(args: &RunArgs, plan: &RunPlan, report: &dopslam::run::RunReport) -> Result<()> {
    let config = &plan.setup.config;
    let baseline_dir = args.out.join(dopslam::io::run_dir::names::NO_DOP);
    let mut baseline = config.clone();
    baseline.dop.mode = dopslam::dop::Mode::Off;
    // The baseline's trajectory and maps go into the run's recording (below).
    baseline.output.rerun = false;
    // ORB-SLAM2 behaviour needs no detector.
    baseline.detector.source = dopslam::detect::Source::None;
    eprintln!(
        "the baseline: the same run with --no-dop into {}",
        baseline_dir.display()
    );
    let baseline_options = dopslam::run::RunOptions {
        rerun: None,
        ..plan.options.clone()
    };
    let baseline_report =
        dopslam::run::run_sequence(plan.sequence, &baseline, &baseline_dir, &baseline_options)?;
    let comparison = super::compare_no_dop::compare_with_baseline(
        &args.out,
        &baseline_dir,
        plan.sequence,
        &args.sequence,
        config,
    )?;
    super::compare_no_dop::print_summary(report, &baseline_report, &comparison);
    if let Some(log) = plan.log() {
        let run = dopslam::io::run_dir::RunDir::new(&baseline_dir);
        dopslam::view::results::log_results(log, &run, "no_dop", None)?;
    }
    Ok(())
}

/// Prints the global pass's summary.
pub fn print_global(global: &dopslam::global::GlobalReport) {
    let rejected = global.candidates.iter().filter(|c| !c.accepted).count();
    let during = global.loops.iter().filter(|l| l.during_tracking).count();
    println!(
        "global pass: {} loop(s) closed ({during} during tracking, {:.0} ms), {} candidate(s) rejected (report.json lists why), {:.0} ms (place recognition beside tracking: {:.0} ms)",
        global.loops.len(),
        global.loop_closing_during_tracking_ms,
        rejected,
        global.total_ms,
        global.loop_detection_ms
    );
    for l in &global.loops {
        let when = if l.during_tracking {
            ", during tracking"
        } else {
            ""
        };
        println!(
            "  loop: keyframe {} (t {:.2}) -> {} (t {:.2}), {} inliers, {} guided matches, moved {:.3} m / {:.2} deg, {} points fused{when}",
            l.pair.keyframe, l.pair.keyframe_time, l.pair.matched, l.pair.matched_time, l.inliers, l.guided_matches, l.correction_m, l.correction_deg, l.fused_points
        );
        if let Some(m) = l.merged {
            println!(
                "    merged map segment {} into segment {}",
                m.segment, m.into
            );
        }
    }
    if let Some(ba) = &global.full_ba {
        println!(
            "  full BA: {} keyframes, {} points, cost {:.4e} -> {:.4e}, {} outliers removed, {:.0} ms",
            ba.keyframes, ba.points, ba.initial_cost, ba.final_cost, ba.outliers_removed, ba.milliseconds
        );
    }
    if let Some(offset) = &global.disparity_offset {
        println!("  {}", offset.summary());
    }
    if let Some(note) = &global.note {
        println!("  {note}");
    }
    if let Some(hint) = global.revisit_hint() {
        println!("  {hint}");
    }
}
