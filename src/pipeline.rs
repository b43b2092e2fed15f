//! The tracking pass over a whole sequence: read frames lazily, extract ORB, track,
//! and write what was computed — also when a frame fails to load or tracking never
//! starts — atomically: `trajectory.txt` (TUM format, every tracked frame),
//! `keyframes.txt`, `report.json` (per-frame state, matches, inliers and times; totals,
//! lost spans, coverage, ATE when the sequence has ground truth) and `map.ply` (the
//! sparse map).

use std::path::{Path, PathBuf};
use std::time::Instant;

use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use thiserror::Error;

use crate::config::Config;
use crate::dense::disparity::StereoDepth;
use crate::dense::masks::Masking;
use crate::dense::{fuse_run, DenseInputs, DenseReport};
use crate::detect::worker::{DetectionWorker, Job, Outcome, Waiting};
use crate::detect::{write_cache, FrameDetections};
use crate::dop::boxes::in_dynamic_box;
use crate::dop::{DopConfig, Mode};
use crate::eval::report::{evaluate, EvalOptions, EvalReport};
use crate::eval::stats::median;
use crate::features::OrbExtractor;
use crate::global::loop_detection::LoopDetection;
use crate::global::GlobalReport;
use crate::io::atomic::write_atomic;
use crate::io::kitti::KittiSequence;
use crate::io::orbslam_settings::{Calibration, OrbSlamSettings};
use crate::io::sequence::{FrameImages, SensorKind, Sequence};
use crate::io::trajectory::TrajectoryFormat;
use crate::io::tum::TumSequence;
use crate::io::{IoError, Trajectory};
use crate::map::Map;
use crate::mapping::dynamic::{apply_detections, object_boxes, DynamicObjects};
use crate::mapping::{LocalMapper, LocalMapping, MappingStats};
use crate::optim::stereo_projection::StereoCamera;
use crate::pacing::{Pace, Pacer};
use crate::tracking::input::{DepthCheck, Picture};
use crate::tracking::{Frame, FrameReport, Tracker, TrackingState};

#[derive(Debug, Error)]
pub enum RunError {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("{0}")]
    Input(String),
    #[error("{message} (outputs of the {done} frames done are in {out})")]
    Interrupted {
        message: String,
        done: usize,
        out: PathBuf,
    },
}

/// Why tracking never started, from what the frames showed: no keypoints (blank
/// images), else too few with depth (the depth scale, the depth images, or for stereo
/// a pair whose left and right are swapped).
fn never_started(lines: &[FrameLine], config: &Config, sensor: SensorKind) -> String {
    let mut keypoints: Vec<f64> = lines.iter().map(|l| l.tracking.keypoints as f64).collect();
    let median_keypoints = median(&mut keypoints);
    let needed = config.tracking.min_initial_points;
    if median_keypoints < needed as f64 {
        return format!(
            "tracking never started: the frames have almost no ORB keypoints (median {median_keypoints:.0}, {needed} needed): are the colour images blank or black?"
        );
    }
    match sensor {
        SensorKind::Rgbd => format!(
            "tracking never started: no frame had {needed} keypoints with depth (check depth_scale and the depth images)"
        ),
        SensorKind::Stereo => format!(
            "tracking never started: no frame had {needed} keypoints matched between the stereo images: check Camera.bf, and that image_0 is the left camera (a swapped pair has no positive disparity)"
        ),
    }
}

/// For a stereo sequence, a warning when its first pair looks swapped (see
/// [`crate::tracking::stereo_matching::looks_swapped`]): such a pair still tracks, badly.
fn warn_if_swapped(sequence: &dyn Sequence, extractor: &OrbExtractor, camera: &StereoCamera) {
    if sequence.sensor() != SensorKind::Stereo || sequence.is_empty() {
        return;
    }
    let Ok(frame) = sequence.load(0) else { return };
    let crate::io::sequence::FrameImages::Stereo { left, right } = &frame.images else {
        return;
    };
    let pair = (left, right);
    if let Some((given, exchanged)) =
        crate::tracking::stereo_matching::looks_swapped(pair, extractor, camera.bf, camera.fx)
    {
        eprintln!(
            "warning: the stereo pair of {} looks swapped: {exchanged} keypoints match with image_1 as the left camera, {given} as given (image_0 must be the left camera)",
            sequence.name()
        );
    }
}

/// Says what is wrong when `root` is no sequence folder: missing, a file, a loop of
/// symbolic links, or a KITTI dataset's root instead of one of its sequences.
pub fn check_sequence_folder(root: &Path) -> Result<(), IoError> {
    match std::fs::metadata(root) {
        Err(e) if e.raw_os_error() == Some(libc::ELOOP) => {
            Err(IoError::invalid(root, "a loop of symbolic links, not a sequence folder"))
        }
        Err(_) => Err(IoError::Missing {
            path: root.to_path_buf(),
            what: "sequence folder".into(),
        }),
        Ok(meta) if !meta.is_dir() => Err(IoError::invalid(
            root,
            "a file, not a sequence folder (TUM/Bonn: the folder holding rgb.txt and depth.txt; KITTI: sequences/NN)",
        )),
        Ok(_) if root.join("sequences").is_dir() && !root.join("image_0").is_dir() && !root.join("rgb.txt").exists() => {
            Err(IoError::invalid(
                root,
                format!(
                    "a KITTI dataset's root: run one of its sequences, e.g. {}",
                    root.join("sequences/00").display()
                ),
            ))
        }
        Ok(_) => Ok(()),
    }
}

/// Opens a TUM/Bonn folder or a KITTI sequence folder (`image_0/` inside).
pub fn open_sequence(root: &Path, config: &Config) -> Result<Box<dyn Sequence>, IoError> {
    check_sequence_folder(root)?;
    if root.join("image_0").is_dir() {
        return Ok(Box::new(KittiSequence::open(root, None)?));
    }
    Ok(Box::new(TumSequence::open(
        root,
        &config.dataset.tum_options(),
    )?))
}

/// The calibration to use: the config's camera, else its settings file, else the
/// sequence's own; RGB-D without a baseline gets ORB-SLAM2's virtual 40 px·m.
pub fn resolve_calibration(
    sequence: &dyn Sequence,
    config: &Config,
) -> Result<Calibration, RunError> {
    let mut calibration = match (&config.dataset.settings, sequence.calibration(), config.dataset.camera) {
        (Some(path), _, _) => OrbSlamSettings::read(path)?.calibration,
        (None, Some(own), _) => own.clone(),
        (None, None, Some(camera)) => Calibration {
            camera,
            bf: None,
            depth_scale: None,
            th_depth: None,
            fps: None,
        },
        (None, None, None) => {
            return Err(RunError::Input(format!(
                "sequence {} has no calibration (no calibration.yaml, and its folder name says no freiburg1/2/3): pass --settings configs/calibration/RGB-D_TUM3.yaml (or another ORB-SLAM2 settings file) or --camera fx,fy,cx,cy; in a config, [dataset] settings or [dataset.camera]",
                sequence.name()
            )))
        }
    };
    if let Some(camera) = config.dataset.camera {
        calibration.camera = camera;
    }
    if calibration.bf.is_none() {
        calibration.bf = Some(40.0);
    }
    Ok(calibration)
}

