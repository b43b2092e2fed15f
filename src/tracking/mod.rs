//! Tracking (ORB-SLAM2 §III): the tracker against the map, and the checks of its
//! input frames. Frames themselves are [`crate::frame`].

pub mod input;
pub mod tracker;

pub use tracker::{FrameReport, Tracker, TrackerConfig, TrackingState};
