//! The DOP model frame by frame, as the tracker applies it: which map points and
//! keypoints are dynamic or wait, each tracked frame's moving probabilities
//! (propagation from its map points or the last frame, expansion, the followed objects'
//! boxes), the geometric check of the matches against the pose, and the keypoint budget
//! that makes up for the keypoints movers take. The run-wide DOP state (detections,
//! followed objects, what waits) is [`crate::dynamics`]'s; it hands the followed
//! objects here after each detection.

use super::Tracker;
use crate::dop::consistency::Verdict;
use crate::dop::tracks::FollowedObjects;
use crate::dop::DopConfig;
use crate::features::{hamming, TH_LOW};
use crate::frame::Frame;
use crate::geometry::se3::Se3;
use crate::map::{Map, MapPoint, MapPointKey};

impl Tracker {
    /// The keypoint budget for the next frame: `n_features` over the static share
    /// \(\phi\) of the last frame's keypoints (those the DOP model did not remove), so
    /// that movers taking keypoints do not leave the pose fewer static ones
    /// ([`crate::features::orb::OrbExtractor::with_budget`] clamps it).
    pub fn feature_budget(&self, n_features: usize) -> usize {
        let (Some(last), Some(dop)) = (&self.last, &self.dop) else {
            return n_features;
        };
        let total = last.frame.moving.len();
        let dynamic = last
            .frame
            .moving
            .iter()
            .filter(|p| dop.removed(**p))
            .count();
        let share = (total - dynamic) as f64 / total.max(1) as f64;
        (n_features as f64 / share.max(0.01)).round() as usize
    }

    /// After detections updated the map: the last frame's keypoints take their map
    /// points' probabilities (the others keep theirs), then expansion runs again, so the
    /// next frame propagates what the detections said.
    pub fn refresh_moving(&mut self, map: &Map) {
        let (Some(dop), Some(last)) = (self.dop.as_ref(), self.last.as_mut()) else {
            return;
        };
        let from_map: Vec<Option<f32>> = last
            .points
            .iter()
            .map(|k| k.and_then(|k| map.points.get(k)).map(|p| p.moving))
            .collect();
        let kept: Vec<Option<f32>> = last
            .frame
            .moving
            .iter()
            .zip(&from_map)
            .map(|(p, m)| (m.is_none() && *p != dop.p_init).then_some(*p))
            .collect();
        let followed = self.followed.as_ref().map(|f| (f, &last.camera_from_world));
        last.frame.moving = propagate_and_expand(dop, &last.frame, &from_map, &kept, followed);
    }

    /// Whether a map point is left out as dynamic.
    pub(super) fn excluded(&self, point: &MapPoint) -> bool {
        self.dop.as_ref().is_some_and(|d| d.removed(point.moving))
    }

    /// Whether a map point waits: for the detection of the keyframe that created it, or
    /// out its probation (made by the newest keyframe, `probation_frames` not yet past;
    /// only with the DOP model, so that `--no-dop` stays ORB-SLAM2's behaviour).
    pub(super) fn awaiting(&self, map: &Map, point: &MapPoint) -> bool {
        map.awaits_detection(point)
            || (self.dop.is_some()
                && point.first_keyframe_id == self.newest_keyframe_id
                && self.frames_since_keyframe < self.config.probation_frames)
    }

    /// Whether keypoint `i` of `frame` is in a removed (dynamic) state.
    pub(super) fn dynamic_keypoint(&self, frame: &Frame, i: usize) -> bool {
        self.dop
            .as_ref()
            .is_some_and(|d| d.removed(frame.moving[i]))
    }