/// Totals of a run.
#[derive(Debug, Clone, Serialize)]
pub struct RunTotals {
    pub frames: usize,
    pub tracked: usize,
    pub lost: usize,
    pub not_initialised: usize,
    /// Tracked frames over all frames, in %.
    pub coverage_percent: f64,
    /// Inclusive frame index ranges where tracking was lost.
    pub lost_spans: Vec<(usize, usize)>,
    /// The map segments: tracking that stays lost starts a new one
    /// (`[tracking] new_map_after_seconds`); a loop merges segments in the global pass.
    pub segments: Vec<SegmentSpan>,
    /// Tracked frames in the largest segment after the merges, over all frames, in %:
    /// the part of the run in one frame of reference.
    pub largest_segment_percent: f64,
    pub keyframes: usize,
    pub map_points: usize,
    /// Tracking time per frame (ORB extraction + tracking), as ORB-SLAM2 prints it.
    pub median_tracking_ms: f64,
    pub mean_tracking_ms: f64,
    pub median_extraction_ms: f64,
    pub median_matching_ms: f64,
    pub median_optimisation_ms: f64,
    /// The DOP model per frame (propagation and expansion; 0 without it).
    pub median_dop_ms: f64,
    /// The process's peak resident memory so far (MiB, Linux): after tracking and the
    /// global pass; the dense pass reports its own.
    pub peak_memory_mib: Option<f64>,
}

/// A map segment of a run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SegmentSpan {
    pub segment: usize,
    /// First and last frame tracked in it, and how many were.
    pub first_frame: usize,
    pub last_frame: usize,
    pub tracked_frames: usize,
    /// The segment a loop merged it into (in the global pass), following later merges.
    pub merged_into: Option<usize>,
}

/// The segments the tracked frames of `lines` were in, and the share of all frames in
/// the largest after `merges` (segment, into).
pub fn segment_spans(lines: &[FrameLine], merges: &[(usize, usize)]) -> (Vec<SegmentSpan>, f64) {
    let mut spans: Vec<SegmentSpan> = Vec::new();
    for line in lines {
        let t = &line.tracking;
        if t.state != TrackingState::Ok {
            continue;
        }
        match spans.iter_mut().find(|s| s.segment == t.segment) {
            Some(span) => {
                span.last_frame = t.index;
                span.tracked_frames += 1;
            }
            None => spans.push(SegmentSpan {
                segment: t.segment,
                first_frame: t.index,
                last_frame: t.index,
                tracked_frames: 1,
                merged_into: None,
            }),
        }
    }
    let root = |s| final_segment(merges, s);
    let mut merged: std::collections::BTreeMap<usize, usize> = Default::default();
    for span in &mut spans {
        let r = root(span.segment);
        span.merged_into = (r != span.segment).then_some(r);
        *merged.entry(r).or_default() += span.tracked_frames;
    }
    let largest = merged.values().max().copied().unwrap_or(0);
    (spans, 100.0 * largest as f64 / lines.len().max(1) as f64)
}

/// The segment that `segment` ended in after `merges` (segment, into), in order.
fn final_segment(merges: &[(usize, usize)], mut segment: usize) -> usize {
    // Each merge moves a segment into another; following them takes at most one step
    // per merge.
    for _ in 0..=merges.len() {
        match merges.iter().find(|(from, _)| *from == segment) {
            Some((_, into)) => segment = *into,
            None => break,
        }
    }
    segment
}

/// One frame's line in the report.
#[derive(Debug, Clone, Serialize)]
pub struct FrameLine {
    #[serde(flatten)]
    pub tracking: FrameReport,
    pub extraction_ms: f64,
    pub tracking_ms: f64,
    /// Against the ground-truth masks of a synthetic sequence (absent elsewhere).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub truth: Option<TruthCounts>,
}

/// What a run was set up with: the effective camera and ORB parameters after the
/// config, the settings file and `--camera`, and the runtime files it loaded.
#[derive(Debug, Clone, Serialize)]
pub struct RunSetup {
    pub calibration: Calibration,
    pub orb: crate::features::orb::OrbConfig,
    /// `ThDepth` and ORB-SLAM2's most frames between keyframes (`Camera.fps`).
    pub th_depth: f64,
    pub max_frames_between_keyframes: usize,
    /// The ORB-SLAM2 settings file and which of its keys were applied.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub settings: Option<crate::config::SettingsApplied>,
    /// The runtime data directory and why it was chosen (`dopslam doctor`).
    pub data_dir: String,
    pub detections: crate::detect::Source,
    /// The detector's files (models, then the ONNX Runtime library) when it is ONNX.
    pub detector_files: Vec<PathBuf>,
    /// The vocabulary file, when loop closing ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vocabulary: Option<PathBuf>,
    /// [`first_frame_hash`] of the sequence: `dopslam fuse` checks that it fuses the
    /// sequence the run tracked.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_frame_hash: Option<String>,
}

/// A fingerprint of a sequence: FNV-1a (64 bits, hex) of its first frame's colour (or
/// left) pixels; `None` when the frame cannot be read.
pub fn first_frame_hash(sequence: &dyn Sequence) -> Option<String> {
    let frame = sequence.load(0).ok()?;
    let bytes: &[u8] = match &frame.images {
        crate::io::sequence::FrameImages::Rgbd { rgb, .. } => rgb.as_raw(),
        crate::io::sequence::FrameImages::Stereo { left, .. } => left.as_raw(),
    };
    let hash = bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    });
    Some(format!("{hash:016x}"))
}

impl RunSetup {
    fn new(sequence: &dyn Sequence, config: &Config, calibration: &Calibration) -> Self {
        let data = crate::io::data_dir::DataDir::locate();
        let absolute = |p: PathBuf| std::path::absolute(&p).unwrap_or(p);
        Self {
            calibration: calibration.clone(),
            orb: config.orb.clone(),
            th_depth: config.tracking.th_depth,
            max_frames_between_keyframes: config.tracking.max_frames_between_keyframes,
            settings: config.dataset.settings_applied.clone(),
            data_dir: format!("{} ({})", absolute(data.path).display(), data.origin),
            detections: config.detector.source,
            detector_files: match config.detector.source {
                crate::detect::Source::Onnx => config
                    .detector
                    .onnx_files()
                    .into_iter()
                    .map(|(p, _)| absolute(p))
                    .collect(),
                _ => Vec::new(),
            },
            vocabulary: (config.global.enabled && config.global.loops.enabled)
                .then(|| absolute(config.global.vocabulary_file())),
            first_frame_hash: first_frame_hash(sequence),
        }
    }
}

