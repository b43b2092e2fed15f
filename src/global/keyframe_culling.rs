//! Redundant keyframes culled after loop closing (issue 83).
//!
//! Loop closing happens after tracking, so a route driven again is tracked as new
//! ground: every lap adds its own keyframes and points. Once the loops are closed,
//! their points are fused with the first visit's, and the later visits' keyframes see
//! what the earlier ones see. Local mapping's redundancy test (ORB-SLAM §VI-E:
//! 90 % of the close points seen by at least three other keyframes at the same or a
//! finer scale, [`crate::mapping::culling::is_redundant`]) then removes them, newest
//! first, before full BA builds its arrays: the map, full BA and the frames'
//! refinement follow the places seen, not the times they were seen. Frames tracked
//! against a culled keyframe keep their pose through it (`Map::remove_keyframe`).
//!
//! It runs only when a loop was closed: without one, local mapping has already
//! examined every keyframe against the keyframes around it.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::map::Map;
use crate::mapping::culling;

/// What the culling did (`report.json` `global.culling`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct CullingReport {
    /// Keyframes in the map before.
    pub keyframes_before: usize,
    /// Keyframes removed as redundant.
    pub keyframes_culled: usize,
    /// Map points before and after (a point no keyframe sees any more goes).
    pub points_before: usize,
    /// Map points after.
    pub points_after: usize,
    /// The culling's time.
    pub milliseconds: f64,
}

/// The test's settings: the close depth (metres) and the share of close points that
/// other keyframes must see (`[mapping] redundancy`).
#[derive(Debug, Clone, Copy)]
pub struct Redundancy {
    /// Points farther than this do not count (RGB-D and stereo: ORB-SLAM2's close points).
    pub close_depth: f32,
    /// The share of close points seen by three others that makes a keyframe redundant.
    pub share: f64,
}

/// Removes every redundant keyframe, newest first (the oldest keyframe of each map
/// segment stays: it holds the segment's world frame).
pub fn cull_redundant(map: &mut Map, redundancy: Redundancy) -> CullingReport {
    let start = Instant::now();
    let mut report = CullingReport {
        keyframes_before: map.keyframes().len(),
        points_before: map.points().len(),
        ..CullingReport::default()
    };
    // The oldest keyframe of each map segment holds its gauge, and stays.
    let anchors = map.segment_anchors();
    let order: Vec<_> = map.keyframe_order().iter().rev().copied().collect();
    for key in order {
        let rooted = map
            .keyframes()
            .get(key)
            .is_some_and(|kf| kf.parent.is_some());
        if !anchors.contains(&key)
            && rooted
            && culling::is_redundant(map, key, redundancy.close_depth, redundancy.share)
        {
            map.remove_keyframe(key);
            report.keyframes_culled += 1;
        }
    }
    report.points_after = map.points().len();
    report.milliseconds = start.elapsed().as_secs_f64() * 1e3;
    report
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Frame;
    use crate::geometry::se3::Se3;
    use crate::map::{KeyFrame, KeyFrameKey, MapPoint};
    use nalgebra::Vector3;

    fn keyframe(n: usize) -> KeyFrame {
        let frame = Frame::from_parts(
            0,
            0.0,
            vec![crate::features::KeyPoint::default(); n],
            vec![[0; 4]; n],
            vec![1.0; n],
            vec![1.0; n],
            (640, 480),
        );
        KeyFrame::new(frame, Se3::identity())
    }

    /// Two visits of one place: four keyframes each, every keyframe seeing the same
    /// twenty points (as after a loop's fusion; enough for covisibility edges), and one
    /// more point only the first visit's first keyframe sees.
    fn two_visits() -> (Map, Vec<KeyFrameKey>) {
        let mut map = Map::default();
        let keys: Vec<KeyFrameKey> = (0..8).map(|_| map.add_keyframe(keyframe(21))).collect();
        for i in 0..21 {
            let point = MapPoint::new(Vector3::z(), [0; 4], Vector3::z(), (0.1, 10.0), 0);
            let p = map.insert_point(point);
            let seen_by = if i == 20 { &keys[..1] } else { &keys[..] };
            for kf in seen_by {
                map.add_observation(p, *kf, i);
            }
        }
        for key in &keys {
            map.update_connections(*key);
        }
        (map, keys)
    }

    #[test]
    fn the_second_visit_goes_newest_first_and_the_oldest_stays() {
        let (mut map, keys) = two_visits();
        let redundancy = Redundancy {
            close_depth: 40.0,
            share: 0.9,
        };
        let report = cull_redundant(&mut map, redundancy);
        // Newest first: each keyframe goes while three others still see its points,
        // down to three keyframes, each seen with two others only. The oldest would
        // stay anyway (it holds the world frame).
        assert_eq!(report.keyframes_before, 8);
        assert_eq!(report.keyframes_culled, 5);
        assert_eq!(map.keyframe_order(), &keys[..3]);
        assert_eq!((report.points_before, report.points_after), (21, 21));
        // A share nothing reaches culls nothing.
        let (mut map, _) = two_visits();
        let strict = Redundancy {
            close_depth: 40.0,
            share: 1.0,
        };
        assert_eq!(cull_redundant(&mut map, strict).keyframes_culled, 0);
    }
}
