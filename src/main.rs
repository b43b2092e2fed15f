//! The `dopslam` command line: parses arguments, calls the library, prints.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context, Result};
use clap::{Args, Parser, Subcommand};

use dopslam::config::Config;
use dopslam::eval::associate::AssociationRule;
use dopslam::eval::ate::PoseRelation;
use dopslam::eval::plot::write_plots;
use dopslam::eval::report::{AlignMode, RpeSpec};
use dopslam::eval::rpe::DeltaUnit;
use dopslam::eval::{evaluate, EvalOptions};
use dopslam::io::atomic::write_atomic;
use dopslam::io::kitti::KittiSequence;
use dopslam::io::sequence::Sequence;
use dopslam::io::trajectory::TrajectoryFormat;
use dopslam::io::tum::TumSequence;
use dopslam::io::Trajectory;

mod cli_batch;
mod cli_doctor;
mod cli_global;
mod cli_maps;
mod cli_recording;
mod cli_stereo;
mod cli_values;
mod cli_view;

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
    Eval(EvalArgs),
    /// Generate the bundled example (ground truth + drifting estimate) and evaluate it.
    Demo(DemoArgs),
    /// Generate a synthetic RGB-D sequence in the TUM layout with exact ground truth.
    Synth(SynthArgs),
    /// Run a sequence: the tracking pass (trajectory, keyframes, sparse map, report), then the dense map (mesh, point cloud, pictures).
    Run(RunArgs),
    /// Fuse a finished run's frames again into a dense map, with other settings, without tracking again.
    Fuse(cli_maps::FuseArgs),
    /// Compare dense maps (PLY) against a static reference and each other: accuracy, completion, ghosts, SA/DA.
    CompareMaps(cli_maps::CompareArgs),
    /// Describe a sequence folder (TUM/Bonn RGB-D or KITTI stereo layout) or a recording (ROS bag, MCAP): frames, pairing, topics, calibration, ground truth.
    Info(InfoArgs),
    /// Write a recording (ROS bag, MCAP, RealSense) as a TUM RGB-D or KITTI stereo folder that every tool reads.
    Convert(cli_recording::ConvertArgs),
    /// Detect objects (COCO) in an image or a sequence: prints them and draws boxes onto PNGs.
    Detect(DetectArgs),
    /// Train or inspect the place-recognition vocabulary (bag of binary words) of the global pass.
    Vocab(cli_global::VocabArgs),
    /// Show where the runtime data (ONNX Runtime, detector models, vocabulary) was found and what is missing.
    Doctor(cli_doctor::DoctorArgs),
    /// Make and optimise 3-D pose graphs in g2o's format (VERTEX_SE3:QUAT / EDGE_SE3:QUAT).
    Graph(cli_global::GraphArgs),
    /// Run many sequences in several modes, repeated, and write the tables, plots and HTML report (resumable).
    Batch(cli_batch::BatchArgs),
    /// Match one rectified stereo pair as tracking does and compare with OpenCV's SGBM disparities.
    Stereo(cli_stereo::StereoArgs),
    /// Build the Rerun recording of a finished run folder (trajectories, events, boxes, removed keypoints, images, dense map) without tracking again.
    View(cli_view::ViewArgs),
}

#[derive(Args)]
struct DetectArgs {
    /// An image file, a sequence folder (TUM/Bonn RGB-D layout) or a recording (ROS bag, MCAP).
    input: PathBuf,
    /// A TOML config whose [detector] section picks the model (default: YOLOv4-tiny ONNX).
    #[arg(long)]
    config: Option<PathBuf>,
    /// The model: yolov4-tiny or yolox-nano (overrides the config).
    #[arg(long, value_enum)]
    model: Option<DetectModelArg>,
    /// The model file (overrides the config); repeat it to run several files of the
    /// model (the same weights at several input sizes) and merge their boxes.
    #[arg(long)]
    model_path: Vec<PathBuf>,
    /// Output folder: annotated PNGs and per-frame JSON (a detection cache).
    #[arg(long, default_value = "outputs/detect")]
    out: PathBuf,
    /// For a sequence: detect every Nth frame.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
    /// Also detect on N x N overlapping tiles of each image and merge the boxes
    /// (overrides the config's [detector] tiles; 1: the whole image only).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=4))]
    tiles: Option<u32>,
    /// Print the detections as JSON on stdout (one array: per image or frame its name,
    /// timestamp, milliseconds and detections) instead of the table.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    topics: cli_recording::TopicArgs,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum DetectModelArg {
    Yolov4Tiny,
    YoloxNano,
    Deimv2Femto,
}