/// What `report.json` holds.
#[derive(Debug, Serialize)]
pub struct RunReport {
    pub sequence: String,
    /// What the run was set up with.
    pub setup: RunSetup,
    /// The sequence folder, when known (for `dopslam fuse`).
    pub sequence_path: Option<PathBuf>,
    /// How moving objects were treated.
    pub mode: Mode,
    pub totals: RunTotals,
    /// ATE of `trajectory.txt` (after the global pass, when it ran).
    pub ate: Option<EvalReport>,
    /// ATE of `trajectory_tracking.txt` (the tracking pass alone), when the global pass ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ate_tracking: Option<EvalReport>,
    pub mapping: MappingStats,
    pub detection: DetectionTotals,
    /// The global pass: loops, candidates, full BA.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub global: Option<GlobalReport>,
    pub frames: Vec<FrameLine>,
    /// Why the run stopped before the last frame (a frame that failed to load, tracking
    /// that never started, an interruption), if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stopped: Option<String>,
    /// The dense pass, when it ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dense: Option<DenseReport>,
}

/// Options of a run.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Stop after this many frames.
    pub max_frames: Option<usize>,
    pub progress: bool,
    /// Run local mapping and detection inline after each keyframe instead of in their
    /// own threads, so that results repeat exactly.
    pub deterministic: bool,
    /// The sequence folder, where the oracle detections are (`detections_oracle/`).
    pub sequence_dir: Option<PathBuf>,
    /// Write each frame with its keypoints coloured by DOP state here (the paper's
    /// Fig. 4): green high-confidence static, yellow low-confidence static, orange
    /// low-confidence dynamic, red high-confidence dynamic (removed: orange and red).
    pub debug_frames: Option<PathBuf>,
    /// Run the dense pass after tracking (`[dense]` settings).
    pub dense: bool,
    /// Real-time mode: frames at the recording's rate, or as fast as tracking goes.
    pub pace: Pace,
}

/// What the keyframe detector did over a run.
#[derive(Debug, Clone, Default, Serialize)]
pub struct DetectionTotals {
    /// Keyframes handed to the detector, those whose detections came back, and those
    /// skipped because a newer keyframe was waiting (real-time mode).
    pub submitted: usize,
    pub detected: usize,
    pub skipped: usize,
    /// Boxes predicted for followed people the detector missed, and keyframes that a
    /// late detection reached after they were made.
    pub predicted_boxes: usize,
    pub later_keyframes_reached: usize,
    /// Person recall on detected keyframes against the ground-truth masks of a
    /// synthetic sequence: people covering at least 1 % of the image, found by a
    /// dynamic box used there (detected or predicted) with IoU >= 0.5.
    pub person_recall: Option<Recall>,
    /// Detections per class name over all keyframes.
    pub per_class: std::collections::BTreeMap<String, usize>,
    /// Detector time per keyframe (in its own thread), milliseconds.
    pub median_ms: f64,
    /// Map points whose moving probability a keyframe's detections updated, and those
    /// removed as dynamic (by the DOP model or, with --mask-boxes, inside a box).
    pub map_points_updated: usize,
    pub map_points_removed: usize,
    /// Updates where a point on a detected dynamic object counted as static because
    /// the geometric check had verified it (`[dop] static_check`).
    pub map_points_verified_static: usize,
    /// Keypoints called dynamic against the synthetic ground-truth masks (`masks/` of
    /// a `dopslam synth` sequence): every tracked frame with --dop, the detected
    /// keyframes with --mask-boxes.
    pub classification: Option<Classification>,
    pub errors: Vec<String>,
}

/// How moving objects are treated in a run of `config`: without detections the DOP
/// model runs on its geometric check alone (when on), else every mode is ORB-SLAM2's.
pub fn effective_mode(config: &Config) -> Mode {
    match config.detector.source {
        crate::detect::Source::None if config.dop.mode == Mode::Dop && config.dop.geometric => {
            Mode::Dop
        }
        crate::detect::Source::None => Mode::Off,
        _ => config.dop.mode,
    }
}

/// The detection source a run of `config` uses: `auto` needs no detector in ORB-SLAM2
/// mode (`--no-dop`) and the ONNX model otherwise; a missing model or runtime library
/// is an error here, before any work, never a silent run without detections.
pub fn detection_source(config: &Config) -> Result<crate::detect::Source, RunError> {
    use crate::detect::Source;
    if config.detector.source == Source::Auto && config.dop.mode == Mode::Off {
        return Ok(Source::None);
    }
    config.detector.resolved_source().map_err(|e| {
        RunError::Input(format!(
            "{e}; or run without a detector: --detections none (config: [detector] source = \"none\")"
        ))
    })
}

/// Before any work (after [`loop_vocabulary`]): the paths are UTF-8 (the report names
/// them), the output and debug folders can be written and are not inside the input
/// sequence, no other run writes into the output
/// folder (the lock returned is held for the run), and an earlier run's outputs there
/// move into `previous/`.
fn prepare_outputs(
    out: &Path,
    options: &RunOptions,
) -> Result<crate::io::output::DirLock, RunError> {
    use crate::io::output;
    let inputs: Vec<&Path> = options.sequence_dir.as_deref().into_iter().collect();
    if let Some(dir) = inputs.first().filter(|d| d.to_str().is_none()) {
        return Err(RunError::Input(format!(
            "the sequence path {} is not valid UTF-8, which report.json cannot name: link it under a UTF-8 name (ln -s) and run that",
            dir.display()
        )));
    }
    output::prepare_dir(out, "output", &inputs)?;
    if let Some(debug) = &options.debug_frames {
        output::prepare_dir(debug, "debug frames", &inputs)?;
    }
    let lock = output::DirLock::take(out)?;
    let moved = output::move_previous_outputs(out, &[])?;
    if !moved.is_empty() && options.progress {
        eprintln!(
            "{} held an earlier run's outputs: moved into {}/previous/ ({})",
            out.display(),
            out.display(),
            moved.join(", ")
        );
    }
    Ok(lock)
}

/// What loop closing runs with: see [`loop_vocabulary`].
type LoopVocabulary = Option<Result<std::sync::Arc<crate::bow::vocabulary::Vocabulary>, String>>;

