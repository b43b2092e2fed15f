//! The essential graph (ORB-SLAM §III-C, §VII-B): every keyframe of the fixed
//! keyframe's map segment, with edges of the spanning tree, of the loops closed so far
//! and of covisibility at least `min_weight` shared points, optimised on SE(3)
//! ([`PoseGraph`]); each map point then follows the keyframe that placed it:
//! \(X \leftarrow T'_{wr} T_{rw} X\).
//!
//! Edge measurements are the relative poses before the current correction
//! (`uncorrected`, for the keyframes the loop correction moved), except loop edges,
//! which carry the corrected relation; identity information, as ORB-SLAM's.

use std::collections::{HashMap, HashSet};

use nalgebra::Matrix6;

use crate::geometry::se3::Se3;
use crate::map::{KeyFrameKey, Map, MapPointKey};
use crate::optim::pose_graph::{GraphOptions, GraphReport, PoseEdge, PoseGraph};

/// Builds and solves the essential graph with `fixed` held, writes the keyframe poses
/// and moves the points. `uncorrected` holds camera-from-world poses before the loop
/// correction; `placed_by` the keyframe that last placed a point (else its first
/// observer).
pub fn optimise(
    map: &mut Map,
    loops: &[(KeyFrameKey, KeyFrameKey)],
    uncorrected: &HashMap<KeyFrameKey, Se3>,
    placed_by: &HashMap<MapPointKey, KeyFrameKey>,
    fixed: KeyFrameKey,
    min_weight: usize,
) -> GraphReport {
    // The fixed keyframe's segment: the others share no edge with it.
    let segment = map.keyframes().get(fixed).map(|kf| kf.segment);
    let keys: Vec<KeyFrameKey> = map
        .keyframe_order()
        .iter()
        .copied()
        .filter(|k| map.keyframes().get(*k).map(|kf| kf.segment) == segment)
        .collect();
    let index: HashMap<KeyFrameKey, usize> =
        keys.iter().enumerate().map(|(i, k)| (*k, i)).collect();
    let world_from = |k: KeyFrameKey| map.keyframes()[k].world_from_camera();
    let before = |k: KeyFrameKey| {
        uncorrected.get(&k).map_or_else(
            || world_from(k),
            |camera_from_world| camera_from_world.inverse(),
        )
    };
    let mut edges = Vec::new();
    let mut seen: HashSet<(usize, usize)> = HashSet::new();
    let mut push = |a: KeyFrameKey, b: KeyFrameKey, measurement: Se3, edges: &mut Vec<PoseEdge>| {
        let (Some(&i), Some(&j)) = (index.get(&a), index.get(&b)) else {
            return;
        };
        if i != j && seen.insert((i.min(j), i.max(j))) {
            edges.push(PoseEdge {
                from: i,
                to: j,
                measurement,
                information: Matrix6::identity(),
            });
        }
    };
    for &(a, b) in loops {
        if map.keyframes().contains_key(a) && map.keyframes().contains_key(b) {
            push(a, b, world_from(a).inverse() * world_from(b), &mut edges);
        }
    }
    for &k in &keys {
        let kf = &map.keyframes()[k];
        if let Some(parent) = kf.parent.filter(|p| map.keyframes().contains_key(*p)) {
            push(parent, k, before(parent).inverse() * before(k), &mut edges);
        }
        for &(other, weight) in &kf.connections {
            if weight >= min_weight && map.keyframes().contains_key(other) {
                push(k, other, before(k).inverse() * before(other), &mut edges);
            }
        }
    }
    let mut graph = PoseGraph {
        poses: keys.iter().map(|k| world_from(*k)).collect(),
        fixed: keys.iter().map(|k| *k == fixed).collect(),
        edges,
    };
    let old: Vec<Se3> = keys
        .iter()
        .map(|k| map.keyframes()[*k].camera_from_world)
        .collect();
    let report = graph.optimise(&GraphOptions::default());
    for (k, world_from_camera) in keys.iter().zip(&graph.poses) {
        map.set_keyframe_pose(*k, world_from_camera.inverse());
    }
    // Points follow their keyframe: X' = T'_wr T_rw X.
    let moves: HashMap<KeyFrameKey, Se3> = keys
        .iter()
        .enumerate()
        .map(|(i, k)| (*k, graph.poses[i] * old[i]))
        .collect();
    move_points(map, placed_by, &moves);
    report
}

/// Each point follows the keyframe that placed it (`placed_by`, else its first observer
/// that moved): \(X' = M X\) with that keyframe's move \(M\) in `moves`.
fn move_points(
    map: &mut Map,
    placed_by: &HashMap<MapPointKey, KeyFrameKey>,
    moves: &HashMap<KeyFrameKey, Se3>,
) {
    let mut moved = Vec::new();
    for (key, point) in map.points() {
        let reference = placed_by
            .get(&key)
            .copied()
            .filter(|k| moves.contains_key(k))
            .or_else(|| {
                point
                    .observations
                    .iter()
                    .map(|(k, _)| *k)
                    .find(|k| moves.contains_key(k))
            });
        if let Some(m) = reference.and_then(|k| moves.get(&k)) {
            moved.push((key, (m * nalgebra::Point3::from(point.position)).coords));
        }
    }
    for (key, position) in moved {
        map.set_point_position(key, position);
    }
}
