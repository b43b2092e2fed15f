//! Camera motions: procedural imitations of TUM's fr3 walking set (static, xyz, rpy,
//! halfsphere), or a recorded trajectory file resampled at given frame times.
//!
//! Camera frames follow the computer-vision convention: x right, y down, z forward.
//! Procedural motions start at the origin looking along world +z, with world -y up.

use std::path::PathBuf;

use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

use crate::geometry::se3::{self, Se3};
use crate::geometry::so3;
use crate::io::trajectory::TrajectoryFormat;
use crate::io::{IoError, Trajectory};

/// The kind of camera motion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MotionKind {
    /// Almost still: a few millimetres and tenths of a degree of hand tremor.
    Static,
    /// Translation back and forth along the three axes (about ±0.3 m).
    Xyz,
    /// Rotation in place about the three axes (about ±20°).
    Rpy,
    /// Moving over a half sphere of about 1 m diameter, looking at its centre.
    Halfsphere,
    /// A full turn on a circle of 0.6 m radius looking outwards, every 30 s: the camera
    /// returns to where it started (for loop closure).
    Loop,
    /// A car driving at 8 m/s along world +z, weaving gently sideways (±2 m over
    /// 320 m), with a little pitch and roll from the road.
    Drive,
    /// A recorded trajectory file (`file`, `format`).
    File,
}

/// The motion section of a synth config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MotionConfig {
    /// Which path the camera takes.
    pub kind: MotionKind,
    /// For `file`: the trajectory (TUM or KITTI format).
    pub file: Option<PathBuf>,
    /// The file's format.
    pub format: TrajectoryFormat,
    /// Multiplies the speed of procedural motions; for `file`, the file's time units
    /// per second of the sequence (10 for KITTI poses at 10 Hz: one pose a frame).
    pub speed: f64,
    /// Where frame 0 starts: for `file`, in the file's time units after its first
    /// stamp (KITTI poses: a pose index; 200 starts at the 201st pose); for the
    /// procedural motions, seconds into the motion (a second recording of a room that
    /// starts elsewhere on the same path: `loop` with 15 starts half a turn on).
    pub start: f64,
}

impl Default for MotionConfig {
    fn default() -> Self {
        Self {
            kind: MotionKind::Xyz,
            file: None,
            format: TrajectoryFormat::Tum,
            speed: 1.0,
            start: 0.0,
        }
    }
}

/// The pose `world_from_camera` of a procedural motion at time `t` seconds.
pub fn procedural_pose(kind: MotionKind, t: f64) -> Se3 {
    let s = |f: f64, phase: f64| (std::f64::consts::TAU * f * t + phase).sin();
    match kind {
        MotionKind::Static | MotionKind::File => {
            let p = Vector3::new(
                0.004 * s(0.3, 0.0),
                0.003 * s(0.23, 1.0),
                0.004 * s(0.17, 2.0),
            );
            let r = Vector3::new(
                0.004 * s(0.21, 0.5),
                0.005 * s(0.13, 1.5),
                0.003 * s(0.27, 2.5),
            );
            Se3::from_parts(p.into(), so3::exp(&r))
        }
        MotionKind::Xyz => {
            let p = Vector3::new(0.3 * s(0.11, 0.0), 0.15 * s(0.07, 1.0), 0.25 * s(0.05, 0.5));
            let r = Vector3::new(0.03 * s(0.09, 0.3), 0.04 * s(0.06, 1.3), 0.02 * s(0.1, 2.0));
            Se3::from_parts(p.into(), so3::exp(&r))
        }
        MotionKind::Rpy => {
            let r = Vector3::new(0.3 * s(0.06, 0.0), 0.35 * s(0.045, 1.0), 0.3 * s(0.08, 2.0));
            let p = Vector3::new(0.02 * s(0.1, 0.0), 0.02 * s(0.07, 0.0), 0.02 * s(0.05, 0.0));
            Se3::from_parts(p.into(), so3::exp(&r))
        }
        MotionKind::Loop => {
            let angle = std::f64::consts::TAU * t / 30.0;
            let position = Vector3::new(0.6 * angle.sin(), 0.02 * s(0.2, 0.0), 0.6 * angle.cos());
            Se3::from_parts(
                position.into(),
                so3::exp(&Vector3::new(0.05 * s(0.1, 0.3), angle, 0.0)),
            )
        }
        MotionKind::Drive => {
            let (speed, period, amplitude) = (8.0, 40.0, 2.0);
            let w = std::f64::consts::TAU / period;
            let position = Vector3::new(amplitude * (w * t).sin(), 0.0, speed * t);
            let yaw = (amplitude * w * (w * t).cos() / speed).atan();
            let r = Vector3::new(0.004 * s(0.7, 0.2), yaw, 0.003 * s(0.9, 1.1));
            Se3::from_parts(position.into(), so3::exp(&r))
        }
        MotionKind::Halfsphere => {
            // Azimuth sweeps ±70°, elevation ±35°, radius 0.5 m around a centre 1.5 m ahead.
            let azimuth = 1.2 * s(0.03, 0.0);
            let elevation = 0.6 * s(0.047, 0.7);
            let centre = Vector3::new(0.0, 0.0, 1.5);
            let offset = Vector3::new(
                azimuth.sin() * elevation.cos(),
                -elevation.sin(),
                -azimuth.cos() * elevation.cos(),
            ) * 0.5;
            let position = centre + offset + Vector3::new(0.0, 0.0, -1.0);
            let forward = (centre - position).normalize();
            let up = Vector3::new(0.0, -1.0, 0.0);
            let right = up.cross(&forward).normalize() * -1.0;
            let down = forward.cross(&right);
            let rotation = nalgebra::Matrix3::from_columns(&[right, down, forward]);
            se3::from_parts(position, rotation)
        }
    }
}