/// The vocabulary of loop closing: `None` without a global pass, `Some(Err(why))` when
/// loop closing is off (the global pass runs without loops). A vocabulary that cannot
/// be read while loop closing is on is an error before any work.
fn loop_vocabulary(config: &crate::global::GlobalConfig) -> Result<LoopVocabulary, RunError> {
    if !config.enabled {
        return Ok(None);
    }
    if !config.loops.enabled {
        return Ok(Some(Err("loop closing is off ([global.loops] enabled = false, --no-loops)".into())));
    }
    crate::global::load_vocabulary(config)
        .map(|v| Some(Ok(v)))
        .map_err(RunError::Input)
}

/// Runs the passes over `sequence` and writes their outputs into `out`: tracking,
/// then (when `options.dense`) the dense map, also after tracking stopped early.
pub fn run_sequence(
    sequence: &dyn Sequence,
    config: &Config,
    out: &Path,
    options: &RunOptions,
) -> Result<RunReport, RunError> {
    let vocabulary = loop_vocabulary(&config.global)?;
    let _lock = prepare_outputs(out, options)?;
    let tracked = track_sequence(sequence, config, out, options, vocabulary);
    if !options.dense {
        return tracked;
    }
    let done = match &tracked {
        Ok(report) => report.totals.tracked,
        Err(RunError::Interrupted { .. }) => 1,
        Err(_) => 0,
    };
    if done == 0 || crate::interrupt::requested() {
        return tracked;
    }
    let dense = dense_pass(
        sequence,
        config,
        (out, out),
        dense_masking(effective_mode(config)),
        options.sequence_dir.as_deref(),
        options.progress,
    );
    // After a tracking failure the dense map of what was tracked is a bonus: the
    // tracking error is the one to report.
    match (tracked, dense) {
        (Ok(mut report), Ok(dense)) => {
            report.dense = Some(dense);
            Ok(report)
        }
        (Ok(_), Err(e)) => Err(e),
        (Err(e), _) => Err(e),
    }
}

/// The dense pass over the run in `run_dir`, outputs into `out_dir` (see
/// [`crate::dense`]); with `sequence_dir`'s ground-truth `masks/`, when it has them,
/// the fused pixels are counted against them.
pub fn dense_pass(
    sequence: &dyn Sequence,
    config: &Config,
    (run_dir, out_dir): (&Path, &Path),
    masking: Masking,
    sequence_dir: Option<&Path>,
    progress: bool,
) -> Result<DenseReport, RunError> {
    let config = &config.for_sensor(sequence.sensor());
    let calibration = resolve_calibration(sequence, config)?;
    let detector = match masking {
        Masking::Dop if config.dense.detect_every > 0 => config
            .detector
            .open(sequence_dir)
            .map_err(|e| RunError::Input(e.to_string()))?,
        _ => None,
    };
    let inputs = DenseInputs {
        sequence,
        camera: calibration.camera,
        run_dir,
        out_dir,
        masking,
        dop: &config.dop,
        dynamic_classes: &config.detector.dynamic_classes,
        truth_masks: sequence_dir.map(|d| d.join("masks")).filter(|d| d.is_dir()),
        progress,
        stereo: (sequence.sensor() == SensorKind::Stereo).then(|| StereoDepth {
            bf: calibration.bf.unwrap_or(40.0),
            sgbm: config.stereo.sgbm(),
        }),
        detector: detector.map(std::sync::Mutex::new),
    };
    Ok(fuse_run(&inputs, &config.dense)?)
}

/// The dense masks that go with a tracking mode.
pub fn dense_masking(mode: Mode) -> Masking {
    match mode {
        Mode::Off => Masking::None,
        Mode::MaskBoxes => Masking::Boxes,
        Mode::Dop => Masking::Dop,
    }
}

