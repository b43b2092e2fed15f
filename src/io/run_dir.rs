//! A run folder: the name of every file a run writes, once. The writer (`run::outputs`,
//! the dense pass) and the readers (`dopslam fuse`, `compare-maps`, the batch) all go
//! through [`RunDir`], so a file cannot be renamed in one place and read under its old
//! name in another. `report.json` reads back typed as a [`RunSummary`] (the parts the
//! readers need; the whole report is `run::RunReport`).

use std::path::{Path, PathBuf};

use serde::Deserialize;

use super::IoError;

/// `segments.txt`: each tracked frame's timestamp and map segment after the loops'
/// merges, a `timestamp segment` line each (the tracking pass writes it, the dense pass
/// fuses only the largest segment).
pub fn write_segments(path: &Path, frames: &[(f64, usize)]) -> Result<(), IoError> {
    let mut text = String::from(
        "# timestamp segment: each tracked frame's map segment after the loops' merges\n",
    );
    for (timestamp, segment) in frames {
        text.push_str(&format!("{timestamp:.6} {segment}\n"));
    }
    super::atomic::write_atomic(path, text.as_bytes())
}

/// Reads [`write_segments`]'s file: `None` when there is none (a run written before
/// the file existed); a malformed line is an error naming it.
pub fn read_segments(path: &Path) -> Result<Option<Vec<(f64, usize)>>, IoError> {
    let Ok(text) = std::fs::read_to_string(path) else {
        return Ok(None);
    };
    let mut frames = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut fields = line.split_whitespace();
        let parsed = match (fields.next(), fields.next(), fields.next()) {
            (Some(t), Some(s), None) => t.parse::<f64>().ok().zip(s.parse::<usize>().ok()),
            _ => None,
        };
        let Some(frame) = parsed else {
            return Err(IoError::invalid(
                path,
                format!("line {}: expected `timestamp segment`, got {line:?}", n + 1),
            ));
        };
        frames.push(frame);
    }
    Ok(Some(frames))
}

/// A run's output folder.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RunDir {
    root: PathBuf,
}

/// Every file's and folder's name in a run folder.
pub mod names {
    /// The camera trajectory after the global pass (TUM format, every tracked frame).
    pub const TRAJECTORY: &str = "trajectory.txt";
    /// The trajectory of the tracking pass, written before the global pass moves the map.
    pub const TRACKING_TRAJECTORY: &str = "trajectory_tracking.txt";
    /// Each keyframe's pose (TUM format).
    pub const KEYFRAMES: &str = "keyframes.txt";
    /// The sparse map (binary PLY).
    pub const SPARSE_MAP: &str = "map.ply";
    /// What the run did.
    pub const REPORT: &str = "report.json";
    /// Each tracked frame's timestamp and map segment after the loops' merges.
    pub const SEGMENTS: &str = "segments.txt";
    /// The dynamic keypoints of each frame (DOP mode).
    pub const DYNAMIC_KEYPOINTS: &str = "dynamic_keypoints.json";
    /// The keyframe detector's boxes, one file per keyframe (a detection cache).
    pub const DETECTIONS: &str = "detections";
    /// Detections the dense pass added on frames between keyframes.
    pub const DENSE_DETECTIONS: &str = "detections_dense";
    /// The TSDF mesh (PLY).
    pub const DENSE_MESH_PLY: &str = "dense_mesh.ply";
    /// The TSDF mesh (OBJ).
    pub const DENSE_MESH_OBJ: &str = "dense_mesh.obj";
    /// The dense point cloud (PLY).
    pub const DENSE_POINTS: &str = "dense_points.ply";
    /// What the dense pass did.
    pub const DENSE_REPORT: &str = "dense.json";
    /// The dense map seen in perspective.
    pub const DENSE_PERSPECTIVE: &str = "dense_perspective.png";
    /// The dense map seen from above.
    pub const DENSE_TOP: &str = "dense_top.png";
    /// The dense pass's mask pictures (`[dense] mask_pictures_every`).
    pub const MASK_PICTURES: &str = "mask_pictures";
    /// What `dopslam eval --save-report` writes beside a run.
    pub const EVALUATION: &str = "evaluation.json";
    /// `dopslam eval`'s plots.
    pub const PLOTS: &str = "plots";
    /// `--compare-no-dop`'s runs and comparison.
    pub const NO_DOP: &str = "no_dop";
    /// `--compare-no-dop`: the keyframes fused again without masks (a point cloud).
    pub const NO_MASKS: &str = "no_masks";
    /// The unmasked fusion's outputs.
    pub const UNMASKED: &str = "unmasked";
    /// `--compare-no-dop`: the comparison of the maps.
    pub const COMPARE_NO_DOP: &str = "compare_no_dop";
    /// The run's Rerun recording (`[output] rerun`).
    pub const RERUN: &str = "run.rrd";
    /// An earlier run's outputs, moved aside.
    pub const PREVIOUS: &str = "previous";
}

