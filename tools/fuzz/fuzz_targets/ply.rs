//! PLY maps for `compare-maps` (ASCII and binary).
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("map.ply", data);
    let _ = dopslam::io::ply::read_ply(&path);
});
