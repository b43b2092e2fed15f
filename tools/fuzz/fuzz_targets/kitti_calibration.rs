//! KITTI calib.txt.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("calib.txt", data);
    let _ = dopslam::io::kitti::read_kitti_calibration(&path, 1241, 376);
});
