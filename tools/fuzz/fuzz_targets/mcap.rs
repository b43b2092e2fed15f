//! MCAP files (ROS 2 storage, uncompressed and zstd/lz4 chunks; the summary and its chunk indexes).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("recording.mcap", data);
    common::open_recording(&path);
});
