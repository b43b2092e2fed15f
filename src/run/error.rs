//! How a run fails.

use std::path::PathBuf;

use thiserror::Error;

use crate::io::IoError;

/// How a run fails; the message names the file or key and what is wrong.
#[derive(Debug, Error)]
pub enum RunError {
    #[error(transparent)]
    /// A file of the run (input or output).
    Io(#[from] IoError),
    /// The run's Rerun recording failed.
    #[error(transparent)]
    View(#[from] crate::view::ViewError),
    /// Loop closing is on but cannot run (no vocabulary): an error before any work.
    #[error(transparent)]
    NoLoops(#[from] crate::global::NoLoops),
    /// Bad input found before any work (a missing model, an empty sequence, no
    /// calibration).
    #[error("{0}")]
    Input(String),
    /// The run stopped before the last frame; what was done is written.
    #[error("{reason} (outputs of the {done} frames done are in {out})")]
    Stopped {
        /// Why.
        reason: StopReason,
        /// Frames done.
        done: usize,
        /// The output folder.
        out: PathBuf,
    },
}

/// Why the tracking pass stopped before the last frame (in `report.json` as its
/// sentence, `stopped`).
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum StopReason {
    /// SIGINT or SIGTERM arrived before frame `frame`.
    #[error("{} at frame {frame}", crate::interrupt::MESSAGE)]
    Interrupted {
        /// The frame not done.
        frame: usize,
    },
    /// A frame could not be loaded or failed its checks (size, depth): the message
    /// names the file and what is wrong.
    #[error("{0}")]
    BadFrame(String),
    /// An observer of the pass (debug pictures, the Rerun recording) failed.
    #[error("{0}")]
    Observer(String),
    /// The frames' records could not be written to (or read back from) their spill
    /// file in the run's folder: the message names the file and the error.
    #[error("{0}")]
    Records(String),
    /// No frame had enough keypoints with depth to start the map; the message says
    /// what the frames had.
    #[error("{0}")]
    NeverStarted(String),
    /// With a loaded map (`--map`): no frame of the first `[tracking]
    /// place_within_frames` was placed in it; the message names the map.
    #[error("{0}")]
    NotPlaced(String),
}

impl serde::Serialize for StopReason {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}
