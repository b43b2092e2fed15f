//! KITTI's odometry metrics, as the devkit (`evaluate_odometry.cpp`) defines them.
//!
//! With ground-truth poses \(Q_i\) and estimated poses \(P_i\) (same frames), the path
//! length \(d_i = \sum_{k \le i} \lVert t(Q_k) - t(Q_{k-1}) \rVert\) gives, for every
//! 10th first frame \(f\) and each length \(L \in \{100, 200, \ldots, 800\}\) m, the
//! last frame \(l\): the first with \(d_l > d_f + L\) (none: no segment). Its error is
//!
//! \[ E = (P_f^{-1} P_l)^{-1} (Q_f^{-1} Q_l), \quad
//!    t_{err} = \lVert t(E) \rVert / L, \quad
//!    r_{err} = \arccos\bigl(\max(\min(\tfrac{1}{2}(\operatorname{tr} R(E) - 1), 1), -1)\bigr) / L. \]
//!
//! The sequence's figures are the means over all segments: translation in % (\(100\,
//! \bar t_{err}\)) and rotation in deg/100 m (\(100 \cdot 180/\pi \cdot \bar r_{err}\)).

use serde::{Deserialize, Serialize};

use crate::geometry::se3::Se3;

/// The devkit's segment lengths, metres.
pub const LENGTHS: [f64; 8] = [100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0];
/// The devkit's step between first frames.
pub const STEP: usize = 10;

/// The errors of one length.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LengthErrors {
    /// The segment length, metres.
    pub length_m: f64,
    /// Segments of that length.
    pub segments: usize,
    /// Mean translation error, % of the length.
    pub translation_percent: f64,
    /// Mean rotation error, degrees per 100 m.
    pub rotation_deg_per_100m: f64,
}

/// KITTI's relative errors of a trajectory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KittiErrors {
    /// Segments over all lengths (0: the path is shorter than 100 m).
    pub segments: usize,
    /// Mean relative translation error, %.
    pub translation_percent: f64,
    /// Mean relative rotation error, degrees per 100 m.
    pub rotation_deg_per_100m: f64,
    /// Per length, those with at least one segment.
    pub per_length: Vec<LengthErrors>,
}

/// Cumulative path length of `poses` (the devkit's `trajectoryDistances`).
pub fn path_distances(poses: &[Se3]) -> Vec<f64> {
    let mut distances = Vec::with_capacity(poses.len());
    let mut total = 0.0;
    for (i, pose) in poses.iter().enumerate() {
        if i > 0 {
            total += (pose.translation.vector - poses[i - 1].translation.vector).norm();
        }
        distances.push(total);
    }
    distances
}

/// The first frame after `first` whose path distance exceeds `first`'s by `length`.
fn last_frame(distances: &[f64], first: usize, length: f64) -> Option<usize> {
    (first..distances.len()).find(|&i| distances[i] > distances[first] + length)
}

