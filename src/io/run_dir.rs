//! A run folder: the name of every file a run writes, once. The writer (`run::outputs`,
//! the dense pass) and the readers (`dopslam fuse`, `compare-maps`, the batch) all go
//! through [`RunDir`], so a file cannot be renamed in one place and read under its old
//! name in another. What the files hold, and reading them back, is
//! `crate::records`'.

use std::path::{Path, PathBuf};

use super::IoError;

/// `segments.txt`: each tracked frame's timestamp and map segment after the loops'
/// merges, a `timestamp segment` line each (the tracking pass writes it, the dense pass
/// fuses only the largest segment).
pub fn write_segments(
    path: &Path,
    frames: impl Iterator<Item = std::io::Result<(f64, usize)>>,
) -> Result<(), IoError> {
    super::atomic::write_atomic_with(path, |out| {
        writeln!(
            out,
            "# timestamp segment: each tracked frame's map segment after the loops' merges"
        )?;
        for frame in frames {
            let (timestamp, segment) = frame?;
            writeln!(out, "{timestamp:.6} {segment}")?;
        }
        Ok(())
    })
}

/// Reads [`write_segments`]'s file line by line, handing each frame's timestamp and
/// segment to `each`: `false` when there is none (a run written before the file
/// existed); a malformed line is an error naming it.
pub fn for_each_segment(
    path: &Path,
    mut each: impl FnMut(f64, usize) -> Result<(), IoError>,
) -> Result<bool, IoError> {
    use std::io::BufRead;
    let Ok(file) = std::fs::File::open(path) else {
        return Ok(false);
    };
    for (n, line) in std::io::BufReader::new(file).lines().enumerate() {
        let line = line.map_err(|e| IoError::read(path, e))?;
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut fields = line.split_whitespace();
        let parsed = match (fields.next(), fields.next(), fields.next()) {
            (Some(t), Some(s), None) => t.parse::<f64>().ok().zip(s.parse::<usize>().ok()),
            _ => None,
        };
        let Some((timestamp, segment)) = parsed else {
            return Err(IoError::invalid(
                path,
                format!("line {}: expected `timestamp segment`, got {line:?}", n + 1),
            ));
        };
        each(timestamp, segment)?;
    }
    Ok(true)
}

/// The layout version of `report.json` and `dense.json` this build writes and reads
/// (their `schema` field; see `crate::records`).
pub const SCHEMA: u32 = 1;

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
    /// The SLAM map a later run can track in (`dopslam run --map`; docs/map_format.md).
    pub const SLAM_MAP: &str = "slam_map.bin";
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
    /// The dense pass's fused state, kept for `dopslam fuse` (`[dense] keep_state`).
    pub const DENSE_STATE: &str = "dense_state";
    /// `dopslam merge`: what each recording gave to the merged map.
    pub const MERGE_REPORT: &str = "merge.json";
    /// `dopslam merge`: each recording's side files (its dense pass's detections).
    pub const MERGED_RECORDINGS: &str = "recordings";
}

/// The files and folders a run writes into its output folder (a batch's `config.toml`,
/// `log.txt` and `run.json` beside them are the batch's own): what
/// [`super::output::move_previous_outputs`] moves aside.
pub const RUN_OUTPUTS: [&str; 27] = [
    names::TRAJECTORY,
    names::SLAM_MAP,
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
    names::DENSE_STATE,
    names::MERGE_REPORT,
    names::MERGED_RECORDINGS,
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

    /// `slam_map.bin`: the SLAM map a later run can track in.
    pub fn slam_map(&self) -> PathBuf {
        self.file(names::SLAM_MAP)
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
}
