//! The DOP model's gate for one frame and its per-frame functions: [`Participation`]
//! says which map points and keypoints take part in the tracker's pose (the dynamic
//! ones never, those waiting for their keyframe's detection or out their probation
//! only when too few others remain) and carries the followed objects the frame's
//! probabilities see; [`propagate_and_expand`] and [`geometric_check`] are the model's
//! steps on one frame. The tracker receives a `Participation` with each frame from
//! [`super::Dynamics`].

use crate::dop::consistency::{Judgement, Verdict};
use crate::dop::tracks::FollowedObjects;
use crate::dop::DopConfig;
use crate::frame::Frame;
use crate::geometry::se3::Se3;
use crate::map::{Map, MapPoint, MapPointKey};

/// Which map points and keypoints take part in one frame's pose.
#[derive(Debug, Clone, Copy, Default)]
pub struct Participation<'a> {
    /// The DOP model (`None`: every point takes part, ORB-SLAM2's behaviour).
    pub dop: Option<&'a DopConfig>,
    /// The objects the model follows, as of the latest detection.
    pub followed: Option<&'a FollowedObjects>,
    /// The newest keyframe's points on probation (DOP only).
    pub probation: Option<Probation>,
}

/// How far around a dynamic box a new point still waits, as a share of the box's
/// width and height on each side (the map's wait zones, [`Map::set_wait_zones`], are
/// the latest detection's dynamic boxes, each widened by this and [`NEAR_BOX_PX`]:
/// [`crate::dop::boxes::ObjectBox::widened`]): the box is the latest detection's, a
/// keyframe or two old, and its mover has moved since.
pub const NEAR_BOX_SHARE: f32 = 0.5;
/// The same, pixels added on each side.
pub const NEAR_BOX_PX: f32 = 16.0;

/// The points of keyframe `keyframe_id` (the newest) stay out of the pose for
/// `frames` frames after it (`[tracking] probation_frames`); `frames_since` have passed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Probation {
    /// The keyframe whose detections the points wait for.
    pub keyframe_id: usize,
    /// Frames tracked since the points were made.
    pub frames_since: usize,
    /// Frames a point waits at most.
    pub frames: usize,
}

impl Participation<'_> {
    /// Whether a map point is left out as dynamic.
    pub fn excluded(&self, point: &MapPoint) -> bool {
        self.dop.is_some_and(|d| d.removed(point.moving))
    }

    /// Whether a map point waits: for the detection of the keyframe that created it, or
    /// out its probation; neither when it lies clear of the map's wait zones
    /// ([`Map::set_wait_zones`]).
    pub fn awaiting(&self, map: &Map, point: &MapPoint) -> bool {
        let on_probation = self
            .probation
            .is_some_and(|p| point.first_keyframe_id == p.keyframe_id && p.frames_since < p.frames);
        // Only a point that waits is looked up in its keyframe (most points do not),
        // and only once: [`Map::awaits_detection`] with the probation beside it.
        (map.keyframe_awaits_detection(point) || on_probation) && !map.clear_of_wait_zones(point)
    }

    /// Whether keypoint `i` of `frame` is in a removed (dynamic) state.
    pub fn dynamic_keypoint(&self, frame: &Frame, i: usize) -> bool {
        self.dop.is_some_and(|d| d.removed(frame.moving[i]))
    }

    /// The gate once the frame being tracked is counted (the keyframe decision looks at
    /// the frame after it was counted).
    pub fn counting_this_frame(&self) -> Self {
        Self {
            probation: self.probation.map(|p| Probation {
                frames_since: p.frames_since + 1,
                ..p
            }),
            ..*self
        }
    }
}

