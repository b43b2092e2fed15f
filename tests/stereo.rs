//! Stereo end to end on the KITTI layout: a generated street (`street_demo`, needs
//! nothing outside the repository) tracked from its stereo pairs with the DOP model,
//! its dense map from OpenCV's SGBM, and bad KITTI input refused by name.

use crate::common;

use std::path::Path;
use std::sync::OnceLock;

use common::{dopslam, temp_dir};

/// A 40-frame street (KITTI 00-02 intrinsics and baseline), generated once.
fn street() -> &'static Path {
    // Kept for the whole process (a static is never dropped): tools/test.sh removes
    // the temporary folder it gives the test run.
    static STREET: OnceLock<common::TestDir> = OnceLock::new();
    STREET.get_or_init(|| {
        let dir = temp_dir("stereo-street");
        let preset = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/street_demo.toml");
        let (ok, _, err) = dopslam(&[
            "synth",
            "--config",
            &preset.to_string_lossy(),
            "--out",
            &dir.to_string_lossy(),
            "--frames",
            "40",
        ]);
        assert!(ok, "{err}");
        dir.child("kitti/sequences/00")
    })
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn a_street_is_tracked_from_its_stereo_pairs_and_mapped_densely() {
    let out = temp_dir("stereo-run");
    let sequence = street();
    // A rendered rig is perfect: its far disparities are as exact as its near ones, so
    // they stay residuals here (the default makes them bearings, for real rigs).
    let perfect_rig = out.join("perfect_rig.toml");
    std::fs::write(&perfect_rig, "[stereo]\nbearing_baselines = 0.0\n").unwrap();
    let run_dir = out.join("run");
    let (ok, stdout, err) = dopslam(&[
        "run",
        &sequence.to_string_lossy(),
        "--out",
        &run_dir.to_string_lossy(),
        "--detections",
        "oracle",
        "--deterministic",
        "--config",
        &perfect_rig.to_string_lossy(),
    ]);
    let dense = cfg!(feature = "opencv");
    assert!(ok, "{stdout}\n{err}");
    let report = json(&run_dir.join("report.json"));
    assert_eq!(report["totals"]["tracked"], 40, "{stdout}");
    let ate = report["ate"]["ape"]["statistics"]["rmse"].as_f64().unwrap();
    // 40 frames at 8 m/s: 32 m driven.
    assert!(ate < 0.15, "ATE RMSE {ate} m");
    // A perfect rig has no disparity offset to find.
    let found = report["global"]["disparity_offset"]["rounds"][0]
        .as_f64()
        .unwrap();
    assert!(found.abs() < 0.15, "offset {found} px on a perfect rig");
    assert!(report["detection"]["per_class"]["car"].as_u64().unwrap() > 0);
    // Parked cars are detected at every keyframe, yet they do not move: the static
    // check gives some of their points back as static.
    let verified = report["detection"]["map_points_verified_static"]
        .as_u64()
        .unwrap();
    assert!(verified > 0, "no detected point verified static");
    if dense {
        let fused = json(&run_dir.join("dense.json"));
        assert!(fused["frames_fused"].as_u64().unwrap() > 30, "{fused}");
        assert_eq!(fused["sgbm"]["downscale"], 1, "{fused}");
        assert!(run_dir.join("dense_mesh.ply").exists());
        // Fused again with SGBM at half size: the same frames, and dense.json says how.
        let half = out.join("half.toml");
        std::fs::write(&half, "[stereo]\nsgbm_downscale = 2\n").unwrap();
        let (ok, stdout, err) = dopslam(&[
            "fuse",
            &run_dir.to_string_lossy(),
            "--config",
            &half.to_string_lossy(),
        ]);
        assert!(
            ok && stdout.contains("matched at 1/2 size"),
            "{stdout}\n{err}"
        );
        let refused = json(&run_dir.join("dense.json"));
        assert_eq!(refused["sgbm"]["downscale"], 2, "{refused}");
        assert_eq!(refused["frames_fused"], fused["frames_fused"], "{refused}");
    } else {
        eprintln!("built without the opencv feature: the dense map of stereo is not checked");
    }
}