/// The tracking pass: tracks every frame of `sequence` and writes its outputs into `out`;
/// loop detection runs beside it with `vocabulary` ([`loop_vocabulary`]).
fn track_sequence(
    sequence: &dyn Sequence,
    config: &Config,
    out: &Path,
    options: &RunOptions,
    vocabulary: LoopVocabulary,
) -> Result<RunReport, RunError> {
    if sequence.is_empty() {
        return Err(RunError::Input(format!(
            "sequence {} has no frames",
            sequence.name()
        )));
    }
    let mut config = config.for_sensor(sequence.sensor());
    config.detector.source = detection_source(&config)?;
    let config = &config;
    let calibration = resolve_calibration(sequence, config)?;
    let camera = StereoCamera::new(&calibration.camera, calibration.bf.unwrap_or(40.0));
    let extractor = OrbExtractor::new(&config.orb);
    warn_if_swapped(sequence, &extractor, &camera);
    let mut tracker = Tracker::new(
        config.tracking.clone(),
        camera,
        extractor.pyramid.clone(),
        calibration.camera.width,
        calibration.camera.height,
    );
    let close_depth = (config.tracking.th_depth * camera.bf / camera.fx) as f32;
    let mapper = LocalMapper::new(
        config.mapping.clone(),
        camera,
        extractor.pyramid.clone(),
        (calibration.camera.width, calibration.camera.height),
        close_depth,
    );
    let mut detection = config
        .detector
        .open(options.sequence_dir.as_deref())
        .map_err(|e| RunError::Input(e.to_string()))?
        .map(|d| DetectionWorker::start(d, options.deterministic, config.detector.latency()));
    let mode = effective_mode(config);
    let mut mapper = mapper;
    if mode == Mode::Dop {
        tracker.dop = Some(config.dop.clone());
        mapper.moving_threshold = config.dop.removal_threshold;
    }
    let moving_threshold = mapper.moving_threshold;
    // Place recognition beside tracking, fed by local mapping.
    let loop_detection = vocabulary.map(|vocabulary| {
        vocabulary.map(|vocabulary| {
            LoopDetection::start(
                vocabulary,
                config.global.loops.clone(),
                tracker.map.clone(),
                options.deterministic,
            )
        })
    });
    if let Some(Ok(detection)) = &loop_detection {
        mapper.then = Some(detection.hand_over());
    }
    let mut mapping = LocalMapping::start(mapper, tracker.map.clone(), options.deterministic);
    let effect = DetectionUse {
        config: &config.dop,
        alpha: match sequence.sensor() {
            SensorKind::Rgbd => config.dop.alpha_rgbd,
            SensorKind::Stereo => config.dop.alpha_stereo,
        },
        mode,
        dynamic_classes: &config.detector.dynamic_classes,
        sequence_dir: options.sequence_dir.as_deref(),
    };
    let mut book = DetectionBook {
        objects: (mode == Mode::Dop).then(|| DynamicObjects::new(calibration.camera)),
        ..DetectionBook::default()
    };
    std::fs::create_dir_all(out).map_err(|source| IoError::Write {
        path: out.to_path_buf(),
        source,
    })?;
    let total = options
        .max_frames
        .map_or(sequence.len(), |m| m.min(sequence.len()));
    let progress = if options.progress {
        ProgressBar::new(total as u64)
    } else {
        ProgressBar::hidden()
    };
    progress.set_style(
        ProgressStyle::with_template(
            "track {bar:40} {pos}/{len} frames {msg} ({per_sec}, {eta} left)",
        )
        .expect("valid template"),
    );
    let mut lines = Vec::with_capacity(total);
    let mut dynamic_keypoints = Vec::new();
    let mut failure: Option<String> = None;
    let mut depth_check = DepthCheck::default();
    let mut pacer = Pacer::new(if options.deterministic {
        Pace::Free
    } else {
        options.pace
    });
    for index in 0..total {
        if crate::interrupt::requested() {
            failure = Some(format!("{} at frame {index}", crate::interrupt::MESSAGE));
            break;
        }
        let loaded = match sequence.load(index) {
            Ok(frame) => frame,
            Err(e) => {
                failure = Some(format!("frame {index}: {e}"));
                break;
            }
        };
        pacer.wait_for(loaded.timestamp);
        let size = match &loaded.images {
            FrameImages::Rgbd { rgb, .. } => rgb.dimensions(),
            FrameImages::Stereo { left, .. } => left.dimensions(),
        };
        let expected = (calibration.camera.width, calibration.camera.height);
        if size != expected {
            failure = Some(format!(
                "frame {index}: the image is {}x{} but the calibration (and the first frame) say {}x{}: every frame of a sequence must have one size",
                size.0, size.1, expected.0, expected.1
            ));
            break;
        }
        let start;
        let budgeted = extractor.with_budget(tracker.feature_budget(config.orb.n_features));
        let (frame, picture) = match loaded.images {
            FrameImages::Rgbd { rgb, depth } => {
                if let Err(message) = depth_check.check(index, &depth, tracker.state, &calibration)
                {
                    failure = Some(message);
                    break;
                }
                start = Instant::now();
                let grey = crate::io::image_files::grey_from_rgb(&rgb);
                let frame = Frame::from_rgbd(
                    index,
                    loaded.timestamp,
                    &grey,
                    &depth,
                    &budgeted,
                    &camera,
                    &calibration.camera,
                );
                (frame, Picture::Colour(rgb))
            }
            FrameImages::Stereo { left, right } => {
                start = Instant::now();
                let frame = Frame::from_stereo(
                    index,
                    loaded.timestamp,
                    (&left, &right),
                    &budgeted,
                    &camera,
                );
                (frame, Picture::Grey(left))
            }
        };
        let extraction_ms = start.elapsed().as_secs_f64() * 1e3;
        let report = tracker.track(frame, mapping.is_idle());
        let tracking_ms = start.elapsed().as_secs_f64() * 1e3;
        if let (Some(dir), Some(frame)) = (&options.debug_frames, tracker.last_frame()) {
            if frame.index == index {
                let mut picture = picture.clone().into_colour();
                let dop = tracker.dop.clone().unwrap_or_default();
                crate::detect::draw::draw_keypoints(&mut picture, frame, &dop);
                let path = dir.join(format!("{index:06}.png"));
                if let Err(e) = std::fs::create_dir_all(dir)
                    .and_then(|_| picture.save(&path).map_err(std::io::Error::other))
                {
                    failure = Some(format!("cannot write {}: {e}", path.display()));
                    break;
                }
            }
        }
        if let Some(key) = report.new_keyframe {
            // Marked before local mapping sees the keyframe, whose BA leaves its points
            // out while they wait.
            let awaits = detection.is_some() && !options.deterministic && tracker.dop.is_some();
            if awaits {
                book.await_detection(&tracker, index, key);
            }
            mapping.insert(key);
            if let Some(worker) = detection.as_mut() {
                book.keyframe_of_frame.insert(index, key);
                book.totals.submitted += 1;
                worker.submit(Job {
                    id: index,
                    timestamp: loaded.timestamp,
                    image: picture.into_colour(),
                });
                if awaits && book.totals.submitted == 1 {
                    // The first map waits for its detection: nothing older can carry
                    // the pose while its points wait.
                    book.receive(
                        &mut tracker,
                        worker.wait(FIRST_DETECTION_WAIT),
                        out,
                        &effect,
                    );
                }
            }
        }
        if let (Some(dop), Some(frame)) = (&tracker.dop, tracker.last_frame()) {
            if report.state == TrackingState::Ok && frame.index == index {
                dynamic_keypoints.push(crate::dense::masks::dynamic_keypoints(frame, dop));
            }
        }
        let mut truth = None;
        if let Some(frame) = tracker.last_frame() {
            if report.state == TrackingState::Ok && frame.index == index {
                if let Some(mask) =
                    ground_truth_mask(options.sequence_dir.as_deref(), loaded.timestamp)
                {
                    let positions: Vec<(f32, f32)> =
                        frame.keypoints.iter().map(|k| (k.x, k.y)).collect();
                    let called: Vec<bool> = match &tracker.dop {
                        Some(dop) => frame.moving.iter().map(|p| dop.removed(*p)).collect(),
                        None => vec![false; positions.len()],
                    };
                    let in_pose: Vec<u32> = report
                        .pose_observations
                        .iter()
                        .map(|o| o.keypoint)
                        .collect();
                    let counts = TruthCounts::new(&mask, &positions, &called, &in_pose);
                    if tracker.dop.is_some() {
                        book.totals
                            .classification
                            .get_or_insert_with(Classification::default)
                            .add(&counts);
                    }
                    truth = Some(counts);
                }
            }
        }
        if let Some(worker) = detection.as_mut() {
            book.receive(&mut tracker, worker.poll(), out, &effect);
        }
        progress.set_message(format!("{:?}", report.state));
        progress.inc(1);
        lines.push(FrameLine {
            tracking: report,
            extraction_ms,
            tracking_ms,
            truth,
        });
    }
    progress.finish_and_clear();
    if failure.is_none() && tracker.state == TrackingState::NotInitialised {
        failure = Some(never_started(&lines, config, sequence.sensor()));
    }
    if let Some(worker) = detection {
        book.receive(&mut tracker, worker.finish(), out, &effect);
    }
    book.totals.median_ms = median(&mut book.milliseconds);
    let stats = mapping.finish();
    // Local mapping has dropped its hand-over: place recognition finishes its queue.
    let recognised = loop_detection.map(|d| d.map(LoopDetection::finish));
    let shared = tracker.map.clone();
    let mut map = shared.write().expect("map lock poisoned");
    // The global pass, on a complete run: the tracking trajectory is kept first.
    let global = if let (Some(recognised), None) = (recognised, &failure) {
        let tracking = trajectory_of(&map, &lines);
        tracking.write(&out.join(TRACKING_TRAJECTORY), TrajectoryFormat::Tum)?;
        let inputs = crate::global::GlobalInputs {
            camera: &camera,
            pyramid: &extractor.pyramid,
            size: (
                calibration.camera.width as f32,
                calibration.camera.height as f32,
            ),
            moving_threshold,
        };
        Some((
            crate::global::run(
                &mut map,
                &inputs,
                &config.global,
                recognised,
                lines.iter_mut().map(|l| &mut l.tracking),
            ),
            tracking,
        ))
    } else {
        None
    };
    if mode == Mode::Dop {
        let json = serde_json::to_string(&dynamic_keypoints).expect("keypoints serialise");
        write_atomic(&out.join(crate::dense::KEYPOINTS_FILE), json.as_bytes())?;
    }
    let report = write_outputs(
        sequence,
        RunSetup::new(sequence, config, &calibration),
        &map,
        (stats, book.totals),
        (lines, failure.clone()),
        (out, options.sequence_dir.as_deref(), mode),
        global,
    )?;
    match failure {
        Some(message) => Err(RunError::Interrupted {
            message,
            done: report.frames.len(),
            out: out.to_path_buf(),
        }),
        None => Ok(report),
    }
}

