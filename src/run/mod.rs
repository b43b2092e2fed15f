//! The offline tool's spine: a run is set-up, tracking pass, global pass, outputs,
//! dense pass, each a call with typed data in and out ([`run_sequence`]).
//!
//! - [`setup`]: everything resolved once, before any output is touched;
//! - [`tracking_pass`]: the frame loop over the online [`crate::system::System`];
//! - [`global_pass`]: loops, essential graph, full BA on the map handed over;
//! - [`outputs`]: trajectory, keyframes, sparse map, segments, `report.json`, named by
//!   [`crate::io::run_dir::RunDir`];
//! - [`dense_pass`]: the dense map of the static scene from the run folder.
//!
//! What watches the frames without taking part (progress, debug pictures, the dynamic
//! keypoints for the dense masks, the ground-truth scorer) is an observer
//! ([`observers`], [`truth`]).

pub mod base_map;
pub mod dense_pass;
pub mod error;
pub mod global_pass;
pub mod observers;
pub mod options;
pub mod outputs;
pub mod plan;
pub mod rerun_log;
pub mod rig_offset;
pub mod setup;
pub mod tracking_pass;
pub mod truth;

use std::borrow::Cow;
use std::path::Path;

pub use crate::records::{FrameLine, RunReport, RunTotals, SegmentSpan};
pub use base_map::base_map;
pub use dense_pass::{dense_pass, merge_pass, DensePass, DenseSetup};
pub use error::{RunError, StopReason};
pub use options::{BaseMap, RunOptions};
pub use plan::{finish_recording, RunPlan};
pub use setup::{
    check_sequence_folder, content_hash, detection_source, effective_mode, first_frame_hash,
    open_sequence, resolve_calibration, Setup,
};

use crate::dop::Mode;
use crate::io::sequence::Sequence;
use crate::view::{At, Entry};
use global_pass::global_pass;
use observers::{DebugFrames, DynamicKeypoints, FrameObserver, Progress};
use outputs::Computed;
use rerun_log::RerunLog;
use tracking_pass::{open_detector, tracking_pass, LoadedBase, TrackingInputs, TrackingPass};
use truth::TruthScorer;

/// Runs the passes over `sequence` and writes their outputs into `out`: the plan
/// resolved ([`RunPlan::resolve`]), executed ([`execute`]) and its own recording
/// closed. A run that stopped early is an error after everything was written.
pub fn run_sequence(
    sequence: &dyn Sequence,
    config: &crate::config::Config,
    out: &Path,
    options: &RunOptions,
) -> Result<RunReport, RunError> {
    let plan = RunPlan::resolve(sequence, config, out, options.clone())?;
    let report = execute(&plan);
    // On an error the recording closes too (what was logged stays readable), and the
    // run's error is the one to report.
    let finished = plan.finish();
    let report = report?;
    finished?;
    Ok(report)
}

/// Runs a plan: tracking, the global pass (on a complete run), the outputs, then (when
/// the plan has a dense set-up) the dense map, also after tracking stopped early. A
/// run that stopped early is an error after everything was written.
pub fn execute(plan: &RunPlan) -> Result<RunReport, RunError> {
    let mut clock = Stopwatch::start();
    // Loaded before any tracking, and only once.
    let detector = open_detector(&plan.setup, &plan.options)?;
    let (base, loaded) = match &plan.options.base_map {
        Some(base) => {
            let (map, loaded) = base_map::load(base)?;
            clock.lap("map");
            let frozen = base.frozen;
            (Some(LoadedBase { map, frozen }), Some(loaded))
        }
        None => (None, None),
    };
    let setup = Cow::Borrowed(&plan.setup);
    if let Some(log) = plan.log() {
        log_pinhole(log, &setup.calibration.camera);
    }
    let mut watch = Watchers::new(plan);
    let inputs = TrackingInputs {
        sequence: plan.sequence,
        setup: &setup,
        detector,
        options: &plan.options,
        run: &plan.run,
        base,
    };
    let mut pass = tracking_pass(inputs, &mut watch.observers())?;
    clock.lap("tracking");
    // The rig's offset the tracking pass found is the run's from here on.
    let setup = match pass.offset.take() {
        Some(found) => Cow::Owned(setup.with_disparity_offset(found)),
        None => setup,
    };
    let global = global_pass(&mut pass, &setup, &plan.run)?;
    if global.is_some() {
        clock.lap("global");
    }
    let stop = pass.stop.clone();
    let mut computed = watch.computed(plan, &setup, pass, global)?;
    computed.loaded = loaded;
    let mut report = outputs::write(&plan.run, computed)?;
    clock.lap("outputs");
    let dense_due = stop.is_some() || report.totals.tracked > 0;
    let dense = match dense_due && !crate::interrupt::requested() {
        true => dense_of(plan, setup.mode, &report),
        false => None,
    };
    if let Some(dense) = dense {
        clock.lap("dense");
        // After a tracking failure the dense map of what was tracked is a bonus: the
        // tracking error is the one to report.
        match (&stop, dense) {
            (None, Ok(dense)) => report.dense = Some(dense),
            (None, Err(e)) => return Err(e),
            (Some(_), _) => {}
        }
    }
    let frames = report.frames.len();
    let recording = frames
        .checked_sub(1)
        .and_then(|last| crate::io::sequence::duration_of(plan.sequence, 0, last));
    report.times = Some(clock.times(recording));
    outputs::write_report(&plan.run, &report)?;
    if let Some(log) = plan.log() {
        crate::view::results::log_results(log, &plan.run, "", plan.sequence.ground_truth())?;
    }
    match stop {
        Some(reason) => Err(RunError::Stopped {
            reason,
            done: frames,
            out: plan.run.root().to_path_buf(),
        }),
        None => Ok(report),
    }
}

