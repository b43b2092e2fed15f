//! How a run fails.

use std::path::PathBuf;

use thiserror::Error;

use crate::io::IoError;

#[derive(Debug, Error)]
pub enum RunError {
    #[error(transparent)]
    Io(#[from] IoError),
    /// Bad input found before any work (a missing model, an empty sequence, no
    /// calibration).
    #[error("{0}")]
    Input(String),
    /// The run stopped before the last frame (a frame that failed to load, tracking
    /// that never started, an interruption); what was done is written.
    #[error("{message} (outputs of the {done} frames done are in {out})")]
    Interrupted {
        message: String,
        done: usize,
        out: PathBuf,
    },
}
