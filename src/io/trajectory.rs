//! Trajectory files: TUM (`t tx ty tz qx qy qz qw`) and KITTI (the 3x4 matrix
//! `world_from_camera`, row-major, 12 numbers a line), read and written.

use std::fmt::Write as _;
use std::io::{BufRead, BufReader};
use std::path::Path;

use nalgebra::{Matrix3, Vector3};

use super::atomic::write_atomic;
use super::errors::{check_exists, read_text, IoError};
use super::file_list::{content, content_lines, parse_numbers};
use crate::geometry::se3::{self, Se3};

/// Timestamped poses `world_from_camera`. KITTI files carry no timestamps; they get
/// their line index (or the times from a `times.txt`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// Seconds, one per pose.
    pub timestamps: Vec<f64>,
    /// `world_from_camera` poses.
    pub poses: Vec<Se3>,
}

/// The trajectory file formats.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum TrajectoryFormat {
    /// `timestamp tx ty tz qx qy qz qw` per line.
    Tum,
    /// The 12 values of a 3x4 matrix per line.
    Kitti,
}

impl Trajectory {
    /// The number of poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// Whether there is no pose.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Appends a pose.
    pub fn push(&mut self, timestamp: f64, pose: Se3) {
        self.timestamps.push(timestamp);
        self.poses.push(pose);
    }

    /// Camera centres in the world frame.
    pub fn positions(&self) -> Vec<Vector3<f64>> {
        self.poses.iter().map(|p| p.translation.vector).collect()
    }

    /// The sub-trajectory at the given indices.
    pub fn select(&self, indices: &[usize]) -> Trajectory {
        Trajectory {
            timestamps: indices.iter().map(|&i| self.timestamps[i]).collect(),
            poses: indices.iter().map(|&i| self.poses[i]).collect(),
        }
    }

    /// Total path length \(\sum_i \|p_{i+1} - p_i\|\) in metres.
    pub fn path_length(&self) -> f64 {
        self.poses
            .windows(2)
            .map(|w| (w[1].translation.vector - w[0].translation.vector).norm())
            .sum()
    }

    /// The first timestamp given to two poses, with their indices (an estimate must
    /// give one pose per time; recorded ground truth sometimes repeats one).
    pub fn repeated_timestamp(&self) -> Option<(f64, usize, usize)> {
        self.timestamps
            .windows(2)
            .position(|w| w[0] == w[1])
            .map(|i| (self.timestamps[i], i + 1, i + 2))
    }

    /// Reads a trajectory in the given format.
    pub fn read(path: &Path, format: TrajectoryFormat) -> Result<Self, IoError> {
        match format {
            TrajectoryFormat::Tum => Self::read_tum(path),
            TrajectoryFormat::Kitti => Self::read_kitti(path),
        }
    }

    /// Reads a TUM trajectory. Comment lines (`#`) and blank lines are skipped; every
    /// other line must hold exactly eight numbers; timestamps must not decrease (real
    /// ground truth repeats some: see [`Trajectory::repeated_timestamp`]).
    pub fn read_tum(path: &Path) -> Result<Self, IoError> {
        let mut trajectory = Trajectory::default();
        for_each_tum(path, |timestamp, pose| {
            trajectory.push(timestamp, pose);
            Ok(())
        })?;
        Ok(trajectory)
    }

    /// Reads a KITTI pose file; timestamps are the line indices 0, 1, 2, …
    pub fn read_kitti(path: &Path) -> Result<Self, IoError> {
        let text = read_text(path)?;
        let mut trajectory = Trajectory::default();
        for (line_number, line) in content_lines(&text) {
            let v = parse_numbers(
                path,
                line_number,
                line,
                12,
                "KITTI: a 3x4 matrix, row-major",
            )?;
            let rotation = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
            let off = (rotation.transpose() * rotation - Matrix3::identity())
                .abs()
                .max();
            if off > 1e-3 || rotation.determinant() < 0.0 {
                return Err(IoError::parse(
                    path,
                    line_number,
                    format!(
                        "the 3x3 part is not a rotation (|R^T R - I| = {off:.3}, det {:.3}): KITTI lines hold a 3x4 [R | t] with R orthonormal",
                        rotation.determinant()
                    ),
                ));
            }
            let translation = Vector3::new(v[3], v[7], v[11]);
            let timestamp = trajectory.len() as f64;
            trajectory.push(timestamp, se3::from_parts(translation, rotation));
        }
        Ok(trajectory)
    }