#[derive(Args)]
struct EvalArgs {
    /// The reference (ground-truth) trajectory file.
    reference: PathBuf,
    /// The estimated trajectory file.
    estimate: PathBuf,
    /// Format of both files (tum: `t tx ty tz qx qy qz qw`; kitti: 12 numbers a line).
    #[arg(long, value_enum, default_value = "tum")]
    format: TrajectoryFormat,
    /// A KITTI times.txt giving both KITTI trajectories timestamps (else poses pair by index).
    #[arg(long)]
    times: Option<PathBuf>,
    /// A TOML config whose [eval] section sets the defaults below.
    #[arg(long)]
    config: Option<PathBuf>,
    /// How poses are paired: evo (nearest timestamp), tum-greedy (associate.py) or by-index.
    #[arg(long, value_enum)]
    association: Option<AssociationRule>,
    /// Association tolerance in seconds (default: evo 0.01, tum-greedy 0.02).
    #[arg(long, value_parser = cli_values::non_negative)]
    max_diff: Option<f64>,
    /// Time offset added to the estimate's timestamps, in seconds.
    #[arg(long, default_value_t = 0.0, allow_hyphen_values = true, value_parser = cli_values::finite)]
    offset: f64,
    /// Alignment of the estimate to the reference.
    #[arg(long, value_enum)]
    align: Option<AlignMode>,
    /// Align using only the first N matched poses.
    #[arg(long)]
    n_align: Option<usize>,
    /// Pose relation of the APE.
    #[arg(long, value_enum, default_value = "trans_part")]
    pose_relation: PoseRelation,
    /// RPE deltas, each a number and a unit: f (frames), m (metres), d (degrees), r (radians), s (seconds, reported per second). Repeat for several.
    #[arg(long = "rpe", default_values_t = vec!["1f".to_string()])]
    rpe: Vec<String>,
    /// Pose relation of the RPE.
    #[arg(long, value_enum, default_value = "trans_part")]
    rpe_relation: PoseRelation,
    /// Fail when fewer than this fraction of the shorter trajectory's poses are matched.
    #[arg(long, value_parser = cli_values::fraction)]
    min_coverage: Option<f64>,
    /// Print the report as JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Write SVG plots (trajectory top view, errors over time) into this folder.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Also write the JSON report to this file.
    #[arg(long)]
    save_report: Option<PathBuf>,
}

#[derive(Args)]
struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "outputs/demo")]
    out: PathBuf,
    /// Seed of the generated drift and noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

