//! A route driven again, merged after loop closing (issue 83).
//!
//! Loop closing happens after tracking, so a route driven again is tracked as new
//! ground: every lap adds its own keyframes and points. Loop closing fuses the points
//! around each loop it closes; between loops the later visit keeps its own copies.
//! Once the loops are closed, the visits lie on one another, and two steps make one
//! map of them before full BA builds its arrays:
//!
//! 1. **Fusion across visits.** Each keyframe takes the points of the (at most
//!    [`VISIT_NEIGHBOURS`]) nearest keyframes that look the same way (optical axes within
//!    [`VISIT_ANGLE_DEG`]) within [`VISIT_SPACINGS`] times the route's median keyframe
//!    spacing, made more than [`VISIT_ROUTE_REACHES`] such distances farther along the
//!    route (another visit), and fuses them as local
//!    mapping fuses its neighbours' ([`fusion::search`]: projected, gated by the
//!    reprojection error, matched by descriptor; a keypoint that already sees a point
//!    merges the two).
//! 2. **Culling.** Local mapping's redundancy test (ORB-SLAM §VI-E: 90 % of the close
//!    points seen by at least three other keyframes at the same or a finer scale,
//!    [`crate::mapping::culling::is_redundant`]) then removes the keyframes the fusion
//!    made redundant, newest first.
//!
//! The map, full BA and the frames' refinement then follow the places seen, not the
//! times they were seen. Frames tracked against a culled keyframe keep their pose
//! through it (`Map::remove_keyframe`). Both run only when a loop was closed: without
//! one, no visit is known to repeat another.

use std::time::Instant;

use serde::{Deserialize, Serialize};

use nalgebra::Vector3;

use super::GlobalInputs;
use crate::map::{KeyFrameKey, Map, MapPointKey};
use crate::mapping::{culling, fusion};

/// What the merge did (`report.json` `global.revisits`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct RevisitReport {
    /// Keyframes that took another visit's points.
    pub keyframes_fused: usize,
    /// Fusions applied (observations added and points merged).
    pub fusions: usize,
    /// Keyframes in the map before.
    pub keyframes_before: usize,
    /// Keyframes removed as redundant.
    pub keyframes_culled: usize,
    /// Map points before and after (a point no keyframe sees any more goes).
    pub points_before: usize,
    /// Map points after.
    pub points_after: usize,
    /// The fusion's and the culling's time.
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

/// How many keyframes of other visits each keyframe fuses at most.
pub const VISIT_NEIGHBOURS: usize = 3;
/// Keyframes farther apart than this many median keyframe spacings are other places.
pub const VISIT_SPACINGS: f64 = 3.0;
/// Keyframes this many reaches or less apart along the route are the same visit.
pub const VISIT_ROUTE_REACHES: f64 = 4.0;
/// Keyframes whose optical axes differ by more than this look at other things.
pub const VISIT_ANGLE_DEG: f64 = 30.0;

/// Fuses the visits of each place, then culls the keyframes that made redundant.
pub fn merge(map: &mut Map, inputs: &GlobalInputs) -> RevisitReport {
    let start = Instant::now();
    let mut report = RevisitReport {
        keyframes_before: map.keyframes().len(),
        points_before: map.points().len(),
        ..RevisitReport::default()
    };
    (report.keyframes_fused, report.fusions) = fuse_visits(map, inputs);
    report.keyframes_culled = cull_redundant(map, inputs.redundancy);
    report.points_after = map.points().len();
    report.milliseconds = start.elapsed().as_secs_f64() * 1e3;
    report
}

/// Where a keyframe is, where it looks, and how far along the route.
struct Viewpoint {
    key: KeyFrameKey,
    centre: Vector3<f64>,
    axis: Vector3<f64>,
    /// The route's length from the first keyframe (metres, keyframe to keyframe).
    along: f64,
}

