//! Seeded synthetic pose graphs like the standard `sphere2500` benchmark: poses on
//! latitude rings of a sphere, odometry edges between consecutive poses and loop
//! edges between neighbouring rings, all measured with Gaussian noise; the initial
//! guess chains the noisy odometry, so it drifts as real odometry does.

use nalgebra::{Matrix6, Vector3};

use crate::geometry::se3::{self, Se3};
use crate::optim::pose_graph::{PoseEdge, PoseGraph};
use crate::random::Rng;

/// A sphere graph's shape and noise.
#[derive(Debug, Clone, Copy)]
pub struct SphereSpec {
    /// Rings of poses.
    pub rings: usize,
    /// Poses per ring.
    pub per_ring: usize,
    /// The sphere's radius, metres.
    pub radius: f64,
    /// Standard deviations of the measurements: metres and radians.
    pub sigma_translation: f64,
    /// Rotation noise, radians.
    pub sigma_rotation: f64,
}

impl Default for SphereSpec {
    /// 50 rings of 50 poses (2500) on a 50 m sphere, like `sphere2500`.
    fn default() -> Self {
        Self {
            rings: 50,
            per_ring: 50,
            radius: 50.0,
            sigma_translation: 0.05,
            sigma_rotation: 0.01,
        }
    }
}

/// The noisy graph (initial guess: chained odometry, first pose fixed) and the true
/// poses.
pub fn sphere(spec: &SphereSpec, seed: u64) -> (PoseGraph, Vec<Se3>) {
    let mut rng = Rng::new(seed);
    let mut truth = Vec::with_capacity(spec.rings * spec.per_ring);
    for ring in 0..spec.rings {
        let latitude = -std::f64::consts::FRAC_PI_2
            + std::f64::consts::PI * (ring as f64 + 0.5) / spec.rings as f64;
        for k in 0..spec.per_ring {
            let longitude = std::f64::consts::TAU * k as f64 / spec.per_ring as f64;
            // Facing along the ring (yaw), tilted with the latitude (pitch).
            let rotation = crate::geometry::so3::exp(&Vector3::new(0.0, 0.0, longitude))
                * crate::geometry::so3::exp(&Vector3::new(0.0, -latitude, 0.0));
            let position = spec.radius
                * Vector3::new(
                    latitude.cos() * longitude.cos(),
                    latitude.cos() * longitude.sin(),
                    latitude.sin(),
                );
            truth.push(Se3::from_parts(position.into(), rotation));
        }
    }
    let information = {
        let mut m = Matrix6::identity();
        for k in 0..3 {
            m[(k, k)] = 1.0 / spec.sigma_translation.powi(2);
            m[(k + 3, k + 3)] = 1.0 / spec.sigma_rotation.powi(2);
        }
        m
    };
    let mut edges = Vec::new();
    let measure = |rng: &mut Rng, from: usize, to: usize| PoseEdge {
        from,
        to,
        measurement: truth[from].inverse()
            * truth[to]
            * se3::gaussian(rng, spec.sigma_translation, spec.sigma_rotation),
        information,
    };
    let n = truth.len();
    for i in 1..n {
        edges.push(measure(&mut rng, i - 1, i));
    }
    for ring in 1..spec.rings {
        for k in 0..spec.per_ring {
            let to = ring * spec.per_ring + k;
            edges.push(measure(&mut rng, to - spec.per_ring, to));
        }
    }
    let mut poses = vec![truth[0]];
    for e in edges.iter().take(n - 1) {
        poses.push(poses[e.from] * e.measurement);
    }
    let mut fixed = vec![false; n];
    fixed[0] = true;
    (
        PoseGraph {
            poses,
            fixed,
            edges,
        },
        truth,
    )
}

/// Root mean square of the position errors (no alignment: pose 0 is fixed at the truth).
pub fn position_rmse(poses: &[Se3], truth: &[Se3]) -> f64 {
    let sum: f64 = poses
        .iter()
        .zip(truth)
        .map(|(a, b)| (a.translation.vector - b.translation.vector).norm_squared())
        .sum();
    (sum / truth.len().max(1) as f64).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::pose_graph::GraphOptions;

    #[test]
    fn a_noisy_sphere_converges_to_the_optimum_near_the_truth() {
        let spec = SphereSpec {
            rings: 16,
            per_ring: 25,
            radius: 20.0,
            ..SphereSpec::default()
        };
        for seed in [1, 2, 3] {
            let (mut graph, truth) = sphere(&spec, seed);
            let before = position_rmse(&graph.poses, &truth);
            let report = graph.optimise(&GraphOptions::default());
            let after = position_rmse(&graph.poses, &truth);
            assert!(report.converged, "{report:?}");
            // The same graph started at the truth reaches the same minimum.
            let mut from_truth = graph.clone();
            from_truth.poses = truth.clone();
            let best = from_truth.optimise(&GraphOptions::default()).final_cost;
            assert!(
                (report.final_cost - best).abs() < 1e-4 * best,
                "seed {seed}: {} vs {best}",
                report.final_cost
            );
            // At the optimum chi^2 follows its distribution: 6 E residuals less 6 (N - 1)
            // parameters.
            let n = graph.poses.len() as f64;
            let expected = 6.0 * graph.edges.len() as f64 - 6.0 * (n - 1.0);
            assert!(
                (report.final_cost / expected - 1.0).abs() < 0.15,
                "{} vs {expected}",
                report.final_cost
            );
            // Chained odometry drifts metres; the optimum keeps within the measurement
            // noise (2.5 % of the radius here).
            assert!(
                before > 3.0 && after < 0.5 * before.min(1.0) + 0.25,
                "seed {seed}: {before} -> {after}"
            );
        }
    }
}