/// The files and folders a run writes into its output folder (a batch's `config.toml`,
/// `log.txt` and `run.json` beside them are the batch's own): what
/// [`super::output::move_previous_outputs`] moves aside.
pub const RUN_OUTPUTS: [&str; 23] = [
    names::TRAJECTORY,
    names::TRACKING_TRAJECTORY,
    names::KEYFRAMES,
    names::SPARSE_MAP,
    names::REPORT,
    names::SEGMENTS,
    names::DYNAMIC_KEYPOINTS,
    names::DETECTIONS,
    names::DENSE_MESH_PLY,
    names::DENSE_MESH_OBJ,
    names::DENSE_POINTS,
    names::DENSE_REPORT,
    names::DENSE_PERSPECTIVE,
    names::DENSE_TOP,
    names::DENSE_DETECTIONS,
    names::MASK_PICTURES,
    names::EVALUATION,
    names::PLOTS,
    names::NO_DOP,
    names::NO_MASKS,
    names::UNMASKED,
    names::COMPARE_NO_DOP,
    names::RERUN,
];

impl RunDir {
    /// The run folder at `root`.
    pub fn new(root: impl Into<PathBuf>) -> Self {
        Self { root: root.into() }
    }

    /// The folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// `root/name`, for a name of [`names`].
    pub fn file(&self, name: &str) -> PathBuf {
        self.root.join(name)
    }

    /// `trajectory.txt`.
    pub fn trajectory(&self) -> PathBuf {
        self.file(names::TRAJECTORY)
    }

    /// `trajectory_tracking.txt`.
    pub fn tracking_trajectory(&self) -> PathBuf {
        self.file(names::TRACKING_TRAJECTORY)
    }

    /// `keyframes.txt`.
    pub fn keyframes(&self) -> PathBuf {
        self.file(names::KEYFRAMES)
    }

    /// `map.ply`.
    pub fn sparse_map(&self) -> PathBuf {
        self.file(names::SPARSE_MAP)
    }

    /// `report.json`.
    pub fn report(&self) -> PathBuf {
        self.file(names::REPORT)
    }

    /// `segments.txt`.
    pub fn segments(&self) -> PathBuf {
        self.file(names::SEGMENTS)
    }

    /// `dynamic_keypoints.json`.
    pub fn dynamic_keypoints(&self) -> PathBuf {
        self.file(names::DYNAMIC_KEYPOINTS)
    }

    /// `detections/`.
    pub fn detections(&self) -> PathBuf {
        self.file(names::DETECTIONS)
    }

    /// `detections_dense/`.
    pub fn dense_detections(&self) -> PathBuf {
        self.file(names::DENSE_DETECTIONS)
    }

    /// `run.rrd`.
    pub fn rerun(&self) -> PathBuf {
        self.file(names::RERUN)
    }

    /// `dense.json`.
    pub fn dense_report(&self) -> PathBuf {
        self.file(names::DENSE_REPORT)
    }

    /// A sub-run of `--compare-no-dop` ([`names::NO_DOP`], [`names::NO_MASKS`]).
    pub fn sub_run(&self, name: &str) -> RunDir {
        RunDir::new(self.file(name))
    }

