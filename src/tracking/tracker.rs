//! The tracker (ORB-SLAM2 §III-B/C, for RGB-D): initialisation from the first frame with
//! enough depth; a constant-velocity motion model with a projection search against the
//! last frame, else brute-force matching against the reference keyframe; local-map
//! tracking (map points of the covisible keyframes projected with scale prediction);
//! pose-only optimisation after each search; the keyframe decision; new map points from
//! depth at keyframes; states OK / LOST with relocalisation against recent keyframes.
//!
//! After each new keyframe a local bundle adjustment refines the covisible window (run
//! in the tracking thread, in a fixed order). Not yet here: the rest of local mapping
//! (triangulation, map point and keyframe culling) in its own thread, and
//! relocalisation by PnP RANSAC over bag-of-words candidates.

use std::time::Instant;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use super::frame::Frame;
use super::matching::{brute_force, search_by_projection, Query};
use crate::features::ScalePyramid;
use crate::geometry::se3::{self, Se3};
use crate::map::{KeyFrame, KeyFrameKey, Map, MapPoint, MapPointKey};
use crate::optim::local_ba::{bundle_adjust, BaObservation, BaProblem};
use crate::optim::pose_only::{optimise_pose, PoseObservation};
use crate::optim::stereo_projection::StereoCamera;

/// Tracking parameters (ORB-SLAM2's values by default).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrackerConfig {
    /// Close/far threshold in baselines (`ThDepth`): close points are trusted for depth.
    pub th_depth: f64,
    /// At most this many frames between keyframes (ORB-SLAM2: the frame rate).
    pub max_frames_between_keyframes: usize,
    /// Keypoints with depth needed to initialise.
    pub min_initial_points: usize,
    /// Inliers needed after local-map tracking.
    pub min_inliers: usize,
    /// Covisible keyframes whose points form the local map.
    pub local_keyframes: usize,
    /// Search radius factor of the motion-model projection search (pixels at level 0).
    pub motion_search_radius: f32,
    /// Run local bundle adjustment after each new keyframe (off by default: without
    /// multi-view triangulation it does not yet improve accuracy on the benchmark).
    pub local_ba: bool,
    /// Keyframes optimised by local BA (the new one and its best covisible ones).
    pub local_ba_keyframes: usize,
}

impl Default for TrackerConfig {
    fn default() -> Self {
        Self {
            th_depth: 40.0,
            max_frames_between_keyframes: 30,
            min_initial_points: 500,
            min_inliers: 30,
            local_keyframes: 20,
            motion_search_radius: 15.0,
            local_ba: false,
            local_ba_keyframes: 10,
        }
    }
}

/// Tracking state of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingState {
    NotInitialised,
    Ok,
    Lost,
}

/// What tracking one frame did, for the report.
#[derive(Debug, Clone, Serialize)]
pub struct FrameReport {
    pub index: usize,
    pub timestamp: f64,
    pub state: TrackingState,
    pub keypoints: usize,
    pub matches: usize,
    pub inliers: usize,
    pub keyframe: bool,
    /// Milliseconds: matching and local-map search, pose optimisation, total tracking
    /// (feature extraction is timed by the caller).
    pub matching_ms: f64,
    pub optimisation_ms: f64,
    #[serde(skip)]
    pub camera_from_world: Option<Se3>,
}

/// The last tracked frame, kept for the motion model.
struct LastFrame {
    frame: Frame,
    camera_from_world: Se3,
    points: Vec<Option<MapPointKey>>,
}

/// RGB-D tracking against a growing map.
pub struct Tracker {
    pub config: TrackerConfig,
    pub camera: StereoCamera,
    pub pyramid: ScalePyramid,
    pub map: Map,
    pub state: TrackingState,
    last: Option<LastFrame>,
    velocity: Option<Se3>,
    reference: Option<KeyFrameKey>,
    frames_since_keyframe: usize,
    width: f32,
    height: f32,
}