/// Step 1: each keyframe fuses the points of its nearest other-visit keyframes
/// (module notes); returns the keyframes that took some and the fusions applied.
fn fuse_visits(map: &mut Map, inputs: &GlobalInputs) -> (usize, usize) {
    let mut views: Vec<Viewpoint> = map
        .keyframe_order()
        .iter()
        .map(|&key| {
            let world_from_camera = map.keyframes()[key].world_from_camera();
            Viewpoint {
                key,
                centre: world_from_camera.translation.vector,
                axis: world_from_camera.rotation * Vector3::z(),
                along: 0.0,
            }
        })
        .collect();
    for i in 1..views.len() {
        views[i].along = views[i - 1].along + (views[i].centre - views[i - 1].centre).norm();
    }
    let Some(reach) = median_spacing(&views).map(|s| s * VISIT_SPACINGS) else {
        return (0, 0);
    };
    let (mut keyframes_fused, mut fusions) = (0, 0);
    let mut touched = Vec::new();
    for view in &views {
        let others = other_visits(&views, view, reach);
        let points: Vec<MapPointKey> = others
            .iter()
            .flat_map(|k| map.keyframes()[*k].map_points.iter().flatten().copied())
            .filter(|p| {
                map.points()
                    .get(*p)
                    .is_some_and(|point| point.moving <= inputs.removal_threshold)
            })
            .collect();
        if points.is_empty() {
            continue;
        }
        let found = fusion::search(
            map,
            view.key,
            &points,
            inputs.camera,
            inputs.pyramid,
            inputs.size,
        );
        let applied = fusion::apply(map, &found);
        if applied > 0 {
            keyframes_fused += 1;
            fusions += applied;
            touched.push(view.key);
            touched.extend(others);
        }
    }
    touched.sort_unstable();
    touched.dedup();
    for key in touched {
        map.update_connections(key);
    }
    (keyframes_fused, fusions)
}

/// The median distance between consecutive keyframes (`None` with fewer than two).
fn median_spacing(views: &[Viewpoint]) -> Option<f64> {
    let mut steps: Vec<f64> = views
        .windows(2)
        .map(|w| (w[1].centre - w[0].centre).norm())
        .collect();
    if steps.is_empty() {
        return None;
    }
    let middle = steps.len() / 2;
    let (_, median, _) = steps.select_nth_unstable_by(middle, f64::total_cmp);
    Some(*median)
}

/// The keyframes (at most [`VISIT_NEIGHBOURS`], nearest first) within `reach` of
/// `view` that look the same way and were made more than [`VISIT_ROUTE_REACHES`]
/// reaches farther along the route (another visit).
fn other_visits(views: &[Viewpoint], view: &Viewpoint, reach: f64) -> Vec<KeyFrameKey> {
    let min_cos = VISIT_ANGLE_DEG.to_radians().cos();
    let mut near: Vec<(f64, KeyFrameKey)> = views
        .iter()
        .filter(|other| (other.along - view.along).abs() > VISIT_ROUTE_REACHES * reach)
        .filter(|other| view.axis.dot(&other.axis) >= min_cos)
        .map(|other| ((other.centre - view.centre).norm(), other.key))
        .filter(|(distance, _)| *distance <= reach)
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    near.into_iter()
        .take(VISIT_NEIGHBOURS)
        .map(|(_, key)| key)
        .collect()
}

