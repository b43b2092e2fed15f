//! The rigidity test of the geometric check: which matched points keep their distances
//! to the others. It needs no pose, so a mover that drags the pose along with it (a
//! large box close to the camera, in front of a flat wall that hardly constrains the
//! camera's sideways motion) is still seen to move.
//!
//! A matched point has a map position \(X_i\) (world) and, from the frame's depth, a
//! position \(Y_i\) (camera). Two static points keep their distance whatever the camera
//! did: \(\big|\,|X_i - X_j| - |Y_i - Y_j|\,\big| \le k \sqrt{\sigma_i^2 + \sigma_j^2}\),
//! with \(\sigma\) the depth noise at each point's depth. A point that moved since its
//! map position was made breaks this with every static partner. A point's *agreement*
//! is the share of its partners it keeps its distance to; the static points agree with
//! the static majority, a mover's points only with the mover's. This is the pairwise
//! invariant of robust registration (TEASER++'s, Yang et al. 2020) used as a vote.

use nalgebra::Vector3;

/// One matched point: its map position, its position from this frame's depth, and the
/// depth noise (standard deviation, metres) that bounds how far the two may disagree.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Matched {
    /// The point in the world frame (the map's).
    pub world: Vector3<f64>,
    /// The point in the camera frame (the frame's depth).
    pub camera: Vector3<f64>,
    /// The depth noise at the point, metres.
    pub sigma: f64,
}

/// Partners each point is compared with, at most (taken at an even stride): the
/// share's binomial spread at one half is then 0.044.
const MAX_PARTNERS: usize = 128;

/// Each point's agreement with `reference` (the points trusted for the pose): the
/// share of those partners (itself left out) whose distance it keeps within
/// `k_sigma` standard deviations. `None` where it has fewer than `min_partners`.
pub fn agreement(
    points: &[Matched],
    reference: &[usize],
    k_sigma: f64,
    min_partners: usize,
) -> Vec<Option<f32>> {
    // (world, camera, k^2 sigma^2) in f32: distances of a few metres to a millimetre.
    let k2 = (k_sigma * k_sigma) as f32;
    let compact = |p: &Matched| {
        (
            p.world.cast::<f32>(),
            p.camera.cast::<f32>(),
            k2 * (p.sigma * p.sigma) as f32,
        )
    };
    let compacted: Vec<_> = points.iter().map(compact).collect();
    let stride = reference.len().div_ceil(MAX_PARTNERS).max(1);
    let partners: Vec<usize> = reference
        .iter()
        .step_by(stride)
        .copied()
        .filter(|&j| j < points.len())
        .collect();
    compacted
        .iter()
        .enumerate()
        .map(|(i, (world, camera, spread))| {
            let (mut kept, mut compared) = (0usize, 0usize);
            for &j in partners.iter().filter(|&&j| j != i) {
                let (q_world, q_camera, q_spread) = &compacted[j];
                let change = (world - q_world).norm() - (camera - q_camera).norm();
                compared += 1;
                kept += usize::from(change * change <= spread + q_spread);
            }
            (compared >= min_partners).then(|| kept as f32 / compared as f32)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::depth_noise::DepthNoise;
    use crate::geometry::se3::{self, Se3};
    use crate::random::Rng;
    use proptest::prelude::*;

    /// `n` static points seen from `camera_from_world`, and `movers` more that moved by
    /// `shift` since the map was made.
    fn scene(
        camera_from_world: &Se3,
        n: usize,
        movers: usize,
        shift: Vector3<f64>,
        seed: u64,
    ) -> Vec<Matched> {
        let mut rng = Rng::new(seed);
        (0..n + movers)
            .map(|i| {
                let world = Vector3::new(
                    rng.range(-2.0, 2.0),
                    rng.range(-1.5, 1.5),
                    rng.range(1.0, 4.0),
                );
                let now = if i >= n { world + shift } else { world };
                let z = (camera_from_world * nalgebra::Point3::from(now)).coords;
                let sigma = DepthNoise::Rgbd.sigma(z.z);
                let noise = Vector3::new(rng.normal(), rng.normal(), rng.normal()) * sigma * 0.5;
                Matched {
                    world,
                    camera: z + noise,
                    sigma,
                }
            })
            .collect()
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(24))]
        #[test]
        fn points_that_moved_disagree_and_static_ones_agree_whatever_the_camera_did(
            motion in crate::geometry::se3::tests::tangent(1.0, 0.5),
            seed in 0u64..1000,
        ) {
            let camera_from_world = se3::exp(&motion);
            let points = scene(&camera_from_world, 200, 30, Vector3::new(0.4, 0.0, 0.2), seed);
            let all: Vec<usize> = (0..points.len()).collect();
            let shares = agreement(&points, &all, 3.0, 20);
            let static_low = shares[..200].iter().filter(|s| s.unwrap() < 0.5).count();
            let movers_high = shares[200..].iter().filter(|s| s.unwrap() >= 0.5).count();
            // At most 2 % of the static points lost; at least 80 % of the movers found (a
            // mover whose shift is across its partners' directions keeps some distances).
            prop_assert!(static_low <= 4, "{static_low} static points below half");
            prop_assert!(movers_high <= 6, "{movers_high} movers at half or more");
        }
    }

    #[test]
    fn too_few_partners_give_no_verdict() {
        let points = scene(&Se3::identity(), 5, 0, Vector3::zeros(), 1);
        let all: Vec<usize> = (0..5).collect();
        assert!(agreement(&points, &all, 3.0, 20)
            .iter()
            .all(Option::is_none));
        assert!(agreement(&points, &all, 3.0, 4)
            .iter()
            .all(|s| s == &Some(1.0)));
    }
}