    /// Replaces the timestamps with those of a KITTI `times.txt` (one number a line).
    pub fn with_times_file(mut self, path: &Path) -> Result<Self, IoError> {
        let times = read_times(path)?;
        if times.len() != self.len() {
            return Err(IoError::invalid(
                path,
                format!(
                    "holds {} times but the trajectory has {} poses",
                    times.len(),
                    self.len()
                ),
            ));
        }
        self.timestamps = times;
        Ok(self)
    }

    /// The TUM text of the trajectory: timestamps with six decimals (as TUM's files),
    /// pose numbers in Rust's shortest round-trip form, so they read back exactly.
    pub fn to_tum_string(&self) -> String {
        let mut out = String::from("# timestamp tx ty tz qx qy qz qw\n");
        for (t, pose) in self.timestamps.iter().zip(&self.poses) {
            let _ = write!(out, "{t:.6} ");
            write_translation_quaternion(&mut out, pose);
            out.push('\n');
        }
        out
    }

    /// The KITTI text of the trajectory (timestamps are dropped).
    pub fn to_kitti_string(&self) -> String {
        let mut out = String::new();
        for pose in &self.poses {
            let r = pose.rotation.matrix();
            let t = pose.translation.vector;
            let row = |i: usize| format!("{} {} {} {}", r[(i, 0)], r[(i, 1)], r[(i, 2)], t[i]);
            let _ = writeln!(out, "{} {} {}", row(0), row(1), row(2));
        }
        out
    }

    /// Writes the trajectory atomically in the given format.
    pub fn write(&self, path: &Path, format: TrajectoryFormat) -> Result<(), IoError> {
        let text = match format {
            TrajectoryFormat::Tum => self.to_tum_string(),
            TrajectoryFormat::Kitti => self.to_kitti_string(),
        };
        write_atomic(path, text.as_bytes())
    }
}

/// Reads a KITTI `times.txt`: one time in seconds a line.
pub fn read_times(path: &Path) -> Result<Vec<f64>, IoError> {
    let text = read_text(path)?;
    let mut times = Vec::new();
    for (line_number, line) in content_lines(&text) {
        times.push(parse_numbers(path, line_number, line, 1, "one time in seconds")?[0]);
    }
    Ok(times)
}

/// Appends `tx ty tz qx qy qz qw` in Rust's shortest round-trip form (TUM and g2o
/// write poses so).
pub fn write_translation_quaternion(out: &mut String, pose: &Se3) {
    let p = pose.translation.vector;
    let q = se3::quaternion_xyzw(pose);
    let _ = write!(
        out,
        "{} {} {} {} {} {} {}",
        p.x, p.y, p.z, q[0], q[1], q[2], q[3]
    );
}

