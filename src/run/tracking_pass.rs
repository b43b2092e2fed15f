//! The tracking pass: the frame loop alone. Each frame is loaded lazily, paced (real
//! time), checked (size, depth), made ready for tracking (ORB extraction, depth or
//! stereo matching), tracked by the [`System`], shown to the observers, and the
//! detections that came back are applied. A frame that fails to load, an
//! interruption, or tracking that never started stops the pass; what was tracked is
//! kept ([`TrackingPass::stop`]).

use std::time::Instant;

use super::error::{RunError, StopReason};
use super::observers::{FrameObserver, FrameView};
use super::options::RunOptions;
use super::rig_offset::OffsetSearch;
use super::setup::Setup;
use crate::config::Config;
use crate::detect::Detector;
use crate::eval::stats::median;
use crate::frame::stereo::{DepthSettings, StereoPair};
use crate::frame::Frame;
use crate::io::image_files::DepthImage;
use crate::io::run_dir::RunDir;
use crate::io::sequence::{FrameImages, SensorKind, Sequence};
use crate::map::record::{FrameRecord, FrameRecords};
use crate::pacing::{Pace, Pacer};
use crate::records::{FrameLine, FrameLines, RigOffset};
use crate::system::worker::Execution;
use crate::system::{Helpers, System, Tracked};
use crate::tracking::input::{DepthCheck, Picture};
use crate::tracking::{TrackedFrame, TrackingState};

/// The Rerun recording's local map: the points of this many recent keyframes.
const RECENT_KEYFRAMES: usize = 10;

/// What the tracking pass hands on.
pub struct TrackingPass {
    /// What the system leaves for the global pass.
    pub tracked: Tracked,
    /// One report line per frame (in a spill file in the run's folder).
    pub lines: FrameLines,
    /// One record per line, for the global pass and the final trajectory (their
    /// observations in a spill file in the run's folder).
    pub records: FrameRecords,
    /// Why the pass stopped before the last frame, if it did.
    pub stop: Option<StopReason>,
    /// Stereo: the rig's disparity offset the pass found and took out
    /// ([`OffsetSearch`]), or its last estimate when none was taken out.
    pub offset: Option<RigOffset>,
}

/// Opens the run's detector (`None` without detection): its model is loaded here,
/// before any frame is tracked, so a model that does not load stops the run first.
pub fn open_detector(
    setup: &Setup,
    options: &RunOptions,
) -> Result<Option<Box<dyn Detector>>, RunError> {
    setup
        .config
        .detector
        .open(options.sequence_dir.as_deref())
        .map_err(|e| RunError::Input(e.to_string()))
}

/// What a tracking pass reads and runs with.
pub struct TrackingInputs<'a> {
    /// The frames.
    pub sequence: &'a dyn Sequence,
    /// The set-up.
    pub setup: &'a Setup,
    /// The keyframe detector ([`open_detector`]), when there is one.
    pub detector: Option<Box<dyn Detector>>,
    /// Frames, pace, determinism, the Rerun recording.
    pub options: &'a RunOptions,
    /// The run folder (the detection cache).
    pub run: &'a RunDir,
    /// The map to track in (`--map`), when there is one.
    pub base: Option<LoadedBase>,
}

/// A loaded map to track the sequence in.
pub struct LoadedBase {
    /// The map.
    pub map: crate::map::Map,
    /// Localisation only.
    pub frozen: bool,
}

/// Tracks the frames of `inputs.sequence` (up to `options.max_frames`) with its
/// detector on the keyframes.
pub fn tracking_pass(
    inputs: TrackingInputs,
    observers: &mut [&mut dyn FrameObserver],
) -> Result<TrackingPass, RunError> {
    let (sequence, setup, options) = (inputs.sequence, inputs.setup, inputs.options);
    let execution = Execution::of(options.deterministic);
    let mut placed = inputs.base.is_none();
    let mut records = FrameRecords::spilling_into(inputs.run.root())?;
    let mut lines = FrameLines::spilling_into(inputs.run.root())?;
    let mut system = start_system(setup, StartInputs::of(inputs, execution));
    let total = options.frames_of(sequence.len());
    let mut loader = Loader::new(sequence, setup, options, execution);
    let mut offset_search = OffsetSearch::of(setup);
    let mut stop = None;
    let logged = options.rerun.as_ref();
    for index in 0..total {
        if crate::interrupt::requested() {
            stop = Some(StopReason::Interrupted { frame: index });
            break;
        }
        let (frame, picture, started, depth) = match loader.next(index, &system) {
            Ok(ready) => ready,
            Err(message) => {
                stop = Some(StopReason::BadFrame(message));
                break;
            }
        };
        let extraction_ms = started.elapsed().as_secs_f64() * 1e3;
        let timestamp = frame.timestamp;
        // The detector takes the picture; a copy only for the debug pictures and the
        // Rerun recording.
        let shown = (options.debug_frames.is_some() || logged.is_some()).then(|| picture.clone());
        let (TrackedFrame { stats, record }, tracking_ms) = system.track(frame, picture, started);
        let recent_map = (logged.is_some() && stats.keyframe)
            .then(|| system.recent_map_points(RECENT_KEYFRAMES));
        let view = FrameView {
            index,
            timestamp,
            stats: &stats,
            record: &record,
            frame: system.tracked_frame(index),
            dop: system.dop(),
            picture: shown.as_ref(),
            depth: depth.as_ref(),
            recent_map: recent_map.as_ref(),
        };
        if let Err(e) = observers.iter_mut().try_for_each(|o| o.on_frame(&view)) {
            stop = Some(StopReason::Observer(e.to_string()));
            break;
        }
        system.receive_detections();
        let applied = system.take_applied();
        observers.iter_mut().for_each(|o| o.on_applied(&applied));
        placed |= stats.state == TrackingState::Ok;
        let line = frame_line(stats, extraction_ms, tracking_ms, observers);
        let search = offset_search.as_mut();
        let kept = lines
            .push(line)
            .and_then(|()| keep_record(&mut records, record, search, &mut system, setup, index));
        if let Err(e) = kept.map(|taken| loader.offset += taken) {
            stop = Some(StopReason::Records(e.to_string()));
            break;
        }
        if let Some(reason) = not_placed(placed, index, &setup.config) {
            stop = Some(reason);
            break;
        }
    }
    let log = FrameLog {
        lines,
        records,
        stop,
    };
    let mut pass = end_pass(system, setup, log, observers);
    pass.offset = offset_search.map(OffsetSearch::finish);
    Ok(pass)
}