/// Interpolates a trajectory at time `t` (linear in translation, slerp in rotation),
/// clamped to its ends. The trajectory's timestamps must be sorted.
pub fn interpolate(trajectory: &Trajectory, t: f64) -> Se3 {
    let stamps = &trajectory.timestamps;
    let upper = stamps.partition_point(|&s| s <= t);
    if upper == 0 {
        return trajectory.poses[0];
    }
    if upper == stamps.len() {
        return trajectory.poses[stamps.len() - 1];
    }
    let (a, b) = (&trajectory.poses[upper - 1], &trajectory.poses[upper]);
    let span = stamps[upper] - stamps[upper - 1];
    let alpha = if span > 0.0 {
        (t - stamps[upper - 1]) / span
    } else {
        0.0
    };
    let qa = UnitQuaternion::from_rotation_matrix(&a.rotation);
    let qb = UnitQuaternion::from_rotation_matrix(&b.rotation);
    let q = qa.slerp(&qb, alpha);
    se3::from_parts(
        a.translation.vector.lerp(&b.translation.vector, alpha),
        *q.to_rotation_matrix().matrix(),
    )
}

/// The camera poses at the given frame times (seconds from the start).
pub fn poses_at(config: &MotionConfig, times: &[f64]) -> Result<Vec<Se3>, IoError> {
    if config.kind != MotionKind::File {
        return Ok(times
            .iter()
            .map(|&t| procedural_pose(config.kind, config.start + t * config.speed))
            .collect());
    }
    let path = config.file.as_ref().ok_or_else(|| {
        IoError::invalid("synth config", "motion.kind = \"file\" needs motion.file")
    })?;
    let trajectory = Trajectory::read(path, config.format)?;
    if trajectory.is_empty() {
        return Err(IoError::invalid(path, "the trajectory is empty"));
    }
    let start = trajectory.timestamps[0] + config.start;
    let duration = trajectory.timestamps[trajectory.len() - 1] - trajectory.timestamps[0];
    if let Some(&last) = times.last() {
        let needed = config.start + last * config.speed;
        if needed > duration + 1e-9 {
            return Err(IoError::invalid(
                path,
                format!(
                    "covers {duration:.3} s but motion.start {} and {} frames need {needed:.3} s; ask for fewer frames",
                    config.start,
                    times.len(),
                ),
            ));
        }
    }
    Ok(times
        .iter()
        .map(|&t| interpolate(&trajectory, start + t * config.speed))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn procedural_motions_are_proper_poses() {
        for kind in [
            MotionKind::Static,
            MotionKind::Xyz,
            MotionKind::Rpy,
            MotionKind::Halfsphere,
        ] {
            for i in 0..50 {
                let pose = procedural_pose(kind, i as f64 * 0.7);
                let r = pose.rotation.matrix();
                assert!(
                    (r.transpose() * r - nalgebra::Matrix3::identity()).norm() < 1e-9,
                    "{kind:?}"
                );
                assert!((r.determinant() - 1.0).abs() < 1e-9, "{kind:?}");
            }
        }
    }

    #[test]
    fn the_loop_returns_to_its_start() {
        let (a, b) = (
            procedural_pose(MotionKind::Loop, 0.0),
            procedural_pose(MotionKind::Loop, 30.0),
        );
        assert!((a.translation.vector - b.translation.vector).norm() < 0.03);
        assert!((a.rotation.matrix() - b.rotation.matrix()).norm() < 0.1);
        let half = procedural_pose(MotionKind::Loop, 15.0);
        assert!((a.translation.vector - half.translation.vector).norm() > 1.1);
    }

    #[test]
    fn interpolation_hits_samples_and_midpoints() {
        let mut trajectory = Trajectory::default();
        trajectory.push(
            0.0,
            se3::exp(&nalgebra::Vector6::new(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)),
        );
        trajectory.push(
            1.0,
            se3::exp(&nalgebra::Vector6::new(1.0, 0.0, 0.0, 0.0, 0.0, 0.0)),
        );
        let mid = interpolate(&trajectory, 0.5);
        assert!((mid.translation.vector.x - 0.5).abs() < 1e-12);
        assert_eq!(interpolate(&trajectory, 5.0), trajectory.poses[1]);
    }

    #[test]
    fn a_file_motion_starts_where_motion_start_says_and_must_fit() {
        let dir = std::env::temp_dir().join(format!("dopslam-motion-start-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("poses.txt");
        // KITTI format: pose k at x = k metres.
        let rows: String = (0..10)
            .map(|k| format!("1 0 0 {k} 0 1 0 0 0 0 1 0\n"))
            .collect();
        std::fs::write(&file, rows).unwrap();
        let config = MotionConfig {
            kind: MotionKind::File,
            file: Some(file),
            format: TrajectoryFormat::Kitti,
            speed: 10.0,
            start: 4.0,
        };
        let poses = poses_at(&config, &[0.0, 0.1, 0.5]).unwrap();
        let x: Vec<f64> = poses.iter().map(|p| p.translation.vector.x).collect();
        assert!(
            (x[0] - 4.0).abs() < 1e-9 && (x[1] - 5.0).abs() < 1e-9 && (x[2] - 9.0).abs() < 1e-9,
            "{x:?}"
        );
        let message = poses_at(&config, &[0.0, 0.6]).unwrap_err().to_string();
        assert!(message.contains("motion.start 4"), "{message}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