/// KITTI's relative errors of `estimate` against `reference`, pose for pose; `None`
/// when the lengths differ.
pub fn kitti_errors(reference: &[Se3], estimate: &[Se3]) -> Option<KittiErrors> {
    if reference.len() != estimate.len() {
        return None;
    }
    let distances = path_distances(reference);
    // Per length: (segments, sum of t_err, sum of r_err).
    let mut sums = [(0usize, 0.0f64, 0.0f64); LENGTHS.len()];
    for first in (0..reference.len()).step_by(STEP) {
        for (k, &length) in LENGTHS.iter().enumerate() {
            let Some(last) = last_frame(&distances, first, length) else {
                continue;
            };
            let truth = reference[first].inverse() * reference[last];
            let estimated = estimate[first].inverse() * estimate[last];
            let error = estimated.inverse() * truth;
            let m = error.rotation.matrix();
            let cosine: f64 = (0.5 * (m[(0, 0)] + m[(1, 1)] + m[(2, 2)] - 1.0)).clamp(-1.0, 1.0);
            sums[k].0 += 1;
            sums[k].1 += error.translation.vector.norm() / length;
            sums[k].2 += cosine.acos() / length;
        }
    }
    let segments: usize = sums.iter().map(|s| s.0).sum();
    let to_report = |t: f64, r: f64, n: usize| {
        let n = n.max(1) as f64;
        (100.0 * t / n, 100.0 * r.to_degrees() / n)
    };
    let (t_all, r_all) = sums.iter().fold((0.0, 0.0), |a, s| (a.0 + s.1, a.1 + s.2));
    let (translation_percent, rotation_deg_per_100m) = to_report(t_all, r_all, segments);
    let per_length = LENGTHS
        .iter()
        .zip(&sums)
        .filter(|(_, s)| s.0 > 0)
        .map(|(&length_m, &(n, t, r))| {
            let (translation_percent, rotation_deg_per_100m) = to_report(t, r, n);
            LengthErrors {
                length_m,
                segments: n,
                translation_percent,
                rotation_deg_per_100m,
            }
        })
        .collect();
    Some(KittiErrors {
        segments,
        translation_percent,
        rotation_deg_per_100m,
        per_length,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Translation3, Vector3};

    /// A straight 300 m drive along z at 1 m a frame.
    fn straight(frames: usize) -> Vec<Se3> {
        (0..frames)
            .map(|i| Se3::from_parts(Translation3::new(0.0, 0.0, i as f64), Rotation3::identity()))
            .collect()
    }

    #[test]
    fn an_exact_estimate_has_no_error() {
        let truth = straight(301);
        let errors = kitti_errors(&truth, &truth).unwrap();
        assert!(errors.segments > 0);
        assert!(errors.translation_percent < 1e-9);
        assert!(errors.rotation_deg_per_100m < 1e-6);
        // 100 m segments start every 10 frames while 101 m remain: frames 0..=190.
        assert_eq!(errors.per_length[0].segments, 20);
        assert_eq!(errors.per_length.len(), 2);
    }

    #[test]
    fn a_scale_drift_of_one_percent_reads_one_percent() {
        let truth = straight(501);
        let estimate: Vec<Se3> = truth
            .iter()
            .map(|p| Se3::from_parts(Translation3::from(p.translation.vector * 1.01), p.rotation))
            .collect();
        let errors = kitti_errors(&truth, &estimate).unwrap();
        // Each segment spans the first frame whose distance exceeds L: L + 1 m, so the
        // error is 1 % of (L + 1) over L.
        for length in &errors.per_length {
            let expected = (length.length_m + 1.0) / length.length_m;
            assert!(
                (length.translation_percent - expected).abs() < 1e-9,
                "{length:?}"
            );
        }
        assert!(errors.rotation_deg_per_100m.abs() < 1e-6);
    }

    #[test]
    fn a_constant_heading_error_is_alignment_free() {
        // The estimate is the truth seen from a rotated, shifted world: relative
        // errors do not change.
        let truth: Vec<Se3> = (0..400)
            .map(|i| {
                let a = i as f64 * 0.01;
                Se3::from_parts(
                    Translation3::new(50.0 * a.sin(), 0.0, 50.0 * (1.0 - a.cos())),
                    Rotation3::from_scaled_axis(Vector3::y() * a),
                )
            })
            .collect();
        let world = Se3::from_parts(
            Translation3::new(3.0, -2.0, 7.0),
            Rotation3::from_euler_angles(0.1, 0.4, -0.2),
        );
        let estimate: Vec<Se3> = truth.iter().map(|p| world * p).collect();
        let errors = kitti_errors(&truth, &estimate).unwrap();
        assert!(errors.segments > 0);
        assert!(errors.translation_percent < 1e-9, "{errors:?}");
        assert!(kitti_errors(&truth, &estimate[1..]).is_none());
    }
}
