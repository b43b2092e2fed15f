//! Local bundle adjustment over the covisible window of a keyframe (ORB-SLAM2 §III-D):
//! the keyframe and its covisible keyframes are free, the other keyframes that see
//! their points are fixed (and so is the map's first keyframe); after the solve,
//! observations above the chi-square gate are removed.
//!
//! The problem is copied out of the map ([`Window::build`], under a read lock), solved
//! without any lock, and written back ([`Window::apply`], under the write lock), so
//! tracking goes on while the solver runs.

use std::collections::HashMap;

use nalgebra::Vector3;

use crate::features::ScalePyramid;
use crate::geometry::stereo_camera::StereoCamera;
use crate::map::{KeyFrameKey, Map, MapPointKey};
use crate::optim::local_ba::{bundle_adjust, BaObservation, BaProblem, BaReport};

/// A copied-out window: the problem and where each of its parts came from.
pub struct Window {
    /// The bundle adjustment problem.
    pub problem: BaProblem,
    cameras: Vec<KeyFrameKey>,
    points: Vec<MapPointKey>,
    /// Per observation: the keyframe and keypoint index.
    sources: Vec<(KeyFrameKey, usize)>,
}

impl Window {
    /// The window around `key` with at most `size` free keyframes; points whose moving
    /// probability is above `removal_threshold` stay out, and so do points whose
    /// keyframe's detection has not come back (real time: they may be on a person)
    /// unless they lie clear of the map's wait zones, as in tracking
    /// ([`Map::awaits_detection`]). `None` when there is nothing to hold the gauge.
    pub fn build(
        map: &Map,
        key: KeyFrameKey,
        size: usize,
        pyramid: &ScalePyramid,
        removal_threshold: f32,
    ) -> Option<Self> {
        let kf = map.keyframes().get(key)?;
        let mut local = vec![key];
        local.extend(
            kf.best_covisible(size.saturating_sub(1))
                .into_iter()
                .filter(|k| map.keyframes().contains_key(*k)),
        );
        Self::over(map, local, pyramid, removal_threshold)
    }

    /// Every keyframe of the map and every point they see whose moving probability is
    /// at most `removal_threshold` (the global pass's full BA); the oldest keyframe of
    /// each map segment holds its gauge.
    pub fn whole_map(map: &Map, pyramid: &ScalePyramid, removal_threshold: f32) -> Option<Self> {
        let keyframes = map
            .keyframe_order()
            .iter()
            .copied()
            .filter(|k| map.keyframes().contains_key(*k))
            .collect();
        Self::over(map, keyframes, pyramid, removal_threshold)
    }

    /// `local` free (but the oldest keyframe of each map segment), the other keyframes
    /// that see their points fixed.
    fn over(
        map: &Map,
        local: Vec<KeyFrameKey>,
        pyramid: &ScalePyramid,
        removal_threshold: f32,
    ) -> Option<Self> {
        // The oldest keyframe of each map segment holds the gauge.
        let anchors = map.segment_anchors();
        let mut point_index = HashMap::new();
        let mut points = Vec::new();
        let mut positions = Vec::new();
        let usable =
            |x: &&crate::map::MapPoint| x.moving <= removal_threshold && !map.awaits_detection(x);
        for k in &local {
            for p in map.keyframes()[*k].map_points.iter().flatten() {
                if let Some(point) = map.points().get(*p).filter(usable) {
                    point_index.entry(*p).or_insert_with(|| {
                        points.push(*p);
                        positions.push(point.position);
                        points.len() - 1
                    });
                }
            }
        }
        let mut fixed: Vec<bool> = local.iter().map(|k| anchors.contains(k)).collect();
        let mut in_window: std::collections::HashSet<KeyFrameKey> = local.iter().copied().collect();
        let mut cameras = local;
        for p in &points {
            for (k, _) in &map.points()[*p].observations {
                if map.keyframes().contains_key(*k) && in_window.insert(*k) {
                    cameras.push(*k);
                    fixed.push(true);
                }
            }
        }
        if !fixed.iter().any(|f| *f) {
            return None;
        }
        let Gathered {
            observations,
            sources,
        } = gather(map, &cameras, &point_index, pyramid);
        let problem = BaProblem {
            poses: cameras
                .iter()
                .map(|k| map.keyframes()[*k].camera_from_world)
                .collect(),
            fixed,
            points: positions,
            observations,
        };
        Some(Self {
            problem,
            cameras,
            points,
            sources,
        })
    }

    /// Solves the problem (ORB-SLAM2's 5 robust then 10 inlier iterations).
    pub fn solve(&mut self, camera: &StereoCamera) -> BaReport {
        self.solve_with(camera, 5, 10)
    }

    /// Solves with `robust` iterations under the Huber kernel, then `inlier` without it.
    pub fn solve_with(&mut self, camera: &StereoCamera, robust: usize, inlier: usize) -> BaReport {
        bundle_adjust(&mut self.problem, camera, robust, inlier)
    }

