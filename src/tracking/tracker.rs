//! The tracker (ORB-SLAM2 §III-B/C, for RGB-D): initialisation from the first frame with
//! enough depth; a constant-velocity motion model with a projection search against the
//! last frame, else brute-force matching against the reference keyframe; local-map
//! tracking (map points of the covisible keyframes projected with scale prediction);
//! pose-only optimisation after each search; the keyframe decision; new map points from
//! depth at keyframes; states OK / LOST with relocalisation by EPnP RANSAC against the
//! keyframes that share the most descriptors with the frame; when relocalisation keeps
//! failing, a new map segment (ORB-SLAM3's Atlas: a new map, merged when a loop
//! connects it).
//!
//! The map is shared with local mapping ([`crate::mapping`]), which may run in its own
//! thread: tracking holds the map's write lock while it tracks one frame (feature
//! extraction happens before, without it) and hands each new keyframe on.

use std::time::Instant;

use nalgebra::{Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::frame::Frame;
use crate::features::TH_LOW;
use crate::frame::matching::{brute_force, search_by_projection, Query};
use crate::dop::consistency::Verdict;
use crate::dop::tracks::FollowedObjects;
use crate::dop::DopConfig;
use crate::features::ScalePyramid;
use crate::features::{hamming, Descriptor};
use crate::geometry::se3::{self, Se3};
use crate::map::visibility::predict_view;
use crate::map::{KeyFrame, KeyFrameKey, Map, MapPoint, MapPointKey, SharedMap};
use crate::optim::pnp::{epnp_ransac, Correspondence, Ransac};
use crate::optim::pose_only::{optimise_pose, within_gate, PoseObservation};
use crate::optim::robust::CHI2_MONO;
use crate::geometry::stereo_camera::StereoCamera;

/// Points that take part in the pose that are enough for a pose of their own, against
/// which waiting points are tested before they join (see [`Tracker::optimise`]).
const MIN_TRUSTED_POINTS: usize = 20;

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
    /// Keyframes are for the camera, not for what moves in front of it: tracking that
    /// gets weak (fewer inliers than 75 % of the reference's points, or too few close
    /// points) makes a keyframe only once the camera has moved this far (metres) or
    /// turned this much (degrees) from the reference keyframe, or when very weak
    /// (below 25 %). A person walking in front of a still camera hides points without
    /// any new view to map.
    pub keyframe_min_translation: f64,
    pub keyframe_min_rotation_deg: f64,
    /// Seconds of failed relocalisation after which a new map segment starts at the
    /// next frame with enough depth (ORB-SLAM3's Atlas without IMU: 3 s). The new
    /// segment starts at the last tracked pose; a loop that connects it to an older
    /// one merges them in the global pass.
    pub new_map_after_seconds: f64,
    /// Real-time mode: points created by a keyframe whose detection has not come back
    /// stay out of the pose when at least this many other matches remain.
    pub held_out_min_points: usize,
    /// A keyframe's new points stay out of the pose for this many frames after it (as
    /// above, while `held_out_min_points` others remain; both modes; with the DOP
    /// model only, `--no-dop` is ORB-SLAM2's behaviour). Their matches are kept and the
    /// geometric check tests them against the pose meanwhile. Measured: it removed the
    /// gap between deterministic and real-time runs (README), also with the geometric
    /// check off. 0 turns it off.
    pub probation_frames: usize,
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
            keyframe_min_translation: 0.05,
            keyframe_min_rotation_deg: 3.0,
            new_map_after_seconds: 3.0,
            held_out_min_points: 60,
            probation_frames: 2,
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
    /// The map segment the frame was tracked in (see [`TrackerConfig::new_map_after_seconds`]).
    pub segment: usize,
    pub keypoints: usize,
    pub matches: usize,
    pub inliers: usize,
    pub keyframe: bool,
    /// DOP: keypoints in a removed (dynamic) state, and local-map points left out as
    /// dynamic.
    pub dynamic_keypoints: usize,
    pub dynamic_map_points: usize,
    /// Map points whose probability the geometric check raised and lowered in this
    /// frame.
    pub geometric_raised: usize,
    pub geometric_lowered: usize,
    /// The keyframe made from this frame, for local mapping.
    #[serde(skip)]
    pub new_keyframe: Option<KeyFrameKey>,
    /// Milliseconds: matching and local-map search, pose optimisation, total tracking
    /// (feature extraction is timed by the caller).
    pub matching_ms: f64,
    pub optimisation_ms: f64,
    /// The DOP model's probabilities (propagation and expansion).
    pub dop_ms: f64,
    #[serde(skip)]
    pub camera_from_world: Option<Se3>,
    /// The reference keyframe and the pose relative to it, \(T_{cr}\): the final
    /// trajectory is \(T_{cr} T_{rw}\) with the reference's corrected pose.
    #[serde(skip)]
    pub reference: Option<(KeyFrameKey, Se3)>,
    /// The keypoints whose map points took part in the final pose as inliers, with
    /// what the global pass needs to estimate the pose again on the final map (and the
    /// keypoint indices, for scoring against ground-truth masks).
    #[serde(skip)]
    pub pose_observations: Vec<FrameObservation>,
}

/// One keypoint of a tracked frame and the map point it saw (undistorted level-0
/// pixel, virtual right coordinate, negative without depth).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameObservation {
    pub point: MapPointKey,
    pub keypoint: u32,
    pub x: f32,
    pub y: f32,
    pub right_u: f32,
    pub level: u8,
}

/// A keyframe's map points that still exist, with the descriptors of the keypoints
/// that observe them (for brute-force matching).
fn live_points(map: &Map, kf: &KeyFrame) -> (Vec<MapPointKey>, Vec<Descriptor>) {
    kf.map_points
        .iter()
        .zip(&kf.frame.descriptors)
        .filter_map(|(p, d)| p.filter(|p| map.points.contains_key(*p)).map(|p| (p, *d)))
        .unzip()
}