/// Timers of one frame.
#[derive(Default)]
struct Timing {
    matching: f64,
    optimisation: f64,
}

impl Tracker {
    pub fn new(
        config: TrackerConfig,
        camera: StereoCamera,
        pyramid: ScalePyramid,
        width: u32,
        height: u32,
    ) -> Self {
        Self {
            config,
            camera,
            pyramid,
            map: Map::default(),
            state: TrackingState::NotInitialised,
            last: None,
            velocity: None,
            reference: None,
            frames_since_keyframe: 0,
            width: width as f32,
            height: height as f32,
        }
    }

    /// Depth (metres) below which a point is close (`ThDepth` baselines).
    fn close_depth(&self) -> f32 {
        (self.config.th_depth * self.camera.bf / self.camera.fx) as f32
    }

    /// Tracks one frame.
    pub fn track(&mut self, frame: Frame) -> FrameReport {
        let mut timing = Timing::default();
        let mut report = FrameReport {
            index: frame.index,
            timestamp: frame.timestamp,
            state: self.state,
            keypoints: frame.len(),
            matches: 0,
            inliers: 0,
            keyframe: false,
            matching_ms: 0.0,
            optimisation_ms: 0.0,
            camera_from_world: None,
        };
        if self.state == TrackingState::NotInitialised {
            let with_depth = frame.depth.iter().filter(|&&z| z > 0.0).count();
            if with_depth >= self.config.min_initial_points {
                let pose = Se3::identity();
                self.insert_keyframe(&frame, pose, vec![None; frame.len()], true);
                report.keyframe = true;
                report.state = TrackingState::Ok;
                report.camera_from_world = Some(pose);
                report.inliers = with_depth;
                self.state = TrackingState::Ok;
                let points = self.map.keyframes[self.reference.unwrap()]
                    .map_points
                    .clone();
                self.last = Some(LastFrame {
                    frame,
                    camera_from_world: pose,
                    points,
                });
            }
            return report;
        }
        let outcome = if self.state == TrackingState::Ok {
            self.track_motion_model(&frame, &mut timing)
                .or_else(|| self.track_reference_keyframe(&frame, &mut timing))
        } else {
            self.relocalise(&frame, &mut timing)
        };
        let tracked = outcome.and_then(|(pose, points)| {
            let (pose, points, inliers) = self.track_local_map(&frame, pose, points, &mut timing);
            (inliers >= self.config.min_inliers).then_some((pose, points, inliers))
        });
        report.matching_ms = timing.matching;
        report.optimisation_ms = timing.optimisation;
        let Some((pose, points, inliers)) = tracked else {
            self.state = TrackingState::Lost;
            self.velocity = None;
            report.state = TrackingState::Lost;
            return report;
        };
        self.state = TrackingState::Ok;
        report.state = TrackingState::Ok;
        report.inliers = inliers;
        report.matches = points.iter().filter(|p| p.is_some()).count();
        if let Some(last) = &self.last {
            self.velocity = Some(se3::normalised(&(pose * last.camera_from_world.inverse())));
        }
        self.frames_since_keyframe += 1;
        let (pose, points) = if self.need_keyframe(&frame, &points, inliers) {
            report.keyframe = true;
            self.insert_keyframe(&frame, pose, points, false);
            let key = self.reference.expect("just inserted");
            if self.config.local_ba {
                let start = Instant::now();
                self.local_bundle_adjustment(key);
                report.optimisation_ms += start.elapsed().as_secs_f64() * 1e3;
            }
            let keyframe = &self.map.keyframes[key];
            (keyframe.camera_from_world, keyframe.map_points.clone())
        } else {
            (pose, points)
        };
        report.camera_from_world = Some(pose);
        self.last = Some(LastFrame {
            frame,
            camera_from_world: pose,
            points,
        });
        report
    }

