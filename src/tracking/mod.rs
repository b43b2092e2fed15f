//! Tracking (ORB-SLAM2 §III): the tracker against the map it is handed
//! ([`tracker`]), its parameters by name ([`params`]), what it reports per frame
//! ([`report`]) and the checks of its input frames ([`input`]). Frames themselves are
//! [`crate::frame`].

pub mod input;
pub mod params;
pub mod report;
pub mod tracker;

pub use params::TrackerConfig;
pub use report::{FrameStats, PoseEstimate, Reject, TrackedFrame, TrackingState};
pub use tracker::Tracker;
