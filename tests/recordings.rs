//! Recordings written by an independent writer (the Python `rosbags` package, through
//! tools/write_recording.py) from one `dopslam synth` folder: each lossless one tracks
//! to the folder's trajectory byte for byte under `--deterministic`, and damaged or
//! unusual ones get the warnings and errors a user needs.
//!
//! The writer runs in the Python that `DOPSLAM_TEST_PYTHON` names, else `data/venv`'s
//! (tools/test.sh installs `rosbags` there). Without it the tests skip, saying why,
//! unless `DOPSLAM_REQUIRE_RECORDING_WRITERS` is set (tools/test.sh sets it).

use crate::common;

use std::path::{Path, PathBuf};

/// The Python with `rosbags`, `numpy` and `PIL`, or `None` (the test skips).
fn writer_python(test: &str) -> Option<PathBuf> {
    common::test_python(test, "rosbags, numpy, PIL")
}

/// Writes `seq` as a recording at `out` with the writer's `options`.
fn write(python: &Path, seq: &Path, out: &Path, options: &[&str]) {
    run_writer(python, "write_recording.py", seq, out, options);
}

/// Runs the writer `tools/SCRIPT SEQ OUT OPTIONS...` and checks that it succeeded.
fn run_writer(python: &Path, script: &str, seq: &Path, out: &Path, options: &[&str]) {
    run_writer_with(python, script, seq, out, options, None);
}

/// [`run_writer`] with `pythonpath` first on the writer's `PYTHONPATH` (an older
/// package installed beside the venv's).
fn run_writer_with(
    python: &Path,
    script: &str,
    seq: &Path,
    out: &Path,
    options: &[&str],
    pythonpath: Option<&Path>,
) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tools")
        .join(script);
    let mut command = std::process::Command::new(python);
    command.arg(script).arg(seq).arg(out).args(options);
    if let Some(dir) = pythonpath {
        command.env("PYTHONPATH", dir);
    }
    let output = command.output().unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
}

/// `dopslam run INPUT --deterministic` without detector, dense or global pass, with a
/// `[dataset]` table; the trajectory's text, and stderr.
fn track(input: &Path, out: &Path, dataset: &str) -> (bool, String, String) {
    let config = out.with_extension("toml");
    std::fs::write(&config, format!("[dataset]\n{dataset}\n")).unwrap();
    let args = [
        "run",
        &input.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--config",
    ];
    let config = config.to_string_lossy();
    let (ok, _, err) = common::dopslam(
        &[
            &args[..],
            &[
                &config,
                "--deterministic",
                "--no-dense",
                "--no-global",
                "--detections",
                "none",
            ],
        ]
        .concat(),
    );
    let trajectory = std::fs::read_to_string(out.join("trajectory.txt")).unwrap_or_default();
    (ok, trajectory, err)
}

