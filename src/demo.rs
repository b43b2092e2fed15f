//! A generated example for the quick start: a ground-truth trajectory sampled at 100 Hz
//! like a motion-capture system, and a drifting, noisy "estimate" at 30 Hz expressed in
//! its own frame (its first pose is the identity, as a SLAM system writes it).
//!
//! Until the tracking pass exists this is what `dopslam demo` evaluates; the estimate's
//! drift and noise are known, so the printed ATE can be checked by eye.

use nalgebra::{Vector3, Vector6};

use crate::geometry::se3::{self, Se3};
use crate::io::Trajectory;
use crate::random::Rng;

/// The ground-truth pose at time `t` (s): a hand-held camera swaying along all three
/// axes in front of a desk, like TUM's fr3 xyz motions.
pub fn demo_pose(t: f64) -> Se3 {
    let position = Vector3::new(
        1.2 + 0.35 * (0.45 * t).sin(),
        -0.4 + 0.15 * (0.8 * t + 0.3).sin(),
        1.5 + 0.2 * (0.3 * t).sin(),
    );
    let rotation = Vector3::new(
        0.1 * (0.4 * t).sin(),
        0.15 * (0.25 * t).sin(),
        0.05 * (0.6 * t).cos(),
    );
    let base = se3::exp(&Vector6::new(0.0, 0.0, 0.0, -1.9, 0.2, 0.3));
    Se3::from_parts(
        position.into(),
        base.rotation * crate::geometry::so3::exp(&rotation),
    )
}

/// Ground truth (100 Hz) and a drifting estimate (30 Hz, timestamps jittered by ±2 ms)
/// over `duration_s` seconds. The estimate's drift is a seeded random walk of
/// `drift_m_per_sqrt_s` metres per square-root second plus white noise of 3 mm.
pub fn demo_trajectories(
    seed: u64,
    duration_s: f64,
    drift_m_per_sqrt_s: f64,
) -> (Trajectory, Trajectory) {
    let mut rng = Rng::new(seed);
    let t0 = 1_700_000_000.0;
    let mut ground_truth = Trajectory::default();
    let gt_count = (duration_s * 100.0) as usize;
    for i in 0..gt_count {
        let t = i as f64 / 100.0;
        ground_truth.push(t0 + t, demo_pose(t));
    }
    let mut estimate = Trajectory::default();
    let first_inverse = demo_pose(0.0).inverse();
    let mut drift = Vector3::zeros();
    let mut yaw_drift = 0.0;
    let dt = 1.0 / 30.0;
    let est_count = (duration_s * 30.0) as usize;
    for i in 0..est_count {
        let t = i as f64 * dt;
        let jitter = rng.range(-0.002, 0.002);
        let step = drift_m_per_sqrt_s * dt.sqrt();
        drift += Vector3::new(rng.normal(), rng.normal(), rng.normal()) * step;
        yaw_drift += 0.002 * dt.sqrt() * rng.normal();
        let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.003;
        let truth = first_inverse * demo_pose(t + jitter);
        let perturbed = Se3::from_parts(
            (truth.translation.vector + drift + noise).into(),
            crate::geometry::so3::exp(&Vector3::new(0.0, yaw_drift, 0.0)) * truth.rotation,
        );
        estimate.push(t0 + t + jitter, perturbed);
    }
    (ground_truth, estimate)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::{evaluate, EvalOptions};

    #[test]
    fn demo_is_seeded_and_evaluates_to_its_noise_level() {
        let (gt, est) = demo_trajectories(1, 20.0, 0.0);
        let (_, again) = demo_trajectories(1, 20.0, 0.0);
        assert_eq!(est, again);
        let report = evaluate(&gt, &est, &EvalOptions::default()).unwrap();
        // Only 3 mm white noise (and up to 2 ms of timing jitter): ATE ~ 3 mm * sqrt(3).
        let rmse = report.ape.statistics.rmse;
        assert!((0.004..0.007).contains(&rmse), "{rmse}");
        assert_eq!(report.matched_poses, est.len());
        let (_, drifting) = demo_trajectories(1, 20.0, 0.01);
        let worse = evaluate(&gt, &drifting, &EvalOptions::default())
            .unwrap()
            .ape
            .statistics
            .rmse;
        assert!(worse > rmse);
    }
}