    /// Optimises a pose from matched points; returns the pose, the inlier matches and
    /// their count.
    fn optimise(
        &self,
        frame: &Frame,
        initial: &Se3,
        points: &[Option<MapPointKey>],
        timing: &mut Timing,
    ) -> (Se3, Vec<Option<MapPointKey>>, usize) {
        let start = Instant::now();
        let mut indices = Vec::new();
        let mut observations = Vec::new();
        for (i, key) in points.iter().enumerate() {
            let Some(point) = key.and_then(|k| self.map.points.get(k)) else {
                continue;
            };
            let k = &frame.keypoints[i];
            let stereo = frame.right_u[i] > 0.0;
            observations.push(PoseObservation {
                point_world: point.position,
                measurement: Vector3::new(k.x as f64, k.y as f64, frame.right_u[i] as f64),
                stereo,
                information: self.pyramid.inverse_sigma2[k.level as usize],
            });
            indices.push(i);
        }
        let mut kept = vec![None; points.len()];
        if observations.len() < 10 {
            timing.optimisation += start.elapsed().as_secs_f64() * 1e3;
            return (*initial, kept, 0);
        }
        let estimate = optimise_pose(&self.camera, initial, &observations);
        let mut inliers = 0;
        for (n, &i) in indices.iter().enumerate() {
            if estimate.inliers[n] {
                kept[i] = points[i];
                inliers += 1;
            }
        }
        timing.optimisation += start.elapsed().as_secs_f64() * 1e3;
        (estimate.camera_from_world, kept, inliers)
    }

    /// Projects the last frame's map points with the constant-velocity prediction.
    fn track_motion_model(
        &mut self,
        frame: &Frame,
        timing: &mut Timing,
    ) -> Option<(Se3, Vec<Option<MapPointKey>>)> {
        let velocity = self.velocity?;
        let last = self.last.as_ref()?;
        let predicted = se3::normalised(&(velocity * last.camera_from_world));
        let start = Instant::now();
        let mut keys = Vec::new();
        let mut queries = Vec::new();
        for (i, key) in last.points.iter().enumerate() {
            let Some(key) = key else { continue };
            let Some(point) = self.map.points.get(*key) else {
                continue;
            };
            let Some((u, v, ur)) = self.project(&predicted, &point.position) else {
                continue;
            };
            let level = last.frame.keypoints[i].level;
            let radius =
                self.config.motion_search_radius * self.pyramid.factors[level as usize] as f32;
            keys.push(*key);
            queries.push(Query {
                u,
                v,
                min_level: level.saturating_sub(1),
                max_level: (level + 1).min(self.pyramid.levels() as u8 - 1),
                radius,
                descriptor: last.frame.descriptors[i],
                right_u: Some(ur),
                angle: Some(last.frame.keypoints[i].angle),
            });
        }
        let mut points = vec![None; frame.len()];
        let mut taken = vec![false; frame.len()];
        let mut matches = search_by_projection(frame, &queries, &mut taken, 0.9, true);
        if matches.len() < 20 {
            for q in &mut queries {
                q.radius *= 2.0;
            }
            taken.iter_mut().for_each(|t| *t = false);
            matches = search_by_projection(frame, &queries, &mut taken, 0.9, true);
        }
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        if matches.len() < 20 {
            return None;
        }
        for (q, i) in matches {
            points[i] = Some(keys[q]);
        }
        let (pose, points, inliers) = self.optimise(frame, &predicted, &points, timing);
        (inliers >= 10).then_some((pose, points))
    }

    /// Brute-force matches against a keyframe's map points, starting from `initial`.
    fn track_against_keyframe(
        &self,
        frame: &Frame,
        keyframe: KeyFrameKey,
        initial: Se3,
        timing: &mut Timing,
    ) -> Option<(Se3, Vec<Option<MapPointKey>>, usize)> {
        let start = Instant::now();
        let kf = self.map.keyframes.get(keyframe)?;
        let mut keys = Vec::new();
        let mut descriptors = Vec::new();
        for (i, key) in kf.map_points.iter().enumerate() {
            if let Some(key) = key.filter(|k| self.map.points.contains_key(*k)) {
                keys.push(key);
                descriptors.push(kf.descriptors[i]);
            }
        }
        let matches = brute_force(frame, &descriptors, 0.7);
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        if matches.len() < 15 {
            return None;
        }
        let mut points = vec![None; frame.len()];
        for (q, i) in matches {
            points[i] = Some(keys[q]);
        }
        let (pose, points, inliers) = self.optimise(frame, &initial, &points, timing);
        (inliers >= 10).then_some((pose, points, inliers))
    }

