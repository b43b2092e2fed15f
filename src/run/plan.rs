//! The plan of a run, resolved once before any work and not changed after: the
//! sequence and its set-up (sensor, calibration, mode, detection source, vocabulary),
//! the run folder (checked, locked, earlier outputs moved aside), what the run is
//! asked to do ([`RunOptions`]), the dense pass's set-up, and the Rerun recording the
//! run logs into, as an observer registered on the plan.

use std::path::Path;

use super::dense_pass::DenseSetup;
use super::error::RunError;
use super::options::RunOptions;
use super::outputs;
use super::setup::Setup;
use crate::config::Config;
use crate::io::output::DirLock;
use crate::io::run_dir::RunDir;
use crate::io::sequence::Sequence;
use crate::view::{LogHandle, Logger, Target};

/// A run, resolved (see the module doc); [`super::execute`] runs it.
pub struct RunPlan<'a> {
    /// The sequence the run reads.
    pub sequence: &'a dyn Sequence,
    /// The config for the sequence's sensor, the calibration, the mode, the detection
    /// source and the vocabulary.
    pub setup: Setup,
    /// The run folder: checked writable, locked while the plan lives.
    pub run: RunDir,
    /// What the run is asked to do besides its config; `options.rerun` is the
    /// recording the run logs into (handed in, or the run's own `run.rrd`).
    pub options: RunOptions,
    /// The dense pass's set-up, when the dense pass runs.
    pub dense: Option<DenseSetup>,
    /// The run's own Rerun recording (`[output] rerun` and none handed in).
    own_recording: Option<Logger>,
    _lock: DirLock,
}

impl<'a> RunPlan<'a> {
    /// Resolves a run of `config` over `sequence` into `out`: every error about the
    /// inputs, the settings, missing detector files, the vocabulary or the outputs
    /// comes here, before any work (the detector loads when [`super::execute`] starts,
    /// before the first frame).
    pub fn resolve(
        sequence: &'a dyn Sequence,
        config: &Config,
        out: &Path,
        mut options: RunOptions,
    ) -> Result<Self, RunError> {
        let mut setup = Setup::resolve(sequence, config)?;
        if let Some(base) = &options.base_map {
            let header = super::base_map::check(&setup, base)?;
            setup = super::base_map::adjust(setup, &header, base.frozen);
        }
        let lock = outputs::prepare(out, &options)?;
        let run = RunDir::new(out);
        let own_recording = match options.rerun {
            Some(_) => None,
            None => open_run_recording(&setup.config, &run)?,
        };
        if let Some(own) = &own_recording {
            options.rerun = Some(own.handle());
        }
        let dense = options.dense.then(|| DenseSetup::of_run(&setup));
        Ok(Self {
            sequence,
            setup,
            run,
            options,
            dense,
            own_recording,
            _lock: lock,
        })
    }

    /// The recording the run logs into, when there is one.
    pub fn log(&self) -> Option<&LogHandle> {
        self.options.rerun.as_ref()
    }

    /// Ends the plan: closes the run's own recording, saying what it held (a handed-in
    /// recording is its owner's to close).
    pub fn finish(self) -> Result<(), RunError> {
        match self.own_recording {
            Some(logger) => finish_recording(logger, self.options.progress),
            None => Ok(()),
        }
    }
}

/// `run.rrd` in the run folder when `[output] rerun` asks for it; opened before any
/// work (a build without the feature says so here).
fn open_run_recording(config: &Config, run: &RunDir) -> Result<Option<Logger>, RunError> {
    if !config.output.rerun {
        return Ok(None);
    }
    Logger::open(Target::File(run.rerun()), &config.output, "dopslam")
        .map(Some)
        .map_err(|e| RunError::Input(format!("[output] rerun: {e}")))
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
