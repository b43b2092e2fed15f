//! The Rerun recording of a run, read back by an independent reader: the Python
//! `rerun-sdk` of the same version (tools/read_rerun.py, through its dataframe API).
//!
//! The reader runs in the Python that `DOPSLAM_TEST_PYTHON` names, else `data/venv`'s
//! (tools/test.sh installs `rerun-sdk` there). Without it the tests skip, saying why,
//! unless `DOPSLAM_REQUIRE_RECORDING_WRITERS` is set (tools/test.sh sets it).

use crate::common;

use std::collections::BTreeMap;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};

use serde_json::Value;

/// The Python with `rerun` (and its dataframe API), or `None` (the test skips).
fn reader_python(test: &str) -> Option<PathBuf> {
    common::test_python(test, "rerun, datafusion")
}

/// What tools/read_rerun.py reads from `rrd`.
fn read(python: &Path, rrd: &Path) -> Value {
    common::read_rerun(python, rrd).unwrap()
}

fn report(run: &Path) -> Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("report.json")).unwrap()).unwrap()
}

/// Per frame index, a count the reader gives.
fn per_frame(read: &Value, key: &str) -> BTreeMap<usize, u64> {
    read[key]
        .as_object()
        .unwrap()
        .iter()
        .map(|(k, v)| (k.parse().unwrap(), v.as_u64().unwrap()))
        .collect()
}

/// The synth `preset` as `edit` changes it, written into a new test folder: the
/// sequence (its guard) and the folder.
fn sequence(
    test: &str,
    preset: &str,
    edit: impl FnOnce(&mut dopslam::synth::SynthConfig),
) -> (common::TestDir, PathBuf) {
    let seq = common::temp_dir(test).child("seq");
    let dir = seq.parent().unwrap().to_path_buf();
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let path = root.join("configs/synth").join(format!("{preset}.toml"));
    let mut synth = dopslam::synth::SynthConfig::load(&path).unwrap();
    edit(&mut synth);
    dopslam::synth::generate(&synth, &seq, false).unwrap();
    (seq, dir)
}

/// Asserts that the list of entities `value` holds each of `names`.
fn assert_has(value: &Value, names: &[&str]) {
    let list = strings(value);
    for name in names {
        assert!(
            list.iter().any(|e| e == name),
            "{name} missing from {list:?}"
        );
    }
}

fn strings(value: &Value) -> Vec<String> {
    value
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap().to_string())
        .collect()
}

