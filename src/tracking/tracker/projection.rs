//! What a pose predicts of map points (ORB-SLAM2's projection searches): the pixel and
//! right coordinate of a point, and the queries of the local-map search (scale
//! prediction, a window by viewing angle) and of relocalisation's search of a
//! keyframe's points.

use std::cell::RefCell;

use nalgebra::{Point3, Vector3};

use crate::dynamics::frames::Participation;
use crate::features::ScalePyramid;
use crate::frame::matching::Query;
use crate::geometry::se3::Se3;
use crate::geometry::stereo_camera::StereoCamera;
use crate::map::visibility::predict_view;
use crate::map::{KeyFrameKey, KeySet, Map, MapPoint, MapPointKey};
use crate::tracking::params::*;

/// The camera, its scale pyramid and the image size: what a projection needs.
#[derive(Clone, Copy)]
pub(super) struct Projector<'a> {
    pub camera: &'a StereoCamera,
    pub pyramid: &'a ScalePyramid,
    /// Image width and height, pixels.
    pub size: (f32, f32),
}

impl Projector<'_> {
    /// Pixel and right coordinate of a world point, if in front and inside the image.
    pub fn project(
        &self,
        camera_from_world: &Se3,
        position: &Vector3<f64>,
    ) -> Option<(f32, f32, f32)> {
        let p = camera_from_world * Point3::from(*position);
        if p.z <= 0.0 {
            return None;
        }
        let uvr = self.camera.project(&p.coords);
        let (u, v) = (uvr.x as f32, uvr.y as f32);
        (u >= 0.0 && v >= 0.0 && u < self.size.0 && v < self.size.1).then_some((u, v, uvr.z as f32))
    }

    /// The local map's points (`unique`: each once, [`local_points`]) not matched yet,
    /// each with its predicted view as a query; counts the points left out as dynamic.
    /// (Reading the keyframes' two halves on two threads when local mapping's core is
    /// idle, in a frozen map, made this slower: 0.42 -> 0.50 ms a frame on the desk
    /// loop, the threads' waking.)
    pub fn local_queries(
        &self,
        map: &Map,
        gate: &Participation,
        unique: &[MapPointKey],
        matched: &KeySet<MapPointKey>,
        pose: &Se3,
        dynamic: &mut usize,
    ) -> (Vec<MapPointKey>, Vec<Query>) {
        let (mut keys, mut queries) = (Vec::new(), Vec::new());
        for key in unique {
            if matched.contains(key) {
                continue;
            }
            let Some(point) = map.points().get(*key) else {
                continue;
            };
            *dynamic += gate.excluded(point) as usize;
            if let Some(query) = self.local_query(point, pose) {
                keys.push(*key);
                queries.push(query);
            }
        }
        (keys, queries)
    }

    /// The query of a local-map point at `pose`, when predicted visible.
    fn local_query(&self, point: &MapPoint, pose: &Se3) -> Option<Query> {
        let view = predict_view(
            point,
            pose,
            self.camera,
            self.size.0,
            self.size.1,
            self.pyramid,
        )?;
        let level = view.level;
        let radius = if view.view_cos > LOCAL_MAP_CLOSE_VIEW_COS {
            LOCAL_MAP_RADIUS_CLOSE_VIEW
        } else {
            LOCAL_MAP_RADIUS
        } * self.pyramid.factors[level as usize] as f32;
        Some(Query {
            u: view.u,
            v: view.v,
            min_level: level.saturating_sub(1),
            max_level: level,
            radius,
            descriptor: point.descriptor,
            right_u: Some(view.right_u),
            angle: None,
        })
    }

    /// The keyframe's points not matched yet, projected at `pose`, as queries.
    pub fn keyframe_queries(
        &self,
        map: &Map,
        key: KeyFrameKey,
        points: &[Option<MapPointKey>],
        pose: &crate::geometry::se3::Se3,
    ) -> (Vec<MapPointKey>, Vec<Query>) {
        let kf = &map.keyframes()[key];
        let (mut query_keys, mut queries) = (Vec::new(), Vec::new());
        for (i, p) in kf.map_points.iter().enumerate() {
            let Some(p) = p.filter(|p| !points.contains(&Some(*p))) else {
                continue;
            };
            let Some(point) = map.points().get(p) else {
                continue;
            };
            let Some((u, v, ur)) = self.project(pose, &point.position) else {
                continue;
            };
            let level = kf.frame.keypoints[i].level;
            query_keys.push(p);
            queries.push(Query {
                u,
                v,
                min_level: level.saturating_sub(1),
                max_level: (level + 1).min(self.pyramid.levels() as u8 - 1),
                radius: RELOCALISATION_SEARCH_RADIUS * self.pyramid.factors[level as usize] as f32,
                descriptor: point.descriptor,
                right_u: Some(ur),
                angle: None,
            });
        }
        (query_keys, queries)
    }
}