/// Keypoints called dynamic (removed) against the ground-truth masks.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Classification {
    pub frames: usize,
    pub true_positives: usize,
    pub false_positives: usize,
    pub false_negatives: usize,
    pub precision: f64,
    pub recall: f64,
}

impl Classification {
    /// Adds one frame's counts.
    fn add(&mut self, counts: &TruthCounts) {
        self.frames += 1;
        self.true_positives += counts.mover_removed;
        self.false_positives += counts.static_removed;
        self.false_negatives += counts.mover_keypoints - counts.mover_removed;
        let tp = self.true_positives as f64;
        self.precision = tp / (tp + self.false_positives as f64).max(1.0);
        self.recall = tp / (tp + self.false_negatives as f64).max(1.0);
    }
}

/// One tracked frame's keypoints against its ground-truth mover mask: how many lie on
/// the static scene and on movers, how many of each were called dynamic (removed), and
/// how many of each took part in the pose as inliers. Keypoints outside the mask (an
/// undistorted position off the image) are not counted.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct TruthCounts {
    pub static_keypoints: usize,
    pub mover_keypoints: usize,
    pub static_removed: usize,
    pub mover_removed: usize,
    pub static_in_pose: usize,
    pub mover_in_pose: usize,
    /// Static keypoints in the pose within [`NEAR_MOVER_PIXELS`] of a mover's pixel:
    /// corners on a mover's outline against the background move with the mover though
    /// their own pixel is static.
    pub near_mover_in_pose: usize,
}

/// How close (pixels, in x and y) to a mover a static keypoint counts as on its outline.
const NEAR_MOVER_PIXELS: i64 = 4;

impl TruthCounts {
    fn new(
        mask: &image::ImageBuffer<image::Luma<u16>, Vec<u16>>,
        positions: &[(f32, f32)],
        called: &[bool],
        in_pose: &[u32],
    ) -> Self {
        // Some(true) on a mover, Some(false) on the static scene, None off the mask.
        let on_mover = |(x, y): (f32, f32)| {
            let (u, v) = (x.round() as u32, y.round() as u32);
            (u < mask.width() && v < mask.height()).then(|| mask.get_pixel(u, v)[0] != 0)
        };
        let mut counts = Self::default();
        for (&position, &removed) in positions.iter().zip(called) {
            match on_mover(position) {
                Some(true) => {
                    counts.mover_keypoints += 1;
                    counts.mover_removed += removed as usize;
                }
                Some(false) => {
                    counts.static_keypoints += 1;
                    counts.static_removed += removed as usize;
                }
                None => {}
            }
        }
        let near_mover = |(x, y): (f32, f32)| {
            let (u, v) = (x.round() as i64, y.round() as i64);
            let r = NEAR_MOVER_PIXELS;
            (v - r..=v + r).any(|y| {
                (u - r..=u + r).any(|x| {
                    x >= 0
                        && y >= 0
                        && x < mask.width() as i64
                        && y < mask.height() as i64
                        && mask.get_pixel(x as u32, y as u32)[0] != 0
                })
            })
        };
        for &i in in_pose {
            let position = positions[i as usize];
            match on_mover(position) {
                Some(true) => counts.mover_in_pose += 1,
                Some(false) => {
                    counts.static_in_pose += 1;
                    counts.near_mover_in_pose += near_mover(position) as usize;
                }
                None => {}
            }
        }
        counts
    }
}

/// The ground-truth mover mask of a frame, when the sequence has one.
fn ground_truth_mask(
    sequence_dir: Option<&Path>,
    timestamp: f64,
) -> Option<image::ImageBuffer<image::Luma<u16>, Vec<u16>>> {
    crate::io::image_files::read_instance_mask(
        &sequence_dir?.join(format!("masks/{timestamp:.6}.png")),
    )
}

/// People found on keyframes against the ground truth.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Recall {
    pub keyframes: usize,
    pub people: usize,
    pub found: usize,
    pub recall: f64,
    /// People covering over 20 % of the image that were missed.
    pub missed_large: usize,
    /// Every person missed, in keyframe order (what to look at when recall is low).
    pub misses: Vec<Miss>,
}

/// A person on a keyframe that no dynamic box found with IoU >= 0.5.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Miss {
    pub timestamp: f64,
    /// The person's tight box from the ground-truth mask.
    pub person: [f32; 4],
    /// Share of the image the box covers.
    pub share: f32,
    /// The best IoU of any dynamic box with it, and that box.
    pub best_iou: f32,
    pub best_box: Option<[f32; 4]>,
}

impl Recall {
    fn add(&mut self, timestamp: f64, people: &[[f32; 4]], boxes: &[[f32; 4]], image_area: f32) {
        self.keyframes += 1;
        for person in people {
            self.people += 1;
            let best = boxes
                .iter()
                .map(|b| (crate::detect::yolo::iou(person, b), *b))
                .max_by(|a, b| a.0.total_cmp(&b.0));
            let best_iou = best.map_or(0.0, |(iou, _)| iou);
            if best_iou >= 0.5 {
                self.found += 1;
                continue;
            }
            let area = crate::detect::yolo::area(person);
            if area > 0.2 * image_area {
                self.missed_large += 1;
            }
            self.misses.push(Miss {
                timestamp,
                person: *person,
                share: area / image_area,
                best_iou,
                best_box: best.map(|(_, b)| b),
            });
        }
        self.recall = self.found as f64 / self.people.max(1) as f64;
    }
}

