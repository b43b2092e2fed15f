//! The relative pose error.
//!
//! For pose pairs \((i, j)\) with reference \(Q\) and estimate \(P\) (evo's `rpe_base`):
//!
//! \[ E_{ij} = (Q_i^{-1} Q_j)^{-1} (P_i^{-1} P_j) \]
//!
//! Pairs are chosen as evo does from the estimate's poses: every `delta`-th frame
//! (consecutive pairs \(0, \delta, 2\delta, \ldots\)), or by travelled path length (metres)
//! or rotation angle. With a delta in **seconds** evo has no definition; we follow TUM's
//! `evaluate_rpe.py --fixed_delta`: for each estimated pose \(i\), \(j\) is the pose
//! closest in time to \(t_i + \delta\) (pairs ending at the last pose are dropped), each
//! matched to the nearest ground-truth stamps within twice the median ground-truth
//! interval, with \(E = ((P_j^{-1}P_i)^{-1}(Q_j^{-1}Q_i))\) as the script writes it; the
//! errors are divided by \(\delta\) so they read as rates (m/s, deg/s).

use serde::{Deserialize, Serialize};

use crate::geometry::se3::{self, Se3};
use crate::geometry::so3;
use crate::io::Trajectory;

use super::ate::PoseRelation;
use super::stats::median_of_sorted;

/// The unit of the RPE delta.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum DeltaUnit {
    /// Frames (evo's `f`).
    #[value(name = "f")]
    Frames,
    /// Metres of travelled path (evo's `m`).
    #[value(name = "m")]
    Metres,
    /// Degrees of accumulated rotation (evo's `d`).
    #[value(name = "d")]
    Degrees,
    /// Radians of accumulated rotation (evo's `r`).
    #[value(name = "r")]
    Radians,
    /// Seconds (TUM's evaluate_rpe.py); errors reported per second.
    #[value(name = "s")]
    Seconds,
}

impl DeltaUnit {
    /// The unit as printed: `frames`, `m`, `deg`, `rad` or `s`.
    pub fn symbol(self) -> &'static str {
        match self {
            Self::Frames => "frames",
            Self::Metres => "m",
            Self::Degrees => "deg",
            Self::Radians => "rad",
            Self::Seconds => "s",
        }
    }
}

/// evo's consecutive pairs every `delta` frames: \((0,\delta), (\delta, 2\delta), \ldots\)
pub fn pairs_by_index(len: usize, delta: usize) -> Vec<(usize, usize)> {
    let ids: Vec<usize> = (0..len).step_by(delta.max(1)).collect();
    ids.windows(2).map(|w| (w[0], w[1])).collect()
}

/// evo's consecutive pairs by accumulated motion: a new id each time the motion
/// accumulated since the last id reaches `delta`.
fn pairs_by_accumulation(
    len: usize,
    delta: f64,
    step: impl Fn(usize) -> f64,
) -> Vec<(usize, usize)> {
    let mut ids = vec![0];
    let mut accumulated = 0.0;
    for i in 1..len {
        accumulated += step(i);
        if accumulated >= delta {
            ids.push(i);
            accumulated = 0.0;
        }
    }
    ids.windows(2).map(|w| (w[0], w[1])).collect()
}

/// Consecutive pairs by travelled path (metres).
pub fn pairs_by_path(poses: &[Se3], delta: f64) -> Vec<(usize, usize)> {
    pairs_by_accumulation(poses.len(), delta, |i| {
        (poses[i].translation.vector - poses[i - 1].translation.vector).norm()
    })
}

/// Consecutive pairs by accumulated rotation angle.
pub fn pairs_by_angle(poses: &[Se3], delta: f64, degrees: bool) -> Vec<(usize, usize)> {
    pairs_by_accumulation(poses.len(), delta, |i| {
        let angle = so3::angle(se3::relative(&poses[i - 1], &poses[i]).rotation.matrix());
        if degrees {
            angle.to_degrees()
        } else {
            angle
        }
    })
}

/// The RPE errors of associated, equally long pose lists (frames, metres, angles).
pub fn relative_errors(
    reference: &[Se3],
    estimate: &[Se3],
    pairs: &[(usize, usize)],
    relation: PoseRelation,
) -> Vec<f64> {
    pairs
        .iter()
        .map(|&(i, j)| {
            let q_rel = se3::relative(&reference[i], &reference[j]);
            let p_rel = se3::relative(&estimate[i], &estimate[j]);
            relation.error_of(&se3::relative(&q_rel, &p_rel))
        })
        .collect()
}