/// The local keyframes of a frame matched to `matches`: the `limit` keyframes that
/// share most of them ([`Map::covisible_keyframes`]), best first; after a revisit
/// (`revisiting`) their neighbours too ([`with_neighbours`]).
pub(super) fn local_keyframes(
    map: &Map,
    matches: &[Option<MapPointKey>],
    limit: usize,
    revisiting: bool,
) -> Vec<KeyFrameKey> {
    let mut local = map.covisible_keyframes(matches.iter().flatten().copied(), limit);
    if revisiting {
        with_neighbours(map, &mut local, REVISIT_LOCAL_KEYFRAMES);
    }
    local
}

/// On a revisit, the local keyframes' best covisible neighbours too
/// ([`REVISIT_NEIGHBOURS`] each, in the local keyframes' order), up to `limit`
/// keyframes in all, as ORB-SLAM2's local map takes them: the keyframes of the earlier
/// visit ahead of the camera, whose points the frame has not matched yet, so that
/// tracking stays on the earlier visit's points instead of mapping the place again.
fn with_neighbours(map: &Map, local: &mut Vec<KeyFrameKey>, limit: usize) {
    let mut listed: KeySet<KeyFrameKey> = local.iter().copied().collect();
    for i in 0..local.len() {
        let Some(keyframe) = map.keyframes().get(local[i]) else {
            continue;
        };
        for neighbour in keyframe.best_covisible(REVISIT_NEIGHBOURS) {
            if local.len() >= limit {
                return;
            }
            if listed.insert(neighbour) {
                local.push(neighbour);
            }
        }
    }
}

/// The local map: the points of the `local` keyframes, each once, in their order; in
/// a frozen map (`frozen`), kept from the last frame while the keyframes are the same
/// set.
pub(super) fn local_points(
    frozen: Option<&RefCell<FrozenLocalMap>>,
    map: &Map,
    local: &[KeyFrameKey],
) -> Vec<MapPointKey> {
    match frozen {
        Some(cache) => cache.borrow_mut().points(map, local).to_vec(),
        None => unique_points(map, local),
    }
}

/// The points of `keyframes`, each once, in their order.
fn unique_points(map: &Map, keyframes: &[KeyFrameKey]) -> Vec<MapPointKey> {
    let mut seen = KeySet::default();
    keyframes
        .iter()
        .flat_map(|&kf| map.keyframes()[kf].map_points.iter().flatten())
        .filter(|key| seen.insert(**key))
        .copied()
        .collect()
}

/// A frozen map's local map, kept while the local keyframes stay the same: their
/// points, each once (a frozen run adds no keyframe or point, so the list stays
/// whole; a point removed meanwhile is skipped where it is looked up).
#[derive(Default)]
pub(super) struct FrozenLocalMap {
    keyframes: Vec<KeyFrameKey>,
    points: Vec<MapPointKey>,
}