/// Propagation (map point, else last frame, else \(P_{init}\)) and, when on,
/// matching point expansion over `frame`'s keypoints; then, given the followed objects
/// and the frame's pose, the unknown keypoints on them are raised
/// ([`crate::dop::raise_unknown_in_boxes`]).
pub fn propagate_and_expand(
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
/// verdicts `checks` (map point, judgement), made at `time`. Frames where more than
/// `geometric_max_outliers` of the matches that took part in the pose are not
/// consistent are skipped: there the pose itself is in doubt. Returns the number of
/// points raised and lowered.
pub fn geometric_check(
    dop: &DopConfig,
    map: &mut Map,
    checks: &[(MapPointKey, Judgement)],
    time: f64,
) -> (usize, usize) {
    let mut judged = Vec::with_capacity(checks.len());
    let (mut total, mut outliers) = (0, 0);
    for &(key, judgement) in checks {
        let Some(point) = map.points().get(key) else {
            continue;
        };
        let dynamic = dop.removed(point.moving);
        if !dynamic {
            total += 1;
            outliers += usize::from(judgement != Judgement::Consistent);
        }
        judged.push((key, judgement, dynamic));
    }
    if total == 0 || outliers as f32 > dop.geometric_max_outliers * total as f32 {
        return (0, 0);
    }
    let (mut raised, mut lowered) = (0, 0);
    for (key, judgement, dynamic) in judged {
        let Some((moving, consistency)) = map.point_dop_mut(key) else {
            continue;
        };
        match consistency.judge(judgement, time, dynamic, moving, dop) {
            Verdict::Raised => raised += 1,
            Verdict::Lowered => lowered += 1,
            Verdict::Unchanged => {}
        }
    }
    (raised, lowered)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dop::boxes::ObjectBox;
    use nalgebra::Vector3;

    fn point(keyframe_id: usize, moving: f32) -> MapPoint {
        let mut p = MapPoint::new(
            Vector3::zeros(),
            [0; 4],
            Vector3::z(),
            (0.0, 0.0),
            keyframe_id,
        );
        p.moving = moving;
        p
    }

    #[test]
    fn without_the_model_every_point_takes_part() {
        let map = Map::default();
        let gate = Participation::default();
        assert!(!gate.excluded(&point(3, 1.0)));
        assert!(!gate.awaiting(&map, &point(3, 0.0)));
    }

    #[test]
    fn dynamic_points_are_left_out_and_new_ones_wait_out_their_probation() {
        let dop = DopConfig::default();
        let mut map = Map::default();
        let probation = Probation {
            keyframe_id: 7,
            frames_since: 1,
            frames: 2,
        };
        let gate = Participation {
            dop: Some(&dop),
            probation: Some(probation),
            ..Participation::default()
        };
        assert!(gate.excluded(&point(1, dop.removal_threshold + 0.01)));
        assert!(!gate.excluded(&point(1, dop.removal_threshold)));
        // The newest keyframe's points wait until `frames` frames have passed.
        assert!(gate.awaiting(&map, &point(7, 0.0)));
        assert!(!gate.counting_this_frame().awaiting(&map, &point(7, 0.0)));
        assert!(!gate.awaiting(&map, &point(6, 0.0)));
        // A keyframe waiting for its detection holds its points back.
        map.await_detection(6);
        assert!(gate.awaiting(&map, &point(6, 0.0)));
    }

    #[test]
    fn only_new_points_near_the_latest_boxes_wait_when_asked() {
        let dop = DopConfig::default();
        let mut map = Map::default();
        let mut frame = Frame::blank(4, (640, 480));
        // On the box, beside it within the widening (100 - 0.5 * 100 - 16 = 34 px),
        // beyond the widening, far from it.
        for (k, (x, y)) in [(110.0, 110.0), (40.0, 150.0), (30.0, 150.0), (500.0, 400.0)]
            .into_iter()
            .enumerate()
        {
            (frame.keypoints[k].x, frame.keypoints[k].y) = (x, y);
        }
        let key = map.add_keyframe(crate::map::KeyFrame::new(frame, Se3::identity()));
        let id = map.keyframes()[key].id;
        map.await_detection(id);
        let on = |i: usize| {
            let mut p = point(id, 0.0);
            p.observations.push((key, i));
            p
        };
        let boxes = [ObjectBox {
            bbox: [100.0, 100.0, 200.0, 300.0],
            dynamic: true,
            depth: None,
            moved: false,
        }
        .widened(NEAR_BOX_SHARE, NEAR_BOX_PX)];
        let gate = Participation {
            dop: Some(&dop),
            probation: Some(Probation {
                keyframe_id: id,
                frames_since: 0,
                frames: 2,
            }),
            ..Participation::default()
        };
        // Before any detection came back there is nothing to be clear of: all wait.
        assert!((0..4).all(|i| gate.awaiting(&map, &on(i))));
        assert!((0..4).all(|i| map.awaits_detection(&on(i))));
        map.set_wait_zones(Some(boxes.to_vec()));
        let waits: Vec<bool> = (0..4).map(|i| gate.awaiting(&map, &on(i))).collect();
        assert_eq!(waits, [true, true, false, false]);
        // Local BA reads the same wait from the map.
        let in_ba: Vec<bool> = (0..4).map(|i| map.awaits_detection(&on(i))).collect();
        assert_eq!(in_ba, waits);
        // Out of probation, after the detection came back, none waits.
        map.detection_came_back(id);
        let later = gate.counting_this_frame().counting_this_frame();
        assert!((0..4).all(|i| !later.awaiting(&map, &on(i))));
        // On probation alone, the zones still decide.
        let on_probation: Vec<bool> = (0..4).map(|i| gate.awaiting(&map, &on(i))).collect();
        assert_eq!(on_probation, [true, true, false, false]);
    }
}
