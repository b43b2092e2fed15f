//! The tracking pass: frames, matching, and the tracker (ORB-SLAM2 §III).

pub mod frame;
pub mod matching;
pub mod tracker;

pub use frame::Frame;
pub use tracker::{FrameReport, Tracker, TrackerConfig, TrackingState};
