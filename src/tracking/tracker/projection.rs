//! What a pose predicts of map points (ORB-SLAM2's projection searches): the pixel and
//! right coordinate of a point, and the queries of the local-map search (scale
//! prediction, a window by viewing angle) and of relocalisation's search of a
//! keyframe's points.

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

    /// The local map's points not matched yet (each once, in the keyframes' order),
    /// each with its predicted view as a query; counts the points left out as dynamic.
    /// (Reading the keyframes' two halves on two threads when local mapping's core is
    /// idle, in a frozen map, made this slower: 0.42 -> 0.50 ms a frame on the desk
    /// loop, the threads' waking.)
    pub fn local_queries(
        &self,
        map: &Map,
        gate: &Participation,
        local: &[KeyFrameKey],
        matched: &KeySet<MapPointKey>,
        pose: &Se3,
        dynamic: &mut usize,
    ) -> (Vec<MapPointKey>, Vec<Query>) {
        let (mut keys, mut queries) = (Vec::new(), Vec::new());
        let mut seen = KeySet::default();
        for &kf in local {
            for key in map.keyframes()[kf].map_points.iter().flatten() {
                if matched.contains(key) || !seen.insert(*key) {
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
