//! What a run is asked to do besides its config: frames, progress, determinism,
//! debug pictures, the dense pass, the pace and the Rerun recording.

use std::path::PathBuf;

use crate::pacing::Pace;

/// Options of a run.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Stop after this many frames.
    pub max_frames: Option<usize>,
    /// Show the progress bar.
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
    /// The Rerun recording the run logs into (`--rerun`, `--rerun-connect`); without
    /// one, `[output] rerun` makes `run.rrd` in the run folder.
    pub rerun: Option<crate::view::LogHandle>,
    /// Track in the map an earlier run left (`--map RUN`), frozen or continued.
    pub base_map: Option<BaseMap>,
}

/// The map an earlier run left, to track the sequence in (`dopslam run --map`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BaseMap {
    /// Its `slam_map.bin`.
    pub file: PathBuf,
    /// Localisation only (`--map-frozen`): no keyframe or point is added, nothing is
    /// optimised, and the run writes no map of its own.
    pub frozen: bool,
}

impl BaseMap {
    /// The run folder the map belongs to (the folder of a `slam_map.bin`), which a
    /// run never writes into; `None` for a map file of another name.
    pub fn run_folder(&self) -> Option<&std::path::Path> {
        let name = crate::io::run_dir::names::SLAM_MAP;
        self.file
            .file_name()
            .is_some_and(|n| n == name)
            .then(|| self.file.parent())
            .flatten()
            .filter(|p| !p.as_os_str().is_empty())
    }
}

impl RunOptions {
    /// How many of a sequence's `len` frames the run tracks (`max_frames` at most).
    pub fn frames_of(&self, len: usize) -> usize {
        self.max_frames.map_or(len, |m| m.min(len))
    }
}
