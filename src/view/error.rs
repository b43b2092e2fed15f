//! Why a Rerun recording could not be made, written or replayed.

use std::path::PathBuf;

use thiserror::Error;

use crate::io::IoError;

/// Why a Rerun recording could not be made, written or replayed.
#[derive(Debug, Error)]
pub enum ViewError {
    /// A run file could not be read, or the recording's file or folder written.
    #[error(transparent)]
    Io(#[from] IoError),
    /// A run's cached detections could not be read.
    #[error(transparent)]
    Detections(#[from] crate::detect::DetectError),
    /// The recording would write over a file.
    #[error("{} exists: a recording is never written over; remove it or name another file", .0.display())]
    Exists(PathBuf),
    /// The recording's folder could not be made.
    #[error("cannot write {}: its folder {} cannot be made: {error}", path.display(), folder.display())]
    Folder {
        /// The recording's file.
        path: PathBuf,
        /// Its folder.
        folder: PathBuf,
        /// Why the folder cannot be made.
        error: std::io::Error,
    },
    /// The recording's file could not be created.
    #[error("cannot write {}: {error}", path.display())]
    Create {
        /// The recording's file.
        path: PathBuf,
        /// The SDK's message.
        error: String,
    },
    /// This build has no Rerun ([`super::MISSING_FEATURE`]).
    #[error("{}", super::MISSING_FEATURE)]
    NotBuilt,
    /// The viewer at `--rerun-connect` could not be reached.
    #[error("--rerun-connect {address}: {message}")]
    Connect {
        /// The viewer's address.
        address: String,
        /// Why it could not be reached.
        message: String,
    },
    /// The Rerun SDK failed to `stage` ("log to", "finish") the recording.
    #[error("cannot {stage} the Rerun recording: {message}")]
    Sdk {
        /// What the SDK was doing.
        stage: &'static str,
        /// The SDK's message.
        message: String,
    },
    /// The logging thread could not start, or panicked.
    #[error("the Rerun logging thread {0}")]
    Thread(String),
    /// [`super::log::Logger::finish`] after the recording was closed.
    #[error("the Rerun recording was closed already")]
    Closed,
    /// Frame `index` of the sequence could not be read for its picture.
    #[error("frame {index}: {source}")]
    Frame {
        /// The frame's index.
        index: usize,
        /// Why it could not be read.
        source: IoError,
    },
}
