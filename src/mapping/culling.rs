//! Map point and keyframe culling (ORB-SLAM §VI-B and §VI-E).
//!
//! A recent point survives its first three keyframes only if tracking finds it in at
//! least a quarter of the frames that should see it (\(found / visible \ge 0.25\)) and,
//! from two keyframes after its creation, at least two keyframes observe it.
//!
//! A keyframe is redundant when at least 90 % of its close map points are seen by at
//! least three other keyframes at the same or a finer scale (ORB-SLAM2 counts only
//! close points for RGB-D and stereo); the map's first keyframe is never removed.

use crate::map::{KeyFrameKey, Map, MapPointKey};

/// Culls the recent points (`recent`, kept in creation order) given the id of the
/// keyframe being processed; returns how many were removed. Points that have passed
/// their probation leave the list.
pub fn cull_points(map: &mut Map, recent: &mut Vec<MapPointKey>, current_id: usize) -> usize {
    let mut removed = 0;
    recent.retain(|&key| {
        let Some(point) = map.points().get(key) else {
            return false;
        };
        let age = current_id.saturating_sub(point.first_keyframe_id);
        if point.found_ratio() < 0.25 || (age >= 2 && point.observations.len() < 2) {
            map.remove_point(key);
            removed += 1;
            false
        } else {
            age < 3
        }
    });
    removed
}

/// Whether `keyframe` is redundant (see the module notes); `close_depth` in metres.
pub fn is_redundant(map: &Map, keyframe: KeyFrameKey, close_depth: f32, redundancy: f64) -> bool {
    let Some(kf) = map.keyframes().get(keyframe) else {
        return false;
    };
    let (mut points, mut redundant) = (0usize, 0usize);
    for (i, key) in kf.map_points.iter().enumerate() {
        let Some(point) = key.and_then(|k| map.points().get(k)) else {
            continue;
        };
        let depth = kf.frame.depth[i];
        if depth <= 0.0 || depth > close_depth {
            continue;
        }
        points += 1;
        if point.observations.len() <= 3 {
            continue;
        }
        let level = kf.frame.keypoints[i].level;
        let finer = point
            .observations
            .iter()
            .filter(|(other, j)| {
                *other != keyframe
                    && map
                        .keyframes()
                        .get(*other)
                        .is_some_and(|o| o.frame.keypoints[*j].level <= level + 1)
            })
            .count();
        if finer >= 3 {
            redundant += 1;
        }
    }
    points > 0 && redundant as f64 > redundancy * points as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Frame;
    use crate::map::{KeyFrame, MapPoint};
    use nalgebra::Vector3;

    fn keyframe(n: usize, depth: f32) -> KeyFrame {
        KeyFrame::new(
            Frame::from_parts(
                0,
                0.0,
                vec![crate::features::KeyPoint::default(); n],
                vec![[0; 4]; n],
                vec![depth; n],
                vec![1.0; n],
                (640, 480),
            ),
            crate::geometry::se3::Se3::identity(),
        )
    }

    fn point(first: usize) -> MapPoint {
        MapPoint::new(Vector3::z(), [0; 4], Vector3::z(), (0.1, 10.0), first)
    }

    #[test]
    fn recent_points_need_to_be_found_and_seen_twice() {
        let mut map = Map::default();
        let a = map.add_keyframe(keyframe(4, 1.0));
        let b = map.add_keyframe(keyframe(4, 1.0));
        let mut keys = Vec::new();
        for i in 0..4 {
            let key = map.insert_point(point(0));
            map.add_observation(key, a, i);
            keys.push(key);
        }
        // Seen by two keyframes, found often: survives.
        map.add_observation(keys[0], b, 0);
        map.point_mut(keys[0]).visible = 10;
        map.point_mut(keys[0]).found = 5;
        // Rarely found when visible: culled at once.
        map.point_mut(keys[1]).visible = 10;
        map.point_mut(keys[1]).found = 2;
        let mut recent = keys.clone();
        assert_eq!(cull_points(&mut map, &mut recent, 1), 1);
        assert!(!map.points().contains_key(keys[1]));
        // Two keyframes later, points seen by one keyframe only go.
        assert_eq!(cull_points(&mut map, &mut recent, 2), 2);
        assert_eq!(recent, vec![keys[0]]);
        // After three keyframes the survivor leaves probation.
        assert_eq!(cull_points(&mut map, &mut recent, 3), 0);
        assert!(recent.is_empty() && map.points().contains_key(keys[0]));
    }

    #[test]
    fn a_keyframe_whose_points_four_others_see_is_redundant() {
        let mut map = Map::default();
        let keys: Vec<KeyFrameKey> = (0..5)
            .map(|_| map.add_keyframe(keyframe(10, 1.0)))
            .collect();
        for i in 0..10 {
            let p = map.insert_point(point(0));
            // Points 0..9 seen by all five keyframes, except point 9 only by two.
            let seen_by = if i == 9 { 2 } else { 5 };
            for kf in &keys[..seen_by] {
                map.add_observation(p, *kf, i);
            }
        }
        // 9 of 10 points are redundant: not more than 90 %.
        assert!(!is_redundant(&map, keys[1], 40.0, 0.9));
        assert!(is_redundant(&map, keys[1], 40.0, 0.85));
        // Far points (beyond the close depth) do not count: 0 close points.
        assert!(!is_redundant(&map, keys[1], 0.5, 0.85));
    }
}