impl FrozenLocalMap {
    /// The points of `local`'s keyframes, each once: kept from the last call when the
    /// keyframes are the same set.
    pub fn points(&mut self, map: &Map, local: &[KeyFrameKey]) -> &[MapPointKey] {
        let mut sorted = local.to_vec();
        sorted.sort_unstable();
        if sorted != self.keyframes {
            self.points = unique_points(map, local);
            self.keyframes = sorted;
        }
        &self.points
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Frame;
    use crate::map::KeyFrame;
    use nalgebra::Vector3;

    /// A map of three keyframes of 8 keypoints; keyframe k sees points 4k..4k+8 (so
    /// neighbours share four), and the frame's matches: one point of each keyframe.
    fn three_keyframes() -> (Map, Vec<KeyFrameKey>, Vec<Option<MapPointKey>>) {
        let mut map = Map::default();
        let blank = || KeyFrame::new(Frame::blank(8, (640, 480)), Se3::identity());
        let keyframes: Vec<KeyFrameKey> = (0..3).map(|_| map.add_keyframe(blank())).collect();
        let points: Vec<MapPointKey> = (0..16)
            .map(|_| {
                let at = Vector3::new(0.0, 0.0, 2.0);
                map.insert_point(MapPoint::new(at, [0; 4], Vector3::z(), (0.1, 10.0), 0))
            })
            .collect();
        for (k, &kf) in keyframes.iter().enumerate() {
            for i in 0..8 {
                map.add_observation(points[4 * k + i], kf, i);
            }
        }
        let matches = vec![Some(points[0]), Some(points[9])];
        (map, keyframes, matches)
    }

    #[test]
    fn the_local_map_lists_each_point_once_and_a_frozen_map_keeps_it() {
        let (mut map, _, matches) = three_keyframes();
        let twenty = local_keyframes(&map, &matches, 20, false);
        let fresh = local_points(None, &map, &twenty);
        // Points 0-15 once each: the three keyframes' 24 slots less 8 shared.
        assert_eq!(fresh.len(), 16);
        assert_eq!(fresh.iter().collect::<KeySet<_>>().len(), 16);
        let cache = RefCell::new(FrozenLocalMap::default());
        assert_eq!(local_points(Some(&cache), &map, &twenty), fresh);
        // The same keyframes: the kept list, even when a point seen by one keyframe
        // alone went (a frozen map's never do: this shows the list was not read again).
        let only_once = *fresh.last().unwrap();
        let (kf, index) = map.points()[only_once].observations[0];
        map.remove_observation(kf, index);
        assert_eq!(local_points(Some(&cache), &map, &twenty), fresh);
        assert_ne!(local_points(None, &map, &twenty), fresh);
        // Fewer local keyframes: another set, read again.
        let two_keyframes = local_keyframes(&map, &matches, 2, false);
        let two = local_points(Some(&cache), &map, &two_keyframes);
        assert_eq!(two, local_points(None, &map, &two_keyframes));
        assert!(two.len() < fresh.len());
    }

    #[test]
    fn a_revisit_takes_the_local_keyframes_neighbours_but_not_theirs() {
        let (mut map, keyframes, _) = three_keyframes();
        for &kf in &keyframes {
            map.update_connections(kf);
        }
        // Point 0 is seen by the first keyframe alone; the second shares four points
        // with it, the third none (it shares with the second only).
        let points = map.keyframes()[keyframes[0]].map_points.clone();
        let matches = vec![points[0]];
        let mut local = local_keyframes(&map, &matches, 20, false);
        assert_eq!(local, vec![keyframes[0]]);
        with_neighbours(&map, &mut local, 1);
        assert_eq!(local, vec![keyframes[0]]);
        with_neighbours(&map, &mut local, 60);
        assert_eq!(local, vec![keyframes[0], keyframes[1]]);
        assert_eq!(local_keyframes(&map, &matches, 20, true), local);
    }
}
