//! What tracking one frame hands on: the report line, the record for the global pass
//! ([`FrameRecord`]), and why a frame was lost.

use serde::{Deserialize, Serialize};

use crate::geometry::se3::Se3;
use crate::map::record::FrameRecord;
use crate::map::MapPointKey;

/// Tracking state of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrackingState {
    /// Before the map's first keyframe.
    NotInitialised,
    /// Tracking.
    Ok,
    /// Lost (relocalising).
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

/// What tracking one frame did: the report line and the record the global pass
/// corrects.
#[derive(Debug, Clone)]
pub struct TrackedFrame {
    /// The report line.
    pub stats: FrameStats,
    /// The hand-off to the global pass.
    pub record: FrameRecord,
}

impl TrackedFrame {
    /// Both halves of `frame` before tracking it, in `state` and `segment`.
    pub fn start(frame: &crate::frame::Frame, state: TrackingState, segment: usize) -> Self {
        Self {
            stats: FrameStats::start(frame, state, segment),
            record: FrameRecord::start(frame.timestamp, segment),
        }
    }

    /// The frame was tracked in `segment`: both halves say so.
    pub fn in_segment(&mut self, segment: usize) {
        self.stats.segment = segment;
        self.record.segment = segment;
    }

    /// Keyframe `key` was made from the frame: both halves say so.
    pub fn made_keyframe(&mut self, key: Option<crate::map::KeyFrameKey>) {
        self.stats.keyframe = key.is_some();
        self.record.keyframe = key;
    }

    /// The frame started map segment `segment` as its first keyframe `key`, at
    /// `camera_from_world`, with `with_depth` keypoints that have depth.
    pub fn started_segment(
        &mut self,
        segment: usize,
        key: Option<crate::map::KeyFrameKey>,
        camera_from_world: Se3,
        with_depth: usize,
    ) {
        self.made_keyframe(key);
        self.stats.state = TrackingState::Ok;
        self.stats.lost = None;
        self.in_segment(segment);
        self.record.camera_from_world = Some(camera_from_world);
        self.record.reference = key.map(|k| (k, Se3::identity()));
        self.stats.inliers = with_depth;
    }
}

/// What tracking one frame did, for the report (one line of `report.json`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FrameStats {
    /// The frame's index.
    pub index: usize,
    /// Seconds.
    pub timestamp: f64,
    /// The tracker's state after the frame.
    pub state: TrackingState,
    /// The map segment the frame was tracked in (see [`super::TrackerConfig::new_map_after_seconds`]).
    pub segment: usize,
    /// Keypoints extracted.
    pub keypoints: usize,
    /// Keypoints matched to map points.
    pub matches: usize,
    /// Matches that are pose inliers.
    pub inliers: usize,
    /// Whether the frame became a keyframe.
    pub keyframe: bool,
    /// Whether the frame was tracked on a revisit: most of its points were made by
    /// older keyframes than the tracker's recent ones (`tracker::revisit`).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub revisiting: bool,
    /// DOP: keypoints in a removed (dynamic) state, and local-map points left out as
    /// dynamic.
    pub dynamic_keypoints: usize,
    /// Map points the DOP model removed.
    pub dynamic_map_points: usize,
    /// Map points whose probability the geometric check raised and lowered in this
    /// frame.
    pub geometric_raised: usize,
    /// Map points whose probability the geometric check lowered.
    pub geometric_lowered: usize,
    /// Matched points the rigidity test found moved (`crate::dop::rigidity`).
    pub rigidity_outliers: usize,
    /// Why a lost frame got no pose (the last search's reason).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lost: Option<Reject>,
    /// Milliseconds: matching and local-map search, pose optimisation, total tracking
    /// (feature extraction is timed by the caller).
    pub matching_ms: f64,
    /// Milliseconds in the pose optimisation.
    pub optimisation_ms: f64,
    /// The DOP model's probabilities (propagation and expansion).
    pub dop_ms: f64,
}

impl FrameStats {
    /// The report line of `frame` before tracking it, in `state` and `segment`.
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
            revisiting: false,
            dynamic_keypoints: 0,
            dynamic_map_points: 0,
            geometric_raised: 0,
            geometric_lowered: 0,
            rigidity_outliers: 0,
            lost: None,
            matching_ms: 0.0,
            optimisation_ms: 0.0,
            dop_ms: 0.0,
        }
    }
}

/// Why a search gave no pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", tag = "reason")]
pub enum Reject {
    /// No motion model yet (just initialised or relocalised) or no last frame.
    NoMotionModel,
    /// The reference keyframe is gone and the segment has none.
    NoReference,
    /// Too few descriptor matches to optimise a pose.
    FewMatches {
        /// How many there were.
        found: usize,
        /// How many are needed.
        needed: usize,
    },
    /// The optimised pose has too few inliers.
    FewInliers {
        /// How many there were.
        found: usize,
        /// How many are needed.
        needed: usize,
    },
    /// No keyframe gave a relocalisation with enough inliers.
    NotRelocalised,
}

/// A pose from matched points: the pose, the matches kept (inliers, and the matches of
/// dynamic or waiting points, which took no part) and the inlier count.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseEstimate {
    /// \(T_{cw}\).
    pub camera_from_world: Se3,
    /// Per keypoint: the map point matched.
    pub matches: Vec<Option<MapPointKey>>,
    /// The inliers' count.
    pub inliers: usize,
}

#[cfg(test)]
mod tests {
    use super::TrackingState;

    #[test]
    fn state_names_are_the_reports() {
        for state in [
            TrackingState::NotInitialised,
            TrackingState::Ok,
            TrackingState::Lost,
        ] {
            assert_eq!(serde_json::to_value(state).unwrap(), state.as_str());
        }
    }
}
