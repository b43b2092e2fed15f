//! What tracking one frame hands on: the report line, the pose observations for the
//! global pass, and why a frame was lost.

use serde::{Deserialize, Serialize};

use crate::geometry::se3::Se3;
use crate::map::{KeyFrameKey, MapPointKey};

/// Tracking state of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingState {
    NotInitialised,
    Ok,
    Lost,
}

impl TrackingState {
    /// The state's name as `report.json` writes it.
    pub fn as_str(self) -> &'static str {
        match self {
            TrackingState::NotInitialised => "not_initialised",
            TrackingState::Ok => "ok",
            TrackingState::Lost => "lost",
        }
    }
}

/// What tracking one frame did, for the report.
#[derive(Debug, Clone, Serialize)]
pub struct FrameReport {
    pub index: usize,
    pub timestamp: f64,
    pub state: TrackingState,
    /// The map segment the frame was tracked in (see [`super::TrackerConfig::new_map_after_seconds`]).
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
    /// Matched points the rigidity test found moved (`crate::dop::rigidity`).
    pub rigidity_outliers: usize,
    /// Why a lost frame got no pose (the last search's reason).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lost: Option<Reject>,
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

impl FrameReport {
    /// The report of `frame` before tracking it, in `state` and `segment`.
    pub fn start(frame: &crate::frame::Frame, state: TrackingState, segment: usize) -> Self {
        Self {
            index: frame.index,
            timestamp: frame.timestamp,
            state,
            segment,
            keypoints: frame.len(),
            matches: 0,
            inliers: 0,
            keyframe: false,
            dynamic_keypoints: 0,
            dynamic_map_points: 0,
            geometric_raised: 0,
            geometric_lowered: 0,
            rigidity_outliers: 0,
            lost: None,
            new_keyframe: None,
            matching_ms: 0.0,
            optimisation_ms: 0.0,
            dop_ms: 0.0,
            camera_from_world: None,
            reference: None,
            pose_observations: Vec::new(),
        }
    }
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

/// Why a search gave no pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case", tag = "reason")]
pub enum Reject {
    /// No motion model yet (just initialised or relocalised) or no last frame.
    NoMotionModel,
    /// The reference keyframe is gone and the segment has none.
    NoReference,
    /// Too few descriptor matches to optimise a pose.
    FewMatches { found: usize, needed: usize },
    /// The optimised pose has too few inliers.
    FewInliers { found: usize, needed: usize },
    /// No keyframe gave a relocalisation with enough inliers.
    NotRelocalised,
}

/// A pose from matched points: the pose, the matches kept (inliers, and the matches of
/// dynamic or waiting points, which took no part) and the inlier count.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseEstimate {
    pub camera_from_world: Se3,
    pub matches: Vec<Option<MapPointKey>>,
    pub inliers: usize,
}

#[cfg(test)]
mod tests {
    use super::TrackingState;

    #[test]
    fn state_names_are_the_reports() {
        for state in [TrackingState::NotInitialised, TrackingState::Ok, TrackingState::Lost] {
            assert_eq!(serde_json::to_value(state).unwrap(), state.as_str());
        }
    }
}