    fn track_reference_keyframe(
        &mut self,
        frame: &Frame,
        timing: &mut Timing,
    ) -> Option<(Se3, Vec<Option<MapPointKey>>)> {
        let initial = self.last.as_ref()?.camera_from_world;
        self.track_against_keyframe(frame, self.reference?, initial, timing)
            .map(|(pose, points, _)| (pose, points))
    }

    /// After a loss: tries the most recent keyframes, each from its own pose.
    fn relocalise(
        &mut self,
        frame: &Frame,
        timing: &mut Timing,
    ) -> Option<(Se3, Vec<Option<MapPointKey>>)> {
        let candidates: Vec<KeyFrameKey> = self
            .map
            .keyframe_order
            .iter()
            .rev()
            .take(10)
            .copied()
            .collect();
        let mut best: Option<(Se3, Vec<Option<MapPointKey>>, usize)> = None;
        for key in candidates {
            let initial = self.map.keyframes[key].camera_from_world;
            if let Some(found) = self.track_against_keyframe(frame, key, initial, timing) {
                if best.as_ref().is_none_or(|b| found.2 > b.2) {
                    best = Some(found);
                }
            }
        }
        best.filter(|b| b.2 >= 30)
            .map(|(pose, points, _)| (pose, points))
    }

    /// Pixel and right coordinate of a world point, if in front and inside the image.
    fn project(&self, camera_from_world: &Se3, position: &Vector3<f64>) -> Option<(f32, f32, f32)> {
        let p = camera_from_world * Point3::from(*position);
        if p.z <= 0.0 {
            return None;
        }
        let uvr = self.camera.project(&p.coords);
        let (u, v) = (uvr.x as f32, uvr.y as f32);
        (u >= 0.0 && v >= 0.0 && u < self.width && v < self.height).then_some((u, v, uvr.z as f32))
    }

    /// Searches the local map (points of the covisible keyframes) and optimises again.
    fn track_local_map(
        &mut self,
        frame: &Frame,
        pose: Se3,
        mut points: Vec<Option<MapPointKey>>,
        timing: &mut Timing,
    ) -> (Se3, Vec<Option<MapPointKey>>, usize) {
        let start = Instant::now();
        let local = self.map.covisible_keyframes(
            points.iter().flatten().copied(),
            self.config.local_keyframes,
        );
        let matched: std::collections::HashSet<MapPointKey> =
            points.iter().flatten().copied().collect();
        let centre = pose.inverse().translation.vector;
        let mut keys = Vec::new();
        let mut queries = Vec::new();
        let mut seen = std::collections::HashSet::new();
        let levels = self.pyramid.levels();
        for kf in local {
            for key in self.map.keyframes[kf].map_points.iter().flatten() {
                if matched.contains(key) || !seen.insert(*key) {
                    continue;
                }
                let Some(point) = self.map.points.get(*key) else {
                    continue;
                };
                let Some((u, v, ur)) = self.project(&pose, &point.position) else {
                    continue;
                };
                let offset = point.position - centre;
                let distance = offset.norm();
                if distance < 0.8 * point.min_distance || distance > 1.2 * point.max_distance {
                    continue;
                }
                let view_cos = offset.dot(&point.normal) / distance;
                if view_cos < 0.5 {
                    continue;
                }
                // Scale prediction: the level at which the point appears this far away.
                let level = ((point.max_distance / distance).ln() / self.pyramid.scale_factor.ln())
                    .ceil()
                    .clamp(0.0, levels as f64 - 1.0) as u8;
                let radius = if view_cos > 0.998 { 2.5 } else { 4.0 }
                    * self.pyramid.factors[level as usize] as f32;
                keys.push(*key);
                queries.push(Query {
                    u,
                    v,
                    min_level: level.saturating_sub(1),
                    max_level: level,
                    radius,
                    descriptor: point.descriptor,
                    right_u: Some(ur),
                    angle: None,
                });
            }
        }
        let mut taken: Vec<bool> = points.iter().map(|p| p.is_some()).collect();
        let matches = search_by_projection(frame, &queries, &mut taken, 0.8, false);
        for (q, i) in matches {
            points[i] = Some(keys[q]);
        }
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        self.optimise(frame, &pose, &points, timing)
    }

