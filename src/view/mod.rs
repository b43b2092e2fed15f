//! A Rerun recording of a run: what the tracking pass saw frame by frame (the image,
//! the keypoints by DOP state, the detector's boxes, the pose, the local map, events)
//! and what the run left (the final trajectory, the ground truth, loops, the dense
//! map). Written to an `.rrd` file or streamed to a running viewer.
//!
//! - [`entry`]: the typed entries (what, when, under which prefix);
//! - [`log`]: the [`Logger`] that writes them on its own thread, so that logging costs
//!   the tracking thread a channel send;
//! - [`entities`]: the entity paths and how each entry becomes Rerun's archetypes
//!   (built with the `rerun` feature only);
//! - [`results`]: what a finished run folder holds, logged (after a run, and by
//!   `dopslam view` for runs made before or elsewhere).

pub mod entities;
pub mod entry;
pub mod error;
pub mod log;
pub mod results;

pub use error::ViewError;

use serde::{Deserialize, Serialize};

use crate::checks::{self, BadValue};

pub use entry::{At, Entry, Level, Target};
pub use log::{LogHandle, LogSummary, Logger};

/// `[output]`: what a run writes beside its fixed outputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Write the run's Rerun recording as `run.rrd` in the run folder.
    pub rerun: bool,
    /// Images are logged downscaled by this factor (0, 1].
    pub rerun_image_scale: f64,
    /// JPEG quality of the logged images (1-100).
    pub rerun_jpeg_quality: u8,
    /// Also log each frame's depth image (RGB-D; larger files).
    pub rerun_depth: bool,
    /// The dense cloud and mesh are decimated to at most this many points / triangles.
    pub rerun_max_points: usize,
    /// Entries the logging thread may fall behind by before images are dropped.
    pub rerun_queue: usize,
    /// Write the SLAM map a later run can track in (`slam_map.bin`, `dopslam run
    /// --map`).
    pub slam_map: bool,
}

impl Default for OutputConfig {
    fn default() -> Self {
        Self {
            rerun: false,
            rerun_image_scale: 0.5,
            rerun_jpeg_quality: 80,
            rerun_depth: false,
            rerun_max_points: 500_000,
            rerun_queue: 64,
            slam_map: true,
        }
    }
}

impl OutputConfig {
    /// Checks each value's range; the message names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        let scale = self.rerun_image_scale;
        if !(scale.is_finite() && scale > 0.0 && scale <= 1.0) {
            return Err(BadValue::new(
                "output.rerun_image_scale",
                format!("must be in (0, 1], got {scale}"),
            ));
        }
        if !(1..=100).contains(&self.rerun_jpeg_quality) {
            return Err(BadValue::new(
                "output.rerun_jpeg_quality",
                format!("must be in 1-100, got {}", self.rerun_jpeg_quality),
            ));
        }
        checks::at_least_one("output.rerun_max_points", self.rerun_max_points as u64)?;
        checks::at_least_one("output.rerun_queue", self.rerun_queue as u64)
    }
}

/// Whether this build can write Rerun recordings (the `rerun` feature).
pub const AVAILABLE: bool = cfg!(feature = "rerun");

/// What a build without the `rerun` feature says when asked for a recording.
pub const MISSING_FEATURE: &str = "this dopslam was built without the `rerun` feature, which --rerun, --rerun-connect, [output] rerun and `dopslam view` need: build it with `cargo build --release --features rerun` (tools/setup.sh does)";
