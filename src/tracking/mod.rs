//! The tracking pass: frames, matching, and the tracker (ORB-SLAM2 §III).

pub mod frame;
pub mod input;
pub mod matching;
pub mod stereo_matching;
pub mod tracker;

pub use frame::Frame;
pub use tracker::{FrameReport, Tracker, TrackerConfig, TrackingState};
