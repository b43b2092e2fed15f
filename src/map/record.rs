//! What the map keeps of a tracked frame that is not (only) a keyframe: its pose
//! relative to its reference keyframe and the map points it saw. The tracking pass
//! writes one [`FrameRecord`] per frame; the global pass corrects them on the final
//! map, and the final trajectory is read from them.

use super::{KeyFrameKey, MapPointKey};
use crate::geometry::se3::Se3;

/// One frame's hand-off from the tracking pass to the global pass.
#[derive(Debug, Clone, Default)]
pub struct FrameRecord {
    /// Seconds (the sequence's clock).
    pub timestamp: f64,
    /// The map segment the frame was tracked in.
    pub segment: usize,
    /// The keyframe made from this frame, if one was (the key it had then).
    pub keyframe: Option<KeyFrameKey>,
    /// The tracked pose, \(T_{cw}\) (none for a lost frame).
    pub camera_from_world: Option<Se3>,
    /// The reference keyframe and the pose relative to it, \(T_{cr}\): the final
    /// trajectory is \(T_{cr} T_{rw}\) with the reference's corrected pose.
    pub reference: Option<(KeyFrameKey, Se3)>,
    /// The keypoints whose map points took part in the final pose as inliers, with
    /// what the global pass needs to estimate the pose again on the final map (and the
    /// keypoint indices, for scoring against ground-truth masks).
    pub observations: Vec<FrameObservation>,
}

impl FrameRecord {
    /// The record of the frame at `timestamp`, before tracking in `segment`.
    pub fn start(timestamp: f64, segment: usize) -> Self {
        Self {
            timestamp,
            segment,
            ..Self::default()
        }
    }

    /// Whether a keyframe was made from this frame.
    pub fn is_keyframe(&self) -> bool {
        self.keyframe.is_some()
    }

    /// The frame's pose placed on its reference keyframe's pose as `keyframe_pose`
    /// gives it now (so frames follow the keyframes' corrections), else the tracked
    /// pose: \(T_{cw} = T_{cr} T_{rw}\).
    pub fn camera_from_world_on(
        &self,
        keyframe_pose: impl Fn(KeyFrameKey) -> Option<Se3>,
    ) -> Option<Se3> {
        self.reference
            .and_then(|(key, camera_from_reference)| {
                Some(camera_from_reference * keyframe_pose(key)?)
            })
            .or(self.camera_from_world)
    }
}

/// One keypoint of a tracked frame and the map point it saw (undistorted level-0
/// pixel, virtual right coordinate, negative without depth).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameObservation {
    /// The map point.
    pub point: MapPointKey,
    /// The keypoint's index in the frame.
    pub keypoint: u32,
    /// Column (undistorted level-0 pixels).
    pub x: f32,
    /// Row.
    pub y: f32,
    /// Virtual right-image column; negative without depth.
    pub right_u: f32,
    /// The keypoint's pyramid level.
    pub level: u8,
}