/// `loop_room` in the default real-time mode with `--rerun`: one pose per tracked
/// frame, each frame's keypoints (kept + removed) as many as report.json counts, the
/// removed ones as its `dynamic_keypoints`, and the loop closed as an event with its
/// edge drawn.
#[test]
fn a_run_logs_every_pose_keypoint_and_the_loop() {
    let Some(python) = reader_python("a_run_logs_every_pose_keypoint_and_the_loop") else {
        return;
    };
    // 34 s at 10 fps: the camera passes its start.
    let seq = common::loop_room_34s();
    let dir = common::temp_dir("rerun-loop");
    let out = dir.join("run");
    let rrd = dir.join("loop.rrd");
    let (ok, _, err) = common::dopslam(&[
        "run",
        &seq.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--detections",
        "oracle",
        "--no-dense",
        "--rerun",
        &rrd.to_string_lossy(),
    ]);
    assert!(ok, "{err}");
    let read = read(&python, &rrd);
    let report = report(&out);
    let frames = report["frames"].as_array().unwrap();
    let tracked: Vec<usize> = frames
        .iter()
        .filter(|f| f["state"] == "ok")
        .map(|f| f["index"].as_u64().unwrap() as usize)
        .collect();
    let poses: Vec<usize> = read["pose_frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect();
    assert_eq!(poses, tracked);
    let (kept, removed) = (per_frame(&read, "kept"), per_frame(&read, "removed"));
    for f in frames.iter().filter(|f| f["state"] == "ok") {
        let i = f["index"].as_u64().unwrap() as usize;
        let all = kept.get(&i).copied().unwrap_or(0) + removed.get(&i).copied().unwrap_or(0);
        assert_eq!(all, f["keypoints"].as_u64().unwrap(), "frame {i}");
        // The first frame shows its keyframe's detection, which it waited for; no
        // pose was estimated on it, so the report counts none removed.
        if i != tracked[0] {
            let removed = removed.get(&i).copied().unwrap_or(0);
            assert_eq!(
                removed,
                f["dynamic_keypoints"].as_u64().unwrap(),
                "frame {i}"
            );
        }
    }
    assert_eq!(read["images"].as_u64().unwrap() as usize, frames.len());
    let events = strings(&read["events"]);
    assert!(
        events.iter().any(|e| e.contains("loop closed")),
        "{events:?}"
    );
    let keyframes = frames.iter().filter(|f| f["keyframe"] == true).count();
    assert_eq!(
        events
            .iter()
            .filter(|e| e.contains("keyframe inserted"))
            .count(),
        keyframes
    );
    // (No detections here: the room has no movers; the view test has boxes.)
    let temporal = [
        "world/camera",
        "world/camera/image",
        "world/map/static",
        "world/keyframes",
    ];
    assert_has(&read["entities"], &temporal);
    assert_has(
        &read["entities"],
        // The path in pieces of 300 centres: 340 frames make two.
        &[
            "world/trajectory/tracking/0",
            "world/trajectory/tracking/1",
            "events",
            "events/loops",
        ],
    );
    let fixed = [
        "world/trajectory/final",
        "world/trajectory/truth",
        "world/loops",
        "world/camera/image",
    ];
    assert_has(&read["static_entities"], &fixed);
    let truth_poses = read["static_sizes"]["world/trajectory/truth"]
        .as_u64()
        .unwrap();
    assert!(truth_poses >= 300, "{truth_poses}");
}

/// `dopslam view` on a finished run (DOP with the dense pass) gives a recording with the
/// run's entities (all but the kept keypoints, which a run folder does not hold), and
/// the dense mesh and cloud; `[output] rerun` writes run.rrd into the run folder.
#[test]
fn view_rebuilds_the_recording_of_a_finished_run() {
    let Some(python) = reader_python("view_rebuilds_the_recording_of_a_finished_run") else {
        return;
    };
    let (seq, dir) = sequence("rerun-view", "walking_xyz", |synth| {
        // Regular 30 Hz timing instead of the recorded one (which lives in ../shared).
        synth.sequence.timing = None;
        synth.sequence.frames = 40;
    });
    let config = dir.join("rerun.toml");
    std::fs::write(
        &config,
        "[output]\nrerun = true\nrerun_image_scale = 0.25\n",
    )
    .unwrap();
    let out = dir.join("run");
    let (ok, _, err) = common::dopslam(&[
        "run",
        &seq.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--config",
        &config.to_string_lossy(),
        "--detections",
        "oracle",
        "--deterministic",
    ]);
    assert!(ok, "{err}");
    let live = read(&python, &out.join("run.rrd"));
    let viewed_path = dir.join("viewed.rrd");
    let (ok, stdout, err) = common::dopslam(&[
        "view",
        &out.to_string_lossy(),
        "-o",
        &viewed_path.to_string_lossy(),
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("40 frames"), "{stdout}");
    let viewed = read(&python, &viewed_path);
    assert!(strings(&live["entities"])
        .iter()
        .any(|e| e == "world/camera/image/detections"));
    let mut expected = strings(&live["entities"]);
    expected.retain(|e| !e.starts_with("world/map/") && e != "world/camera/image/keypoints");
    let mut got = strings(&viewed["entities"]);
    got.retain(|e| e != "world/camera/image/keypoints");
    assert_eq!(got, expected);
    assert_eq!(viewed["pose_frames"], live["pose_frames"]);
    assert_eq!(per_frame(&viewed, "removed"), per_frame(&live, "removed"));
    assert_eq!(viewed["images"], live["images"]);
    let fixed = [
        "world/dense/mesh",
        "world/dense/cloud",
        "world/trajectory/final",
        "world/trajectory/truth",
    ];
    assert_has(&live["static_entities"], &fixed);
    assert_has(&viewed["static_entities"], &fixed);
    // A recording is never written over.
    let (ok, _, err) = common::dopslam(&[
        "view",
        &out.to_string_lossy(),
        "-o",
        &viewed_path.to_string_lossy(),
    ]);
    assert!(!ok && err.contains("exists"), "{err}");
}

/// An `.rrd` that cannot be written fails before any work, naming it; a viewer that
/// does not answer is a warning and the run goes on.
#[test]
fn unwritable_recordings_fail_first_and_a_missing_viewer_warns() {
    let seq = common::temp_dir("rerun-bad").child("seq");
    let dir = seq.parent().unwrap().to_path_buf();
    common::synth_static_room(&seq, 12);
    let blocker = dir.join("file");
    std::fs::write(&blocker, "x").unwrap();
    let rrd = blocker.join("run.rrd");
    let out = dir.join("run");
    // A short run without detector, dense or global pass, logged as `rerun_args` say.
    let run = |rerun_args: &[&str]| {
        let (seq, out) = (seq.to_string_lossy(), out.to_string_lossy());
        let mut args = vec!["run", &seq, "--out", &out, "--detections", "none"];
        args.extend(["--no-dense", "--no-global"]);
        args.extend(rerun_args);
        common::dopslam(&args)
    };
    let (ok, _, err) = run(&["--rerun", &rrd.to_string_lossy()]);
    assert!(!ok, "{err}");
    assert!(
        err.contains("run.rrd") && err.contains("cannot be made"),
        "{err}"
    );
    assert!(!out.join("report.json").exists(), "the run started: {err}");
    // Nor into the input sequence.
    let (ok, _, err) = run(&["--rerun", &seq.join("run.rrd").to_string_lossy()]);
    assert!(!ok && err.contains("never writes into its inputs"), "{err}");
    assert!(!seq.join("run.rrd").exists());
    // A port nothing listens on (bound, then released).
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let (ok, _, err) = run(&["--rerun-connect", &format!("127.0.0.1:{port}")]);
    assert!(ok, "{err}");
    assert!(
        err.contains("warning: --rerun-connect") && err.contains("goes on"),
        "{err}"
    );
    assert!(out.join("report.json").exists());
    // A viewer that accepts and never reads: the run and `view --connect` end after a
    // bounded wait, saying what was not delivered.
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let address = format!("127.0.0.1:{}", listener.local_addr().unwrap().port());
    std::thread::spawn(move || {
        let held: Vec<_> = listener.incoming().collect();
        drop(held);
    });
    let (seq_arg, out_arg) = (seq.to_string_lossy(), out.to_string_lossy());
    let limit = std::time::Duration::from_secs(120);
    let mut args = vec!["run", &seq_arg, "--out", &out_arg, "--detections", "none"];
    args.extend(["--no-dense", "--no-global", "--rerun-connect", &address]);
    let (ok, _, err) = common::dopslam_within(&args, limit);
    assert!(ok && err.contains("stopped taking the recording"), "{err}");
    assert!(err.contains("the run's files are complete"), "{err}");
    assert!(out.join("report.json").exists());
    let view = ["view", &out_arg, "--connect", &address];
    let (ok, _, err) = common::dopslam_within(&view, limit);
    assert!(ok && err.contains("stopped taking the recording"), "{err}");
    // `view` of a run folder whose trajectory is damaged leaves no partial recording.
    for name in ["trajectory.txt", "trajectory_tracking.txt"] {
        if out.join(name).exists() {
            std::fs::write(out.join(name), "1.0 not a pose\n").unwrap();
        }
    }
    let partial = dir.join("partial.rrd");
    let (ok, _, err) = common::dopslam(&["view", &out_arg, "-o", &partial.to_string_lossy()]);
    assert!(
        !ok && err.contains("partial recording") && err.contains("removed"),
        "{err}"
    );
    assert!(!partial.exists());
    // `view` of what is not a finished run folder names it.
    let missing = dir.join("missing");
    for (folder, says) in [
        (missing, "no such run folder"),
        (seq.to_path_buf(), "not a finished run folder"),
    ] {
        let (ok, _, err) = common::dopslam(&[
            "view",
            &folder.to_string_lossy(),
            "-o",
            &dir.join("v.rrd").to_string_lossy(),
        ]);
        assert!(!ok && err.contains(says), "{err}");
    }
    assert!(!dir.join("v.rrd").exists());
}

/// `--rerun-connect` to a listening Rerun server (the rerun-sdk's own, saving what it
/// receives): every tracked frame's pose and image arrive.
#[test]
fn streaming_to_a_listening_server_delivers_every_pose() {
    let Some(python) = reader_python("streaming_to_a_listening_server_delivers_every_pose") else {
        return;
    };
    let seq = common::temp_dir("rerun-connect").child("seq");
    let dir = seq.parent().unwrap().to_path_buf();
    common::synth_static_room(&seq, 20);
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let received = dir.join("received.rrd");
    let _server = Server(
        std::process::Command::new(python.with_file_name("rerun"))
            .process_group(0)
            .args([
                "--port",
                &port.to_string(),
                "--save",
                &received.to_string_lossy(),
            ])
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap(),
    );
    let listening = (0..100).any(|_| {
        std::thread::sleep(std::time::Duration::from_millis(100));
        std::net::TcpStream::connect(("127.0.0.1", port)).is_ok()
    });
    assert!(listening, "the Rerun server did not listen on {port}");
    let out = dir.join("run");
    let (ok, _, err) = common::dopslam(&[
        "run",
        &seq.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--detections",
        "none",
        "--no-dense",
        "--no-global",
        "--rerun-connect",
        &format!("127.0.0.1:{port}"),
    ]);
    assert!(ok, "{err}");
    assert!(!err.contains("warning: --rerun-connect"), "{err}");
    let tracked = report(&out)["frames"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|f| f["state"] == "ok")
        .count();
    // The server writes what it receives as it comes: wait for the last of it.
    let mut poses = 0;
    for _ in 0..50 {
        std::thread::sleep(std::time::Duration::from_millis(200));
        // (A file caught mid-write may not read yet.)
        if let Ok(got) = common::read_rerun(&python, &received) {
            poses = got["pose_frames"].as_array().unwrap().len();
            if poses == tracked {
                break;
            }
        }
    }
    assert_eq!(poses, tracked);
}

/// A Rerun server of a test, stopped with its children however the test ends: the
/// venv's `rerun` script runs the viewer binary as its child, so the whole process
/// group goes.
struct Server(std::process::Child);

impl Drop for Server {
    fn drop(&mut self) {
        // SAFETY: kill(2) on the group this test started (process_group(0) above).
        unsafe {
            libc::kill(-(self.0.id() as i32), libc::SIGKILL);
        }
        let _ = self.0.wait();
    }
}