/// A frame's report line from its tracking `stats` and its extraction and tracking
/// times (milliseconds), with what the observers found of it.
fn frame_line(
    stats: crate::tracking::FrameStats,
    extraction_ms: f64,
    tracking_ms: f64,
    observers: &mut [&mut dyn FrameObserver],
) -> FrameLine {
    let mut line = FrameLine {
        tracking: stats,
        extraction_ms,
        tracking_ms,
        truth: None,
    };
    observers.iter_mut().for_each(|o| o.annotate(&mut line));
    line
}

/// Keeps frame `index`'s record (its observations to the spill file); in a stereo
/// run's first frames, the rig's offset search looks at the map after it. Returns the
/// offset to add to every later frame's matches (0 when none was taken out).
fn keep_record(
    records: &mut FrameRecords,
    record: FrameRecord,
    search: Option<&mut OffsetSearch>,
    system: &mut System,
    setup: &Setup,
    index: usize,
) -> Result<f64, crate::io::IoError> {
    records.push(record)?;
    match search {
        Some(search) => Ok(search
            .after_frame(system, records, setup, index)?
            .unwrap_or(0.0)),
        None => Ok(0.0),
    }
}

/// What the frame loop wrote down: a line and a record per frame, and why it stopped
/// early, if it did.
struct FrameLog {
    lines: FrameLines,
    records: FrameRecords,
    stop: Option<StopReason>,
}

/// The end of a pass: the observers finish, a map that never started is the reason
/// to stop, and the system hands its map over (the detections that came back at its
/// end shown to the observers).
fn end_pass(
    system: System,
    setup: &Setup,
    log: FrameLog,
    observers: &mut [&mut dyn FrameObserver],
) -> TrackingPass {
    let FrameLog {
        lines,
        records,
        mut stop,
    } = log;
    observers.iter_mut().for_each(|o| o.finish());
    if stop.is_none() && system.state() == TrackingState::NotInitialised {
        let why = never_started(&lines, &setup.config, setup.sensor);
        stop = Some(StopReason::NeverStarted(why));
    }
    let tracked = system.finish();
    observers
        .iter_mut()
        .for_each(|o| o.on_applied(&tracked.applied));
    TrackingPass {
        tracked,
        lines,
        records,
        stop,
        offset: None,
    }
}

/// With a loaded map, the reason to stop after frame `index` when no frame up to it
/// was `placed` and `[tracking] place_within_frames` have passed.
fn not_placed(placed: bool, index: usize, config: &Config) -> Option<StopReason> {
    (!placed && index + 1 >= config.tracking.place_within_frames).then(|| {
        StopReason::NotPlaced(format!(
            "none of the first {} frames was placed in the loaded map (--map) by relocalisation: is this a recording of the same place? ([tracking] place_within_frames)",
            index + 1
        ))
    })
}

/// What the system of a run starts with besides its set-up.
struct StartInputs<'a> {
    detector: Option<Box<dyn Detector>>,
    run: &'a RunDir,
    execution: Execution,
    base: Option<LoadedBase>,
    /// The sequence's name: the map's recording.
    recording: &'a str,
}

impl<'a> StartInputs<'a> {
    fn of(inputs: TrackingInputs<'a>, execution: Execution) -> Self {
        Self {
            detector: inputs.detector,
            run: inputs.run,
            execution,
            base: inputs.base,
            recording: inputs.sequence.name(),
        }
    }
}