    /// ORB-SLAM2's keyframe decision for RGB-D: enough frames since the last keyframe,
    /// or too few tracked points compared with the reference keyframe, or too few
    /// tracked close points while many untracked close ones are available.
    fn need_keyframe(&self, frame: &Frame, points: &[Option<MapPointKey>], inliers: usize) -> bool {
        let Some(reference) = self.reference.and_then(|k| self.map.keyframes.get(k)) else {
            return true;
        };
        let reference_points = reference
            .map_points
            .iter()
            .flatten()
            .filter(|k| self.map.points.contains_key(**k))
            .count();
        let close = self.close_depth();
        let (mut tracked_close, mut untracked_close) = (0, 0);
        for (i, z) in frame.depth.iter().enumerate() {
            if *z > 0.0 && *z < close {
                if points[i].is_some() {
                    tracked_close += 1;
                } else {
                    untracked_close += 1;
                }
            }
        }
        let need_close = tracked_close < 100 && untracked_close > 70;
        let timeout = self.frames_since_keyframe >= self.config.max_frames_between_keyframes;
        let weak = (inliers as f64) < 0.75 * reference_points as f64 || need_close;
        (timeout || weak) && inliers > 15
    }

    /// Local bundle adjustment around keyframe `key` (ORB-SLAM2 §III-D): the keyframe
    /// and its best covisible keyframes are free, the other keyframes that see their
    /// points are fixed (the map's first keyframe always is); observations that end
    /// above the chi-square gate are removed, and points left unobserved go.
    fn local_bundle_adjustment(&mut self, key: KeyFrameKey) {
        let first = self.map.keyframe_order[0];
        let mut local = vec![key];
        local.extend(
            self.map
                .covisible_keyframes(
                    self.map.keyframes[key].map_points.iter().flatten().copied(),
                    self.config.local_ba_keyframes + 1,
                )
                .into_iter()
                .filter(|k| *k != key)
                .take(self.config.local_ba_keyframes.saturating_sub(1)),
        );
        let mut point_index = std::collections::HashMap::new();
        let mut points = Vec::new();
        for kf in &local {
            for p in self.map.keyframes[*kf].map_points.iter().flatten() {
                if let Some(point) = self.map.points.get(*p) {
                    point_index.entry(*p).or_insert_with(|| {
                        points.push((*p, point.position));
                        points.len() - 1
                    });
                }
            }
        }
        let mut cameras: Vec<KeyFrameKey> = local.clone();
        let mut fixed: Vec<bool> = local.iter().map(|k| *k == first).collect();
        for (p, _) in &points {
            for (kf, _) in &self.map.points[*p].observations {
                if !cameras.contains(kf) && self.map.keyframes.contains_key(*kf) {
                    cameras.push(*kf);
                    fixed.push(true);
                }
            }
        }
        if !fixed.iter().any(|f| *f) {
            return;
        }
        let mut observations = Vec::new();
        let mut sources = Vec::new();
        for (c, kf) in cameras.iter().enumerate() {
            let keyframe = &self.map.keyframes[*kf];
            for (i, p) in keyframe.map_points.iter().enumerate() {
                let Some(&j) = p.and_then(|p| point_index.get(&p)) else {
                    continue;
                };
                let k = &keyframe.keypoints[i];
                observations.push(BaObservation {
                    camera: c,
                    point: j,
                    measurement: Vector3::new(k.x as f64, k.y as f64, keyframe.right_u[i] as f64),
                    stereo: keyframe.right_u[i] > 0.0,
                    information: self.pyramid.inverse_sigma2[k.level as usize],
                });
                sources.push((*kf, i));
            }
        }
        let mut problem = BaProblem {
            poses: cameras
                .iter()
                .map(|k| self.map.keyframes[*k].camera_from_world)
                .collect(),
            fixed,
            points: points.iter().map(|(_, x)| *x).collect(),
            observations,
        };
        let report = bundle_adjust(&mut problem, &self.camera, 5, 10);
        for (c, kf) in cameras.iter().enumerate() {
            if !problem.fixed[c] {
                self.map.keyframes[*kf].camera_from_world = problem.poses[c];
            }
        }
        for ((p, _), x) in points.iter().zip(&problem.points) {
            self.map.points[*p].position = *x;
        }
        for ((kf, i), inlier) in sources.iter().zip(&report.inliers) {
            if *inlier {
                continue;
            }
            let keyframe = &mut self.map.keyframes[*kf];
            if let Some(p) = keyframe.map_points[*i].take() {
                if let Some(point) = self.map.points.get_mut(p) {
                    point.observations.retain(|(k, j)| !(k == kf && j == i));
                    if point.observations.is_empty() {
                        self.map.remove_point(p);
                    }
                }
            }
        }
    }