/// TUM's `find_closest_index`: a binary search that remembers the closest element seen.
pub fn find_closest_index(sorted: &[f64], t: f64) -> usize {
    let mut beginning = 0;
    let mut end = sorted.len();
    let mut best = 0;
    let mut difference = (sorted[0] - t).abs();
    while beginning < end {
        let middle = (beginning + end) / 2;
        if (sorted[middle] - t).abs() < difference {
            difference = (sorted[middle] - t).abs();
            best = middle;
        }
        if t == sorted[middle] {
            return middle;
        } else if sorted[middle] > t {
            end = middle;
        } else {
            beginning = middle + 1;
        }
    }
    best
}

/// RPE with a delta in seconds, as TUM's `evaluate_rpe.py --fixed_delta` (see the module
/// doc). Works on the whole (aligned) estimate and the whole reference, not on the
/// associated pairs. Returns `(t_i, error / delta_s)` for each pair.
pub fn relative_errors_seconds(
    reference: &Trajectory,
    estimate: &Trajectory,
    delta_s: f64,
    offset: f64,
    relation: PoseRelation,
) -> Vec<(f64, f64)> {
    let (gt_t, est_t) = (&reference.timestamps, &estimate.timestamps);
    if gt_t.len() < 2 || est_t.len() < 2 {
        return Vec::new();
    }
    let mut intervals: Vec<f64> = gt_t.windows(2).map(|w| w[1] - w[0]).collect();
    intervals.sort_by(f64::total_cmp);
    let max_gap = 2.0 * median_of_sorted(&intervals);
    let last = est_t.len() - 1;
    let mut errors = Vec::new();
    for i in 0..est_t.len() {
        let j = find_closest_index(est_t, est_t[i] + delta_s);
        if j == last {
            continue;
        }
        let g0 = find_closest_index(gt_t, est_t[i] + offset);
        let g1 = find_closest_index(gt_t, est_t[j] + offset);
        if (gt_t[g0] - (est_t[i] + offset)).abs() > max_gap
            || (gt_t[g1] - (est_t[j] + offset)).abs() > max_gap
        {
            continue;
        }
        let est_motion = se3::relative(&estimate.poses[j], &estimate.poses[i]);
        let gt_motion = se3::relative(&reference.poses[g1], &reference.poses[g0]);
        let error = se3::relative(&est_motion, &gt_motion);
        let value = match relation {
            PoseRelation::TransPart => error.translation.vector.norm(),
            other => other.error_of(&error),
        };
        errors.push((est_t[i], value / delta_s));
    }
    errors
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector6;

    #[test]
    fn pairs_follow_evo() {
        assert_eq!(pairs_by_index(7, 3), vec![(0, 3), (3, 6)]);
        assert_eq!(pairs_by_index(3, 1), vec![(0, 1), (1, 2)]);
        let poses: Vec<Se3> = [0.0, 0.4, 0.7, 1.2, 1.3, 2.5]
            .iter()
            .map(|&x| se3::exp(&Vector6::new(x, 0.0, 0.0, 0.0, 0.0, 0.0)))
            .collect();
        // path since last id: 0.4, 0.7 (<1), 1.2 -> id 3; 0.1, 1.3 -> id 5
        assert_eq!(pairs_by_path(&poses, 1.0), vec![(0, 3), (3, 5)]);
    }

    #[test]
    fn closest_index_matches_the_script() {
        let v = [0.0, 1.0, 2.0, 3.0];
        assert_eq!(find_closest_index(&v, 1.4), 1);
        assert_eq!(find_closest_index(&v, 1.6), 2);
        assert_eq!(find_closest_index(&v, -5.0), 0);
        assert_eq!(find_closest_index(&v, 9.0), 3);
        assert_eq!(find_closest_index(&v, 2.0), 2);
    }

    #[test]
    fn a_constant_drift_gives_a_constant_relative_error() {
        let mut gt = Trajectory::default();
        let mut est = Trajectory::default();
        for i in 0..50 {
            let t = i as f64 * 0.1;
            gt.push(t, se3::exp(&Vector6::new(t, 0.0, 0.0, 0.0, 0.0, 0.0)));
            est.push(t, se3::exp(&Vector6::new(1.1 * t, 0.0, 0.0, 0.0, 0.0, 0.0)));
        }
        let errors = relative_errors(
            &gt.poses,
            &est.poses,
            &pairs_by_index(50, 10),
            PoseRelation::TransPart,
        );
        assert!(errors.iter().all(|e| (e - 0.1).abs() < 1e-12));
        let per_second = relative_errors_seconds(&gt, &est, 1.0, 0.0, PoseRelation::TransPart);
        assert_eq!(
            per_second.len(),
            39,
            "pairs whose end is the last pose are dropped"
        );
        assert!(
            per_second.iter().all(|e| (e.1 - 0.1).abs() < 1e-9),
            "{per_second:?}"
        );
    }
}
