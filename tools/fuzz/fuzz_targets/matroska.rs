//! Azure Kinect recordings (Matroska `.mkv`: EBML, tracks, attachments, clusters).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("recording.mkv", data);
    common::open_recording(&path);
});
