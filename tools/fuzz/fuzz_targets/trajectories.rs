//! Trajectories in the TUM and KITTI formats.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("trajectory.txt", data);
    let _ = dopslam::io::trajectory::Trajectory::read_tum(&path);
    let _ = dopslam::io::trajectory::Trajectory::read_kitti(&path);
});
