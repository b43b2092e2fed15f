//! The rigid motion between a keyframe and a loop candidate, as RANSAC
//! ([`crate::optim::ransac`]) fits it: Horn's closed form on the matched map points
//! in the two cameras' frames, a match an inlier when the motion carries each point
//! onto the other keyframe's keypoint within the \(\chi^2_2\) gate
//! (\(e^2 < 9.21\,\sigma^2_{level}\)) in both directions.

use nalgebra::{Point3, Vector3};

use super::candidates::LoopKeys;
use super::LoopInputs;
use crate::geometry::se3::Se3;
use crate::map::{KeyFrame, Map};
use crate::optim::ransac::Estimator;

/// The matched points of two keyframes `a` (the keyframe, \(k\)) and `b` (the
/// candidate, \(c\)) in each camera's frame.
pub struct RigidMotion<'a> {
    a: &'a KeyFrame,
    b: &'a KeyFrame,
    matches: &'a [(usize, usize)],
    /// \(P_k\): match m's point in the keyframe's camera frame.
    in_a: Vec<Vector3<f64>>,
    /// \(P_c\): the same in the candidate's.
    in_b: Vec<Vector3<f64>>,
    inputs: &'a LoopInputs,
}

impl<'a> RigidMotion<'a> {
    /// The matches `(keypoint of key, keypoint of candidate)`, each observing a point.
    pub fn new(
        map: &'a Map,
        keys: LoopKeys,
        matches: &'a [(usize, usize)],
        inputs: &'a LoopInputs,
    ) -> Self {
        let (a, b) = (
            &map.keyframes()[keys.keyframe],
            &map.keyframes()[keys.matched],
        );
        let in_camera = |kf: &KeyFrame, i: usize| -> Vector3<f64> {
            let p =
                map.points()[kf.map_points[i].expect("matched keypoints observe points")].position;
            (kf.camera_from_world * Point3::from(p)).coords
        };
        Self {
            a,
            b,
            matches,
            in_a: matches.iter().map(|&(i, _)| in_camera(a, i)).collect(),
            in_b: matches.iter().map(|&(_, j)| in_camera(b, j)).collect(),
            inputs,
        }
    }

    /// Whether `p` (in `kf`'s camera frame) projects onto `kf`'s keypoint `i`.
    fn reprojects(&self, kf: &KeyFrame, i: usize, p: &Vector3<f64>) -> bool {
        if p.z <= 0.0 {
            return false;
        }
        let uv = self.inputs.camera.project(p);
        let k = &kf.frame.keypoints[i];
        let e2 = (uv.x - k.x as f64).powi(2) + (uv.y - k.y as f64).powi(2);
        e2 < 9.21 * self.inputs.pyramid.sigma2[k.level as usize]
    }
}

impl Estimator for RigidMotion<'_> {
    /// \(T_{kc}\), with \(P_k = T_{kc} P_c\).
    type Model = Se3;

    fn count(&self) -> usize {
        self.matches.len()
    }

    fn sample_size(&self) -> usize {
        3
    }

    fn fit(&self, indices: &[usize]) -> Option<Se3> {
        let source: Vec<Vector3<f64>> = indices.iter().map(|&m| self.in_b[m]).collect();
        let target: Vec<Vector3<f64>> = indices.iter().map(|&m| self.in_a[m]).collect();
        let s = crate::geometry::alignment::horn(&source, &target).ok()?;
        Some(Se3::from_parts(s.translation.into(), s.rotation))
    }

    fn inliers(&self, t: &Se3) -> Vec<usize> {
        let inverse = t.inverse();
        (0..self.matches.len())
            .filter(|&m| {
                let (i, j) = self.matches[m];
                self.reprojects(self.a, i, &(t * Point3::from(self.in_b[m])).coords)
                    && self.reprojects(self.b, j, &(inverse * Point3::from(self.in_a[m])).coords)
            })
            .collect()
    }
}
