//! The files a run writes, one Rust type per section, read back by every reader (the
//! run folder's commands, the Rerun replay, the batch): `report.json`
//! ([`RunReport`]), `dense.json` ([`crate::dense::DenseReport`]) and, in a batch,
//! `run.json` ([`RunRecord`]). Each file carries
//! the version of its layout ([`SCHEMA`]); a reader refuses another version by name
//! instead of misreading it.

pub mod frame_lines;
pub mod report;
pub mod run;
pub mod setup;
pub mod slam_map;

pub use frame_lines::FrameLines;
pub use report::{FrameLine, Lap, RunReport, RunTimes, RunTotals, SegmentSpan, StageTime};
pub use run::{MapFigures, RunFigures, RunInputs, RunRecord, RunStatus};
pub use setup::{ProfileApplied, RigOffset, RunSetup, SettingsApplied, TakenOut};
pub use slam_map::{LoadedMap, SavedMap, SlamMapReport};

use crate::dense::DenseReport;
use crate::io::errors::read_text;
use crate::io::run_dir::RunDir;
use crate::io::IoError;

pub use crate::io::run_dir::SCHEMA;

/// A run folder's `report.json`.
pub fn read_report(run: &RunDir) -> Result<RunReport, IoError> {
    read_versioned(&run.report(), "run report (report.json)")
}

/// A run folder's `dense.json`, when the dense pass wrote one.
pub fn read_dense(run: &RunDir) -> Result<Option<DenseReport>, IoError> {
    let path = run.dense_report();
    if !path.exists() {
        return Ok(None);
    }
    read_versioned(&path, "dense report (dense.json)").map(Some)
}

/// A merged map's `merge.json` (`dopslam merge`) in the folder `merged`.
pub fn read_merge(merged: &RunDir) -> Result<crate::dense::merge::MergeReport, IoError> {
    let path = merged.file(crate::io::run_dir::names::MERGE_REPORT);
    read_versioned(&path, "merge report (merge.json)")
}

/// The alignment of a run's trajectory to its sequence's ground truth
/// ([`crate::dense::compare_maps::pose_alignment`]; the run's `report.json` names the
/// sequence), if both exist.
pub fn run_alignment(run_dir: &std::path::Path) -> Option<crate::geometry::se3::Se3> {
    use crate::io::trajectory::{Trajectory, TrajectoryFormat};
    let run = RunDir::new(run_dir);
    let sequence = read_report(&run).ok()?.sequence_path?;
    let reference =
        Trajectory::read(&sequence.join("groundtruth.txt"), TrajectoryFormat::Tum).ok()?;
    let estimate = Trajectory::read(&run.trajectory(), TrajectoryFormat::Tum).ok()?;
    crate::dense::compare_maps::pose_alignment(&estimate, &reference)
}

/// The file at `path`, a `what` of this build's [`SCHEMA`].
fn read_versioned<T: serde::de::DeserializeOwned>(
    path: &std::path::Path,
    what: &str,
) -> Result<T, IoError> {
    let text = read_text(path)?;
    let value: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| IoError::invalid(path, format!("not a dopslam {what}: {e}")))?;
    let Some(object) = value.as_object() else {
        return Err(IoError::invalid(
            path,
            format!("not a dopslam {what}: not a JSON object"),
        ));
    };
    match object.get("schema").and_then(|v| v.as_u64()) {
        Some(version) if version == u64::from(SCHEMA) => {}
        Some(version) => {
            return Err(IoError::invalid(
                path,
                format!("a {what} of layout version {version}, and this dopslam reads version {SCHEMA}: read it with the dopslam that wrote it, or run the sequence again"),
            ))
        }
        None => {
            return Err(IoError::invalid(
                path,
                format!("not a dopslam {what} of this version: it has no layout version (`schema`), as a dopslam from before version {SCHEMA} wrote them, or another program; run the sequence again"),
            ))
        }
    }
    serde_json::from_value(value)
        .map_err(|e| IoError::invalid(path, format!("not a dopslam {what}: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_foreign_or_other_version_report_is_an_error_naming_the_file() {
        let dir = std::env::temp_dir().join(format!("dopslam-records-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let run = RunDir::new(&dir);
        let e = read_report(&run).unwrap_err().to_string();
        assert!(e.contains("report.json"), "{e}");
        std::fs::write(run.report(), "[1, 2]").unwrap();
        let e = read_report(&run).unwrap_err().to_string();
        assert!(e.contains("not a dopslam run report"), "{e}");
        // A report from before the layout was versioned, or another program's JSON.
        std::fs::write(run.report(), "{\"mode\": \"dop\", \"frames\": []}").unwrap();
        let e = read_report(&run).unwrap_err().to_string();
        assert!(e.contains("no layout version"), "{e}");
        std::fs::write(run.report(), "{\"schema\": 99}").unwrap();
        let e = read_report(&run).unwrap_err().to_string();
        assert!(
            e.contains("layout version 99") && e.contains("reads version 1"),
            "{e}"
        );
        // This version, but not a whole report: the missing section is named.
        std::fs::write(
            run.report(),
            format!("{{\"schema\": {SCHEMA}, \"sequence\": \"x\"}}"),
        )
        .unwrap();
        let e = read_report(&run).unwrap_err().to_string();
        assert!(
            e.contains("not a dopslam run report") && e.contains("missing field"),
            "{e}"
        );
        // No dense.json: no dense report, not an error.
        assert!(read_dense(&run).unwrap().is_none());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