/// The tight boxes of the people in a synthetic frame's mask that cover at least 1 %
/// of it (the class of each instance from the frame's oracle file).
fn ground_truth_people(
    sequence_dir: Option<&Path>,
    timestamp: f64,
) -> Option<(Vec<[f32; 4]>, f32)> {
    let dir = sequence_dir?;
    let mask = ground_truth_mask(Some(dir), timestamp)?;
    let text = std::fs::read_to_string(crate::detect::cache_file(
        &dir.join("detections_oracle"),
        timestamp,
    ))
    .ok()?;
    let oracle: FrameDetections = serde_json::from_str(&text).ok()?;
    let people: std::collections::HashSet<u16> = oracle
        .detections
        .iter()
        .filter(|d| d.class == "person")
        .filter_map(|d| d.instance)
        .collect();
    let mut boxes: std::collections::BTreeMap<u16, ([u32; 4], usize)> = Default::default();
    for (x, y, p) in mask.enumerate_pixels() {
        let id = p[0];
        if id == 0 || !people.contains(&id) {
            continue;
        }
        let entry = boxes.entry(id).or_insert(([x, y, x + 1, y + 1], 0));
        entry.0 = [
            entry.0[0].min(x),
            entry.0[1].min(y),
            entry.0[2].max(x + 1),
            entry.0[3].max(y + 1),
        ];
        entry.1 += 1;
    }
    let image_area = (mask.width() * mask.height()) as f32;
    let people = boxes
        .into_values()
        .filter(|(_, count)| *count as f32 >= 0.01 * image_area)
        .map(|(b, _)| b.map(|v| v as f32))
        .collect();
    Some((people, image_area))
}

/// How detections act on the map.
struct DetectionUse<'a> {
    config: &'a DopConfig,
    /// The sensor's weight of a detection (the paper: 0.3 RGB-D, 0.5 stereo).
    alpha: f32,
    mode: Mode,
    dynamic_classes: &'a [String],
    sequence_dir: Option<&'a Path>,
}

/// What the run keeps of the detector's work: the keyframe made from each submitted
/// frame, the totals for the report, and the detector's time per keyframe.
#[derive(Default)]
struct DetectionBook {
    keyframe_of_frame: std::collections::HashMap<usize, crate::map::KeyFrameKey>,
    totals: DetectionTotals,
    milliseconds: Vec<f64>,
    /// The DOP model's followed objects (DOP mode only).
    objects: Option<DynamicObjects>,
    /// Keyframe ids of submitted frames whose detection has not come back.
    awaited: Waiting,
}

/// How long real-time mode waits for the first keyframe's detection.
const FIRST_DETECTION_WAIT: std::time::Duration = std::time::Duration::from_secs(5);

impl DetectionBook {
    /// Real-time mode: keyframe `key`, made from frame `index`, waits for its detection
    /// (its new points stay out of the pose and of local BA meanwhile, see
    /// [`crate::map::Map::awaiting_detection`]).
    fn await_detection(&mut self, tracker: &Tracker, index: usize, key: crate::map::KeyFrameKey) {
        let mut map = tracker.map.write().expect("map lock poisoned");
        if let Some(id) = map.keyframes.get(key).map(|kf| kf.id) {
            self.awaited.insert(index, id);
            map.awaiting_detection.insert(id);
        }
    }

    /// Attaches detections that came back to their keyframes (which local mapping may
    /// have culled meanwhile) and writes them to the run's detection cache
    /// (`OUT/detections/`, readable back with `source = "cache"`).
    fn receive(
        &mut self,
        tracker: &mut Tracker,
        outcomes: Vec<Outcome>,
        out: &Path,
        effect: &DetectionUse,
    ) {
        let (totals, milliseconds) = (&mut self.totals, &mut self.milliseconds);
        if outcomes.is_empty() {
            return;
        }
        let shared = tracker.map.clone();
        let mut map = shared.write().expect("map lock poisoned");
        for outcome in outcomes {
            for id in self.awaited.release(&outcome) {
                map.awaiting_detection.remove(&id);
            }
            if outcome.skipped {
                totals.skipped += 1;
                continue;
            }
            match outcome.detections {
                Ok(detections) => {
                    totals.detected += 1;
                    milliseconds.push(outcome.milliseconds);
                    for d in &detections {
                        *totals.per_class.entry(d.class.clone()).or_default() += 1;
                    }
                    let frame = FrameDetections {
                        timestamp: outcome.timestamp,
                        detections,
                    };
                    if let Err(e) = write_cache(&out.join("detections"), &frame) {
                        totals.errors.push(e.to_string());
                    }
                    let Some(&key) = self.keyframe_of_frame.get(&outcome.id) else {
                        continue;
                    };
                    if effect.mode == Mode::MaskBoxes {
                        mask_boxes_classification(&map, key, &frame, effect, totals);
                    }
                    if let Some(objects) = self.objects.as_mut() {
                        let done = objects.receive(
                            &mut map,
                            key,
                            &frame.detections,
                            effect.dynamic_classes,
                            effect.config,
                            effect.alpha,
                        );
                        totals.map_points_updated += done.effect.updated;
                        totals.map_points_removed += done.effect.removed;
                        totals.map_points_verified_static += done.effect.verified_static;
                        totals.predicted_boxes += done.predicted_boxes;
                        totals.later_keyframes_reached += done.later_keyframes;
                        if let Some((people, image_area)) =
                            ground_truth_people(effect.sequence_dir, frame.timestamp)
                        {
                            totals
                                .person_recall
                                .get_or_insert_with(Recall::default)
                                .add(frame.timestamp, &people, &done.boxes, image_area);
                        }
                    } else if effect.mode != Mode::Off {
                        let done = apply_detections(
                            &mut map,
                            key,
                            &frame.detections,
                            effect.dynamic_classes,
                            &DopConfig {
                                mode: effect.mode,
                                ..effect.config.clone()
                            },
                            effect.alpha,
                        );
                        totals.map_points_updated += done.updated;
                        totals.map_points_removed += done.removed;
                        totals.map_points_verified_static += done.verified_static;
                    }
                    if let Some(kf) = map.keyframes.get_mut(key) {
                        kf.detections = Some(frame.detections);
                    }
                }
                Err(e) => totals.errors.push(format!("frame {}: {e}", outcome.id)),
            }
        }
        // Every frame from now on sees the followed objects; the last frame's keypoints
        // take their points' new probabilities, so that the next frame propagates what
        // the detections said.
        if let Some(objects) = &self.objects {
            tracker.followed = Some(objects.followed(effect.alpha));
        }
        tracker.refresh_moving(&map);
    }
}