    /// `report.json`, read back typed: an error names the file and what is wrong
    /// (missing: not a finished run).
    pub fn read_summary(&self) -> Result<RunSummary, IoError> {
        let path = self.report();
        let text = super::errors::read_text(&path)?;
        let summary: RunSummary = serde_json::from_str(&text)
            .map_err(|e| IoError::invalid(&path, format!("not a dopslam run report: {e}")))?;
        if summary.frames.is_empty() && summary.totals.is_none() {
            return Err(IoError::invalid(
                &path,
                "not a dopslam run report: it lists no frames and no totals (every run's report.json has both)",
            ));
        }
        Ok(summary)
    }
}

/// The parts of a run's `report.json` that other commands read: what `dopslam fuse`
/// needs may be all a report has (an older run's); the totals the batch reads are
/// there in every finished run ([`RunSummary::totals`]).
#[derive(Debug, Clone, Deserialize)]
pub struct RunSummary {
    #[serde(default)]
    /// The sequence's name.
    pub sequence: Option<String>,
    /// The sequence folder the run tracked, when known.
    #[serde(default)]
    pub sequence_path: Option<PathBuf>,
    /// How moving objects were treated: `off`, `mask-boxes` or `dop` (empty when the
    /// report does not say).
    #[serde(default)]
    pub mode: String,
    #[serde(default)]
    /// What the run was set up with.
    pub setup: Option<SetupSummary>,
    #[serde(default)]
    totals: Option<TotalsSummary>,
    #[serde(default)]
    detection: Option<DetectionSummary>,
    #[serde(default)]
    /// Its frames.
    pub frames: Vec<FrameSummary>,
    #[serde(default)]
    /// Its global pass.
    pub global: Option<GlobalSummary>,
}

/// The part of `report.json`'s setup that is read back.
#[derive(Debug, Clone, Deserialize)]
pub struct SetupSummary {
    #[serde(default)]
    /// The first frame's hash (a run is fused with its own sequence).
    pub first_frame_hash: Option<String>,
    #[serde(default)]
    /// The calibration.
    pub calibration: Option<CalibrationSummary>,
    #[serde(default)]
    /// Stereo: the rig's disparity offset tracking added to every match.
    pub disparity_offset: Option<OffsetSummary>,
}

/// The camera a run used (`setup.calibration.camera`).
#[derive(Debug, Clone, Deserialize)]
pub struct CalibrationSummary {
    /// The camera.
    pub camera: crate::geometry::camera::PinholeCamera,
}

/// The part of `report.json`'s totals that is read back.
#[derive(Debug, Clone, Deserialize)]
pub struct TotalsSummary {
    /// Frames read.
    pub frames: usize,
    /// Frames tracked.
    pub tracked: usize,
    /// Tracked over read, %.
    pub coverage_percent: f64,
    /// Keyframes.
    pub keyframes: usize,
    /// Map points.
    pub map_points: usize,
    /// Median tracking time, ms.
    pub median_tracking_ms: f64,
    /// Mean tracking time, ms.
    pub mean_tracking_ms: f64,
}

/// The part of `report.json`'s detection totals that is read back.
#[derive(Debug, Clone, Deserialize)]
pub struct DetectionSummary {
    /// Map points removed as dynamic.
    pub map_points_removed: usize,
}

/// One frame's line (what older reports may lack reads as zero, empty or false).
#[derive(Debug, Clone, Deserialize)]
pub struct FrameSummary {
    /// Keypoints found dynamic.
    pub dynamic_keypoints: usize,
    #[serde(default)]
    /// The frame's index.
    pub index: usize,
    #[serde(default)]
    /// Seconds.
    pub timestamp: f64,
    /// `ok`, `lost` or `not_initialised`.
    #[serde(default)]
    pub state: String,
    #[serde(default)]
    /// Whether it became a keyframe.
    pub keyframe: bool,
    #[serde(default)]
    /// Keypoints extracted.
    pub keypoints: usize,
    /// Why a lost frame got no pose (`{"reason": ...}`).
    #[serde(default)]
    pub lost: Option<serde_json::Value>,
}

