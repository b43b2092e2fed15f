//! Duplicate fusion (ORB-SLAM §VI-D, "search in neighbours"): map points are projected
//! into a keyframe; where one lands on a keypoint with a close descriptor and a small
//! reprojection error, either the keypoint gains the observation or, when it already
//! sees another point, the two points are merged (the one with more observations
//! stays). This is what lets independent keyframes share points, so that the
//! covisibility graph and bundle adjustment connect them.

use crate::features::TH_LOW;
use crate::features::{hamming, ScalePyramid};
use crate::geometry::stereo_camera::StereoCamera;
use crate::map::visibility::predict_view;
use crate::map::{KeyFrameKey, Map, MapPointKey};
use crate::optim::robust::{CHI2_MONO, CHI2_STEREO};

/// One change found by a fusion search, applied later under the write lock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fusion {
    /// Keypoint `index` of `keyframe` observes `point`.
    Observe {
        /// The map point.
        point: MapPointKey,
        /// The keyframe.
        keyframe: KeyFrameKey,
        /// The keypoint's index in the keyframe.
        index: usize,
    },
    /// `a` and `b` are the same point.
    Merge {
        /// One point (the one with more observations is kept).
        a: MapPointKey,
        /// The other.
        b: MapPointKey,
    },
}

/// Projects `points` into `keyframe` and finds fusions.
pub fn search(
    map: &Map,
    keyframe: KeyFrameKey,
    points: &[MapPointKey],
    camera: &StereoCamera,
    pyramid: &ScalePyramid,
    size: (f32, f32),
) -> Vec<Fusion> {
    let Some(kf) = map.keyframes().get(keyframe) else {
        return Vec::new();
    };
    search_from(
        map,
        keyframe,
        &kf.camera_from_world,
        points,
        camera,
        pyramid,
        size,
    )
}

/// [`search`] with the keyframe placed at `camera_from_world` instead of its own pose
/// (loop closing's guided search, before the correction is applied).
pub fn search_from(
    map: &Map,
    keyframe: KeyFrameKey,
    camera_from_world: &crate::geometry::se3::Se3,
    points: &[MapPointKey],
    camera: &StereoCamera,
    pyramid: &ScalePyramid,
    size: (f32, f32),
) -> Vec<Fusion> {
    let Some(kf) = map.keyframes().get(keyframe) else {
        return Vec::new();
    };
    let frame = &kf.frame;
    let mut found = Vec::new();
    for &key in points {
        let Some(point) = map.points().get(key) else {
            continue;
        };
        if point.observations.iter().any(|(k, _)| *k == keyframe) {
            continue;
        }
        let Some(view) = predict_view(point, camera_from_world, camera, size.0, size.1, pyramid)
        else {
            continue;
        };
        let radius = 3.0 * pyramid.factors[view.level as usize] as f32;
        let mut best = (TH_LOW + 1, usize::MAX);
        for i in frame.features_in_area(
            view.u,
            view.v,
            radius,
            view.level.saturating_sub(1),
            view.level,
        ) {
            let k = &frame.keypoints[i];
            let (ex, ey) = ((view.u - k.x) as f64, (view.v - k.y) as f64);
            let information = pyramid.inverse_sigma2[k.level as usize];
            let right = frame.right_u[i];
            let gated = if right > 0.0 {
                let er = (view.right_u - right) as f64;
                (ex * ex + ey * ey + er * er) * information > CHI2_STEREO
            } else {
                (ex * ex + ey * ey) * information > CHI2_MONO
            };
            if gated {
                continue;
            }
            let d = hamming(&point.descriptor, &frame.descriptors[i]);
            if d < best.0 {
                best = (d, i);
            }
        }
        let index = best.1;
        if index == usize::MAX {
            continue;
        }
        found.push(match kf.map_points[index] {
            Some(other) if other != key => Fusion::Merge { a: key, b: other },
            Some(_) => continue,
            None => Fusion::Observe {
                point: key,
                keyframe,
                index,
            },
        });
    }
    found
}

/// Applies fusions in order; entities removed since the search are skipped. Returns
/// the number applied.
pub fn apply(map: &mut Map, fusions: &[Fusion]) -> usize {
    let mut applied = 0;
    for fusion in fusions {
        match *fusion {
            Fusion::Observe {
                point,
                keyframe,
                index,
            } => {
                let free = map
                    .keyframes()
                    .get(keyframe)
                    .is_some_and(|kf| kf.map_points[index].is_none());
                if free && map.points().contains_key(point) {
                    map.add_observation(point, keyframe, index);
                    applied += 1;
                }
            }
            Fusion::Merge { a, b } => {
                let (Some(pa), Some(pb)) = (map.points().get(a), map.points().get(b)) else {
                    continue;
                };
                if pa.observations.len() > pb.observations.len() {
                    map.replace_point(b, a);
                } else {
                    map.replace_point(a, b);
                }
                applied += 1;
            }
        }
    }
    applied
}
