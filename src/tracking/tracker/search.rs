//! The searches that give a frame its matches (ORB-SLAM2 §III-B/C): the motion model
//! (the last frame's points projected with the constant-velocity prediction),
//! brute force against the reference keyframe, and the local map (points of the
//! covisible keyframes projected with scale prediction); each followed by pose-only
//! optimisation ([`super::pose`]).

use std::time::Instant;

use super::projection::{local_keyframes, local_points};
use super::{Timing, TrackInput, Tracker};
use crate::features::Descriptor;
use crate::frame::matching::{brute_force, search_by_projection, Query};
use crate::geometry::se3::{self, Se3};
use crate::map::{KeyFrame, KeyFrameKey, KeySet, Map, MapPointKey};
use crate::tracking::params::*;
use crate::tracking::report::{PoseEstimate, Reject};

/// A keyframe's map points that still exist, with the descriptors of the keypoints
/// that observe them (for brute-force matching).
pub(super) fn live_points(map: &Map, kf: &KeyFrame) -> (Vec<MapPointKey>, Vec<Descriptor>) {
    kf.map_points
        .iter()
        .zip(&kf.frame.descriptors)
        .filter_map(|(p, d)| p.filter(|p| map.points().contains_key(*p)).map(|p| (p, *d)))
        .unzip()
}

/// What the local-map search saw, for the map's counters, the DOP report and the
/// geometric check.
#[derive(Default)]
pub(super) struct LocalSearch {
    /// Map points predicted visible in the frame (culling's counters).
    pub visible: Vec<MapPointKey>,
    /// Local-map points left out as dynamic.
    pub dynamic: usize,
    /// Every match of the search, before the optimisation kept its inliers.
    pub candidates: Vec<Option<MapPointKey>>,
}

/// An estimate with at least `needed` inliers, else why not.
fn enough(estimate: PoseEstimate, needed: usize) -> Result<PoseEstimate, Reject> {
    if estimate.inliers >= needed {
        Ok(estimate)
    } else {
        Err(Reject::FewInliers {
            found: estimate.inliers,
            needed,
        })
    }
}

impl Tracker {
    /// Projects the last frame's map points with the constant-velocity prediction.
    pub(super) fn track_motion_model(
        &self,
        input: TrackInput,
        timing: &mut Timing,
    ) -> Result<PoseEstimate, Reject> {
        let TrackInput { map, frame, .. } = input;
        let (Some(velocity), Some(last)) = (self.velocity, self.last.as_ref()) else {
            return Err(Reject::NoMotionModel);
        };
        let predicted = se3::normalised(&(velocity * last.camera_from_world));
        let start = Instant::now();
        let mut keys = Vec::new();
        let mut queries = Vec::new();
        for (i, key) in last.points.iter().enumerate() {
            let Some(key) = key else { continue };
            let Some(point) = map.points().get(*key) else {
                continue;
            };
            let Some((u, v, ur)) = self.projector().project(&predicted, &point.position) else {
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
        let mut matches =
            search_by_projection(frame, &queries, &mut taken, MOTION_MATCH_RATIO, true);
        if matches.len() < MIN_MOTION_MATCHES {
            for q in &mut queries {
                q.radius *= 2.0;
            }
            taken.iter_mut().for_each(|t| *t = false);
            matches = search_by_projection(frame, &queries, &mut taken, MOTION_MATCH_RATIO, true);
        }
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        if matches.len() < MIN_MOTION_MATCHES {
            return Err(Reject::FewMatches {
                found: matches.len(),
                needed: MIN_MOTION_MATCHES,
            });
        }
        for (q, i) in matches {
            points[i] = Some(keys[q]);
        }
        enough(
            self.optimise(input, &predicted, &points, timing),
            MIN_SEARCH_INLIERS,
        )
    }

    /// Brute-force matches against a keyframe's map points, starting from `initial`.
    pub(super) fn track_against_keyframe(
        &self,
        input: TrackInput,
        keyframe: KeyFrameKey,
        initial: Se3,
        timing: &mut Timing,
    ) -> Result<PoseEstimate, Reject> {
        let TrackInput { map, frame, .. } = input;
        let start = Instant::now();
        let kf = map.keyframes().get(keyframe).ok_or(Reject::NoReference)?;
        let (keys, descriptors) = live_points(map, kf);
        let matches = brute_force(frame, &descriptors, REFERENCE_MATCH_RATIO);
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        if matches.len() < MIN_BRUTE_FORCE_MATCHES {
            return Err(Reject::FewMatches {
                found: matches.len(),
                needed: MIN_BRUTE_FORCE_MATCHES,
            });
        }
        let mut points = vec![None; frame.len()];
        for (q, i) in matches {
            points[i] = Some(keys[q]);
        }
        enough(
            self.optimise(input, &initial, &points, timing),
            MIN_SEARCH_INLIERS,
        )
    }

    /// Brute force against the reference keyframe, from the last frame's pose.
    pub(super) fn track_reference_keyframe(
        &self,
        input: TrackInput,
        timing: &mut Timing,
    ) -> Result<PoseEstimate, Reject> {
        let initial = self
            .last
            .as_ref()
            .ok_or(Reject::NoMotionModel)?
            .camera_from_world;
        let reference = self.reference.ok_or(Reject::NoReference)?;
        self.track_against_keyframe(input, reference, initial, timing)
    }

    /// Searches the local map (points of the covisible keyframes) from `found`'s pose
    /// and matches, and optimises again; with at least `min_inliers` inliers.
    pub(super) fn track_local_map(
        &self,
        input: TrackInput,
        found: PoseEstimate,
        seen: &mut LocalSearch,
        timing: &mut Timing,
    ) -> Result<PoseEstimate, Reject> {
        let TrackInput { map, frame, gate } = input;
        let start = Instant::now();
        let (pose, mut points) = (found.camera_from_world, found.matches);
        let matched: KeySet<MapPointKey> = points.iter().flatten().copied().collect();
        let local = local_keyframes(map, &points, self.config.local_keyframes, self.revisiting);
        let unique = local_points(self.frozen_local.as_ref(), map, &local);
        let (keys, queries) =
            self.projector()
                .local_queries(map, gate, &unique, &matched, &pose, &mut seen.dynamic);
        let mut taken: Vec<bool> = points.iter().map(|p| p.is_some()).collect();
        let matches =
            search_by_projection(frame, &queries, &mut taken, LOCAL_MAP_MATCH_RATIO, false);
        for (q, i) in matches {
            points[i] = Some(keys[q]);
        }
        timing.matching += start.elapsed().as_secs_f64() * 1e3;
        seen.visible.extend(keys.iter().chain(&matched).copied());
        let estimate = self.optimise(input, &pose, &points, timing);
        seen.candidates = points;
        enough(estimate, self.config.min_inliers)
    }
}