    /// Makes `frame` a keyframe: map points from depth for its unmatched close keypoints
    /// (nearest first; far ones too until 100 are made).
    fn insert_keyframe(
        &mut self,
        frame: &Frame,
        camera_from_world: Se3,
        mut points: Vec<Option<MapPointKey>>,
        first: bool,
    ) {
        let key = self.map.add_keyframe(KeyFrame {
            frame_index: frame.index,
            timestamp: frame.timestamp,
            camera_from_world,
            keypoints: frame.keypoints.clone(),
            descriptors: frame.descriptors.clone(),
            depth: frame.depth.clone(),
            right_u: frame.right_u.clone(),
            map_points: vec![None; frame.len()],
        });
        let world_from_camera = camera_from_world.inverse();
        let centre = world_from_camera.translation.vector;
        let close = self.close_depth();
        let mut candidates: Vec<usize> = (0..frame.len())
            .filter(|&i| frame.depth[i] > 0.0 && points[i].is_none())
            .collect();
        candidates.sort_by(|&a, &b| frame.depth[a].total_cmp(&frame.depth[b]));
        for (created, i) in candidates.into_iter().enumerate() {
            if !first && frame.depth[i] > close && created >= 100 {
                break;
            }
            let k = &frame.keypoints[i];
            let z = frame.depth[i] as f64;
            let p_camera = Vector3::new(
                (k.x as f64 - self.camera.cx) * z / self.camera.fx,
                (k.y as f64 - self.camera.cy) * z / self.camera.fy,
                z,
            );
            let position = (world_from_camera * Point3::from(p_camera)).coords;
            let offset = position - centre;
            let distance = offset.norm();
            let max_distance = distance * self.pyramid.factors[k.level as usize];
            let point = self.map.points.insert(MapPoint {
                position,
                descriptor: frame.descriptors[i],
                normal: offset / distance,
                min_distance: max_distance / self.pyramid.factors[self.pyramid.levels() - 1],
                max_distance,
                observations: Vec::new(),
            });
            points[i] = Some(point);
        }
        for (i, point) in points.iter().enumerate() {
            let Some(point) = point else { continue };
            if let Some(p) = self.map.points.get_mut(*point) {
                p.observations.push((key, i));
                self.map.keyframes[key].map_points[i] = Some(*point);
            }
        }
        self.reference = Some(key);
        self.frames_since_keyframe = 0;
    }
}