/// With --mask-boxes: the keyframe's keypoints inside dynamic boxes against its mask.
fn mask_boxes_classification(
    map: &Map,
    key: crate::map::KeyFrameKey,
    frame: &FrameDetections,
    effect: &DetectionUse,
    totals: &mut DetectionTotals,
) {
    let (Some(kf), Some(mask)) = (
        map.keyframes.get(key),
        ground_truth_mask(effect.sequence_dir, frame.timestamp),
    ) else {
        return;
    };
    let boxes = object_boxes(&frame.detections, effect.dynamic_classes);
    let positions: Vec<(f32, f32)> = kf.frame.keypoints.iter().map(|k| (k.x, k.y)).collect();
    let called: Vec<bool> = positions
        .iter()
        .map(|&(x, y)| in_dynamic_box(&boxes, x, y))
        .collect();
    totals
        .classification
        .get_or_insert_with(Classification::default)
        .add(&TruthCounts::new(&mask, &positions, &called, &[]));
}

/// The trajectory of the tracking pass written before the global pass moves the map.
pub const TRACKING_TRAJECTORY: &str = "trajectory_tracking.txt";

/// Every tracked frame's pose: relative to its reference keyframe, placed on that
/// keyframe's current pose (so frames follow the keyframes' corrections).
fn trajectory_of(map: &Map, lines: &[FrameLine]) -> Trajectory {
    let mut trajectory = Trajectory::default();
    for line in lines {
        let corrected = line
            .tracking
            .reference
            .and_then(|(key, camera_from_reference)| {
                Some(camera_from_reference * map.keyframe_pose(key)?)
            });
        if let Some(pose) = corrected.or(line.tracking.camera_from_world) {
            trajectory.push(line.tracking.timestamp, pose.inverse());
        }
    }
    trajectory
}

/// Writes trajectory, keyframes, map and report; evaluates against ground truth (also
/// the tracking pass's trajectory, when the global pass ran after it).
fn write_outputs(
    sequence: &dyn Sequence,
    setup: RunSetup,
    map: &Map,
    (mapping, detection): (MappingStats, DetectionTotals),
    (lines, stopped): (Vec<FrameLine>, Option<String>),
    (out, sequence_path, mode): (&Path, Option<&Path>, Mode),
    global: Option<(GlobalReport, Trajectory)>,
) -> Result<RunReport, RunError> {
    // A second Ctrl-C waits until the set is written.
    let _writing = crate::interrupt::Writing::start();
    let trajectory = trajectory_of(map, &lines);
    trajectory.write(&out.join("trajectory.txt"), TrajectoryFormat::Tum)?;
    let mut keyframes = Trajectory::default();
    for key in &map.keyframe_order {
        let kf = &map.keyframes[*key];
        keyframes.push(kf.frame.timestamp, kf.world_from_camera());
    }
    keyframes.write(&out.join("keyframes.txt"), TrajectoryFormat::Tum)?;
    crate::io::ply::write_ply(
        &out.join("map.ply"),
        &map.to_mesh(),
        None,
        crate::io::ply::PlyEncoding::Binary,
        "dopslam sparse map",
    )?;
    let mut lost_spans: Vec<(usize, usize)> = Vec::new();
    for line in &lines {
        if line.tracking.state == TrackingState::Lost {
            match lost_spans.last_mut() {
                Some(span) if span.1 + 1 == line.tracking.index => span.1 = line.tracking.index,
                _ => lost_spans.push((line.tracking.index, line.tracking.index)),
            }
        }
    }
    let merges: Vec<(usize, usize)> = global
        .iter()
        .flat_map(|(g, _)| g.loops.iter().filter_map(|l| l.merged))
        .map(|m| (m.segment, m.into))
        .collect();
    let (segments, largest_segment_percent) = segment_spans(&lines, &merges);
    let mut by_frame = String::from(
        "# timestamp segment: each tracked frame's map segment after the loops' merges\n",
    );
    for line in lines
        .iter()
        .filter(|l| l.tracking.state == TrackingState::Ok)
    {
        let segment = final_segment(&merges, line.tracking.segment);
        by_frame.push_str(&format!("{:.6} {segment}\n", line.tracking.timestamp));
    }
    write_atomic(&out.join(crate::dense::SEGMENTS_FILE), by_frame.as_bytes())?;
    let count = |state| lines.iter().filter(|l| l.tracking.state == state).count();
    let tracked = trajectory.len();
    let column = |f: fn(&FrameLine) -> f64| median(&mut lines.iter().map(f).collect::<Vec<_>>());
    let totals = RunTotals {
        frames: lines.len(),
        tracked,
        lost: count(TrackingState::Lost),
        not_initialised: count(TrackingState::NotInitialised),
        coverage_percent: 100.0 * tracked as f64 / lines.len().max(1) as f64,
        lost_spans,
        segments,
        largest_segment_percent,
        keyframes: map.keyframes.len(),
        map_points: map.points.len(),
        median_tracking_ms: column(|l| l.tracking_ms),
        mean_tracking_ms: lines.iter().map(|l| l.tracking_ms).sum::<f64>()
            / lines.len().max(1) as f64,
        median_extraction_ms: column(|l| l.extraction_ms),
        median_matching_ms: column(|l| l.tracking.matching_ms),
        median_optimisation_ms: column(|l| l.tracking.optimisation_ms),
        median_dop_ms: column(|l| l.tracking.dop_ms),
        peak_memory_mib: crate::memory::peak_resident_mib(),
    };
    let ate_of = |trajectory: &Trajectory| match sequence.ground_truth() {
        Some(gt) if trajectory.len() >= 3 => evaluate(
            gt,
            trajectory,
            &EvalOptions {
                min_coverage: 0.0,
                ..EvalOptions::default()
            },
        )
        .ok(),
        _ => None,
    };
    let ate = ate_of(&trajectory);
    let (global, ate_tracking) = match global {
        Some((report, tracking)) => (Some(report), ate_of(&tracking)),
        None => (None, None),
    };
    let report = RunReport {
        sequence: sequence.name().to_string(),
        setup,
        sequence_path: sequence_path.map(|p| p.canonicalize().unwrap_or_else(|_| p.to_path_buf())),
        mode,
        totals,
        ate,
        ate_tracking,
        mapping,
        detection,
        global,
        frames: lines,
        stopped,
        dense: None,
    };
    let json = serde_json::to_string_pretty(&report).map_err(|e| RunError::Input(e.to_string()))?;
    write_atomic(&out.join("report.json"), json.as_bytes())?;
    Ok(report)
}
