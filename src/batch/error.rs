//! How a batch, or one of its runs, fails. A run's failure is recorded in its
//! `run.json` as the error's sentence; a batch's stops `dopslam batch`.

use std::path::PathBuf;

use thiserror::Error;

use super::manifest::ManifestError;
use crate::eval::plot::PlotError;
use crate::io::IoError;

/// How a batch, or one of its runs, fails.
#[derive(Debug, Error)]
pub enum BatchError {
    /// The manifest cannot be read or planned (boxed: the largest of these errors).
    #[error(transparent)]
    Manifest(Box<ManifestError>),
    /// A file the batch reads or writes (a run's config, `run.json`, the tables).
    #[error(transparent)]
    Io(#[from] IoError),
    /// A folder or file that could not be created, cleared, moved or locked.
    #[error("cannot {action} {}: {source}", path.display())]
    File {
        /// What was done: `create`, `clear`, `move`, `lock`, ….
        action: &'static str,
        /// The folder or file.
        path: PathBuf,
        /// Why it failed.
        source: std::io::Error,
    },
    /// The output folder lies inside one of the batch's recorded sequences.
    #[error(
        "the output folder {} is inside the input sequence {} ({sequence}): choose another --out (a batch never writes into its inputs)",
        out.display(),
        input.display()
    )]
    OutputInInput {
        /// The output folder.
        out: PathBuf,
        /// The input sequence it lies in.
        input: PathBuf,
        /// The sequence's name.
        sequence: String,
    },
    /// The output folder lies inside a run folder whose map a sequence loads.
    #[error(
        "the output folder {} is inside {}, the run whose map {sequence} loads: choose another --out (a batch never writes into its inputs)",
        out.display(),
        map.display()
    )]
    OutputInMap {
        /// The output folder.
        out: PathBuf,
        /// The run folder.
        map: PathBuf,
        /// The sequence that loads it.
        sequence: String,
    },
    /// `dopslam merge` of a group's runs failed (its own error line, or where its log is).
    #[error("{0}")]
    MergeFailed(String),
    /// Another batch holds the output folder's lock.
    #[error("another dopslam batch is writing into {}: wait for it to end or choose another --out", .0.display())]
    Busy(PathBuf),
    /// The same shard already runs on the output folder.
    #[error("shard {shard} of the batch in {} is already running: a shard runs once at a time (wait for it, or cancel it)", out.display())]
    ShardBusy {
        /// The output folder.
        out: PathBuf,
        /// The shard, `K/N`.
        shard: String,
    },
    /// `--collect` with another manifest than the one the batch ran with.
    #[error(
        "{} is the batch of another manifest (its copy {} differs from {}): collect with that manifest, or run this one into another --out",
        out.display(),
        copy.display(),
        manifest.display()
    )]
    OtherManifest {
        /// The output folder.
        out: PathBuf,
        /// The manifest's copy in it.
        copy: PathBuf,
        /// The manifest given.
        manifest: PathBuf,
    },
    /// A run's `config.toml` could not be written as TOML.
    #[error("config: {0}")]
    ConfigText(#[from] toml::ser::Error),
    /// `dopslam run` could not be started or watched.
    #[error("cannot {action} {}: {source}", program.display())]
    Process {
        /// `start` or `wait for`.
        action: &'static str,
        /// The program.
        program: PathBuf,
        /// Why it failed.
        source: std::io::Error,
    },
    /// The run ended with an error: its own error line, or its exit status.
    #[error("{0}")]
    RunFailed(String),
    /// The evaluation of a finished run against the ground truth.
    #[error("evaluation: {0}")]
    Evaluation(#[from] crate::eval::report::EvalError),
    /// A figure of the report.
    #[error(transparent)]
    Plot(#[from] PlotError),
    /// A synthetic sequence could not be generated.
    #[error(transparent)]
    Synth(#[from] crate::synth::SynthError),
    /// A Slurm option or `sbatch` itself.
    #[error(transparent)]
    Slurm(#[from] super::slurm::SlurmError),
}

impl From<ManifestError> for BatchError {
    fn from(error: ManifestError) -> Self {
        Self::Manifest(Box::new(error))
    }
}

impl BatchError {
    /// The error of `action` (`"create"`, `"move"`, …) on `path`, for `map_err`.
    pub fn file(
        action: &'static str,
        path: impl Into<PathBuf>,
    ) -> impl FnOnce(std::io::Error) -> Self {
        let path = path.into();
        move |source| Self::File {
            action,
            path,
            source,
        }
    }
}
