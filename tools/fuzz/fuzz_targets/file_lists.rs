//! TUM lists (rgb.txt, depth.txt, associations) and KITTI times.txt.
#![no_main]
use libfuzzer_sys::fuzz_target;

#[path = "common.rs"]
mod common;

fuzz_target!(|data: &[u8]| {
    let path = common::scratch("rgb.txt", data);
    let _ = dopslam::io::file_list::read_file_list(&path, 1);
    let _ = dopslam::io::trajectory::read_times(&path);
    let root = path.parent().expect("a folder");
    let _ = dopslam::io::tum::read_association_file(root, &path);
});