#[derive(Args)]
struct SynthArgs {
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
    #[arg(long, value_parser = cli_values::at_least_one)]
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

#[derive(Args)]
struct InfoArgs {
    /// The sequence folder, or a recording (ROS 1 .bag, ROS 2 bag folder, .mcap, .db3).
    sequence: PathBuf,
    /// A TOML config ([dataset] section: depth scale, association tolerance or file).
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    topics: cli_recording::TopicArgs,
    /// Also decode every frame, one core, and say how fast (frames/s) and at what peak
    /// memory: checks that a recording or folder reads whole, and that reading is no
    /// bottleneck.
    #[arg(long)]
    read_frames: bool,
}

#[derive(Args)]
struct RunArgs {
    /// The sequence folder (TUM/Bonn RGB-D layout, KITTI stereo, or one written by `dopslam
    /// synth`), or a recording (ROS 1 .bag, ROS 2 bag folder, .mcap, .db3).
    sequence: PathBuf,
    #[command(flatten)]
    topics: cli_recording::TopicArgs,
    /// A TOML config (configs/default.toml lists every key).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Output folder: trajectory.txt, keyframes.txt, report.json, map.ply.
    #[arg(long, default_value = "outputs/run")]
    out: PathBuf,
    /// Track only the first N frames.
    #[arg(long, value_parser = cli_values::at_least_one)]
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
    #[command(flatten)]
    rerun: cli_view::RerunArgs,
}

/// `--camera fx,fy,cx,cy[,width,height]`; without a size, the first frame's.
fn parse_camera(
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

fn parse_rpe(text: &str) -> Result<RpeSpec> {
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

/// Before any work: `detect` writes neither into an input sequence nor over an input
/// image (`NAME.png` and `NAME.json` in `--out`), and `--out` can be written.
fn check_detect_outputs(args: &DetectArgs) -> Result<()> {
    use dopslam::io::output::{check_file, prepare_dir};
    if args.input.is_dir() {
        prepare_dir(&args.out, "output", &[&args.input])?;
        return Ok(());
    }
    let name = args
        .input
        .file_stem()
        .map_or("image".into(), |s| s.to_string_lossy().into_owned());
    for ext in ["png", "json"] {
        check_file(
            &args.out.join(format!("{name}.{ext}")),
            "detection output",
            &[&args.input],
        )?;
    }
    prepare_dir(&args.out, "output", &[])?;
    Ok(())
}

fn run_detect(args: DetectArgs) -> Result<()> {
    use dopslam::detect::{Model, Source};
    let config = load_config(args.config.as_deref())?;
    check_detect_outputs(&args)?;
    let mut detector_config = config.detector.clone();
    if matches!(detector_config.source, Source::None | Source::Auto) {
        detector_config.source = Source::Onnx;
    }
    if let Some(model) = args.model {
        detector_config.model = match model {
            DetectModelArg::Yolov4Tiny => Model::Yolov4Tiny,
            DetectModelArg::YoloxNano => Model::YoloxNano,
            DetectModelArg::Deimv2Femto => Model::Deimv2Femto,
        };
    }
    if !args.model_path.is_empty() {
        detector_config.model_path = None;
        detector_config.model_paths = args.model_path.clone();
    }
    if let Some(tiles) = args.tiles {
        detector_config.tiles = tiles;
    }
    let mut detector = detector_config
        .open(args.input.is_dir().then_some(args.input.as_path()))?
        .expect("a source other than none");
    let mut all = Vec::new();
    let mut detect_one = |name: String, timestamp: f64, image: image::RgbImage| -> Result<()> {
        all.push(detect_and_write(
            detector.as_mut(),
            &args,
            (name, timestamp, image),
        )?);
        Ok(())
    };
    if args.input.is_dir() || dopslam::io::recording::is_recording(&args.input) {
        let mut config = config.clone();
        args.topics.apply(&mut config);
        let sequence = dopslam::run::open_sequence(&args.input, &config)?;
        // One frame at a time: a long sequence is never held whole.
        for index in (0..sequence.len()).step_by(args.every as usize) {
            let frame = sequence.load(index)?;
            let image = match frame.images {
                dopslam::io::sequence::FrameImages::Rgbd { rgb, .. } => rgb,
                // The left image, in colour, as the tracking pass hands it to the detector.
                dopslam::io::sequence::FrameImages::Stereo { left, .. } => {
                    image::DynamicImage::ImageLuma8(left).to_rgb8()
                }
            };
            detect_one(format!("{:.6}", frame.timestamp), frame.timestamp, image)?;
        }
    } else {
        let image = image::open(&args.input)
            .with_context(|| format!("cannot read image {}", args.input.display()))?
            .to_rgb8();
        let name = args
            .input
            .file_stem()
            .map_or("image".into(), |s| s.to_string_lossy().into_owned());
        detect_one(name, 0.0, image)?;
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&all)?);
        eprintln!("wrote {}", args.out.display());
    } else {
        println!("wrote {}", args.out.display());
    }
    Ok(())
}

/// Detects on one image of `dopslam detect`, prints its boxes (unless `--json`), writes
/// the image with its boxes drawn and the detections (a sequence's into its detection
/// cache), and returns the image's entry of the `--json` list.
fn detect_and_write(
    detector: &mut dyn dopslam::detect::Detector,
    args: &DetectArgs,
    (name, timestamp, mut image): (String, f64, image::RgbImage),
) -> Result<serde_json::Value> {
    use dopslam::detect::{draw::draw_detections, FrameDetections};
    let start = std::time::Instant::now();
    let detections = detector.detect(timestamp, &image)?;
    let ms = start.elapsed().as_secs_f64() * 1e3;
    if !args.json {
        println!("{name}: {} detections ({ms:.1} ms)", detections.len());
        for d in &detections {
            let [x1, y1, x2, y2] = d.bbox;
            println!(
                "  {} {:.2} [{x1:.0},{y1:.0},{x2:.0},{y2:.0}]",
                d.class, d.score
            );
        }
    }
    draw_detections(&mut image, &detections);
    let png = args.out.join(format!("{name}.png"));
    image
        .save(&png)
        .with_context(|| format!("cannot write {}", png.display()))?;
    let frame = FrameDetections {
        timestamp,
        detections,
    };
    if args.input.is_dir() {
        dopslam::detect::write_cache(&args.out.join("detections"), &frame)?;
    } else {
        // The same per-frame JSON as a sequence's detection cache.
        let json = serde_json::to_string_pretty(&frame)?;
        write_atomic(&args.out.join(format!("{name}.json")), json.as_bytes())?;
    }
    Ok(serde_json::json!({
        "name": name,
        "timestamp": timestamp,
        "milliseconds": ms,
        "detections": frame.detections,
    }))
}

fn load_config(path: Option<&Path>) -> Result<Config> {
    match path {
        Some(path) => Ok(Config::load(path)?),
        None => Ok(Config::default()),
    }
}

fn read_trajectory(
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

fn run_eval(args: EvalArgs) -> Result<()> {
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
    let report = evaluate(&reference, &estimate, &options).with_context(|| {
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
        for path in write_plots(&report, dir)? {
            eprintln!("wrote {}", path.display());
        }
    }
    Ok(())
}

fn run_demo(args: DemoArgs) -> Result<()> {
    let (ground_truth, estimate) = dopslam::demo::demo_trajectories(args.seed, 30.0, 0.004);
    let gt_path = args.out.join("groundtruth.txt");
    let est_path = args.out.join("estimate.txt");
    ground_truth.write(&gt_path, TrajectoryFormat::Tum)?;
    estimate.write(&est_path, TrajectoryFormat::Tum)?;
    println!(
        "generated {} ({} poses) and {} ({} poses)",
        gt_path.display(),
        ground_truth.len(),
        est_path.display(),
        estimate.len()
    );
    run_eval(EvalArgs {
        reference: gt_path,
        estimate: est_path,
        format: TrajectoryFormat::Tum,
        times: None,
        config: None,
        association: None,
        max_diff: None,
        offset: 0.0,
        align: None,
        n_align: None,
        pose_relation: PoseRelation::TransPart,
        rpe: vec!["1f".into(), "1s".into()],
        rpe_relation: PoseRelation::TransPart,
        min_coverage: None,
        json: false,
        plot: Some(args.out.join("plots")),
        save_report: Some(args.out.join("report.json")),
    })
}

fn run_synth(args: SynthArgs) -> Result<()> {
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

fn run_info(args: InfoArgs) -> Result<()> {
    let mut config = load_config(args.config.as_deref())?;
    let root = &args.sequence;
    if dopslam::io::recording::is_recording(root) {
        args.topics.apply(&mut config);
        cli_recording::print_recording_info(root, &config)?;
    } else {
        describe_folder(root, &config)?;
    }
    if args.read_frames {
        cli_recording::read_all_frames(root, &config)?;
    }
    Ok(())
}

/// `dopslam info` on a TUM/Bonn or KITTI folder.
fn describe_folder(root: &Path, config: &Config) -> Result<()> {
    dopslam::run::check_sequence_folder(root)?;
    let sequence: Box<dyn Sequence> = if root.join("image_0").is_dir() {
        Box::new(KittiSequence::open(root, None)?)
    } else {
        let options = config.dataset.tum_options();
        let tum = TumSequence::open(root, &options)?;
        println!(
            "rgb.txt / depth.txt entries: {} / {}, paired: {} (tolerance {} s)",
            tum.listed.0,
            tum.listed.1,
            tum.len(),
            options.max_difference
        );
        Box::new(tum)
    };
    println!(
        "sequence {} ({:?}): {} frames",
        sequence.name(),
        sequence.sensor(),
        sequence.len()
    );
    if !sequence.is_empty() {
        let (first, last) = (
            sequence.timestamp(0),
            sequence.timestamp(sequence.len() - 1),
        );
        println!("time span {:.3} s ({first:.6} .. {last:.6})", last - first);
    }
    match sequence.calibration() {
        Some(c) => println!(
            "calibration: {:?}, bf {:?}, depth scale {:?}",
            c.camera, c.bf, c.depth_scale
        ),
        None => {
            println!("calibration: none found (give one with [dataset] settings = \"camera.yaml\")")
        }
    }
    match sequence.ground_truth() {
        Some(gt) => println!(
            "ground truth: {} poses, path length {:.3} m",
            gt.len(),
            gt.path_length()
        ),
        None => println!("ground truth: none"),
    }
    Ok(())
}

fn run_run(args: RunArgs) -> Result<()> {
    use clap::ValueEnum;
    let mut config = run_config(&args)?;
    let options = dopslam::run::RunOptions {
        max_frames: args.frames,
        progress: true,
        deterministic: args.deterministic,
        sequence_dir: Some(args.sequence.clone()),
        debug_frames: args.debug_frames.clone(),
        dense: !args.no_dense && config.dense.enabled,
        pace: args.pace,
        rerun: None,
    };
    // A missing detector fails here, a missing vocabulary when the run starts: both
    // before any work.
    let source = dopslam::run::detection_source(&config)?;
    config.detector.source = source;
    let sequence = dopslam::run::open_sequence(&args.sequence, &config)?;
    if let Some(text) = &args.camera {
        config.dataset.camera = Some(parse_camera(text, sequence.as_ref())?);
    }
    let mode = dopslam::run::effective_mode(&config);
    eprintln!(
        "detections: {}; moving objects: {}",
        source
            .to_possible_value()
            .map_or("?".into(), |v| v.get_name().to_string()),
        mode.to_possible_value()
            .map_or("?".into(), |v| v.get_name().to_string())
    );
    let logger = cli_view::open_for_run(&args.rerun, &config, &args.sequence)?;
    let options = dopslam::run::RunOptions {
        rerun: logger.as_ref().map(|l| l.handle()),
        ..options
    };
    let report = dopslam::run::run_sequence(sequence.as_ref(), &config, &args.out, &options);
    // On an error the recording closes as it drops: what was logged stays readable.
    let mut report = report?;
    // --rerun's, or the run's own run.rrd ([output] rerun).
    let recording = logger.or(report.recording.take());
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
        let log = recording.as_ref().map(|l| l.handle());
        compare_no_dop(&args, &config, sequence.as_ref(), &options, (&report, log))?;
    }
    if let Some(logger) = recording {
        dopslam::run::finish_recording(logger, true)?;
    }
    Ok(())
}

/// The configuration of `dopslam run`: the file, then ORB-SLAM2's settings, then the
/// command line's options over both.
fn run_config(args: &RunArgs) -> Result<dopslam::config::Config> {
    let mut config = load_config(args.config.as_deref())?;
    args.topics.apply(&mut config);
    if let Some(source) = args.detections {
        config.detector.source = source;
    }
    match &args.settings {
        Some(path) => cli_maps::apply_settings(&mut config, path)?,
        None => cli_maps::print_settings_notes(&config),
    }
    if args.no_loops {
        config.global.loops.enabled = false;
    }
    if args.no_global {
        config.global.enabled = false;
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
fn print_run_summary(report: &dopslam::run::RunReport) {
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
    if let Some(global) = &report.global {
        cli_global::print_global(global);
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
        cli_maps::print_dense(dense);
    }
}

/// `run --compare-no-dop`: the same run with --no-dop into OUT/no_dop, the two dense
/// maps compared, and the baseline's trajectory and dense map in the run's recording.
fn compare_no_dop(
    args: &RunArgs,
    config: &Config,
    sequence: &dyn Sequence,
    options: &dopslam::run::RunOptions,
    (report, log): (&dopslam::run::RunReport, Option<dopslam::view::LogHandle>),
) -> Result<()> {
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
        ..options.clone()
    };
    let baseline_report =
        dopslam::run::run_sequence(sequence, &baseline, &baseline_dir, &baseline_options)?;
    let comparison = cli_maps::compare_with_baseline(
        (&args.out, &baseline_dir),
        sequence,
        &args.sequence,
        config,
    )?;
    cli_maps::print_summary(report, &baseline_report, &comparison);
    if let Some(log) = &log {
        let run = dopslam::io::run_dir::RunDir::new(&baseline_dir);
        dopslam::view::results::log_results(log, &run, "no_dop", None)?;
    }
    Ok(())
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
        Command::Run(_) | Command::Fuse(_) | Command::Batch(_)
    ) {
        dopslam::interrupt::install();
    }
    let result = match cli.command {
        Command::Eval(args) => run_eval(args),
        Command::Demo(args) => run_demo(args),
        Command::Synth(args) => run_synth(args),
        Command::Info(args) => run_info(args),
        Command::Convert(args) => load_config(args.config.as_deref())
            .and_then(|config| cli_recording::run_convert(args, config)),
        Command::Run(args) => run_run(args),
        Command::Fuse(args) => cli_maps::run_fuse(args),
        Command::CompareMaps(args) => cli_maps::run_compare(args),
        Command::Detect(args) => run_detect(args),
        Command::Vocab(args) => cli_global::run_vocab(args),
        Command::Graph(args) => cli_global::run_graph(args),
        Command::Doctor(args) => cli_doctor::run_doctor(args),
        Command::Batch(args) => cli_batch::run_batch(args),
        Command::Stereo(args) => cli_stereo::run_stereo(args),
        Command::View(args) => {
            load_config(args.config.as_deref()).and_then(|config| cli_view::run_view(args, config))
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