/// The system of the run, with its helpers (the vocabulary and the detector), on a
/// new map or the loaded one; the calling thread (tracking's) joins its own pool when
/// no local mapping runs beside it.
fn start_system(setup: &Setup, inputs: StartInputs) -> System {
    let helpers = Helpers {
        vocabulary: setup.vocabulary.clone(),
        detector: inputs
            .detector
            .map(|d| (d, setup.config.detector.latency())),
    };
    let (mut map, placing) = match inputs.base {
        Some(base) => (
            base.map,
            Some(crate::system::Placing {
                frozen: base.frozen,
            }),
        ),
        None => (crate::map::Map::default(), None),
    };
    map.begin_recording(inputs.recording);
    // Without local mapping beside it (a frozen map, or inline), tracking has the cores
    // to itself and works in its own pool (`join_own_pool`: docs/design.md, "Tracking's
    // own thread pool"); beside local mapping it made stereo tracking slower.
    let frozen = placing.as_ref().is_some_and(|placing| placing.frozen);
    if frozen || matches!(inputs.execution, Execution::Inline) {
        crate::threads::join_own_pool();
    }
    let system = setup.system(inputs.execution, inputs.run.detections());
    System::start_in(&system, helpers, map, placing)
}

/// Where the pass's frames come from, and how each is made ready.
struct Loader<'a> {
    sequence: &'a dyn Sequence,
    setup: &'a Setup,
    /// Whether each frame's depth is kept (for the Rerun recording).
    keep_depth: bool,
    pacer: Pacer,
    depth_check: DepthCheck,
    /// Pixels added to every stereo disparity: the rig's offset, as known so far.
    offset: f64,
}

impl<'a> Loader<'a> {
    /// The loader of `sequence` for a pass with `options`, its helpers run as
    /// `execution` says (inline: no pacing).
    fn new(
        sequence: &'a dyn Sequence,
        setup: &'a Setup,
        options: &RunOptions,
        execution: Execution,
    ) -> Self {
        Self {
            sequence,
            setup,
            keep_depth: options
                .rerun
                .as_ref()
                .is_some_and(|log| log.config.rerun_depth),
            pacer: Pacer::new(match execution {
                Execution::Inline => Pace::Free,
                Execution::Threads => options.pace,
            }),
            depth_check: DepthCheck::default(),
            offset: setup.disparity_offset_px(),
        }
    }

    /// Frame `index` loaded, paced, checked and made ready for tracking, with the time
    /// its extraction started and (when `keep_depth`) its depth; an error says why the
    /// pass must stop.
    fn next(
        &mut self,
        index: usize,
        system: &System,
    ) -> Result<(Frame, Picture, Instant, Option<DepthImage>), String> {
        let setup = self.setup;
        let loaded = self
            .sequence
            .load(index)
            .map_err(|e| format!("frame {index}: {e}"))?;
        self.pacer.wait_for(loaded.timestamp);
        let size = match &loaded.images {
            FrameImages::Rgbd { rgb, .. } => rgb.dimensions(),
            FrameImages::Stereo { left, .. } => left.dimensions(),
        };
        let calibration = &setup.calibration;
        let expected = (calibration.camera.width, calibration.camera.height);
        if size != expected {
            return Err(format!(
                "frame {index}: the image is {}x{} but the first frame is {}x{}: every frame of a sequence must have one size",
                size.0, size.1, expected.0, expected.1
            ));
        }
        self.ready(index, loaded, system)
    }

    /// A loaded frame made ready for tracking (ORB, depth or stereo matching).
    fn ready(
        &mut self,
        index: usize,
        loaded: crate::io::sequence::Frame,
        system: &System,
    ) -> Result<(Frame, Picture, Instant, Option<DepthImage>), String> {
        let setup = self.setup;
        let calibration = &setup.calibration;
        let budgeted = setup
            .extractor
            .with_budget(system.feature_budget(setup.config.orb.n_features));
        Ok(match loaded.images {
            FrameImages::Rgbd { rgb, depth } => {
                self.depth_check
                    .check(index, &depth, system.state(), calibration)?;
                let started = Instant::now();
                let grey = crate::io::image_files::grey_from_rgb(&rgb);
                let frame = Frame::from_rgbd(
                    index,
                    loaded.timestamp,
                    &grey,
                    &depth,
                    &budgeted,
                    &setup.camera,
                    &calibration.camera,
                );
                (
                    frame,
                    Picture::Colour(rgb),
                    started,
                    self.keep_depth.then_some(depth),
                )
            }
            FrameImages::Stereo { left, right } => {
                let started = Instant::now();
                let frame = Frame::from_stereo(
                    index,
                    loaded.timestamp,
                    StereoPair {
                        left: &left,
                        right: &right,
                    },
                    &budgeted,
                    &setup.camera,
                    DepthSettings {
                        bearing_depth: setup.bearing_depth,
                        disparity_offset: self.offset,
                    },
                );
                (frame, Picture::Grey(left), started, None)
            }
        })
    }
}

/// Why tracking never started, from what the frames showed: no keypoints (blank
/// images), else too few with depth (the depth scale, the depth images, or for stereo
/// a pair whose left and right are swapped).
fn never_started(lines: &FrameLines, config: &Config, sensor: SensorKind) -> String {
    let mut keypoints: Vec<f64> = lines
        .iter()
        .map_while(Result::ok)
        .map(|l| l.tracking.keypoints as f64)
        .collect();
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
