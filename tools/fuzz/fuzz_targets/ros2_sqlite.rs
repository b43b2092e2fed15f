//! ROS 2 SQLite bags (`.db3`).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("recording.db3", data);
    common::open_recording(&path);
});
