//! A loop confirmed by the loops found next (ORB-SLAM3's geometric check over
//! consecutive keyframes, offline): stage 3 can pass a wrong rigid motion where a
//! place repeats itself (26 inliers and 98 guided matches between two views of one
//! street corner 44 degrees apart put a keyframe 41 degrees off on the KITTI 00
//! street, where tracking had drifted 0.6 degrees). The next keyframes that found the
//! same place are verified on their own, and each gives the loop keyframe's pose
//! through their tracked relative pose; a loop that every one of them places
//! elsewhere is not closed. A loop that none of them can check is closed as before.

use crate::geometry::se3::Se3;

/// The most two placements of one keyframe may differ by, degrees.
pub const AGREE_DEG: f64 = 3.0;
/// And metres, plus [`AGREE_SHARE`] of the distance between the two keyframes.
pub const AGREE_M: f64 = 1.0;
/// The share of the distance between the two keyframes added to [`AGREE_M`].
pub const AGREE_SHARE: f64 = 0.05;

/// How far apart two placements of a loop keyframe are.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Disagreement {
    /// Between the camera centres, metres.
    pub metres: f64,
    /// Between the orientations, degrees.
    pub degrees: f64,
    /// What the centres may differ by, metres.
    pub tolerance_m: f64,
}

impl Disagreement {
    /// The loop keyframe `keyframe` (its pose now, \(T_{kw}\)) corrected to
    /// `corrected` (\(T'_{kw}\)), against a later keyframe (`later`, \(T_{lw}\)) that
    /// its own loop corrects to `later_corrected`: the later one's placement predicted
    /// from the first loop, \(T_{lw} T_{kw}^{-1} T'_{kw}\), against its own.
    pub fn between(keyframe: &Se3, corrected: &Se3, later: &Se3, later_corrected: &Se3) -> Self {
        let predicted = later * keyframe.inverse() * corrected;
        let centre = |camera_from_world: &Se3| camera_from_world.inverse().translation.vector;
        let turn = later_corrected.rotation * predicted.rotation.inverse();
        Self {
            metres: (centre(&predicted) - centre(later_corrected)).norm(),
            degrees: turn.angle().to_degrees(),
            tolerance_m: AGREE_M + AGREE_SHARE * (centre(later) - centre(keyframe)).norm(),
        }
    }

    /// Whether the two placements agree.
    pub fn agrees(&self) -> bool {
        self.degrees <= AGREE_DEG && self.metres <= self.tolerance_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Translation3, Vector3};

    fn pose(t: [f64; 3], axis_angle: [f64; 3]) -> Se3 {
        Se3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            Rotation3::from_scaled_axis(Vector3::from(axis_angle)),
        )
    }

    #[test]
    fn two_loops_that_move_the_map_alike_agree_and_a_turned_one_does_not() {
        // Two keyframes 5 m apart along a drifted path; the truth moves both by the
        // same correction.
        let keyframe = pose([0.0, 0.0, 0.0], [0.0, 0.1, 0.0]);
        let later = pose([0.3, 0.0, -5.0], [0.0, 0.15, 0.0]);
        let correction = pose([8.0, 0.5, -3.0], [0.0, 0.3, 0.02]);
        let corrected = keyframe * correction;
        let later_corrected = later * correction;
        let same = Disagreement::between(&keyframe, &corrected, &later, &later_corrected);
        assert!(same.metres < 1e-9 && same.degrees < 1e-6, "{same:?}");
        assert!(same.agrees());
        // A little noise in the second loop still agrees.
        let noisy = pose([0.2, 0.0, 0.1], [0.0, 0.01, 0.0]) * later_corrected;
        assert!(Disagreement::between(&keyframe, &corrected, &later, &noisy).agrees());
        // A first loop 40 degrees off places the later keyframe far from its own loop.
        let wrong = pose([0.0, 0.0, 0.0], [0.0, 0.7, 0.0]) * corrected;
        let apart = Disagreement::between(&keyframe, &wrong, &later, &later_corrected);
        assert!(apart.degrees > 35.0 && !apart.agrees(), "{apart:?}");
    }
}
