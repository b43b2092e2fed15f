//! What one finished batch run leaves behind (`run.json`), read from the run's own
//! `report.json` and its evaluation. Versioned like the run's other files
//! ([`super::SCHEMA`]); a `run.json` without a version is of the layout before
//! versioning, the same as version 1.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::dop::Mode;
use crate::io::run_dir::RunDir;
use crate::io::IoError;

/// Whether a run finished.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RunStatus {
    /// Finished.
    Ok,
    /// Failed (see `error`).
    Failed,
}

/// What decided a batch run's result, key by key (`run.json`'s `inputs`; the batch's
/// fingerprint).
pub type RunInputs = BTreeMap<String, String>;

/// `run.json`: written last and atomically, so its presence marks a finished run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunRecord {
    /// The layout version ([`super::SCHEMA`]; absent in files from before versioning,
    /// whose layout is version 1's).
    #[serde(default = "first_layout")]
    pub schema: u32,
    /// The sequence's name.
    pub sequence: String,
    /// The mode.
    pub mode: Mode,
    /// 1-based.
    pub repetition: usize,
    /// Finished or failed.
    pub status: RunStatus,
    /// Why it failed (the run's own error message, or what was wrong with its outputs).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<String>,
    /// Wall-clock seconds of the whole run (tracking, global pass, dense map).
    pub seconds: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// The run's figures, when it finished.
    pub figures: Option<RunFigures>,
    /// What decided the result ([`super::fingerprint`]): a run whose inputs differ
    /// from the batch's is not taken for one of its runs.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub inputs: RunInputs,
    /// Set on a run kept with `--keep-stale` although its inputs differ: what differs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stale: Option<String>,
}

/// The layout of a `run.json` that names none.
fn first_layout() -> u32 {
    1
}

/// The figures of a successful run.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RunFigures {
    /// Frames read.
    pub frames: usize,
    /// Frames tracked.
    pub tracked: usize,
    /// Tracked over read, %.
    pub coverage_percent: f64,
    /// Keyframes at the end.
    pub keyframes: usize,
    /// Map points at the end.
    pub map_points: usize,
    /// Tracking time per frame (ORB extraction + tracking), ms.
    pub median_tracking_ms: f64,
    /// The mean of the same.
    pub mean_tracking_ms: f64,
    /// Keypoints removed as dynamic before pose estimation, per tracked frame.
    pub keypoints_removed_per_frame: f64,
    /// Map points removed as dynamic over the run.
    pub map_points_removed: usize,
    /// Loops closed.
    pub loops: usize,
    /// ATE RMSE of `trajectory.txt` (m), when the sequence has ground truth.
    pub ate_rmse: Option<f64>,
    /// ATE RMSE of the tracking pass alone (`trajectory_tracking.txt`), when the global pass ran.
    pub ate_tracking_rmse: Option<f64>,
    /// RPE RMSE over the batch's delta, translation (m/s) and rotation (deg/s).
    pub rpe_translation: Option<f64>,
    /// RPE RMSE, rotation (deg/s).
    pub rpe_rotation_deg: Option<f64>,
    /// The dense map against the static scene, where the sequence has one.
    pub map: Option<MapFigures>,
    /// KITTI's relative errors (%, deg/100 m), where the path reaches 100 m.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kitti_translation_percent: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    /// KITTI's rotation error, degrees per 100 m.
    pub kitti_rotation_deg_per_100m: Option<f64>,
    /// A run in a loaded map (`--map`): the frame it was placed at.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub placed_at_frame: Option<usize>,
    /// A run in a loaded map: ATE RMSE (m) in the map's frame, without alignment (the
    /// map's frame put on the ground truth's by the first pose of the run that made
    /// the map).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ate_map_frame_rmse: Option<f64>,
}

/// The dense map's figures.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct MapFigures {
    /// Median distance of the map's points to the static scene, m.
    pub accuracy_median: Option<f64>,
    /// Points left by moving objects (ghosts), and their share of the map.
    pub ghost_points: Option<usize>,
    /// Their share of the map.
    pub ghost_fraction: Option<f64>,
    /// Depth pixels on movers kept out of the map (%), against the ground-truth masks.
    pub dynamic_removed_percent: Option<f64>,
}

