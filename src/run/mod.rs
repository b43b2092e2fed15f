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

pub mod dense_pass;
pub mod error;
pub mod global_pass;
pub mod observers;
pub mod options;
pub mod outputs;
pub mod report;
pub mod rerun_log;
pub mod rig_offset;
pub mod setup;
pub mod tracking_pass;
pub mod truth;

use std::path::Path;

pub use dense_pass::{dense_pass, DenseSetup};
pub use error::{RunError, StopReason};
pub use options::RunOptions;
pub use report::{FrameLine, RunReport, RunTotals, SegmentSpan};
pub use setup::{
    check_sequence_folder, content_hash, detection_source, effective_mode, first_frame_hash,
    open_sequence, resolve_calibration, RunSetup, Setup,
};

use crate::dop::Mode;
use crate::io::run_dir::RunDir;
use crate::io::sequence::Sequence;
use crate::view::{At, Entry, Logger, Target};
use global_pass::global_pass;
use observers::{DebugFrames, DynamicKeypoints, FrameObserver, Progress};
use outputs::Computed;
use rerun_log::RerunLog;
use tracking_pass::{open_detector, tracking_pass, TrackingPass};
use truth::TruthScorer;

/// Runs the passes over `sequence` and writes their outputs into `out`: tracking, the
/// global pass (on a complete run), the outputs, then (when `options.dense`) the dense
/// map, also after tracking stopped early. A run that stopped early is an error after
/// everything was written.
pub fn run_sequence(
    sequence: &dyn Sequence,
    config: &crate::config::Config,
    out: &Path,
    options: &RunOptions,
) -> Result<RunReport, RunError> {
    let mut setup = Setup::resolve(sequence, config)?;
    let _lock = outputs::prepare(out, options)?;
    let run = RunDir::new(out);
    // Loaded before any tracking (the rig offset's pass included) and only once.
    let detector = open_detector(&setup, options)?;
    if let Some(found) = rig_offset::estimate(sequence, &setup, options, &run)? {
        setup.disparity_offset = Some(found);
    }
    let own_log = open_run_recording(config, &run, options)?;
    let options = &RunOptions {
        rerun: options
            .rerun
            .clone()
            .or_else(|| own_log.as_ref().map(|l| l.handle())),
        ..options.clone()
    };
    if let Some(log) = &options.rerun {
        log_pinhole(log, &setup.calibration.camera);
    }
    let mut watch = Watchers::new(sequence, options);
    let mut pass = tracking_pass(
        sequence,
        (&setup, detector),
        options,
        &run,
        &mut watch.observers(),
    )?;
    let global = global_pass(&mut pass, &setup, &run)?;
    let stop = pass.stop.clone();
    let mut report = outputs::write(
        &run,
        watch.computed(sequence, &setup, options, pass, global, &run)?,
    )?;
    let dense_due = stop.is_some() || report.totals.tracked > 0;
    if options.dense && dense_due && !crate::interrupt::requested() {
        let dense = dense_pass(
            sequence,
            &DenseSetup::of_run(&setup).with_disparity_offset(report.disparity_offset_px()),
            (out, out),
            setup.mode,
            options.sequence_dir.as_deref(),
            options.progress,
        );
        // After a tracking failure the dense map of what was tracked is a bonus: the
        // tracking error is the one to report.
        match (&stop, dense) {
            (None, Ok(dense)) => report.dense = Some(dense),
            (None, Err(e)) => return Err(e),
            (Some(_), _) => {}
        }
    }
    if let Some(log) = &options.rerun {
        crate::view::results::log_results(log, &run, "", sequence.ground_truth())?;
    }
    report.recording = own_log;
    match stop {
        Some(reason) => Err(RunError::Stopped {
            reason,
            done: report.frames.len(),
            out: out.to_path_buf(),
        }),
        None => Ok(report),
    }
}

/// `run.rrd` in the run folder when `[output] rerun` asks for it and no recording was
/// handed in; opened before any work (a build without the feature says so here). The
/// run hands it back open in [`RunReport::recording`].
fn open_run_recording(
    config: &crate::config::Config,
    run: &RunDir,
    options: &RunOptions,
) -> Result<Option<Logger>, RunError> {
    if !config.output.rerun || options.rerun.is_some() {
        return Ok(None);
    }
    let target = Target::File(run.rerun());
    Logger::open(target, &config.output, "dopslam")
        .map(Some)
        .map_err(|e| RunError::Input(format!("[output] rerun: {e}")))
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

/// Closes a recording and says what it held (images dropped when logging fell
/// behind are always said).
pub fn finish_recording(logger: Logger, progress: bool) -> Result<(), RunError> {
    let target = logger.target.clone();
    let summary = logger.finish()?;
    if let Some(warning) = summary.warning(&target) {
        eprintln!("warning: {warning}");
    } else if progress {
        eprintln!(
            "Rerun recording: {} entries to {}",
            summary.logged,
            target.name()
        );
    }
    Ok(())
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
    fn new(sequence: &dyn Sequence, options: &RunOptions) -> Self {
        let total = options
            .max_frames
            .map_or(sequence.len(), |m| m.min(sequence.len()));
        Self {
            progress: Progress::new(total, options.progress),
            debug: options.debug_frames.clone().map(|dir| DebugFrames { dir }),
            rerun: options.rerun.clone().map(RerunLog::new),
            keypoints: DynamicKeypoints::default(),
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
        sequence: &'a dyn Sequence,
        setup: &Setup,
        options: &'a RunOptions,
        pass: TrackingPass,
        global: Option<(crate::global::GlobalReport, crate::io::Trajectory)>,
        run: &RunDir,
    ) -> Result<Computed<'a>, RunError> {
        let TrackingPass {
            tracked,
            mut lines,
            records,
            stop,
        } = pass;
        for (line, truth) in lines.iter_mut().zip(self.truth.per_frame) {
            line.truth = truth;
        }
        let mut detection = tracked.detection;
        detection.classification = self.truth.classification;
        detection.person_recall = self.truth.person_recall;
        // The set of outputs starts here: a second Ctrl-C from now on waits for all of it.
        let writing = crate::interrupt::Writing::start();
        if setup.mode == Mode::Dop {
            outputs::write_dynamic_keypoints(run, &self.keypoints.frames)?;
        }
        let computed = Computed {
            writing,
            sequence,
            sequence_path: options.sequence_dir.as_deref(),
            setup: RunSetup::new(sequence, setup),
            mode: setup.mode,
            map: tracked.map,
            mapping: tracked.mapping,
            detection,
            lines,
            records,
            stopped: stop,
            global,
        };
        Ok(computed)
    }
}
