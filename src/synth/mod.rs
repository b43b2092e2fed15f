//! `dopslam synth`: synthetic RGB-D sequences with exact ground truth, written in the
//! real TUM layout so every reader and outside tool takes them unchanged.
//!
//! A textured room with furniture ([`scene`]), a street canyon with parked and
//! moving cars or a highway with traffic both ways ([`street`], [`outdoor`]), seen
//! along procedural or recorded camera motions ([`motion`]), with movers
//! ([`movers`]: people as boxes or real cut-outs on billboards ([`sprite`]), seated
//! people who leave, pushed objects of static classes), rendered by ray casting with
//! Kinect-like depth, colour noise, optional motion blur and exposure drift
//! ([`render`]), written with instance masks, oracle detections ([`oracle`]), the
//! exact static geometry and, optionally, a stereo pair in the KITTI
//! layout ([`writer`]).

pub mod ba_problems;
pub mod config;
pub mod motion;
pub mod movers;
pub mod oracle;
pub mod outdoor;
pub mod pose_graphs;
pub mod preview;
pub mod render;
pub mod scene;
pub mod sprite;
pub mod street;
pub mod texture;
pub mod writer;

pub use config::SynthConfig;
pub use writer::{generate, SynthError, SynthSummary};
