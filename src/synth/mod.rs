//! `dopslam synth`: synthetic RGB-D sequences with exact ground truth, written in the
//! real TUM layout so every reader and outside tool takes them unchanged.
//!
//! This first part renders static scenes (a textured room with furniture) along
//! procedural or recorded camera motions. Movers, masks, oracle detections and stereo
//! output are still to come (issue 3).

pub mod config;
pub mod motion;
pub mod movers;
pub mod oracle;
pub mod preview;
pub mod render;
pub mod scene;
pub mod texture;
pub mod writer;

pub use config::SynthConfig;
pub use writer::{generate, SynthError, SynthSummary};
