//! The commands of `dopslam`, one module each (`dopslam run` in [`run`], `dopslam
//! compare-maps` in [`compare_maps`], ...), and what several share: the topic options
//! ([`topics`]), the Rerun options ([`view`]), ORB-SLAM2's settings ([`settings`]) and
//! the argument parsers ([`values`]).

use std::path::Path;

use anyhow::Result;
use dopslam::config::Config;

pub mod batch;
pub mod compare_maps;
pub mod compare_no_dop;
pub mod convert;
pub mod demo;
pub mod detect;
pub mod doctor;
pub mod eval;
pub mod fuse;
pub mod graph;
pub mod info;
pub mod merge;
pub mod run;
pub mod settings;
pub mod stereo;
pub mod synth;
pub mod topics;
pub mod values;
pub mod view;
pub mod vocab;

/// The config file given with `--config`, or the defaults.
pub fn load_config(path: Option<&Path>) -> Result<Config> {
    match path {
        Some(path) => Ok(Config::load(path)?),
        None => Ok(Config::default()),
    }
}