impl RunFigures {
    /// The figures a run folder's `report.json` and `dense.json` (when the dense pass
    /// ran) hold; the evaluation and the map comparison are added by the caller.
    pub fn from_run(dir: &Path) -> Result<Self, IoError> {
        let run = RunDir::new(dir);
        let report = crate::records::read_report(&run)?;
        let dense = crate::records::read_dense(&run)?;
        let (t, detection) = (&report.totals, &report.detection);
        let mut removed = 0;
        report
            .frames
            .try_for_each(|f| removed += f.tracking.dynamic_keypoints)?;
        Ok(Self {
            frames: t.frames,
            tracked: t.tracked,
            coverage_percent: t.coverage_percent,
            keyframes: t.keyframes,
            map_points: t.map_points,
            median_tracking_ms: t.median_tracking_ms,
            mean_tracking_ms: t.mean_tracking_ms,
            keypoints_removed_per_frame: removed as f64 / t.tracked.max(1) as f64,
            map_points_removed: detection.map_points_removed,
            loops: report.global.as_ref().map_or(0, |g| g.loops.len()),
            placed_at_frame: report
                .slam_map
                .as_ref()
                .and_then(|m| m.loaded.as_ref())
                .and_then(|l| l.placed_at_frame),
            map: dense.and_then(|d| d.truth).map(|truth| MapFigures {
                dynamic_removed_percent: Some(100.0 * truth.dynamic_removed),
                ..MapFigures::default()
            }),
            ..Self::default()
        })
    }
}

/// A run's folder: `<out>/runs/<sequence>/<mode>/r<repetition>`.
pub fn run_dir(out: &Path, sequence: &str, mode: Mode, repetition: usize) -> PathBuf {
    out.join("runs")
        .join(sequence)
        .join(mode.name())
        .join(format!("r{repetition}"))
}

impl RunRecord {
    /// A failed record with no figures (the caller fills in what happened).
    pub fn new(sequence: &str, mode: Mode, repetition: usize) -> Self {
        Self {
            schema: super::SCHEMA,
            sequence: sequence.to_string(),
            mode,
            repetition,
            status: RunStatus::Failed,
            error: None,
            seconds: 0.0,
            figures: None,
            inputs: Default::default(),
            stale: None,
        }
    }

    /// This run's folder under the batch's output folder.
    pub fn dir(&self, out: &Path) -> PathBuf {
        run_dir(out, &self.sequence, self.mode, self.repetition)
    }

    /// Writes `run.json` into `dir` atomically.
    pub fn write(&self, dir: &Path) -> Result<(), IoError> {
        let json = serde_json::to_string_pretty(self).unwrap_or_default();
        crate::io::atomic::write_atomic(&dir.join("run.json"), json.as_bytes())
    }

    /// Reads `run.json` in `dir`, if the run finished (and its layout is this build's).
    pub fn read(dir: &Path) -> Option<Self> {
        let text = std::fs::read_to_string(dir.join("run.json")).ok()?;
        Self::parse(&text).ok()
    }

    /// A `run.json`'s text, of this build's layout version.
    fn parse(text: &str) -> Result<Self, String> {
        let record: Self = serde_json::from_str(text).map_err(|e| e.to_string())?;
        if record.schema != super::SCHEMA {
            return Err(format!(
                "a run record of layout version {}, and this dopslam reads version {}",
                record.schema,
                super::SCHEMA
            ));
        }
        Ok(record)
    }

    /// Why the `run.json` in `dir` cannot be read, when it is there but [`Self::read`]
    /// cannot take it (cut short, edited by hand); `None` when it reads or is absent.
    pub fn unreadable(dir: &Path) -> Option<String> {
        let path = dir.join("run.json");
        let why = match std::fs::read_to_string(&path) {
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return None,
            Err(e) => e.to_string(),
            Ok(text) => Self::parse(&text).err()?,
        };
        Some(format!("{} cannot be read ({why})", path.display()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `run.json` cut short is said, with its path; an absent one is not.
    #[test]
    fn a_cut_run_record_is_named() {
        let dir = std::env::temp_dir().join(format!("dopslam-run-record-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert_eq!(RunRecord::unreadable(&dir), None);
        std::fs::write(dir.join("run.json"), "{\"sequence\": \"a\", \"mo").unwrap();
        let why = RunRecord::unreadable(&dir).unwrap();
        assert!(
            why.contains("run.json cannot be read") && why.contains("EOF"),
            "{why}"
        );
        assert!(RunRecord::read(&dir).is_none());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// `run.json` carries its layout version: another version is named and not taken;
    /// a file from before versioning (no `schema`) reads as version 1.
    #[test]
    fn a_run_record_of_another_layout_is_not_taken() {
        let record = RunRecord::new("seq", Mode::Dop, 1);
        let text = serde_json::to_string(&record).unwrap();
        assert!(text.starts_with("{\"schema\":1,"), "{text}");
        assert_eq!(RunRecord::parse(&text).unwrap().sequence, "seq");
        let later = text.replace("\"schema\":1", "\"schema\":7");
        let why = RunRecord::parse(&later).unwrap_err();
        assert!(why.contains("layout version 7"), "{why}");
        let before = text.replace("\"schema\":1,", "");
        assert_eq!(RunRecord::parse(&before).unwrap().schema, 1);
    }
}