/// Step 2: removes every redundant keyframe, newest first (the oldest keyframe of each
/// map segment stays: it holds the segment's world frame); returns how many.
fn cull_redundant(map: &mut Map, redundancy: Redundancy) -> usize {
    // The oldest keyframe of each map segment holds its gauge, and stays.
    let anchors = map.segment_anchors();
    let order: Vec<_> = map.keyframe_order().iter().rev().copied().collect();
    let mut culled = 0;
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
            culled += 1;
        }
    }
    culled
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::{KeyPoint, ScalePyramid};
    use crate::frame::Frame;
    use crate::geometry::camera::PinholeCamera;
    use crate::geometry::se3::Se3;
    use crate::geometry::stereo_camera::StereoCamera;
    use crate::map::{KeyFrame, MapPoint};

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
        let culled = cull_redundant(&mut map, redundancy);
        // Newest first: each keyframe goes while three others still see its points,
        // down to three keyframes, each seen with two others only. The oldest would
        // stay anyway (it holds the world frame).
        assert_eq!(culled, 5);
        assert_eq!(map.keyframe_order(), &keys[..3]);
        assert_eq!(map.points().len(), 21);
        // A share nothing reaches culls nothing.
        let (mut map, _) = two_visits();
        let strict = Redundancy {
            close_depth: 40.0,
            share: 1.0,
        };
        assert_eq!(cull_redundant(&mut map, strict), 0);
    }

    /// A street driven twice: ten keyframes 0.1 m apart along x, then the same ten
    /// poses again, each visit with its own copy of the forty points it sees (what
    /// tracking makes of a revisit before any loop fuses it).
    fn driven_twice(camera: &StereoCamera) -> Map {
        let mut rng = crate::random::Rng::new(3);
        let world: Vec<Vector3<f64>> = (0..40)
            .map(|_| Vector3::new(-0.3 + 1.5 * rng.uniform(), 0.8 * rng.uniform() - 0.4, 2.0))
            .collect();
        let descriptors: Vec<[u64; 4]> = (0..40)
            .map(|_| std::array::from_fn(|_| (rng.uniform() * u64::MAX as f64) as u64))
            .collect();
        let mut map = Map::default();
        for _visit in 0..2 {
            let points: Vec<MapPointKey> = world
                .iter()
                .zip(&descriptors)
                .map(|(x, d)| map.insert_point(MapPoint::new(*x, *d, Vector3::z(), (0.1, 2.0), 0)))
                .collect();
            for step in 0..10u8 {
                let pose = Se3::translation(-0.1 * f64::from(step), 0.0, 0.0);
                let seen: Vec<Vector3<f64>> =
                    world.iter().map(|x| camera.project(&(pose * x))).collect();
                let keypoints = seen
                    .iter()
                    .map(|s| KeyPoint {
                        x: s.x as f32,
                        y: s.y as f32,
                        ..KeyPoint::default()
                    })
                    .collect();
                let right = seen.iter().map(|s| s.z as f32).collect();
                let frame = Frame::from_parts(
                    0,
                    0.0,
                    keypoints,
                    descriptors.clone(),
                    vec![2.0; 40],
                    right,
                    (640, 480),
                );
                let key = map.add_keyframe(KeyFrame::new(frame, pose));
                for (i, p) in points.iter().enumerate() {
                    map.add_observation(*p, key, i);
                }
                map.update_connections(key);
            }
        }
        map
    }

    #[test]
    fn a_second_visit_fuses_into_the_first_and_its_keyframes_go() {
        let camera = StereoCamera::new(&PinholeCamera::tum_fr3(), 40.0);
        let pyramid = ScalePyramid::new(8, 1.2);
        let inputs = GlobalInputs {
            camera: &camera,
            pyramid: &pyramid,
            stereo: false,
            size: (640.0, 480.0),
            removal_threshold: 0.6,
            prediction_gate_share: 0.7,
            redundancy: Redundancy {
                close_depth: 3.0,
                share: 0.9,
            },
        };
        let mut map = driven_twice(&camera);
        let first: Vec<KeyFrameKey> = map.keyframe_order()[..10].to_vec();
        let report = merge(&mut map, &inputs);
        // Every second-visit point merges with its first-visit twin (the first keyframe
        // that fuses merges nearly all: every keyframe sees every point).
        assert_eq!(
            (report.points_before, report.points_after),
            (80, 40),
            "{report:?}"
        );
        assert!(report.keyframes_fused >= 1 && report.fusions >= 39, "{report:?}");
        // Then all twenty keyframes see the same points: newest first, they go while
        // three others see them.
        assert_eq!(report.keyframes_culled, 17, "{report:?}");
        assert_eq!(map.keyframe_order(), &first[..3]);
        // Turned round, the second visit looks at other things: nothing fuses.
        let mut map = driven_twice(&camera);
        let second: Vec<KeyFrameKey> = map.keyframe_order()[10..].to_vec();
        for key in second {
            let turned = Se3::rotation(Vector3::y() * std::f64::consts::PI);
            let pose = map.keyframes()[key].camera_from_world;
            map.set_keyframe_pose(key, turned * pose);
        }
        let report = merge(&mut map, &inputs);
        assert_eq!((report.fusions, report.points_after), (0, 80), "{report:?}");
    }
}