/// Reads a TUM trajectory line by line as [`Trajectory::read_tum`] does, handing each
/// timestamp and pose (`world_from_camera`) to `each` in the file's order: no list is
/// held. The number of poses.
pub fn for_each_tum(
    path: &Path,
    mut each: impl FnMut(f64, Se3) -> Result<(), IoError>,
) -> Result<usize, IoError> {
    check_exists(path, "no such file")?;
    let file = std::fs::File::open(path).map_err(|e| IoError::read(path, e))?;
    let mut previous: Option<(f64, usize)> = None;
    let mut poses = 0;
    for (index, raw) in BufReader::new(file).lines().enumerate() {
        let raw = raw.map_err(|e| IoError::read(path, e))?;
        let line_number = index + 1;
        let Some(line) = content(&raw) else {
            continue;
        };
        let values = parse_numbers(
            path,
            line_number,
            line,
            8,
            "TUM: timestamp tx ty tz qx qy qz qw",
        )?;
        let q = [values[4], values[5], values[6], values[7]];
        if q.iter().map(|v| v * v).sum::<f64>() < 1e-12 {
            return Err(IoError::parse(
                path,
                line_number,
                "the quaternion has zero length",
            ));
        }
        let timestamp = values[0];
        if let Some((before, before_line)) = previous {
            if timestamp < before {
                return Err(IoError::parse(
                    path,
                    line_number,
                    format!("timestamps are not sorted: {timestamp} comes after {before} (line {before_line})"),
                ));
            }
        }
        previous = Some((timestamp, line_number));
        let translation = Vector3::new(values[1], values[2], values[3]);
        each(timestamp, se3::from_translation_quaternion(translation, q))?;
        poses += 1;
    }
    Ok(poses)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector6;

    fn temp_dir(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("dopslam-traj-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn sample() -> Trajectory {
        let mut t = Trajectory::default();
        for i in 0..5 {
            let xi = Vector6::new(
                0.1 * i as f64,
                -0.2,
                0.3 * i as f64,
                0.05 * i as f64,
                0.2,
                -0.1,
            );
            t.push(100.0 + 0.033 * i as f64, se3::exp(&xi));
        }
        t
    }

    #[test]
    fn tum_and_kitti_roundtrip() {
        let dir = temp_dir("roundtrip");
        let original = sample();
        for format in [TrajectoryFormat::Tum, TrajectoryFormat::Kitti] {
            let path = dir.join("t.txt");
            original.write(&path, format).unwrap();
            let back = Trajectory::read(&path, format).unwrap();
            assert_eq!(back.len(), original.len());
            for (a, b) in back.poses.iter().zip(&original.poses) {
                assert!((se3::to_matrix(a) - se3::to_matrix(b)).norm() < 1e-12);
            }
            if format == TrajectoryFormat::Tum {
                for (a, b) in back.timestamps.iter().zip(&original.timestamps) {
                    assert!((a - b).abs() < 1e-6);
                }
            }
        }
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn malformed_lines_are_named() {
        let dir = temp_dir("malformed");
        let path = dir.join("bad.txt");
        std::fs::write(&path, "# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0 1\n").unwrap();
        let message = Trajectory::read_tum(&path).unwrap_err().to_string();
        assert!(
            message.contains("bad.txt:3") && message.contains("expected 8 numbers"),
            "{message}"
        );

        std::fs::write(&path, "1.0 0 0 0 0 0 0 1\n2.0 0 0 x 0 0 0 1\n").unwrap();
        let message = Trajectory::read_tum(&path).unwrap_err().to_string();
        assert!(
            message.contains("bad.txt:2") && message.contains("\"x\""),
            "{message}"
        );

        std::fs::write(&path, "2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n").unwrap();
        let message = Trajectory::read_tum(&path).unwrap_err().to_string();
        assert!(
            message.contains("not sorted") && message.contains("bad.txt:2"),
            "{message}"
        );

        std::fs::write(&path, "1 0 0 0 0 1 0 0 0 0 1\n").unwrap();
        let message = Trajectory::read_kitti(&path).unwrap_err().to_string();
        assert!(
            message.contains("expected 12 numbers") && message.contains("found 11"),
            "{message}"
        );

        let missing = Trajectory::read_tum(&dir.join("nope.txt"))
            .unwrap_err()
            .to_string();
        assert!(
            missing.contains("nope.txt") && missing.contains("not found"),
            "{missing}"
        );
        std::fs::remove_dir_all(dir).unwrap();
    }
}