    /// Writes poses and points back and removes the outlier observations; entities
    /// removed meanwhile are skipped. Returns the number of observations removed.
    pub fn apply(&self, map: &mut Map, report: &BaReport, scale_factors: &[f64]) -> usize {
        for (c, k) in self.cameras.iter().enumerate() {
            if !self.problem.fixed[c] {
                map.set_keyframe_pose(*k, self.problem.poses[c]);
            }
        }
        for (p, x) in self.points.iter().zip(&self.problem.points) {
            map.set_point_position(*p, *x);
        }
        let mut removed = 0;
        for (((k, i), inlier), o) in self
            .sources
            .iter()
            .zip(&report.inliers)
            .zip(&self.problem.observations)
        {
            let same = map
                .keyframes()
                .get(*k)
                .is_some_and(|kf| kf.map_points[*i] == Some(self.points[o.point]));
            if !inlier && same {
                map.remove_observation(*k, *i);
                removed += 1;
            }
        }
        for p in &self.points {
            map.update_point(*p, scale_factors);
        }
        removed
    }
}

/// The observations of a window's points by its cameras, and the keypoint each came
/// from.
struct Gathered {
    observations: Vec<BaObservation>,
    sources: Vec<(KeyFrameKey, usize)>,
}

/// Every observation of a point of `point_index` by one of `cameras` (index in it).
fn gather(
    map: &Map,
    cameras: &[KeyFrameKey],
    point_index: &HashMap<MapPointKey, usize>,
    pyramid: &ScalePyramid,
) -> Gathered {
    // Counted first: a whole map's observations are the largest arrays of a full
    // BA, and growing them by doubling would leave up to half of them unused.
    let count = cameras
        .iter()
        .map(|k| {
            let keyframe = &map.keyframes()[*k];
            keyframe
                .map_points
                .iter()
                .filter(|p| p.is_some_and(|p| point_index.contains_key(&p)))
                .count()
        })
        .sum();
    let mut observations = Vec::with_capacity(count);
    let mut sources = Vec::with_capacity(count);
    for (c, k) in cameras.iter().enumerate() {
        let keyframe = &map.keyframes()[*k];
        for (i, p) in keyframe.map_points.iter().enumerate() {
            let Some(&j) = p.and_then(|p| point_index.get(&p)) else {
                continue;
            };
            let kp = &keyframe.frame.keypoints[i];
            let right = keyframe.frame.right_u[i];
            observations.push(BaObservation {
                camera: c,
                point: j,
                measurement: Vector3::new(kp.x as f64, kp.y as f64, right as f64),
                stereo: right > 0.0,
                information: pyramid.inverse_sigma2[kp.level as usize],
            });
            sources.push((*k, i));
        }
    }
    Gathered {
        observations,
        sources,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Frame;
    use crate::geometry::se3::Se3;
    use crate::map::{KeyFrame, MapPoint};

    /// Real time: the points a keyframe made before its detection came back may be on
    /// a person, and stay out of local BA until it does; with wait zones, only those
    /// within them (as in tracking).
    #[test]
    fn points_waiting_for_their_detection_stay_out_of_the_window() {
        let n = 5;
        let mut frame = Frame::blank(n, (640, 480));
        (frame.keypoints[3].x, frame.keypoints[3].y) = (50.0, 60.0);
        (frame.keypoints[4].x, frame.keypoints[4].y) = (500.0, 400.0);
        let mut map = Map::default();
        let first = map.add_keyframe(KeyFrame::new(frame.clone(), Se3::identity()));
        let second = map.add_keyframe(KeyFrame::new(frame, Se3::identity()));
        for i in 0..n {
            // Three points from the first keyframe, two made by the second.
            let made_by = if i < 3 { 0 } else { 1 };
            let point = map.insert_point(MapPoint::new(
                Vector3::new(i as f64 * 0.1, 0.0, 2.0),
                [0; 4],
                Vector3::z(),
                (0.1, 10.0),
                made_by,
            ));
            if i < 3 {
                map.add_observation(point, first, i);
            }
            map.add_observation(point, second, i);
        }
        let pyramid = ScalePyramid::new(8, 1.2);
        let points = |map: &Map| {
            Window::build(map, second, 10, &pyramid, 1.0)
                .unwrap()
                .points
                .len()
        };
        assert_eq!(points(&map), 5);
        map.await_detection(1);
        assert_eq!(points(&map), 3);
        // A zone around the second keyframe's keypoint 3: keypoint 4 lies clear of it.
        let zone = crate::dop::boxes::ObjectBox {
            bbox: [20.0, 20.0, 100.0, 100.0],
            dynamic: true,
            depth: None,
            moved: false,
        };
        map.set_wait_zones(Some(vec![zone]));
        assert_eq!(points(&map), 4);
        map.set_wait_zones(Some(Vec::new()));
        assert_eq!(points(&map), 5);
        map.detection_came_back(1);
        map.set_wait_zones(None);
        assert_eq!(points(&map), 5);
    }
}
