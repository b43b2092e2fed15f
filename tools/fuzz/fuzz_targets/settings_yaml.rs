//! ORB-SLAM2 settings files (`--settings`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("settings.yaml", data);
    let _ = dopslam::io::orbslam_settings::OrbSlamSettings::read(&path);
});