/// The part of `report.json`'s global pass that is read back.
#[derive(Debug, Clone, Deserialize)]
pub struct GlobalSummary {
    /// The loops closed.
    pub loops: Vec<serde_json::Value>,
    /// Every loop candidate that reached consistency checking, with its outcome.
    #[serde(default)]
    pub candidates: Vec<serde_json::Value>,
    /// Stereo: the rig's disparity offset the pass took out, when it did.
    #[serde(default)]
    pub disparity_offset: Option<OffsetSummary>,
}

/// The part of `setup.disparity_offset` and `global.disparity_offset` that is read
/// back.
#[derive(Debug, Clone, Deserialize)]
pub struct OffsetSummary {
    /// Pixels added to every disparity.
    pub offset_px: f64,
}

impl RunSummary {
    /// The camera the run used, when its report says.
    pub fn camera(&self) -> Option<&crate::geometry::camera::PinholeCamera> {
        Some(&self.setup.as_ref()?.calibration.as_ref()?.camera)
    }

    /// The rig's disparity offset in the run's disparities, pixels: what tracking added
    /// and what the global pass took out after it (0 when neither); `dopslam fuse`
    /// adds it to the dense disparities too.
    pub fn disparity_offset_px(&self) -> f64 {
        [
            self.setup
                .as_ref()
                .and_then(|s| s.disparity_offset.as_ref()),
            self.global
                .as_ref()
                .and_then(|g| g.disparity_offset.as_ref()),
        ]
        .into_iter()
        .flatten()
        .map(|o| o.offset_px)
        .sum()
    }

    /// The first frame's fingerprint the run recorded (`dopslam fuse` checks it).
    pub fn first_frame_hash(&self) -> Option<&str> {
        self.setup.as_ref()?.first_frame_hash.as_deref()
    }

    /// The run's totals and detection totals; an error naming `report` when the report
    /// has none (not a finished dopslam run).
    pub fn totals(&self, report: &Path) -> Result<(&TotalsSummary, &DetectionSummary), IoError> {
        match (&self.totals, &self.detection) {
            (Some(totals), Some(detection)) => Ok((totals, detection)),
            _ => Err(IoError::invalid(
                report,
                "not a dopslam run report: no totals (an unfinished or foreign run)",
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn run_outputs_are_distinct_names() {
        let mut sorted = RUN_OUTPUTS.to_vec();
        sorted.sort();
        sorted.dedup();
        assert_eq!(sorted.len(), RUN_OUTPUTS.len());
        assert!(!RUN_OUTPUTS.contains(&names::PREVIOUS));
    }

    #[test]
    fn a_missing_or_foreign_report_is_an_error_naming_the_file() {
        let dir = std::env::temp_dir().join(format!("dopslam-run-dir-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let run = RunDir::new(&dir);
        let e = run.read_summary().unwrap_err().to_string();
        assert!(e.contains("report.json"), "{e}");
        std::fs::write(run.report(), "[1, 2]").unwrap();
        let e = run.read_summary().unwrap_err().to_string();
        assert!(e.contains("not a dopslam run report"), "{e}");
        // Any JSON object is not a report: one lists frames or totals.
        std::fs::write(run.report(), "{\"mode\": \"dop\"}").unwrap();
        let e = run.read_summary().unwrap_err().to_string();
        assert!(
            e.contains("not a dopslam run report") && e.contains("no frames"),
            "{e}"
        );
        // What fuse needs may be all there is; the totals are asked for by name.
        std::fs::write(
            run.report(),
            "{\"mode\": \"dop\", \"frames\": [{\"dynamic_keypoints\": 0}]}",
        )
        .unwrap();
        let summary = run.read_summary().unwrap();
        assert_eq!(summary.mode, "dop");
        let e = summary.totals(&run.report()).unwrap_err().to_string();
        assert!(e.contains("report.json") && e.contains("no totals"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