    /// The DOP model's probabilities for a tracked frame at `camera_from_world`
    /// (propagation from its map points, else from the last frame's keypoints, else
    /// P_init; then expansion and the followed objects' boxes).
    pub(super) fn moving_probabilities(
        &self,
        dop: &DopConfig,
        map: &Map,
        frame: &Frame,
        camera_from_world: &Se3,
        points: &[Option<MapPointKey>],
    ) -> Vec<f32> {
        let from_map: Vec<Option<f32>> = points
            .iter()
            .map(|k| k.and_then(|k| map.points.get(k)).map(|p| p.moving))
            .collect();
        let from_last: Vec<Option<f32>> = match (&self.last, dop.propagation) {
            (Some(last), true) => (0..frame.len())
                .map(|i| {
                    if from_map[i].is_some() {
                        return None;
                    }
                    let k = &frame.keypoints[i];
                    let candidates = last.frame.features_in_area(
                        k.x,
                        k.y,
                        20.0,
                        k.level.saturating_sub(1),
                        k.level + 1,
                    );
                    candidates
                        .into_iter()
                        .map(|j| {
                            (
                                hamming(&frame.descriptors[i], &last.frame.descriptors[j]),
                                j,
                            )
                        })
                        .filter(|(d, _)| *d <= TH_LOW)
                        .min()
                        .map(|(_, j)| last.frame.moving[j])
                })
                .collect(),
            _ => vec![None; frame.len()],
        };
        let followed = self.followed.as_ref().map(|f| (f, camera_from_world));
        propagate_and_expand(dop, frame, &from_map, &from_last, followed)
    }
}

/// Propagation (map point, else last frame, else \(P_{init}\)) and, when on,
/// matching point expansion over `frame`'s keypoints; then, given the followed objects
/// and the frame's pose, the unknown keypoints on them are raised
/// ([`crate::dop::raise_unknown_in_boxes`]).
pub(super) fn propagate_and_expand(
    dop: &DopConfig,
    frame: &Frame,
    from_map: &[Option<f32>],
    from_last: &[Option<f32>],
    followed: Option<(&FollowedObjects, &Se3)>,
) -> Vec<f32> {
    let (p, origins) = crate::dop::propagate(from_map, from_last, dop.p_init);
    let mut p = if dop.expansion {
        let positions: Vec<(f32, f32)> = frame.keypoints.iter().map(|k| (k.x, k.y)).collect();
        crate::dop::expand(dop, &positions, &p, &origins)
    } else {
        p
    };
    if let Some((objects, camera_from_world)) = followed.filter(|_| dop.track_frames) {
        let boxes = objects.boxes_at(frame.timestamp, camera_from_world, dop);
        // Most frames have no person: no keypoint list to build.
        if !boxes.iter().any(|b| b.dynamic) {
            return p;
        }
        crate::dop::raise_unknown_in_boxes(
            dop,
            &frame.dop_keypoints(),
            &origins,
            &mut p,
            &boxes,
            objects.alpha,
        );
    }
    p
}

/// The DOP model's geometric check ([`crate::dop::consistency`]) on one frame's
/// verdicts `checks` (map point, consistent), made at `time`. Frames where more than
/// `geometric_max_outliers` of the matches that took part in the pose are inconsistent
/// are skipped: there the pose itself is in doubt. Returns the number of points raised
/// and lowered.
pub(super) fn geometric_check(
    dop: &DopConfig,
    map: &mut Map,
    checks: &[(MapPointKey, bool)],
    time: f64,
) -> (usize, usize) {
    let mut judged = Vec::with_capacity(checks.len());
    let (mut total, mut outliers) = (0, 0);
    for &(key, consistent) in checks {
        let Some(point) = map.points.get(key) else {
            continue;
        };
        let dynamic = dop.removed(point.moving);
        if !dynamic {
            total += 1;
            outliers += usize::from(!consistent);
        }
        judged.push((key, consistent, dynamic));
    }
    if total == 0 || outliers as f32 > dop.geometric_max_outliers * total as f32 {
        return (0, 0);
    }
    let (mut raised, mut lowered) = (0, 0);
    for (key, consistent, dynamic) in judged {
        let point = &mut map.points[key];
        match point
            .consistency
            .observe(consistent, time, dynamic, &mut point.moving, dop)
        {
            Verdict::Raised => raised += 1,
            Verdict::Lowered => lowered += 1,
            Verdict::Unchanged => {}
        }
    }
    (raised, lowered)
}