#[test]
fn a_rigs_disparity_offset_is_found_and_taken_out() {
    // The same street through a rig whose right principal point sits 1 px off what
    // calib.txt says: every disparity 1 px short, the path too long.
    let dir = temp_dir("stereo-rig");
    let preset = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/street_demo.toml"),
    )
    .unwrap()
    .replace(
        "baseline = 0.5372",
        "baseline = 0.5372\nrectification_error_px = 1.0",
    );
    let config = dir.join("rig.toml");
    std::fs::write(&config, preset).unwrap();
    let (ok, _, err) = dopslam(&[
        "synth",
        "--config",
        &config.to_string_lossy(),
        "--out",
        &dir.join("seq").to_string_lossy(),
        "--frames",
        "40",
    ]);
    assert!(ok, "{err}");
    let sequence = dir.join("seq/kitti/sequences/00");
    // The default estimates it while tracking and tracks on with it; a threshold above
    // the estimate keeps it in; a known offset is taken as given; a run too short for
    // a sure estimate leaves it at 0 and says why.
    let strict = dir.join("strict.toml");
    std::fs::write(&strict, "[global]\ndisparity_offset_min_px = 2.0\n").unwrap();
    let known = dir.join("known.toml");
    std::fs::write(&known, "[stereo]\ndisparity_offset_px = 1.0\n").unwrap();
    let mut reports = Vec::new();
    for (name, config) in [
        ("run", None),
        ("strict", Some(&strict)),
        ("known", Some(&known)),
        ("short", None),
    ] {
        let run_dir = dir.join(name);
        let mut args = vec![
            "run",
            sequence.to_str().unwrap(),
            "--out",
            run_dir.to_str().unwrap(),
            "--no-dense",
            "--no-dop",
            "--deterministic",
        ];
        if let Some(config) = config {
            args.extend(["--config", config.to_str().unwrap()]);
        }
        if name == "short" {
            args.extend(["--frames", "4"]);
        }
        let (ok, stdout, err) = dopslam(&args);
        assert!(ok, "{stdout}\n{err}");
        assert!(stdout.contains("stereo disparity offset"), "{stdout}");
        reports.push(json(&run_dir.join("report.json")));
    }
    let px = |v: &serde_json::Value| v.as_f64().unwrap();
    let ate = |r: &serde_json::Value| px(&r["ate"]["ape"]["statistics"]["rmse"]);
    // Estimated while tracking, from a map of a few keyframes, and added to every later
    // match: the global pass finds none left.
    let estimated = &reports[0]["setup"]["disparity_offset"];
    assert_eq!(estimated["source"], "estimated", "{estimated}");
    let added = px(&estimated["offset_px"]);
    assert!(
        (added - 1.0).abs() < 0.15,
        "added {added} px for a 1 px offset"
    );
    let at_frame = estimated["frames"].as_u64().unwrap();
    assert!(at_frame < 40, "found at frame {at_frame}: {estimated}");
    assert!(px(&estimated["estimate"]["sigma_px"]) > 0.0, "{estimated}");
    let left = px(&reports[0]["global"]["disparity_offset"]["rounds"][0]);
    assert!(left.abs() < 0.15, "{left} px left after adding {added}");
    assert!(ate(&reports[0]) < 0.15, "ATE {} m", ate(&reports[0]));
    // Below the threshold: estimated, and added nowhere, with the reason.
    let strict = &reports[1];
    let kept = &strict["setup"]["disparity_offset"];
    assert_eq!(px(&kept["offset_px"]), 0.0, "{kept}");
    let first = px(&kept["estimate"]["rounds"][0]);
    assert!((first - 1.0).abs() < 0.3, "{kept}");
    let why = kept["estimate"]["verdict"].as_str().unwrap();
    assert!(why.contains("below the threshold (2 px)"), "{why}");
    assert_eq!(px(&strict["global"]["disparity_offset"]["offset_px"]), 0.0);
    assert!(
        ate(strict) > 2.0 * ate(&reports[0]),
        "ATE {} m with the offset kept",
        ate(strict)
    );
    // Four frames: no map to be sure from, nothing added, and report.json says why.
    let short = &reports[3]["setup"]["disparity_offset"];
    assert_eq!(px(&short["offset_px"]), 0.0, "{short}");
    let why = short["estimate"]["verdict"].as_str().unwrap();
    assert!(why.contains("no estimate within"), "{why}");
    // Given: no estimate before tracking, and none left after it.
    let given = &reports[2];
    assert_eq!(given["setup"]["disparity_offset"]["source"], "config");
    assert!(given["setup"]["disparity_offset"].get("estimate").is_none());
    let left = px(&given["global"]["disparity_offset"]["rounds"][0]);
    assert!(left.abs() < 0.15, "{left} px left after a known 1 px");
}

