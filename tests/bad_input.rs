//! Bad input on the command line, one case a test: each ends with a message that names
//! the file (and line or frame) and what is wrong, a non-zero exit, and keeps what was
//! already computed. (More cases live in cli.rs, tracking.rs, layouts.rs, detect.rs.)

use crate::common;

use std::path::Path;

use common::{dopslam, sorted_files as sorted};

/// A six-frame static room in a fresh folder.
fn room(name: &str) -> common::TestDir {
    let seq = common::temp_dir(name).child("seq");
    common::synth_static_room(&seq, 6);
    seq
}

fn run(seq: &Path, out: &str) -> (bool, String, String) {
    let out = seq.parent().unwrap().join(out);
    dopslam(&[
        "run",
        &seq.to_string_lossy(),
        "--detections",
        "none",
        "--no-dense",
        "--out",
        &out.to_string_lossy(),
    ])
}

#[test]
fn a_malformed_line_in_rgb_txt_is_named_with_its_line() {
    let seq = room("bad-line");
    let text = std::fs::read_to_string(seq.join("rgb.txt")).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[3] = "garbage here";
    std::fs::write(seq.join("rgb.txt"), lines.join("\n")).unwrap();
    let (ok, _, err) = run(&seq, "out");
    assert!(
        !ok && err.contains("rgb.txt:4") && err.contains("timestamp"),
        "{err}"
    );
}

#[test]
fn timestamps_out_of_order_are_sorted() {
    let seq = room("bad-order");
    let text = std::fs::read_to_string(seq.join("rgb.txt")).unwrap();
    let (comments, mut entries): (Vec<&str>, Vec<&str>) =
        text.lines().partition(|l| l.starts_with('#'));
    entries.reverse();
    std::fs::write(seq.join("rgb.txt"), [comments, entries].concat().join("\n")).unwrap();
    let (ok, out, err) = run(&seq, "out");
    assert!(ok && out.contains("tracked 6 of 6"), "{out}{err}");
    // Not silently: the warning names the file and the lines that go backwards.
    assert!(
        err.contains("rgb.txt: timestamps go backwards on line(s) 4, 5, 6, 7, 8"),
        "{err}"
    );
}

#[test]
fn colour_and_depth_that_never_pair_say_so() {
    let seq = room("bad-pairs");
    let text = std::fs::read_to_string(seq.join("depth.txt")).unwrap();
    let shifted: Vec<String> = text
        .lines()
        .map(|l| match l.split_once(' ') {
            Some((t, rest)) if !l.starts_with('#') => {
                format!("{:.6} {rest}", t.parse::<f64>().unwrap() + 100.0)
            }
            _ => l.to_string(),
        })
        .collect();
    std::fs::write(seq.join("depth.txt"), shifted.join("\n")).unwrap();
    let (ok, _, err) = run(&seq, "out");
    assert!(
        !ok && err.contains("rgb.txt") && err.contains("max_difference"),
        "{err}"
    );
}

#[test]
fn an_eight_bit_depth_map_is_refused_by_name() {
    let seq = room("bad-depth8");
    let depths = sorted(&seq.join("depth"));
    image::GrayImage::new(640, 480).save(&depths[0]).unwrap();
    let (ok, _, err) = run(&seq, "out");
    let name = depths[0]
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    assert!(
        !ok && err.contains(&name) && err.contains("16-bit"),
        "{err}"
    );
}

#[test]
fn a_truncated_png_mid_sequence_stops_there_and_keeps_the_frames_before() {
    let seq = room("bad-truncated");
    let images = sorted(&seq.join("rgb"));
    let bytes = std::fs::read(&images[3]).unwrap();
    std::fs::write(&images[3], &bytes[..bytes.len() / 3]).unwrap();
    let (ok, _, err) = run(&seq, "out");
    let name = images[3]
        .file_name()
        .unwrap()
        .to_string_lossy()
        .into_owned();
    assert!(
        !ok && err.contains(&name) && err.contains("frame 3"),
        "{err}"
    );
    let trajectory =
        std::fs::read_to_string(seq.parent().unwrap().join("out/trajectory.txt")).unwrap();
    assert_eq!(
        trajectory.lines().filter(|l| !l.starts_with('#')).count(),
        3
    );
}

#[test]
fn images_of_changing_size_are_refused() {
    let seq = room("bad-size");
    let images = sorted(&seq.join("rgb"));
    image::RgbImage::new(320, 240).save(&images[2]).unwrap();
    let (ok, _, err) = run(&seq, "out");
    assert!(
        !ok && err.contains("320x240") && err.contains("frame 2"),
        "{err}"
    );
}

#[test]
fn settings_without_camera_fx_are_refused_by_name() {
    let seq = room("bad-settings");
    let text = std::fs::read_to_string(seq.join("calibration.yaml")).unwrap();
    let without: String = text
        .lines()
        .filter(|l| !l.starts_with("Camera.fx"))
        .map(|l| format!("{l}\n"))
        .collect();
    let path = seq.parent().unwrap().join("nofx.yaml");
    std::fs::write(&path, without).unwrap();
    let out = seq.parent().unwrap().join("out");
    let (ok, _, err) = dopslam(&[
        "run",
        &seq.to_string_lossy(),
        "--settings",
        &path.to_string_lossy(),
        "--detections",
        "none",
        "--out",
        &out.to_string_lossy(),
    ]);
    assert!(
        !ok && err.contains("nofx.yaml") && err.contains("Camera.fx"),
        "{err}"
    );
}

#[test]
fn an_unwritable_output_folder_is_named() {
    let seq = room("bad-out");
    let blocker = seq.parent().unwrap().join("a-file");
    std::fs::write(&blocker, "not a folder").unwrap();
    let (ok, _, err) = run(&seq, "a-file/run");
    assert!(
        !ok && err.contains("a-file") && err.contains("cannot create the output folder"),
        "{err}"
    );
}

#[test]
fn a_trajectory_with_nan_is_refused_with_its_line() {
    let dir = common::temp_dir("bad-nan");
    let path = dir.join("nan.txt");
    std::fs::write(
        &path,
        "1.0 0 0 0 0 0 0 1\n2.0 nan 0 0 0 0 0 1\n3.0 1 0 0 0 0 0 1\n",
    )
    .unwrap();
    let p = path.to_string_lossy();
    let (ok, _, err) = dopslam(&["eval", &p, &p]);
    assert!(
        !ok && err.contains("nan.txt:2") && err.contains("finite"),
        "{err}"
    );
}

#[test]
fn a_missing_sequence_folder_is_named() {
    let dir = common::temp_dir("bad-missing");
    let (ok, _, err) = run(&dir.join("nowhere"), "out");
    assert!(!ok && err.contains("nowhere"), "{err}");
}
