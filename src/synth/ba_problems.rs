//! Seeded synthetic bundle-adjustment problems shaped like an RGB-D SLAM map: keyframes
//! along a wandering path through a room, each seeing the points of the walls and
//! furniture in front of it (about 100-400 observations per keyframe, every point seen
//! by several keyframes), stereo-like measurements (ORB-SLAM2's virtual right
//! coordinate) with pixel noise, and poses and points perturbed from the truth.

use nalgebra::{Point3, Vector3};

use crate::geometry::se3::{self, Se3};
use crate::geometry::stereo_camera::StereoCamera;
use crate::optim::local_ba::{BaObservation, BaProblem};
use crate::random::Rng;

/// The shape of a problem.
#[derive(Debug, Clone, Copy)]
pub struct BaSpec {
    /// Keyframes.
    pub keyframes: usize,
    /// Points.
    pub points: usize,
    /// Pixel noise of the measurements.
    pub pixel_sigma: f64,
    /// Perturbation of the initial poses (metres, radians) and points (metres).
    pub pose_sigma: (f64, f64),
    /// Perturbation of the initial points, metres.
    pub point_sigma: f64,
    /// Observations per keyframe at most (a keyframe's map points, ORB-SLAM2: a few
    /// hundred); the visible points beyond are left unseen at random.
    pub per_keyframe: usize,
}

impl BaSpec {
    /// `keyframes` keyframes and `points` points, at most 600 observations a keyframe,
    /// 0.5 px noise, 3 cm / 0.6 degree pose and 5 cm point perturbations.
    pub fn new(keyframes: usize, points: usize) -> Self {
        Self {
            keyframes,
            points,
            pixel_sigma: 0.5,
            pose_sigma: (0.03, 0.01),
            point_sigma: 0.05,
            per_keyframe: 600,
        }
    }
}

/// `n` points on the walls of a 8 x 3 x 8 m room and on boxes inside it.
fn room_points(n: usize, rng: &mut Rng) -> Vec<Vector3<f64>> {
    (0..n)
        .map(|_| {
            let (a, b) = (rng.range(-4.0, 4.0), rng.range(-1.5, 1.5));
            match rng.next_u64() % 5 {
                0 => Vector3::new(a, b, 4.0),
                1 => Vector3::new(a, b, -4.0),
                2 => Vector3::new(4.0, b, a),
                3 => Vector3::new(-4.0, b, a),
                _ => Vector3::new(
                    rng.range(-2.5, 2.5),
                    rng.range(0.0, 1.5),
                    rng.range(-2.5, 2.5),
                ),
            }
        })
        .collect()
}

/// `n` poses (camera-from-world) along a slow loop around the room's centre, looking
/// outwards and sideways.
fn loop_poses(n: usize) -> Vec<Se3> {
    (0..n)
        .map(|i| {
            let t = i as f64 / n as f64;
            let angle = std::f64::consts::TAU * 1.5 * t;
            let centre = Vector3::new(
                1.2 * (2.0 * angle).cos(),
                0.1 * (5.0 * angle).sin(),
                1.2 * angle.sin(),
            );
            let world_from_camera = Se3::from_parts(
                centre.into(),
                crate::geometry::so3::exp(&Vector3::new(0.05 * (3.0 * angle).sin(), angle, 0.0)),
            );
            world_from_camera.inverse()
        })
        .collect()
}

/// The problem (first pose fixed), the true poses (camera-from-world) and points.
pub fn room_problem(
    spec: &BaSpec,
    camera: &StereoCamera,
    seed: u64,
) -> (BaProblem, Vec<Se3>, Vec<Vector3<f64>>) {
    let mut rng = Rng::new(seed);
    let points = room_points(spec.points, &mut rng);
    let poses = loop_poses(spec.keyframes);
    let mut observations = Vec::new();
    for (c, pose) in poses.iter().enumerate() {
        let visible: Vec<(usize, Vector3<f64>)> = points
            .iter()
            .enumerate()
            .filter_map(|(j, x)| {
                let p = (pose * Point3::from(*x)).coords;
                let z = camera.project(&p);
                let inside = (0.0..640.0).contains(&z.x) && (0.0..480.0).contains(&z.y);
                (p.z > 0.3 && p.z < 6.0 && inside).then_some((j, z))
            })
            .collect();
        let keep = spec.per_keyframe as f64 / visible.len().max(1) as f64;
        for (j, z) in visible {
            if rng.uniform() >= keep {
                continue;
            }
            let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * spec.pixel_sigma;
            observations.push(BaObservation {
                camera: c,
                point: j,
                measurement: z + noise,
                stereo: true,
                information: 1.0 / (spec.pixel_sigma * spec.pixel_sigma),
            });
        }
    }
    let (ts, rs) = spec.pose_sigma;
    let initial_poses = poses
        .iter()
        .enumerate()
        .map(|(i, t)| {
            if i == 0 {
                *t
            } else {
                se3::gaussian(&mut rng, ts, rs) * t
            }
        })
        .collect();
    let initial_points = points
        .iter()
        .map(|x| x + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * spec.point_sigma)
        .collect();
    let problem = BaProblem {
        poses: initial_poses,
        fixed: (0..spec.keyframes).map(|i| i == 0).collect(),
        points: initial_points,
        observations,
    };
    (problem, poses, points)
}

/// RMS of the camera-centre errors, metres.
pub fn centre_rmse(poses: &[Se3], truth: &[Se3]) -> f64 {
    let sum: f64 = poses
        .iter()
        .zip(truth)
        .map(|(a, b)| {
            (a.inverse().translation.vector - b.inverse().translation.vector).norm_squared()
        })
        .sum();
    (sum / truth.len().max(1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::local_ba::bundle_adjust;

    #[test]
    fn a_room_problem_converges_to_the_truth() {
        let camera = StereoCamera::new(&crate::geometry::camera::PinholeCamera::tum_fr3(), 40.0);
        let (mut problem, poses, _) = room_problem(&BaSpec::new(40, 2000), &camera, 3);
        let per_keyframe = problem.observations.len() / 40;
        assert!(
            per_keyframe > 100,
            "{per_keyframe} observations per keyframe"
        );
        let before = centre_rmse(&problem.poses, &poses);
        let report = bundle_adjust(&mut problem, &camera, 10, 5);
        let after = centre_rmse(&problem.poses, &poses);
        assert!(before > 0.03 && after < 0.003, "{before} -> {after}");
        // Whitened errors follow chi^2(3): about 5 % lie above the 95 % gate (fewer
        // after the inlier pass fits them).
        let outliers = report.inliers.iter().filter(|i| !**i).count() as f64;
        let share = outliers / report.inliers.len() as f64;
        assert!((0.02..0.07).contains(&share), "{share}");
    }
}
