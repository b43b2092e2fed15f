//! ROS 1 bags (`.bag`: uncompressed, bz2 and lz4 chunks, with or without index).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("recording.bag", data);
    common::open_recording(&path);
});