#[test]
fn each_writer_s_recording_tracks_as_its_folder() {
    let Some(python) = writer_python("each_writer_s_recording_tracks_as_its_folder") else {
        return;
    };
    let dir = common::temp_dir("recordings-equal");
    let seq = dir.join("seq");
    common::synth_static_room(&seq, 24);
    let (ok, folder, err) = track(&seq, &dir.join("out-folder"), "");
    assert!(ok, "{err}");
    assert_eq!(folder.lines().filter(|l| !l.starts_with('#')).count(), 24);
    // (name, writer options, [dataset] keys): 16-bit depth keeps the folder's 5000 per metre.
    let cases: [(&str, &[&str], &str); 8] = [
        ("ros1.bag", &["--format", "ros1", "--shuffle"], ""),
        (
            "ros1-bz2.bag",
            &[
                "--format",
                "ros1",
                "--compression",
                "bz2",
                "--rgb",
                "bgr8",
                "--depth",
                "16UC1",
            ],
            "depth_scale = 5000.0",
        ),
        (
            "ros1-lz4.bag",
            &[
                "--format",
                "ros1",
                "--compression",
                "lz4",
                "--rgb",
                "png",
                "--depth",
                "compressedDepth",
            ],
            "depth_scale = 5000.0",
        ),
        ("ros2-sqlite", &["--format", "ros2-sqlite"], ""),
        // rosbag2's compression modes, and a bag split into files.
        (
            "ros2-zstd-file",
            &["--format", "ros2-sqlite", "--compression", "zstd-file"],
            "",
        ),
        (
            "ros2-mcap-zstd-message",
            &["--format", "ros2-mcap", "--compression", "zstd-message"],
            "",
        ),
        (
            "ros2-split",
            &["--format", "ros2-sqlite", "--split", "3"],
            "",
        ),
        (
            "ros2-mcap",
            &[
                "--format",
                "ros2-mcap",
                "--rgb",
                "png",
                "--depth",
                "16UC1",
                "--ground-truth",
            ],
            "depth_scale = 5000.0\nground_truth_topic = \"/ground_truth\"",
        ),
    ];
    for (name, options, dataset) in cases {
        let recording = dir.join(name);
        write(&python, &seq, &recording, options);
        let (ok, trajectory, err) = track(&recording, &dir.join(format!("out-{name}")), dataset);
        assert!(ok, "{name}: {err}");
        assert_eq!(
            trajectory, folder,
            "{name}: the trajectory differs from the folder's"
        );
        if name == "ros1.bag" {
            assert!(
                err.contains("come before an earlier stamp"),
                "{name}: {err}"
            );
        }
    }
    // The ground truth from the MCAP bag's pose topic scores the run as groundtruth.txt does.
    let ate = |out: &str| -> serde_json::Value {
        let report = std::fs::read_to_string(dir.join(out).join("report.json")).unwrap();
        serde_json::from_str::<serde_json::Value>(&report).unwrap()["ate"]["ape"]["statistics"]
            ["rmse"]
            .clone()
    };
    assert!(ate("out-folder").as_f64().is_some_and(|r| r > 0.0));
    assert_eq!(ate("out-ros2-mcap"), ate("out-folder"));
    // The MCAP file alone opens as its bag folder does.
    let mcap = common::sorted_files(&dir.join("ros2-mcap"))
        .into_iter()
        .find(|p| p.extension().is_some_and(|e| e == "mcap"));
    let (ok, trajectory, err) = track(
        &mcap.unwrap(),
        &dir.join("out-mcap-file"),
        "depth_scale = 5000.0",
    );
    assert!(ok && trajectory == folder, "{err}");
    // `dopslam convert` writes the TUM folder that tracks the same; it never overwrites.
    let tum = dir.join("converted");
    let bag = dir.join("ros1-bz2.bag");
    let convert = |out: &Path| {
        let args = [
            "convert",
            &bag.to_string_lossy(),
            &out.to_string_lossy(),
            "--config",
        ];
        let config = dir.join("out-ros1-bz2.toml"); // track()'s [dataset] depth_scale = 5000
        common::dopslam(&[&args[..], &[&config.to_string_lossy()[..]]].concat())
    };
    let (ok, _, err) = convert(&tum);
    assert!(ok, "{err}");
    let (ok, trajectory, err) = track(&tum, &dir.join("out-converted"), "");
    assert!(ok && trajectory == folder, "{err}");
    let (ok, _, err) = convert(&tum);
    assert!(!ok && err.contains("not an empty folder"), "{err}");
}

/// `dopslam info PATH EXTRA...`: success, stdout, stderr.
fn info(path: &Path, extra: &[&str]) -> (bool, String, String) {
    common::dopslam(&[&["info", &path.to_string_lossy()][..], extra].concat())
}

/// The bag header's `index_pos` field, and where its 8 bytes are.
fn index_pos(bag: &[u8]) -> (u64, usize) {
    let at = bag.windows(10).position(|w| w == b"index_pos=").unwrap() + 10;
    (u64::from_le_bytes(bag[at..at + 8].try_into().unwrap()), at)
}