/// A three-frame copy of the street in the KITTI layout, to break.
fn small_copy(name: &str) -> common::TestDir {
    let from = street();
    let to = temp_dir(name).child("00");
    for sub in ["image_0", "image_1"] {
        std::fs::create_dir_all(to.join(sub)).unwrap();
        for i in 0..3 {
            let file = format!("{sub}/{i:06}.png");
            std::fs::copy(from.join(&file), to.join(&file)).unwrap();
        }
    }
    std::fs::copy(from.join("calib.txt"), to.join("calib.txt")).unwrap();
    let times: String = std::fs::read_to_string(from.join("times.txt"))
        .unwrap()
        .lines()
        .take(3)
        .map(|l| format!("{l}\n"))
        .collect();
    std::fs::write(to.join("times.txt"), times).unwrap();
    to
}

fn run_fails(sequence: &Path) -> String {
    let out = sequence.parent().unwrap().join("run");
    let (ok, stdout, err) = dopslam(&[
        "run",
        &sequence.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--detections",
        "none",
    ]);
    assert!(!ok, "a bad sequence must fail: {stdout}");
    err
}

#[test]
fn fewer_right_images_than_left_is_refused() {
    let sequence = small_copy("stereo-fewer-right");
    std::fs::remove_file(sequence.join("image_1/000002.png")).unwrap();
    let err = run_fails(&sequence);
    assert!(
        err.contains("image_1") && err.contains("2 right images"),
        "{err}"
    );
}