/// The last tracked frame, kept for the motion model.
struct LastFrame {
    frame: Frame,
    camera_from_world: Se3,
    points: Vec<Option<MapPointKey>>,
}

/// RGB-D tracking against a growing map.
pub struct Tracker {
    config: TrackerConfig,
    camera: StereoCamera,
    pyramid: ScalePyramid,
    state: TrackingState,
    last: Option<LastFrame>,
    velocity: Option<Se3>,
    reference: Option<KeyFrameKey>,
    frames_since_keyframe: usize,
    /// The id of the keyframe this tracker made last (its points are on probation).
    newest_keyframe_id: usize,
    /// The active map segment, the number of segments started, and since when
    /// (timestamp) tracking is lost.
    segment: usize,
    segments: usize,
    lost_since: Option<f64>,
    width: f32,
    height: f32,
    /// The DOP model, when on: dynamic keypoints and map points stay out of pose
    /// estimation and new points.
    dop: Option<DopConfig>,
    /// The objects the DOP model follows, as of the latest detection (handed over by
    /// the caller after each one): with `dop.track_frames`, every frame sees their
    /// predicted boxes.
    followed: Option<FollowedObjects>,
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
            state: TrackingState::NotInitialised,
            last: None,
            velocity: None,
            reference: None,
            frames_since_keyframe: 0,
            newest_keyframe_id: usize::MAX,
            segment: 0,
            segments: 0,
            lost_since: None,
            width: width as f32,
            height: height as f32,
            dop: None,
            followed: None,
        }
    }

    /// Turns the DOP model on: dynamic keypoints and map points stay out of pose
    /// estimation and new points.
    pub fn with_dop(mut self, dop: DopConfig) -> Self {
        self.dop = Some(dop);
        self
    }

    /// The DOP model, when on.
    pub fn dop(&self) -> Option<&DopConfig> {
        self.dop.as_ref()
    }

    /// The objects the DOP model follows, as of the latest detection.
    pub fn set_followed(&mut self, followed: FollowedObjects) {
        self.followed = Some(followed);
    }

    pub fn state(&self) -> TrackingState {
        self.state
    }

    /// The last tracked frame (with its moving probabilities).
    pub fn last_frame(&self) -> Option<&Frame> {
        self.last.as_ref().map(|l| &l.frame)
    }

    /// The keypoint budget for the next frame: `n_features` over the static share
    /// \(\phi\) of the last frame's keypoints (those the DOP model did not remove), so
    /// that movers taking keypoints do not leave the pose fewer static ones
    /// ([`crate::features::orb::OrbExtractor::with_budget`] clamps it).
    pub fn feature_budget(&self, n_features: usize) -> usize {
        let (Some(last), Some(dop)) = (&self.last, &self.dop) else {
            return n_features;
        };
        let total = last.frame.moving.len();
        let dynamic = last
            .frame
            .moving
            .iter()
            .filter(|p| dop.removed(**p))
            .count();
        let share = (total - dynamic) as f64 / total.max(1) as f64;
        (n_features as f64 / share.max(0.01)).round() as usize
    }

    /// After detections updated the map: the last frame's keypoints take their map
    /// points' probabilities (the others keep theirs), then expansion runs again, so the
    /// next frame propagates what the detections said.
    pub fn refresh_moving(&mut self, map: &Map) {
        let (Some(dop), Some(last)) = (self.dop.as_ref(), self.last.as_mut()) else {
            return;
        };
        let from_map: Vec<Option<f32>> = last
            .points
            .iter()
            .map(|k| k.and_then(|k| map.points.get(k)).map(|p| p.moving))
            .collect();
        let kept: Vec<Option<f32>> = last
            .frame
            .moving
            .iter()
            .zip(&from_map)
            .map(|(p, m)| (m.is_none() && *p != dop.p_init).then_some(*p))
            .collect();
        let followed = self.followed.as_ref().map(|f| (f, &last.camera_from_world));
        last.frame.moving = propagate_and_expand(dop, &last.frame, &from_map, &kept, followed);
    }

    /// Whether a map point is left out as dynamic.
    fn excluded(&self, point: &MapPoint) -> bool {
        self.dop.as_ref().is_some_and(|d| d.removed(point.moving))
    }

    /// Whether a map point waits: for the detection of the keyframe that created it, or
    /// out its probation (made by the newest keyframe, `probation_frames` not yet past;
    /// only with the DOP model, so that `--no-dop` stays ORB-SLAM2's behaviour).
    fn awaiting(&self, map: &Map, point: &MapPoint) -> bool {
        map.awaits_detection(point)
            || (self.dop.is_some()
                && point.first_keyframe_id == self.newest_keyframe_id
                && self.frames_since_keyframe < self.config.probation_frames)
    }

    /// Whether keypoint `i` of `frame` is in a removed (dynamic) state.
    fn dynamic_keypoint(&self, frame: &Frame, i: usize) -> bool {
        self.dop
            .as_ref()
            .is_some_and(|d| d.removed(frame.moving[i]))
    }

    /// The DOP model's probabilities for a tracked frame at `camera_from_world`
    /// (propagation from its map points, else from the last frame's keypoints, else
    /// P_init; then expansion and the followed objects' boxes).
    fn moving_probabilities(
        &self,
        dop: &DopConfig,
        map: &Map,
        frame: &Frame,
        camera_from_world: &Se3,
        points: &[Option<MapPointKey>],
    ) -> Vec<f32> {
        let from_map: Vec<Option<f32>> = points
            .iter()
            .map(|k| k.and_then(|k| map.points.get(k)).map(|p| p.moving))
            .collect();
        let from_last: Vec<Option<f32>> = match (&self.last, dop.propagation) {
            (Some(last), true) => (0..frame.len())
                .map(|i| {
                    if from_map[i].is_some() {
                        return None;
                    }
                    let k = &frame.keypoints[i];
                    let candidates = last.frame.features_in_area(
                        k.x,
                        k.y,
                        20.0,
                        k.level.saturating_sub(1),
                        k.level + 1,
                    );
                    candidates
                        .into_iter()
                        .map(|j| {
                            (
                                hamming(&frame.descriptors[i], &last.frame.descriptors[j]),
                                j,
                            )
                        })
                        .filter(|(d, _)| *d <= TH_LOW)
                        .min()
                        .map(|(_, j)| last.frame.moving[j])
                })
                .collect(),
            _ => vec![None; frame.len()],
        };
        let followed = self.followed.as_ref().map(|f| (f, camera_from_world));
        propagate_and_expand(dop, frame, &from_map, &from_last, followed)
    }

    /// Depth (metres) below which a point is close (`ThDepth` baselines).
    fn close_depth(&self) -> f32 {
        (self.config.th_depth * self.camera.bf / self.camera.fx) as f32
    }

    /// Tracks one frame; a new keyframe is returned in the report for local mapping.
    ///
    /// `mapping_idle` says whether local mapping has caught up (always in deterministic
    /// mode); while it has not, a keyframe is only made when tracking gets weak.
    /// Searches and pose optimisation hold the map's read lock, so they run while local
    /// mapping searches too; only the counters and a new keyframe take the write lock.
    pub fn track(&mut self, shared: &SharedMap, mut frame: Frame, mapping_idle: bool) -> FrameReport {
        let mut timing = Timing::default();
        let mut report = FrameReport {
            index: frame.index,
            timestamp: frame.timestamp,
            state: self.state,
            segment: self.segment,
            keypoints: frame.len(),
            matches: 0,
            inliers: 0,
            keyframe: false,
            dynamic_keypoints: 0,
            dynamic_map_points: 0,
            geometric_raised: 0,
            geometric_lowered: 0,
            new_keyframe: None,
            matching_ms: 0.0,
            optimisation_ms: 0.0,
            dop_ms: 0.0,
            camera_from_world: None,
            reference: None,
            pose_observations: Vec::new(),
        };
        if self.state == TrackingState::NotInitialised {
            let mut map = shared.write().expect("map lock poisoned");
            self.start_segment(&mut map, frame, Se3::identity(), &mut report);
            return report;
        }
        let map = shared.read().expect("map lock poisoned");
        // Local mapping may have culled the reference keyframe: take the segment's newest.
        if self
            .reference
            .is_some_and(|k| !map.keyframes.contains_key(k))
        {
            self.reference = map.newest_of_segment(self.segment);
        }
        let outcome = if self.state == TrackingState::Ok {
            self.track_motion_model(&map, &frame, &mut timing)
                .or_else(|| self.track_reference_keyframe(&map, &frame, &mut timing))
        } else {
            self.relocalise(&map, &frame, &mut timing)
        };
        let mut visible = Vec::new();
        let mut dynamic_map_points = 0;
        let mut candidates = Vec::new();
        let tracked = outcome.and_then(|(pose, points)| {
            let (pose, points, inliers) = self.track_local_map(
                &map,
                &frame,
                pose,
                points,
                (&mut visible, &mut dynamic_map_points, &mut candidates),
                &mut timing,
            );
            (inliers >= self.config.min_inliers).then_some((pose, points, inliers))
        });
        drop(map);
        let mut map = shared.write().expect("map lock poisoned");
        // Counters for map point culling: predicted visible here, found as an inlier.
        for key in &visible {
            if let Some(p) = map.points.get_mut(*key) {
                p.visible += 1;
            }
        }
        if let Some((_, points, _)) = &tracked {
            for key in points.iter().flatten() {
                if let Some(p) = map.points.get_mut(*key) {
                    p.found += 1;
                }
            }
        }
        if let (Some((pose, points, _)), Some(dop)) = (&tracked, &self.dop) {
            if dop.geometric {
                let checks = self.consistency(&map, &frame, pose, &candidates, points);
                (report.geometric_raised, report.geometric_lowered) =
                    geometric_check(dop, &mut map, &checks, frame.timestamp);
            }
        }
        report.matching_ms = timing.matching;
        report.optimisation_ms = timing.optimisation;
        let Some((pose, points, inliers)) = tracked else {
            self.state = TrackingState::Lost;
            self.velocity = None;
            report.state = TrackingState::Lost;
            let since = *self.lost_since.get_or_insert(frame.timestamp);
            if frame.timestamp - since >= self.config.new_map_after_seconds {
                if let Some(last) = self.last.as_ref().map(|l| l.camera_from_world) {
                    self.start_segment(&mut map, frame, last, &mut report);
                }
            }
            return report;
        };
        self.lost_since = None;
        self.state = TrackingState::Ok;
        report.state = TrackingState::Ok;
        report.segment = self.segment;
        report.inliers = inliers;
        report.matches = points.iter().filter(|p| p.is_some()).count();
        report.pose_observations = points
            .iter()
            .enumerate()
            .filter_map(|(i, k)| {
                let key = k.filter(|&k| map.points.get(k).is_some_and(|p| !self.excluded(p)))?;
                let keypoint = &frame.keypoints[i];
                Some(FrameObservation {
                    point: key,
                    keypoint: i as u32,
                    x: keypoint.x,
                    y: keypoint.y,
                    right_u: frame.right_u[i],
                    level: keypoint.level,
                })
            })
            .collect();
        if let Some(last) = &self.last {
            self.velocity = Some(se3::normalised(&(pose * last.camera_from_world.inverse())));
        }
        if let Some(dop) = &self.dop {
            let start = Instant::now();
            frame.moving = self.moving_probabilities(dop, &map, &frame, &pose, &points);
            report.dynamic_keypoints = frame.moving.iter().filter(|p| dop.removed(**p)).count();
            report.dop_ms = start.elapsed().as_secs_f64() * 1e3;
        }
        report.dynamic_map_points = dynamic_map_points;
        self.frames_since_keyframe += 1;
        let (pose, points) =
            if self.need_keyframe(&map, &frame, &pose, &points, inliers, mapping_idle) {
                self.insert_keyframe(&mut map, &frame, pose, points, false);
                let key = self.reference.expect("just inserted");
                report.keyframe = true;
                report.new_keyframe = Some(key);
                let keyframe = &map.keyframes[key];
                (keyframe.camera_from_world, keyframe.map_points.clone())
            } else {
                (pose, points)
            };
        report.camera_from_world = Some(pose);
        report.reference = self.reference.and_then(|k| {
            let keyframe = map.keyframes.get(k)?;
            Some((k, pose * keyframe.world_from_camera()))
        });
        self.last = Some(LastFrame {
            frame,
            camera_from_world: pose,
            points,
        });
        report
    }

    /// Starts a map segment (the first, or a new one after tracking stayed lost) with
    /// `frame` as its first keyframe at `camera_from_world`, when the frame has enough
    /// keypoints with depth.
    fn start_segment(
        &mut self,
        map: &mut Map,
        frame: Frame,
        camera_from_world: Se3,
        report: &mut FrameReport,
    ) {
        let with_depth = frame.depth.iter().filter(|&&z| z > 0.0).count();
        if with_depth < self.config.min_initial_points {
            return;
        }
        self.segment = self.segments;
        self.segments += 1;
        self.insert_keyframe(
            map,
            &frame,
            camera_from_world,
            vec![None; frame.len()],
            true,
        );
        report.keyframe = true;
        report.new_keyframe = self.reference;
        report.state = TrackingState::Ok;
        report.segment = self.segment;
        report.camera_from_world = Some(camera_from_world);
        report.reference = self.reference.map(|k| (k, Se3::identity()));
        report.inliers = with_depth;
        self.state = TrackingState::Ok;
        self.velocity = None;
        self.lost_since = None;
        let points = self
            .reference
            .and_then(|k| map.keyframes.get(k))
            .map_or_else(Vec::new, |kf| kf.map_points.clone());
        self.last = Some(LastFrame {
            frame,
            camera_from_world,
            points,
        });
    }

    /// Optimises a pose from matched points; returns the pose, the inlier matches (and
    /// the matches of dynamic points, which take no part) and the inlier count.
    fn optimise(
        &self,
        map: &Map,
        frame: &Frame,
        initial: &Se3,
        points: &[Option<MapPointKey>],
        timing: &mut Timing,
    ) -> (Se3, Vec<Option<MapPointKey>>, usize) {
        let start = Instant::now();
        let mut indices = Vec::new();
        let mut observations = Vec::new();
        let mut kept = vec![None; points.len()];
        let mut awaiting = Vec::new();
        for (i, key) in points.iter().enumerate() {
            let Some(point) = key.and_then(|k| map.points.get(k)) else {
                continue;
            };
            if self.excluded(point) {
                // Dynamic: no part in the pose, but the match is kept so that its
                // keypoint inherits the point's probability.
                kept[i] = points[i];
                continue;
            }
            if self.awaiting(map, point) {
                awaiting.push((i, point));
                continue;
            }
            observations.push(self.observation(frame, i, point));
            indices.push(i);
        }
        if observations.len() >= self.config.held_out_min_points {
            // Kept like dynamic matches until the detection says what they are.
            for (i, _) in awaiting {
                kept[i] = points[i];
            }
        } else {
            // Too few others to go without them: the waiting points join the pose,
            // but when the others can give a pose of their own, only those that agree
            // with it (a person the detector has not reported yet moved away from it,
            // and would outnumber the room's few points).
            let trusted = (observations.len() >= MIN_TRUSTED_POINTS)
                .then(|| optimise_pose(&self.camera, initial, &observations))
                .filter(|estimate| {
                    estimate.inliers.iter().filter(|i| **i).count() >= MIN_TRUSTED_POINTS
                });
            for (i, point) in awaiting {
                let observation = self.observation(frame, i, point);
                let agrees = trusted.as_ref().is_none_or(|estimate| {
                    within_gate(&self.camera, &estimate.camera_from_world, &observation)
                });
                if agrees {
                    observations.push(observation);
                    indices.push(i);
                } else {
                    kept[i] = points[i];
                }
            }
        }
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

    /// Keypoint `i` of `frame` seeing `point`, for the pose optimisation.
    fn observation(&self, frame: &Frame, i: usize, point: &MapPoint) -> PoseObservation {
        let k = &frame.keypoints[i];
        PoseObservation::of_keypoint(
            point.position,
            (k.x, k.y, frame.right_u[i]),
            self.pyramid.inverse_sigma2[k.level as usize],
        )
    }

    /// The geometric check's verdicts on the frame's final matches: the optimisation's
    /// inliers are consistent; points that took no part (dynamic) are tested against
    /// the final pose with the same gate.
    fn consistency(
        &self,
        map: &Map,
        frame: &Frame,
        pose: &Se3,
        candidates: &[Option<MapPointKey>],
        inliers: &[Option<MapPointKey>],
    ) -> Vec<(MapPointKey, bool)> {
        candidates
            .iter()
            .zip(inliers)
            .enumerate()
            .filter_map(|(i, (candidate, inlier))| {
                let key = (*candidate)?;
                let point = map.points.get(key)?;
                let consistent = if self.excluded(point) || self.awaiting(map, point) {
                    within_gate(&self.camera, pose, &self.observation(frame, i, point))
                } else {
                    inlier.is_some()
                };
                Some((key, consistent))
            })
            .collect()
    }

    /// Projects the last frame's map points with the constant-velocity prediction.
    fn track_motion_model(
        &mut self,
        map: &Map,
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
            let Some(point) = map.points.get(*key) else {
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
        let (pose, points, inliers) = self.optimise(map, frame, &predicted, &points, timing);
        (inliers >= 10).then_some((pose, points))
    }

    /// Brute-force matches against a keyframe's map points, starting from `initial`.
    fn track_against_keyframe(
        &self,
        map: &Map,
        frame: &Frame,
        keyframe: KeyFrameKey,
        initial: Se3,
        timing: &mut Timing,
    ) -> Option<(Se3, Vec<Option<MapPointKey>>, usize)> {
        let start = Instant::now();
        let (keys, descriptors) = live_points(map, map.keyframes.get(keyframe)?);
        let matches = brute_force(frame, &descriptors, 0.7);
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        if matches.len() < 15 {
            return None;
        }
        let mut points = vec![None; frame.len()];
        for (q, i) in matches {
            points[i] = Some(keys[q]);
        }
        let (pose, points, inliers) = self.optimise(map, frame, &initial, &points, timing);
        (inliers >= 10).then_some((pose, points, inliers))
    }

    fn track_reference_keyframe(
        &mut self,
        map: &Map,
        frame: &Frame,
        timing: &mut Timing,
    ) -> Option<(Se3, Vec<Option<MapPointKey>>)> {
        let initial = self.last.as_ref()?.camera_from_world;
        self.track_against_keyframe(map, frame, self.reference?, initial, timing)
            .map(|(pose, points, _)| (pose, points))
    }

    /// After a loss (ORB-SLAM §V-A): keyframes ranked by how many of a sample of the
    /// frame's descriptors match their points; for the best five, brute-force matches,
    /// EPnP in RANSAC, pose-only optimisation, and when that leaves fewer than 50
    /// inliers a projection search of the keyframe's points for more. Accepted with 50.
    fn relocalise(
        &mut self,
        map: &Map,
        frame: &Frame,
        timing: &mut Timing,
    ) -> Option<(Se3, Vec<Option<MapPointKey>>)> {
        let start = Instant::now();
        let sample: Vec<usize> = (0..frame.len()).step_by(4).collect();
        let mut ranked: Vec<(usize, usize, KeyFrameKey)> = map
            .keyframe_order
            .iter()
            .map(|&key| {
                let kf = &map.keyframes[key];
                let descriptors: Vec<_> = kf
                    .map_points
                    .iter()
                    .zip(&kf.frame.descriptors)
                    .filter(|(p, _)| p.is_some())
                    .map(|(_, d)| d)
                    .collect();
                let hits = sample
                    .iter()
                    .filter(|&&i| {
                        descriptors
                            .iter()
                            .any(|d| hamming(&frame.descriptors[i], d) <= TH_LOW)
                    })
                    .count();
                (hits, kf.id, key)
            })
            .collect();
        ranked.sort_by(|a, b| b.0.cmp(&a.0).then(b.1.cmp(&a.1)));
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        for (_, _, key) in ranked.into_iter().take(5) {
            if let Some(found) = self.relocalise_against(map, frame, key, timing) {
                // Any segment's keyframes are searched: the camera may come back to an
                // older segment, which becomes the active one again.
                self.segment = map.keyframes[key].segment;
                self.reference = Some(key);
                return Some(found);
            }
        }
        None
    }

    fn relocalise_against(
        &self,
        map: &Map,
        frame: &Frame,
        key: KeyFrameKey,
        timing: &mut Timing,
    ) -> Option<(Se3, Vec<Option<MapPointKey>>)> {
        let start = Instant::now();
        let kf = &map.keyframes[key];
        let (keys, descriptors) = live_points(map, kf);
        let matches = brute_force(frame, &descriptors, 0.75);
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        if matches.len() < 15 {
            return None;
        }
        let start = Instant::now();
        let fx2 = self.camera.fx * self.camera.fx;
        let correspondences: Vec<Correspondence> = matches
            .iter()
            .map(|&(q, i)| {
                let k = &frame.keypoints[i];
                Correspondence {
                    world: map.points[keys[q]].position,
                    normalised: nalgebra::Vector2::new(
                        (k.x as f64 - self.camera.cx) / self.camera.fx,
                        (k.y as f64 - self.camera.cy) / self.camera.fy,
                    ),
                }
            })
            .collect();
        let thresholds: Vec<f64> = matches
            .iter()
            .map(|&(_, i)| CHI2_MONO * self.pyramid.sigma2[frame.keypoints[i].level as usize] / fx2)
            .collect();
        let (pose, inliers) = epnp_ransac(&correspondences, &thresholds, &Ransac::default())?;
        timing.optimisation += start.elapsed().as_secs_f64() * 1e3;
        let mut points = vec![None; frame.len()];
        for (&(q, i), inlier) in matches.iter().zip(&inliers) {
            if *inlier {
                points[i] = Some(keys[q]);
            }
        }
        let (mut pose, mut points, mut count) = self.optimise(map, frame, &pose, &points, timing);
        if count < 10 {
            return None;
        }
        if count < 50 {
            let start = Instant::now();
            let mut taken: Vec<bool> = points.iter().map(|p| p.is_some()).collect();
            let (mut query_keys, mut queries) = (Vec::new(), Vec::new());
            for (i, p) in kf.map_points.iter().enumerate() {
                let Some(p) = p.filter(|p| !points.contains(&Some(*p))) else {
                    continue;
                };
                let Some(point) = map.points.get(p) else {
                    continue;
                };
                let Some((u, v, ur)) = self.project(&pose, &point.position) else {
                    continue;
                };
                let level = kf.frame.keypoints[i].level;
                query_keys.push(p);
                queries.push(Query {
                    u,
                    v,
                    min_level: level.saturating_sub(1),
                    max_level: (level + 1).min(self.pyramid.levels() as u8 - 1),
                    radius: 10.0 * self.pyramid.factors[level as usize] as f32,
                    descriptor: point.descriptor,
                    right_u: Some(ur),
                    angle: None,
                });
            }
            for (q, i) in search_by_projection(frame, &queries, &mut taken, 0.9, false) {
                points[i] = Some(query_keys[q]);
            }
            timing.matching += start.elapsed().as_secs_f64() * 1e3;
            (pose, points, count) = self.optimise(map, frame, &pose, &points, timing);
        }
        (count >= 50).then_some((pose, points))
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
        map: &Map,
        frame: &Frame,
        pose: Se3,
        mut points: Vec<Option<MapPointKey>>,
        (visible, dynamic, candidates): (
            &mut Vec<MapPointKey>,
            &mut usize,
            &mut Vec<Option<MapPointKey>>,
        ),
        timing: &mut Timing,
    ) -> (Se3, Vec<Option<MapPointKey>>, usize) {
        let start = Instant::now();
        let local = map.covisible_keyframes(
            points.iter().flatten().copied(),
            self.config.local_keyframes,
        );
        let matched: std::collections::HashSet<MapPointKey> =
            points.iter().flatten().copied().collect();
        let mut keys = Vec::new();
        let mut queries = Vec::new();
        let mut seen = std::collections::HashSet::new();
        for kf in local {
            for key in map.keyframes[kf].map_points.iter().flatten() {
                if matched.contains(key) || !seen.insert(*key) {
                    continue;
                }
                let Some(point) = map.points.get(*key) else {
                    continue;
                };
                if self.excluded(point) {
                    *dynamic += 1;
                }
                let Some(view) = predict_view(
                    point,
                    &pose,
                    &self.camera,
                    (self.width, self.height),
                    &self.pyramid,
                ) else {
                    continue;
                };
                let level = view.level;
                let radius = if view.view_cos > 0.998 { 2.5 } else { 4.0 }
                    * self.pyramid.factors[level as usize] as f32;
                keys.push(*key);
                queries.push(Query {
                    u: view.u,
                    v: view.v,
                    min_level: level.saturating_sub(1),
                    max_level: level,
                    radius,
                    descriptor: point.descriptor,
                    right_u: Some(view.right_u),
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
        visible.extend(keys.iter().chain(&matched).copied());
        let result = self.optimise(map, frame, &pose, &points, timing);
        *candidates = points;
        result
    }

    /// ORB-SLAM2's keyframe decision for RGB-D, adapted: a keyframe when enough frames
    /// passed, or when tracking is weak (inliers below 75 % of the reference keyframe's
    /// points, or too few tracked close points while many untracked close ones are
    /// available) and local mapping is idle or tracking is very weak (below 25 %).
    /// Unlike ORB-SLAM2 the timeout alone makes a keyframe, and all the reference's
    /// points count: on slow static sequences that keeps the map fresh (loop_room,
    /// real-time mode: 0.0084 m, against 0.0299 m with ORB-SLAM2's rule, which made 15
    /// keyframes instead of 77).
    fn need_keyframe(
        &self,
        map: &Map,
        frame: &Frame,
        pose: &Se3,
        points: &[Option<MapPointKey>],
        inliers: usize,
        mapping_idle: bool,
    ) -> bool {
        let Some(reference) = self.reference.and_then(|k| map.keyframes.get(k)) else {
            return true;
        };
        // Points the DOP model leaves out cannot be tracked, and points that wait (for
        // their keyframe's detection, or out their probation) take no part in the pose
        // yet: neither counts. Counted, the points a keyframe makes on a person the
        // detector has not reported yet make the next frames look weak, and each of them
        // a keyframe that makes more such points.
        let reference_points = reference
            .map_points
            .iter()
            .flatten()
            .filter(|k| {
                map.points
                    .get(**k)
                    .is_some_and(|p| !self.excluded(p) && !self.awaiting(map, p))
            })
            .count();
        // Close points: tracked ones that take part in the pose, and untracked ones that
        // could make new points (dynamic keypoints cannot, so they do not ask for a
        // keyframe; otherwise a person close to the camera makes one every frame).
        let close = self.close_depth();
        let (mut tracked_close, mut untracked_close) = (0, 0);
        for (i, z) in frame.depth.iter().enumerate() {
            if *z > 0.0 && *z < close {
                match points[i].and_then(|k| map.points.get(k)) {
                    Some(p) if !self.excluded(p) => tracked_close += 1,
                    Some(_) => {}
                    None if !self.dynamic_keypoint(frame, i) => untracked_close += 1,
                    None => {}
                }
            }
        }
        let need_close = tracked_close < 100 && untracked_close > 70;
        let timeout = self.frames_since_keyframe >= self.config.max_frames_between_keyframes;
        let very_weak = (inliers as f64) < 0.25 * reference_points as f64;
        let moved = {
            let relative = *pose * reference.world_from_camera();
            relative.translation.vector.norm() >= self.config.keyframe_min_translation
                || relative.rotation.angle().to_degrees() >= self.config.keyframe_min_rotation_deg
        };
        let weak = moved && ((inliers as f64) < 0.75 * reference_points as f64 || need_close);
        (timeout || very_weak || (weak && (mapping_idle || need_close))) && inliers > 15
    }

    /// Makes `frame` a keyframe: map points from depth for its unmatched close keypoints
    /// (nearest first; far ones too until 100 are made).
    fn insert_keyframe(
        &mut self,
        map: &mut Map,
        frame: &Frame,
        camera_from_world: Se3,
        points: Vec<Option<MapPointKey>>,
        first: bool,
    ) {
        let mut keyframe = KeyFrame::new(frame.clone(), camera_from_world);
        keyframe.segment = self.segment;
        let key = map.add_keyframe(keyframe);
        let id = map.keyframes[key].id;
        let world_from_camera = camera_from_world.inverse();
        let close = self.close_depth();
        for (i, point) in points.iter().enumerate() {
            if let Some(point) = point {
                map.add_observation(*point, key, i);
            }
        }
        let mut candidates: Vec<usize> = (0..frame.len())
            .filter(|&i| {
                frame.depth[i] > 0.0 && points[i].is_none() && !self.dynamic_keypoint(frame, i)
            })
            .collect();
        candidates.sort_by(|&a, &b| frame.depth[a].total_cmp(&frame.depth[b]));
        for (created, i) in candidates.into_iter().enumerate() {
            if !first && frame.depth[i] > close && created >= 100 {
                break;
            }
            let position = (world_from_camera * Point3::from(self.back_project(frame, i))).coords;
            let point = map.points.insert(MapPoint::new(
                position,
                frame.descriptors[i],
                Vector3::z(),
                (0.0, 0.0),
                id,
            ));
            map.add_observation(point, key, i);
            map.update_point(point, &self.pyramid.factors);
        }
        self.reference = Some(key);
        self.frames_since_keyframe = 0;
        self.newest_keyframe_id = id;
    }

    /// Camera-frame position of keypoint `i` from its depth.
    fn back_project(&self, frame: &Frame, i: usize) -> Vector3<f64> {
        let k = &frame.keypoints[i];
        let z = frame.depth[i] as f64;
        Vector3::new(
            (k.x as f64 - self.camera.cx) * z / self.camera.fx,
            (k.y as f64 - self.camera.cy) * z / self.camera.fy,
            z,
        )
    }
}

/// Propagation (map point, else last frame, else \(P_{init}\)) and, when on,
/// matching point expansion over `frame`'s keypoints; then, given the followed objects
/// and the frame's pose, the unknown keypoints on them are raised
/// ([`crate::dop::raise_unknown_in_boxes`]).
fn propagate_and_expand(
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
/// verdicts `checks` (map point, consistent), made at `time`. Frames where more than
/// `geometric_max_outliers` of the matches that took part in the pose are inconsistent
/// are skipped: there the pose itself is in doubt. Returns the number of points raised
/// and lowered.
fn geometric_check(
    dop: &DopConfig,
    map: &mut Map,
    checks: &[(MapPointKey, bool)],
    time: f64,
) -> (usize, usize) {
    let mut judged = Vec::with_capacity(checks.len());
    let (mut total, mut outliers) = (0, 0);
    for &(key, consistent) in checks {
        let Some(point) = map.points.get(key) else {
            continue;
        };
        let dynamic = dop.removed(point.moving);
        if !dynamic {
            total += 1;
            outliers += usize::from(!consistent);
        }
        judged.push((key, consistent, dynamic));
    }
    if total == 0 || outliers as f32 > dop.geometric_max_outliers * total as f32 {
        return (0, 0);
    }
    let (mut raised, mut lowered) = (0, 0);
    for (key, consistent, dynamic) in judged {
        let point = &mut map.points[key];
        match point
            .consistency
            .observe(consistent, time, dynamic, &mut point.moving, dop)
        {
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
    use crate::geometry::camera::PinholeCamera;

    fn map_with_points(n: usize) -> (Map, Vec<MapPointKey>) {
        let mut map = Map::default();
        let keys = (0..n)
            .map(|_| {
                map.points.insert(MapPoint::new(
                    Vector3::z(),
                    [0; 4],
                    Vector3::z(),
                    (0.1, 10.0),
                    0,
                ))
            })
            .collect();
        (map, keys)
    }

    /// Verdicts: the first `outliers` points inconsistent, the others consistent.
    fn checks(keys: &[MapPointKey], outliers: usize) -> Vec<(MapPointKey, bool)> {
        keys.iter()
            .enumerate()
            .map(|(i, k)| (*k, i >= outliers))
            .collect()
    }

    #[test]
    fn geometric_check_raises_points_that_stay_outliers() {
        let dop = DopConfig::default();
        let (mut map, keys) = map_with_points(10);
        // Points 0 and 1 are outliers, the rest inliers.
        assert_eq!(
            geometric_check(&dop, &mut map, &checks(&keys, 2), 0.0),
            (0, 0)
        );
        assert_eq!(map.points[keys[0]].consistency.outlier_run, 1);
        // The second frame in a row raises them: 0.5 -> 0.65.
        assert_eq!(
            geometric_check(&dop, &mut map, &checks(&keys, 2), 0.1),
            (2, 0)
        );
        assert!((map.points[keys[0]].moving - 0.65).abs() < 1e-6);
        assert!((map.points[keys[2]].moving - 0.5).abs() < 1e-6);
        // Now dynamic, they are not raised again.
        assert_eq!(
            geometric_check(&dop, &mut map, &checks(&keys, 2), 0.2),
            (0, 0)
        );
        assert_eq!(
            geometric_check(&dop, &mut map, &checks(&keys, 2), 0.3),
            (0, 0)
        );
        // A consistent frame resets the count.
        let (mut map, keys) = map_with_points(10);
        geometric_check(&dop, &mut map, &checks(&keys, 1), 0.0);
        geometric_check(&dop, &mut map, &checks(&keys, 0), 0.1);
        assert_eq!(map.points[keys[0]].consistency.outlier_run, 0);
    }

    #[test]
    fn geometric_check_skips_frames_where_the_pose_is_in_doubt() {
        let dop = DopConfig::default();
        let (mut map, keys) = map_with_points(10);
        // 4 of 10 outliers: above geometric_max_outliers (0.35).
        for n in 0..3 {
            assert_eq!(
                geometric_check(&dop, &mut map, &checks(&keys, 4), f64::from(n)),
                (0, 0)
            );
        }
        assert!(keys
            .iter()
            .all(|k| map.points[*k].consistency == Default::default()));
        // Dynamic points do not count towards the share: 4 dynamic outliers of 10 do
        // not put the pose in doubt.
        for k in &keys[..4] {
            map.points[*k].moving = 0.9;
        }
        geometric_check(&dop, &mut map, &checks(&keys, 4), 4.0);
        assert_eq!(map.points[keys[9]].consistency.inlier_run, 1);
    }

    /// Real time: the points of a keyframe whose detection has not come back take no
    /// part in the pose while enough others remain. Here they sit on a person who
    /// moved 10 cm and outnumber the room's points; held out, the pose is the room's.
    #[test]
    fn points_awaiting_their_detection_stay_out_of_the_pose() {
        let pinhole = PinholeCamera::tum_fr3();
        let camera = StereoCamera::new(&pinhole, 40.0);
        let mut tracker = Tracker::new(
            TrackerConfig::default(),
            camera,
            ScalePyramid::new(8, 1.2),
            pinhole.width,
            pinhole.height,
        );
        tracker.dop = Some(DopConfig::default());
        let (room, person) = (80, 120);
        let mut map = Map::default();
        let (mut keypoints, mut keys) = (Vec::new(), Vec::new());
        for i in 0..room + person {
            let (x, y) = (20.0 + (i % 20) as f64 * 30.0, 20.0 + (i / 20) as f64 * 40.0);
            let z = 2.0 + (i % 7) as f64 * 0.3;
            let seen = pinhole.unproject(&nalgebra::Vector2::new(x, y), z);
            // The person's points were made where the person stood a frame ago.
            let (position, first) = if i < room {
                (seen, 0)
            } else {
                (seen + Vector3::new(0.1, 0.0, 0.0), 7)
            };
            keys.push(Some(map.points.insert(MapPoint::new(
                position,
                [0; 4],
                Vector3::z(),
                (0.1, 10.0),
                first,
            ))));
            keypoints.push(crate::features::KeyPoint {
                x: x as f32,
                y: y as f32,
                ..Default::default()
            });
        }
        let n = keypoints.len();
        let frame = Frame::from_parts(
            1,
            0.1,
            keypoints,
            vec![[0; 4]; n],
            vec![0.0; n],
            vec![-1.0; n],
            (pinhole.width, pinhole.height),
        );
        let error_with = |tracker: &Tracker, map: &Map, keys: &[Option<MapPointKey>]| {
            let (pose, _, _) =
                tracker.optimise(map, &frame, &Se3::identity(), keys, &mut Timing::default());
            pose.translation.vector.norm()
        };
        let mixed = error_with(&tracker, &map, &keys);
        assert!(mixed > 0.02, "the person pulls the pose: {mixed}");
        map.awaiting_detection.insert(7);
        assert!(error_with(&tracker, &map, &keys) < 1e-3);
        // With too few other points the awaiting ones join, but only those that agree
        // with the pose the others give on their own: not the person's.
        tracker.config.held_out_min_points = room + 1;
        assert!(error_with(&tracker, &map, &keys) < 1e-3);
        // With too few for a pose of their own, all join.
        let few: Vec<Option<MapPointKey>> = keys
            .iter()
            .enumerate()
            .map(|(i, k)| k.filter(|_| i < 10 || i >= room))
            .collect();
        map.awaiting_detection.clear();
        let few_mixed = error_with(&tracker, &map, &few);
        map.awaiting_detection.insert(7);
        assert!((error_with(&tracker, &map, &few) - few_mixed).abs() < 1e-9);
        assert!(few_mixed > 0.02, "{few_mixed}");
    }

    /// A still camera whose reference keyframe made 400 points on a person the
    /// detector has not reported yet: the frame tracks the room's 100. Counted, those
    /// 400 make the frame look very weak (a keyframe, which makes more such points);
    /// while they wait for their detection they do not count.
    #[test]
    fn points_that_wait_do_not_make_keyframes() {
        let pinhole = PinholeCamera::tum_fr3();
        let mut tracker = Tracker::new(
            TrackerConfig::default(),
            StereoCamera::new(&pinhole, 40.0),
            ScalePyramid::new(8, 1.2),
            pinhole.width,
            pinhole.height,
        );
        tracker.dop = Some(DopConfig::default());
        let (room, person) = (100, 400);
        let n = room + person;
        let frame = Frame::blank(n, (pinhole.width, pinhole.height));
        let mut map = Map::default();
        let mut keyframe = KeyFrame::new(frame.clone(), Se3::identity());
        for (i, slot) in keyframe.map_points.iter_mut().enumerate() {
            let first = if i < room { 0 } else { 7 };
            *slot = Some(map.points.insert(MapPoint::new(
                Vector3::z(),
                [0; 4],
                Vector3::z(),
                (0.1, 10.0),
                first,
            )));
        }
        let tracked: Vec<Option<MapPointKey>> = (0..n)
            .map(|i| keyframe.map_points[i].filter(|_| i < room))
            .collect();
        tracker.reference = Some(map.add_keyframe(keyframe));
        tracker.frames_since_keyframe = 5;
        let need =
            |map: &Map| tracker.need_keyframe(map, &frame, &Se3::identity(), &tracked, room, true);
        assert!(need(&map), "100 of 500 points: very weak");
        map.awaiting_detection.insert(7);
        assert!(!need(&map));
    }

    #[test]
    fn dynamic_points_that_stay_consistent_are_lowered_back_into_the_pose() {
        let dop = DopConfig::default();
        let (mut map, keys) = map_with_points(10);
        // Two points on a parked car: detected, dynamic, but they never move.
        for k in &keys[..2] {
            map.points[*k].moving = 0.75;
        }
        let mut lowered = 0;
        for n in 0..30 {
            lowered += geometric_check(&dop, &mut map, &checks(&keys, 0), f64::from(n) * 0.1).1;
        }
        assert!(lowered > 0);
        assert!(keys[..2]
            .iter()
            .all(|k| !dop.removed(map.points[*k].moving)));
        assert!(keys[..2]
            .iter()
            .all(|k| map.points[*k].consistency.verified_static(&dop)));
    }
}