#[test]
fn damaged_and_unusual_recordings_are_read_or_refused_with_reasons() {
    let Some(python) =
        writer_python("damaged_and_unusual_recordings_are_read_or_refused_with_reasons")
    else {
        return;
    };
    let dir = common::temp_dir("recordings-bad");
    let seq = dir.join("seq");
    common::synth_static_room(&seq, 12);
    let bag = dir.join("full.bag");
    write(
        &python,
        &seq,
        &bag,
        &["--format", "ros1", "--compression", "lz4"],
    );
    let bytes = std::fs::read(&bag).unwrap();

    // No index (a recorder that died): index_pos 0 and no index section; all frames read.
    let (pos, at) = index_pos(&bytes);
    let mut unindexed = bytes[..pos as usize].to_vec();
    unindexed[at..at + 8].copy_from_slice(&0u64.to_le_bytes());
    let path = dir.join("unindexed.bag");
    std::fs::write(&path, &unindexed).unwrap();
    let (ok, out, err) = info(&path, &[]);
    assert!(ok, "{err}");
    assert!(
        out.contains("no index") && out.contains("frames: 12 "),
        "{out}"
    );

    // Cut in the middle of a chunk: the frames of the whole chunks before it, a warning
    // naming the byte.
    let path = dir.join("cut.bag");
    std::fs::write(&path, &unindexed[..unindexed.len() * 2 / 3]).unwrap();
    let (ok, out, err) = info(&path, &[]);
    assert!(ok, "{err}");
    assert!(out.contains("cut short") && out.contains("byte"), "{out}");
    let frames: usize = out
        .split("frames: ")
        .nth(1)
        .unwrap()
        .split(' ')
        .next()
        .unwrap()
        .parse()
        .unwrap();
    assert!((1..12).contains(&frames), "{out}");
    // Converted, its folder keeps the cut; a run of it keeps it in report.json.
    let converted = dir.join("cut-tum");
    let (ok, _, err) = common::dopslam(&[
        "convert",
        &path.to_string_lossy(),
        "--to",
        "tum",
        &converted.to_string_lossy(),
    ]);
    assert!(ok, "{err}");
    let kept = std::fs::read_to_string(converted.join("conversion_warnings.txt")).unwrap();
    assert!(
        kept.contains("cut short") && kept.contains("byte"),
        "{kept}"
    );
    let run = dir.join("out-cut");
    let (ok, _, err) = track(&path, &run, "");
    assert!(ok, "{err}");
    let report = std::fs::read_to_string(run.join("report.json")).unwrap();
    let report: serde_json::Value = serde_json::from_str(&report).unwrap();
    let warnings = report["setup"]["input_warnings"].to_string();
    assert!(
        warnings.contains("cut short") && warnings.contains("byte"),
        "{warnings}"
    );

    // A topic that is not there: the error lists the topics present with their types.
    let (ok, _, err) = info(
        &bag,
        &["--depth-topic", "/camera/depth_registered/image_raw"],
    );
    assert!(
        !ok && err.contains("/camera/depth/image (sensor_msgs/Image, 12 messages)"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    // No depth frames at all; a colour encoding no reader takes, named at the frame.
    let odd = dir.join("odd.bag");
    write(
        &python,
        &seq,
        &odd,
        &["--format", "ros1", "--rgb", "8UC3", "--no-depth"],
    );
    let (ok, _, err) = info(&odd, &[]);
    assert!(!ok && err.contains("no colour image topic found"), "{err}");
    let odd2 = dir.join("odd2.bag");
    write(&python, &seq, &odd2, &["--format", "ros1", "--rgb", "8UC3"]);
    let (ok, _, err) = common::dopslam(&[
        "run",
        &odd2.to_string_lossy(),
        "--rgb-topic",
        "/camera/rgb/image_color",
        "--out",
        &dir.join("out-odd").to_string_lossy(),
        "--no-dense",
        "--detections",
        "none",
    ]);
    assert!(
        !ok && err.contains("\"8UC3\" is not a colour encoding"),
        "{err}"
    );
    let (ok, _, err) = info(&odd, &["--rgb-topic", "/camera/rgb/image_color"]);
    assert!(!ok && err.contains("no depth image topic found"), "{err}");

    // A corrupt JPEG in frame 6: the run stops there as for a corrupt PNG in a folder,
    // naming the recording and the frame's stamp, with what was done written.
    let jpeg = dir.join("jpeg.bag");
    write(
        &python,
        &seq,
        &jpeg,
        &["--format", "ros1", "--rgb", "jpeg", "--corrupt-frame", "6"],
    );
    let out = dir.join("out-jpeg");
    let (ok, _, err) = common::dopslam(&[
        "run",
        &jpeg.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--no-dense",
        "--detections",
        "none",
    ]);
    assert!(
        !ok && err.contains("jpeg.bag") && err.contains("colour image stamped"),
        "{err}"
    );
    assert!(
        out.join("trajectory.txt").exists(),
        "the frames before it are written"
    );

    // Not a bag at all, and a bag of an older format.
    let path = dir.join("text.bag");
    std::fs::write(&path, "hello").unwrap();
    let (ok, _, err) = info(&path, &[]);
    assert!(!ok && err.contains("not a ROS bag"), "{err}");
    let path = dir.join("not.mcap");
    std::fs::write(&path, vec![7u8; 100]).unwrap();
    let (ok, _, err) = info(&path, &[]);
    assert!(
        !ok && err.contains("not.mcap") && !err.contains("panicked"),
        "{err}"
    );
    // A split bag missing one of the files its metadata lists: named.
    let split = dir.join("split");
    write(
        &python,
        &seq,
        &split,
        &["--format", "ros2-sqlite", "--split", "2"],
    );
    std::fs::remove_file(split.join("split_1.db3")).unwrap();
    let (ok, _, err) = info(&split, &[]);
    assert!(
        !ok && err.contains("split_1.db3") && !err.contains("panicked"),
        "{err}"
    );
    let path = dir.join("not.db3");
    std::fs::write(&path, vec![7u8; 100]).unwrap();
    let (ok, _, err) = info(&path, &[]);
    assert!(
        !ok && err.contains("not.db3") && !err.contains("panicked"),
        "{err}"
    );
}

/// A synth preset with a depth camera of its own (other intrinsics, 25 mm beside the
/// colour camera) and noise-free depth, so the colour camera's depth is the truth.
const DEPTH_CAMERA_PRESET: &str = r#"
name = "depth_camera"
[sequence]
frames = 6
fps = 30.0
seed = 11
[motion]
kind = "xyz"
[scene]
room_margin = 2.5
furniture = 14
clearance = 0.9
[sensor]
depth_noise = false
disparity_step = 0.0
[depth_camera]
offset = [0.025, 0.0, 0.0]
[depth_camera.camera]
fx = 570.0
fy = 570.0
cx = 318.5
cy = 242.5
width = 640
height = 480
distortion = [0.0, 0.0, 0.0, 0.0, 0.0]
"#;

/// Whether `module` imports in `python`; when not, the test skips, saying so, unless
/// `DOPSLAM_REQUIRE_RECORDING_WRITERS` is set (then it fails).
fn python_has(python: &Path, module: &str, test: &str) -> bool {
    let ok = std::process::Command::new(python)
        .args(["-c", &format!("import {module}")])
        .output();
    if ok.is_ok_and(|o| o.status.success()) {
        return true;
    }
    assert!(
        std::env::var_os("DOPSLAM_REQUIRE_RECORDING_WRITERS").is_none(),
        "{test}: {module} is missing"
    );
    eprintln!(
        "skipping {test}: {} cannot import {module}",
        python.display()
    );
    false
}

/// Opens `recording` (of the synth folder `seq`, written in the depth camera's own
/// geometry) and checks each frame against the folder: stamps, colour (equal when
/// `colour_tolerance` is 0, else the mean absolute difference of the channels at most
/// that), and the registered depth against the colour camera's true depth.
/// Returns the share of pixels within 1 mm and the truth's coverage.
fn registered_depth_against_truth(
    recording: &Path,
    seq: &Path,
    colour_tolerance: f64,
) -> (f64, f64) {
    use dopslam::io::image_files::{read_depth, read_rgb};
    use dopslam::io::recording::{RecordingOptions, RecordingSequence};
    use dopslam::io::sequence::{FrameImages, Sequence};
    let sequence = RecordingSequence::open(
        recording,
        &RecordingOptions {
            max_difference: 0.02,
            ..Default::default()
        },
    )
    .unwrap();
    assert!(
        !sequence.description.registered,
        "the depth is in its own camera"
    );
    let names: Vec<String> = std::fs::read_to_string(seq.join("rgb.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split_whitespace().nth(1).unwrap().to_owned())
        .collect();
    assert_eq!(sequence.len(), names.len());
    let (mut close, mut both, mut truth_valid) = (0usize, 0usize, 0usize);
    for (index, name) in names.iter().enumerate() {
        let FrameImages::Rgbd { rgb, depth } = sequence.load(index).unwrap().images else {
            panic!("RGB-D")
        };
        // Matroska keeps milliseconds (ffmpeg's time scale); the bags, microseconds.
        assert!(
            (sequence.timestamp(index) - name[4..name.len() - 4].parse::<f64>().unwrap()).abs()
                < 6e-4
        );
        let colour = read_rgb(&seq.join(name)).unwrap();
        if colour_tolerance == 0.0 {
            assert_eq!(
                rgb, colour,
                "frame {index}: the colour image, channels in order"
            );
        } else {
            let sum: f64 = rgb
                .as_raw()
                .iter()
                .zip(colour.as_raw())
                .map(|(a, b)| (*a as f64 - *b as f64).abs())
                .sum();
            let mean = sum / colour.as_raw().len() as f64;
            eprintln!(
                "{}: frame {index}: colour off by {mean:.2} on average",
                recording.display()
            );
            assert!(
                mean <= colour_tolerance,
                "frame {index}: colour off by {mean:.2} on average"
            );
        }
        let truth = read_depth(&seq.join(name.replace("rgb/", "depth/")), 5000.0).unwrap();
        for (r, t) in depth.metres.iter().zip(&truth.metres) {
            truth_valid += usize::from(*t > 0.0);
            if *t > 0.0 && *r > 0.0 {
                both += 1;
                close += usize::from((r - t).abs() <= 0.001);
            }
        }
    }
    let (share, coverage) = (close as f64 / both as f64, both as f64 / truth_valid as f64);
    eprintln!("{}: registered depth within 1 mm of the truth on {:.2} % of {both} pixels; {:.1} % of the truth's pixels have depth", recording.display(), 100.0 * share, 100.0 * coverage);
    (share, coverage)
}

#[test]
fn a_realsense_recording_is_registered_into_the_colour_camera() {
    let test = "a_realsense_recording_is_registered_into_the_colour_camera";
    let Some(python) = writer_python(test) else {
        return;
    };
    if !python_has(&python, "pyrealsense2", test) {
        return;
    }
    let dir = common::temp_dir("recordings-realsense");
    let seq = preset_sequence(&dir, DEPTH_CAMERA_PRESET);
    let recording = dir.join("realsense.db3");
    run_writer(&python, "write_realsense.py", &seq, &recording, &[]);
    let (share, coverage) = registered_depth_against_truth(&recording, &seq, 0.0);
    assert!(share >= 0.99, "{share}");
    // The depth camera's narrower view ((535/570)^2 = 0.88 of the colour image) bounds it.
    assert!(coverage >= 0.85, "{coverage}");
    // librealsense before 2.56 (pyrealsense2 2.55, which tools/test.sh installs beside
    // the venv's) writes a ROS 1 bag: its own camera infos, Float32 depth unit, tf topics.
    let old = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/pyrealsense2-2.55");
    if !old.join("pyrealsense2").is_dir() {
        assert!(
            std::env::var_os("DOPSLAM_REQUIRE_RECORDING_WRITERS").is_none(),
            "{test}: {} is missing (tools/test.sh installs pyrealsense2 2.55 there)",
            old.display()
        );
        eprintln!("skipping the librealsense 2.55 bag: no {}", old.display());
        return;
    }
    let bag = dir.join("realsense-2.55.bag");
    run_writer_with(&python, "write_realsense.py", &seq, &bag, &[], Some(&old));
    assert_eq!(
        &std::fs::read(&bag).unwrap()[..13],
        b"#ROSBAG V2.0\n",
        "a ROS 1 bag"
    );
    let (share, coverage) = registered_depth_against_truth(&bag, &seq, 0.0);
    assert!(share >= 0.99 && coverage >= 0.85, "{share} {coverage}");
    let (ok, folder, err) = track(&seq, &dir.join("out-folder"), "");
    assert!(ok, "{err}");
    let (ok, trajectory, err) = track(&bag, &dir.join("out-bag"), "");
    assert!(
        ok && trajectory.lines().count() == folder.lines().count(),
        "{err}"
    );
}

/// The 6 frames of the synth preset `text`, written under `dir` (`seq`).
fn preset_sequence(dir: &Path, text: &str) -> PathBuf {
    let preset = dir.join("preset.toml");
    std::fs::write(&preset, text).unwrap();
    let seq = dir.join("seq");
    common::synth_preset(&preset, &seq, 6);
    seq
}

/// [`DEPTH_CAMERA_PRESET`] with an Azure Kinect's depth camera: 640x576 (NFOV unbinned),
/// 32 mm beside the colour camera and a little behind it.
fn kinect_preset() -> String {
    DEPTH_CAMERA_PRESET
        .replace(
            "offset = [0.025, 0.0, 0.0]",
            "offset = [0.032, 0.002, 0.004]",
        )
        .replace(
            "fx = 570.0\nfy = 570.0\ncx = 318.5\ncy = 242.5",
            "fx = 504.0\nfy = 504.5\ncx = 321.5\ncy = 330.0",
        )
        .replace("height = 480", "height = 576")
}

#[test]
fn an_azure_kinect_recording_is_registered_and_tracks_as_its_folder() {
    let test = "an_azure_kinect_recording_is_registered_and_tracks_as_its_folder";
    let Some(python) = writer_python(test) else {
        return;
    };
    let ffmpeg = std::process::Command::new("ffmpeg")
        .arg("-version")
        .output();
    if !ffmpeg.is_ok_and(|o| o.status.success()) {
        assert!(
            std::env::var_os("DOPSLAM_REQUIRE_RECORDING_WRITERS").is_none(),
            "{test}: ffmpeg is missing (tools/test.sh installs it)"
        );
        eprintln!("skipping {test}: no ffmpeg");
        return;
    }
    let dir = common::temp_dir("recordings-kinect");
    let text = kinect_preset();
    assert!(text.contains("height = 576") && text.contains("fx = 504.0"));
    let seq = preset_sequence(&dir, &text);
    let recording = dir.join("kinect.mkv");
    run_writer(&python, "write_kinect.py", &seq, &recording, &[]);
    let (share, coverage) = registered_depth_against_truth(&recording, &seq, 0.0);
    assert!(share >= 0.99, "{share}");
    assert!(coverage >= 0.85, "{coverage}");
    // The other colour modes (lossy: JPEG, and chroma at half resolution in NV12 and
    // YUY2) read with their colours close to the folder's.
    for (mode, tolerance) in [("mjpeg", 3.0), ("nv12", 3.0), ("yuy2", 3.0)] {
        let file = dir.join(format!("kinect-{mode}.mkv"));
        run_writer(&python, "write_kinect.py", &seq, &file, &["--colour", mode]);
        let (share, _) = registered_depth_against_truth(&file, &seq, tolerance);
        assert!(share >= 0.99, "{mode}: {share}");
    }
    // The run takes its cameras from the recording and tracks as the folder does.
    let (ok, folder, err) = track(&seq, &dir.join("out-folder"), "");
    assert!(ok, "{err}");
    // The ground truth from a TUM file (the recording has no pose topic).
    let truth = format!("ground_truth_file = {:?}", seq.join("groundtruth.txt"));
    let (ok, trajectory, err) = track(&recording, &dir.join("out-mkv"), &truth);
    assert!(ok, "{err}");
    let ate = |out: &str| -> f64 {
        let report = std::fs::read_to_string(dir.join(out).join("report.json")).unwrap();
        serde_json::from_str::<serde_json::Value>(&report).unwrap()["ate"]["ape"]["statistics"]
            ["rmse"]
            .as_f64()
            .unwrap_or(f64::NAN)
    };
    let (a, b) = (ate("out-folder"), ate("out-mkv"));
    assert!(a > 0.0 && (a - b).abs() < 0.002, "{a} {b}");
    let both = format!("{truth}\nground_truth_topic = \"/mocap\"");
    let (ok, _, err) = track(&recording, &dir.join("out-both"), &both);
    assert!(!ok && err.contains("choose one"), "{err}");
    let positions = |t: &str| -> Vec<[f64; 3]> {
        t.lines()
            .filter(|l| !l.starts_with('#'))
            .map(|l| {
                let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
                [v[1], v[2], v[3]]
            })
            .collect()
    };
    let (a, b) = (positions(&folder), positions(&trajectory));
    assert_eq!(a.len(), b.len());
    let worst = a
        .iter()
        .zip(&b)
        .map(|(p, q)| (0..3).map(|i| (p[i] - q[i]).powi(2)).sum::<f64>().sqrt())
        .fold(0.0, f64::max);
    eprintln!(
        "Azure Kinect recording vs folder: positions differ by at most {:.2} mm",
        worst * 1e3
    );
    assert!(worst < 0.002, "{worst} m");
    // Cut in the middle of a frame: the frames before the cut are read, saying where.
    let bytes = std::fs::read(&recording).unwrap();
    let cut = dir.join("cut.mkv");
    std::fs::write(&cut, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let (ok, out, err) = info(&cut, &[]);
    assert!(ok, "{err}");
    let text = format!("{out}{err}");
    assert!(
        text.contains("cut short") && text.contains("byte"),
        "{text}"
    );
    // Damaged anywhere in its headers (tracks, tags, attachment, first cluster): read or
    // refused, never a panic.
    {
        use dopslam::io::recording::{RecordingOptions, RecordingSequence};
        use dopslam::io::sequence::Sequence;
        let damaged = dir.join("damaged.mkv");
        for at in (0..bytes.len().min(6000)).step_by(149) {
            let mut copy = bytes.clone();
            copy[at] ^= 0xA5;
            std::fs::write(&damaged, &copy).unwrap();
            let options = RecordingOptions {
                max_difference: 0.02,
                ..Default::default()
            };
            if let Ok(sequence) = RecordingSequence::open(&damaged, &options) {
                if !sequence.is_empty() {
                    let _ = sequence.load(0);
                }
            }
        }
    }
    // Without its calibration attachment: named, no work done.
    let mut renamed = bytes.clone();
    let at = renamed
        .windows(16)
        .position(|w| w == b"calibration.json")
        .unwrap();
    renamed[at..at + 16].copy_from_slice(b"calibratiom.json");
    let no_calibration = dir.join("no-calibration.mkv");
    std::fs::write(&no_calibration, &renamed).unwrap();
    let (ok, _, err) = info(&no_calibration, &[]);
    assert!(
        !ok && err.contains("calibration.json") && !err.contains("panicked"),
        "{err}"
    );
}

#[test]
fn a_stereo_bag_tracks_as_its_kitti_folder_and_converts_back() {
    let Some(python) = writer_python("a_stereo_bag_tracks_as_its_kitti_folder_and_converts_back")
    else {
        return;
    };
    let dir = common::temp_dir("recordings-stereo");
    let seq = dir.join("seq");
    let preset = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/street_demo.toml");
    common::synth_preset(&preset, &seq, 20);
    let kitti = seq.join("kitti/sequences/00");
    let (ok, folder, err) = track(&kitti, &dir.join("out-folder"), "");
    assert!(ok, "{err}");
    let bag = dir.join("stereo.bag");
    write(&python, &seq, &bag, &["--format", "ros1", "--stereo"]);
    let (ok, out, err) = common::dopslam(&["info", &bag.to_string_lossy()]);
    assert!(
        ok && out.contains("stereo pair: left /stereo/left/image_rect")
            && out.contains("baseline 0.5372"),
        "{out}{err}"
    );
    let (ok, trajectory, err) = track(&bag, &dir.join("out-bag"), "");
    assert!(ok, "{err}");
    assert_eq!(
        trajectory, folder,
        "the stereo bag's trajectory differs from the folder's"
    );
    // Back to a KITTI folder: the same again; and not to the TUM layout.
    let converted = dir.join("converted");
    let (ok, _, err) = common::dopslam(&[
        "convert",
        &bag.to_string_lossy(),
        "--to",
        "kitti",
        &converted.to_string_lossy(),
    ]);
    assert!(ok, "{err}");
    let (ok, trajectory, err) = track(&converted, &dir.join("out-converted"), "");
    assert!(ok && trajectory == folder, "{err}");
    let (ok, _, err) = common::dopslam(&[
        "convert",
        &bag.to_string_lossy(),
        &dir.join("tum").to_string_lossy(),
    ]);
    assert!(!ok && err.contains("--to kitti"), "{err}");
}

/// The writer's Python, a test folder `name` and a static room of `frames` frames in
/// it, or `None` (the test skips) when the writer is missing.
fn writer_and_room(
    test: &str,
    name: &str,
    frames: usize,
) -> Option<(PathBuf, common::TestDir, PathBuf)> {
    let python = writer_python(test)?;
    let dir = common::temp_dir(name);
    let seq = dir.join("seq");
    common::synth_static_room(&seq, frames);
    Some((python, dir, seq))
}

/// The files in `dir`, by name.
fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// A recording with colour alone (no depth, no second camera) is monocular: refused as
/// such by `info` and `run`, also with a colour topic named and a camera given, never
/// taken for a stereo pair of one topic with itself.
#[test]
fn a_recording_without_depth_or_a_pair_is_refused_as_monocular() {
    let Some((python, dir, seq)) = writer_and_room(
        "a_recording_without_depth_or_a_pair_is_refused_as_monocular",
        "recordings-mono",
        4,
    ) else {
        return;
    };
    let bag = dir.join("mono.bag");
    write(&python, &seq, &bag, &["--format", "ros1", "--no-depth"]);
    for extra in [&[][..], &["--rgb-topic", "/camera/rgb/image_color"][..]] {
        let (ok, out, err) = info(&bag, extra);
        assert!(
            !ok && err.contains("monocular input is not supported"),
            "{out}{err}"
        );
        assert!(
            !out.contains("stereo pair") && !err.contains("panicked"),
            "{out}{err}"
        );
    }
    let (ok, out, err) = common::dopslam(&[
        "run",
        &bag.to_string_lossy(),
        "--rgb-topic",
        "/camera/rgb/image_color",
        "--camera",
        "525,525,319.5,239.5",
        "--out",
        &dir.join("out").to_string_lossy(),
        "--no-dense",
        "--detections",
        "none",
    ]);
    assert!(
        !ok && err.contains("monocular input is not supported"),
        "{out}{err}"
    );
    assert!(!out.contains("tracked"), "{out}");
    // Its colour topic named as depth: refused by `info` already, not at frame 0.
    let (ok, _, err) = info(&bag, &["--depth-topic", "/camera/rgb/image_color"]);
    assert!(
        !ok && err.contains("carries colour or grey images, not depth"),
        "{err}"
    );
}

/// A ROS 2 SQLite bag in WAL mode (rosbag2's `resilient` preset) is read without any
/// file appearing beside it; a journal its recorder left there is named as unread.
#[test]
fn a_wal_mode_sqlite_bag_is_read_without_writing_beside_it() {
    let Some((python, dir, seq)) = writer_and_room(
        "a_wal_mode_sqlite_bag_is_read_without_writing_beside_it",
        "recordings-wal",
        4,
    ) else {
        return;
    };
    // A folder whose name SQLite's URIs would misread unless encoded (the writer
    // itself cannot write there: it is renamed after).
    let bag = dir.join("wal bag?#%");
    write(
        &python,
        &seq,
        &dir.join("wal"),
        &["--format", "ros2-sqlite"],
    );
    std::fs::rename(dir.join("wal"), &bag).unwrap();
    let db3 = common::sorted_files(&bag)
        .into_iter()
        .find(|p| p.extension().is_some_and(|e| e == "db3"))
        .unwrap();
    {
        let connection = rusqlite::Connection::open(&db3).unwrap();
        let mode: String = connection
            .query_row("PRAGMA journal_mode=WAL", [], |row| row.get(0))
            .unwrap();
        assert_eq!(mode, "wal");
    }
    let before = names_in(&bag);
    for path in [bag.clone(), db3.clone()] {
        let (ok, out, err) = info(&path, &[]);
        assert!(ok && out.contains("frames: 4 "), "{out}{err}");
        assert_eq!(names_in(&bag), before, "nothing written beside the bag");
    }
    // Nor converted into it.
    let inside = bag.join("tum");
    let (ok, _, err) = common::dopslam(&[
        "convert",
        &bag.to_string_lossy(),
        "--to",
        "tum",
        &inside.to_string_lossy(),
    ]);
    assert!(!ok && err.contains("never writes into its inputs"), "{err}");
    assert_eq!(names_in(&bag), before, "nothing written into the bag");
    let mut journal = db3.clone().into_os_string();
    journal.push("-wal");
    std::fs::write(&journal, [1u8; 64]).unwrap();
    let (ok, out, err) = info(&db3, &[]);
    assert!(ok && (out + &err).contains("-wal (64 bytes) lies beside the bag"));
    // A bag folder without its metadata.yaml is still a bag, not a TUM folder.
    std::fs::remove_file(&journal).unwrap();
    std::fs::remove_file(bag.join("metadata.yaml")).unwrap();
    let (ok, out, err) = info(&bag, &[]);
    let said = out + &err;
    assert!(
        ok && said.contains("frames: 4 ") && said.contains("no metadata.yaml"),
        "{said}"
    );
    // And a TUM folder named like a bag is a TUM folder.
    let named = dir.join("seq.bag");
    std::fs::rename(&seq, &named).unwrap();
    let (ok, out, err) = info(&named, &[]);
    assert!(
        ok && out.contains("sequence seq.bag (Rgbd): 4 frames"),
        "{out}{err}"
    );
}

/// An MCAP file whose summary lies about a chunk (shorter than a record's frame, or at
/// an offset near 2^64) is refused with the index and the byte named, never a panic; a
/// cut one says how to recover it.
#[test]
fn a_lying_or_cut_mcap_is_named_not_panicked_on() {
    let Some((python, dir, seq)) = writer_and_room(
        "a_lying_or_cut_mcap_is_named_not_panicked_on",
        "recordings-mcap",
        4,
    ) else {
        return;
    };
    let bag = dir.join("bag");
    write(&python, &seq, &bag, &["--format", "ros2-mcap"]);
    let file = common::sorted_files(&bag)
        .into_iter()
        .find(|p| p.extension().is_some_and(|e| e == "mcap"))
        .unwrap();
    let bytes = std::fs::read(&file).unwrap();
    let summary = mcap::read::Summary::read(&bytes).unwrap().unwrap();
    let index = &summary.chunk_indexes[0];
    // The chunk index record holds the chunk's offset then its length.
    let key = [
        index.chunk_start_offset.to_le_bytes(),
        index.chunk_length.to_le_bytes(),
    ]
    .concat();
    let at = bytes.windows(16).rposition(|w| w == &key[..]).unwrap();
    let crc_at = bytes.len() - mcap::MAGIC.len() - 4;
    for (name, offset, length) in [
        ("short.mcap", index.chunk_start_offset, 5u64),
        ("far.mcap", u64::MAX - 255, index.chunk_length),
    ] {
        let mut lying = bytes.clone();
        lying[at..at + 8].copy_from_slice(&offset.to_le_bytes());
        lying[at + 8..at + 16].copy_from_slice(&length.to_le_bytes());
        lying[crc_at..crc_at + 4].copy_from_slice(&[0; 4]); // no summary CRC to check
        let path = dir.join(name);
        std::fs::write(&path, &lying).unwrap();
        let (ok, out, err) = info(&path, &[]);
        assert!(!ok && !err.contains("panicked"), "{out}{err}");
        assert!(
            err.contains(name) && err.contains("chunk index 0") && err.contains("byte"),
            "{err}"
        );
    }
    let path = dir.join("cut.mcap");
    std::fs::write(&path, &bytes[..bytes.len() * 2 / 3]).unwrap();
    let (ok, _, err) = info(&path, &[]);
    assert!(
        !ok && err.contains("cut short") && err.contains("mcap recover"),
        "{err}"
    );
}