/// The dense pass of a run that wrote `report`, when the plan has one, with the
/// run's masking `mode`.
fn dense_of(
    plan: &RunPlan,
    mode: Mode,
    report: &RunReport,
) -> Option<Result<crate::dense::DenseReport, RunError>> {
    let dense = plan
        .dense
        .clone()?
        .with_disparity_offset(report.disparity_offset_px());
    let pass = DensePass {
        sequence: plan.sequence,
        setup: &dense,
        run_dir: plan.run.root(),
        out_dir: plan.run.root(),
        masking: mode,
        sequence_dir: plan.options.sequence_dir.as_deref(),
        progress: plan.options.progress,
    };
    Some(dense_pass(&pass))
}

/// The wall time and peak memory of a run's stages, one lap each.
struct Stopwatch {
    start: std::time::Instant,
    last: std::time::Instant,
    laps: Vec<crate::records::Lap>,
}

impl Stopwatch {
    fn start() -> Self {
        crate::memory::start_sampling();
        crate::memory::stage_peak_mib();
        let now = std::time::Instant::now();
        Self {
            start: now,
            last: now,
            laps: Vec::new(),
        }
    }

    /// The time since the last lap (or the start) as stage `name`, with the peak
    /// memory since then.
    fn lap(&mut self, name: &'static str) {
        let now = std::time::Instant::now();
        self.laps.push(crate::records::Lap {
            stage: name,
            seconds: (now - self.last).as_secs_f64(),
            peak_memory_mib: crate::memory::stage_peak_mib(),
        });
        self.last = now;
    }

    /// The laps and the whole, against a recording of `recording_s` seconds.
    fn times(&self, recording_s: Option<f64>) -> crate::records::RunTimes {
        let total = self.start.elapsed().as_secs_f64();
        let peak = crate::memory::peak_resident_mib();
        crate::records::RunTimes::new(recording_s, &self.laps, total, peak)
    }
}

/// The camera's pinhole, logged once.
pub fn log_pinhole(log: &crate::view::LogHandle, camera: &crate::geometry::camera::PinholeCamera) {
    let entry = Entry::Pinhole {
        fx: camera.fx,
        fy: camera.fy,
        cx: camera.cx,
        cy: camera.cy,
        width: camera.width,
        height: camera.height,
    };
    log.log("", At::Always, entry);
}

/// The observers of a run's tracking pass.
struct Watchers {
    progress: Progress,
    debug: Option<DebugFrames>,
    rerun: Option<RerunLog>,
    keypoints: DynamicKeypoints,
    truth: TruthScorer,
}

impl Watchers {
    fn new(plan: &RunPlan) -> Self {
        let options = &plan.options;
        let total = options.frames_of(plan.sequence.len());
        Self {
            progress: Progress::new(total, options.progress),
            debug: options.debug_frames.clone().map(|dir| DebugFrames { dir }),
            rerun: options.rerun.clone().map(RerunLog::new),
            keypoints: DynamicKeypoints::new(plan.run.root().to_path_buf()),
            truth: TruthScorer::new(options.sequence_dir.clone()),
        }
    }

    fn observers(&mut self) -> Vec<&mut dyn FrameObserver> {
        let mut list: Vec<&mut dyn FrameObserver> = Vec::new();
        if let Some(debug) = self.debug.as_mut() {
            list.push(debug);
        }
        if let Some(rerun) = self.rerun.as_mut() {
            list.push(rerun);
        }
        list.push(&mut self.keypoints);
        list.push(&mut self.truth);
        list.push(&mut self.progress);
        list
    }

    /// What the passes computed, with what the observers saw; the dynamic keypoints
    /// (DOP) are written here.
    fn computed<'a>(
        self,
        plan: &'a RunPlan,
        setup: &Setup,
        pass: TrackingPass,
        global: Option<(crate::global::GlobalReport, crate::io::Trajectory)>,
    ) -> Result<Computed<'a>, RunError> {
        let TrackingPass {
            tracked,
            lines,
            records,
            stop,
            offset: _,
        } = pass;
        let mut detection = tracked.detection;
        detection.classification = self.truth.classification;
        detection.person_recall = self.truth.person_recall;
        // The set of outputs starts here: a second Ctrl-C from now on waits for all of it.
        let writing = crate::interrupt::Writing::start();
        if setup.mode == Mode::Dop {
            outputs::write_dynamic_keypoints(&plan.run, &self.keypoints)?;
        }
        let computed = Computed {
            writing,
            sequence: plan.sequence,
            sequence_path: plan.options.sequence_dir.as_deref(),
            setup: crate::records::RunSetup::new(plan.sequence, setup),
            mode: setup.mode,
            map: tracked.map,
            mapping: tracked.mapping,
            detection,
            lines,
            records,
            stopped: stop,
            global,
            map_header: (setup.config.output.slam_map
                && !plan.options.base_map.as_ref().is_some_and(|b| b.frozen))
            .then(|| base_map::header_of(setup, 0.0)),
            loaded: None,
        };
        Ok(computed)
    }
}