/// Found by fuzzing (`tools/fuzz`, target `kitti_calibration`): a key padded with
/// blanks skipped the count check and a short line then panicked.
#[test]
fn a_short_projection_line_with_a_padded_key_is_refused_by_line() {
    let sequence = small_copy("stereo-short-p0");
    let calib = std::fs::read_to_string(sequence.join("calib.txt")).unwrap();
    let broken: String = calib
        .lines()
        .map(|l| {
            if l.starts_with("P0:") {
                "  P0 : 718.856\n".to_string()
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    std::fs::write(sequence.join("calib.txt"), broken).unwrap();
    let err = run_fails(&sequence);
    assert!(
        err.contains("calib.txt") && err.contains("P0: expected 12 numbers, found 1"),
        "{err}"
    );
}

#[test]
fn a_missing_calib_txt_is_named() {
    let sequence = small_copy("stereo-no-calib");
    std::fs::remove_file(sequence.join("calib.txt")).unwrap();
    let err = run_fails(&sequence);
    assert!(err.contains("calib.txt"), "{err}");
}

/// In KITTI's layout the order of `times.txt` decides which image is which frame: a
/// time going backwards is refused, naming the line.
#[test]
fn times_going_backwards_are_refused() {
    let sequence = small_copy("stereo-times");
    let text = std::fs::read_to_string(sequence.join("times.txt")).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines.swap(1, 2);
    std::fs::write(sequence.join("times.txt"), lines.join("\n")).unwrap();
    let err = run_fails(&sequence);
    assert!(
        err.contains("times.txt") && err.contains("on line 3"),
        "{err}"
    );
}

#[test]
fn a_right_image_of_another_size_is_refused() {
    let sequence = small_copy("stereo-sizes");
    image::GrayImage::new(620, 188)
        .save(sequence.join("image_1/000001.png"))
        .unwrap();
    let err = run_fails(&sequence);
    assert!(err.contains("frame 1") && err.contains("620x188"), "{err}");
    // What was tracked before the bad frame is kept.
    assert!(sequence
        .parent()
        .unwrap()
        .join("run/trajectory.txt")
        .exists());
}

/// The real KITTI pair in `../shared/data`: most keypoints find a depth, and their
/// disparities agree with OpenCV's SGBM to within a pixel.
#[test]
fn the_real_kitti_pair_matches_like_sgbm() {
    let Some(data) = common::shared_data("the_real_kitti_pair_matches_like_sgbm") else {
        return;
    };
    if !cfg!(feature = "opencv") {
        eprintln!(
            "skipping the_real_kitti_pair_matches_like_sgbm: built without the opencv feature"
        );
        return;
    }
    let dir = temp_dir("stereo-real-pair");
    let json_path = dir.join("stereo.json");
    let settings =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/calibration/Stereo_KITTI00-02.yaml");
    let frames = data.join("frames/kitti");
    let (ok, stdout, err) = dopslam(&[
        "stereo",
        &frames.join("stereo_left.png").to_string_lossy(),
        &frames.join("stereo_right.png").to_string_lossy(),
        "--settings",
        &settings.to_string_lossy(),
        "--json",
        &json_path.to_string_lossy(),
    ]);
    assert!(ok, "{stdout}\n{err}");
    let figures = json(&json_path);
    assert!(
        figures["matched_percent"].as_f64().unwrap() > 40.0,
        "{figures}"
    );
    assert!(
        figures["median_difference_px"].as_f64().unwrap() < 1.0,
        "{figures}"
    );
}

/// `dopslam stereo --downscale 2 --truth-depth`: a textured pair shifted by 24 pixels
/// against its true depth \(bf / 24\): most pixels in range get a depth, and it is
/// right; a truth of another size is an error naming the file.
#[test]
fn sgbm_at_half_size_is_measured_against_a_true_depth() {
    if !cfg!(feature = "opencv") {
        eprintln!("skipping sgbm_at_half_size_is_measured_against_a_true_depth: built without the opencv feature");
        return;
    }
    let dir = temp_dir("stereo-truth-depth");
    let texture = |x: u32, y: u32| ((x / 2 * 7919 + y / 2 * 104_729) % 251) as u8;
    let left = image::GrayImage::from_fn(400, 160, |x, y| image::Luma([texture(x, y)]));
    let right = image::GrayImage::from_fn(400, 160, |x, y| image::Luma([texture(x + 24, y)]));
    left.save(dir.join("left.png")).unwrap();
    right.save(dir.join("right.png")).unwrap();
    let settings =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/calibration/Stereo_KITTI00-02.yaml");
    // Camera.bf 386.1694 / 24 px = 16.09 m, in millimetres.
    let millimetres = (386.1694_f64 / 24.0 * 1000.0).round() as u16;
    for (name, width, height) in [("truth.png", 400, 160), ("small.png", 200, 80)] {
        let depth = image::ImageBuffer::from_pixel(width, height, image::Luma([millimetres]));
        depth.save(dir.join(name)).unwrap();
    }
    let s = |name: &str| dir.join(name).to_string_lossy().into_owned();
    let args = |truth: &str| {
        vec![
            "stereo".to_string(),
            s("left.png"),
            s("right.png"),
            "--settings".into(),
            settings.to_string_lossy().into_owned(),
            "--downscale".into(),
            "2".into(),
            "--truth-depth".into(),
            s(truth),
            "--depth-scale".into(),
            "1000".into(),
            "--json".into(),
            s("stereo.json"),
        ]
    };
    let run = |truth: &str| {
        let args = args(truth);
        dopslam(&args.iter().map(String::as_str).collect::<Vec<_>>())
    };
    let (ok, stdout, err) = run("truth.png");
    assert!(ok, "{stdout}\n{err}");
    let figures = json(&dir.join("stereo.json"));
    let depth = &figures["depth"];
    assert_eq!(figures["sgbm_downscale"], 2, "{figures}");
    assert_eq!(depth["truth_pixels"], 400 * 160, "{figures}");
    assert!(depth["valid_percent"].as_f64().unwrap() > 60.0, "{figures}");
    assert!(depth["median_error_m"].as_f64().unwrap() < 0.3, "{figures}");
    assert!(
        depth["within_tolerance_percent"].as_f64().unwrap() > 50.0,
        "{figures}"
    );
    let (ok, _, err) = run("small.png");
    assert!(
        !ok && err.contains("small.png") && err.contains("200x80"),
        "{err}"
    );
}
