//! Pose graphs in g2o's format (`dopslam graph`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("graph.g2o", data);
    let _ = dopslam::io::g2o::G2oGraph::read(&path);
});
