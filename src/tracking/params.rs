//! Tracking's parameters: the configurable ones ([`TrackerConfig`], ORB-SLAM2's values
//! by default) and ORB-SLAM2's fixed thresholds, by name (ORB-SLAM2 `Tracking.cc`,
//! `ORBmatcher` ratios; kept as they are there unless a comment says otherwise).

use serde::{Deserialize, Serialize};

/// Nearest-to-second-nearest descriptor ratio of the motion-model projection search.
pub const MOTION_MATCH_RATIO: f32 = 0.9;
/// Matches the motion model needs (searched again with twice the radius below).
pub const MIN_MOTION_MATCHES: usize = 20;
/// Ratio of the brute-force search against the reference keyframe.
pub const REFERENCE_MATCH_RATIO: f32 = 0.7;
/// Brute-force matches needed before a pose is optimised (reference keyframe and
/// relocalisation candidates).
pub const MIN_BRUTE_FORCE_MATCHES: usize = 15;
/// Inliers a motion-model, reference-keyframe or relocalisation pose needs.
pub const MIN_SEARCH_INLIERS: usize = 10;
/// Observations below which no pose is optimised.
pub const MIN_POSE_OBSERVATIONS: usize = 10;
/// Points that take part in the pose that are enough for a pose of their own, against
/// which waiting points are tested before they join (see `Tracker::optimise`).
pub const MIN_TRUSTED_POINTS: usize = 20;
/// Ratio of the local-map projection search.
pub const LOCAL_MAP_MATCH_RATIO: f32 = 0.8;
/// Local-map search radius (pixels at level 0) for a view close to the point's mean
/// viewing direction (cosine above [`LOCAL_MAP_CLOSE_VIEW_COS`]), and otherwise.
pub const LOCAL_MAP_RADIUS_CLOSE_VIEW: f32 = 2.5;
/// The projection search radius (pixels at level 0) otherwise.
pub const LOCAL_MAP_RADIUS: f32 = 4.0;
/// The cosine above which the view counts as close.
pub const LOCAL_MAP_CLOSE_VIEW_COS: f64 = 0.998;
/// Relocalisation: every n-th keypoint of the frame ranks the keyframes, the best
/// few are tried.
pub const RELOCALISATION_SAMPLE_STEP: usize = 4;
/// Relocalisation candidates tried at most.
pub const RELOCALISATION_CANDIDATES: usize = 5;
/// Ratio of the brute-force search against a relocalisation candidate.
pub const RELOCALISATION_MATCH_RATIO: f32 = 0.75;
/// Inliers that accept a relocalisation (below it, a projection search of the
/// candidate's points for more first).
pub const RELOCALISATION_ACCEPT: usize = 50;
/// Radius (pixels at level 0) and ratio of that projection search.
pub const RELOCALISATION_SEARCH_RADIUS: f32 = 10.0;
/// The descriptor ratio of that search.
pub const RELOCALISATION_SEARCH_RATIO: f32 = 0.9;
/// Keyframe decision: tracked close points below this while more untracked close
/// ones than [`KEYFRAME_UNTRACKED_CLOSE`] are available ask for a keyframe.
pub const KEYFRAME_TRACKED_CLOSE: usize = 100;
/// Untracked close points that ask for a keyframe.
pub const KEYFRAME_UNTRACKED_CLOSE: usize = 70;
/// Weak tracking: inliers below this share of the reference keyframe's points; very
/// weak below the second.
pub const KEYFRAME_WEAK_RATIO: f64 = 0.75;
/// The share of the reference keyframe's points below which tracking is very weak.
pub const KEYFRAME_VERY_WEAK_RATIO: f64 = 0.25;
/// A frame is on a revisit when most of its matched points were made by keyframes
/// more than this many keyframes older than the tracker's newest.
pub const REVISIT_KEYFRAMES: usize = 20;
/// On a revisit the local map also takes this many best covisible neighbours of each
/// local keyframe (ORB-SLAM2's 10)...
pub const REVISIT_NEIGHBOURS: usize = 10;
/// ... up to this many keyframes in all.
pub const REVISIT_LOCAL_KEYFRAMES: usize = 60;
/// On a revisit the keyframe decision counts the points of the old keyframe that
/// shares most of the frame's matches seen by at least this many keyframes.
pub const REVISIT_MIN_OBSERVATIONS: usize = 3;
/// Inliers a frame needs to become a keyframe.
pub const KEYFRAME_MIN_INLIERS: usize = 15;
/// A keyframe makes points for its unmatched keypoints with depth, nearest first: the
/// close ones, and far ones too until this many are made.
pub const NEW_POINTS_AT_LEAST: usize = 100;

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
    /// The same for the rotation, degrees.
    pub keyframe_min_rotation_deg: f64,
    /// Seconds of failed relocalisation after which a new map segment starts at the
    /// next frame with enough depth (ORB-SLAM3's Atlas without IMU: 3 s). The new
    /// segment starts at the last tracked pose; a loop that connects it to an older
    /// one merges them in the global pass.
    pub new_map_after_seconds: f64,
    /// With a loaded map (`dopslam run --map`): the frames wait, each relocalised
    /// against the map, until one is placed in it; when none of the first this many
    /// is, the run stops with an error (a recording of another place).
    pub place_within_frames: usize,
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
    /// Only the new points near a mover wait (DOP model only): a new point whose
    /// keypoint lies clear of every dynamic box of the latest detection that came back
    /// (each widened by half its size and 16 pixels on every side: the dynamics'
    /// `Participation::awaiting`; the map's wait zones) takes part at once, in the pose
    /// and in local BA, skipping both its detection wait and its probation; points
    /// near a box, and all of them before the first detection comes back, wait. On for
    /// stereo (`[stereo]`; real KITTI 01 at 25 m/s: a keyframe's points are the ones
    /// that matter, docs/design.md), off for RGB-D (a person who walks in from the edge
    /// has no box yet).
    pub wait_near_boxes_only: bool,
    /// The prediction gate of the pose ([`crate::optim::pose_only`]; DOP model only):
    /// when at least this share of a frame's matches lie within half the inlier gate of
    /// the predicted pose, the pose is optimised from those alone and the rest are
    /// judged by the result. A mover that starts to move cannot drag the pose along a
    /// direction the static scene hardly constrains. 0 turns it off.
    pub prediction_gate_share: f64,
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
            place_within_frames: 300,
            held_out_min_points: 60,
            probation_frames: 2,
            wait_near_boxes_only: false,
            prediction_gate_share: 0.6,
        }
    }
}
