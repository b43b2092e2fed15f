//! The command line on bad input: a clear message naming the file (and line), a
//! non-zero exit. And the demo end to end.

use crate::common;

use std::path::Path;
use std::process::Command;

use common::dopslam;

fn write(path: &Path, text: &str) -> String {
    std::fs::write(path, text).unwrap();
    path.to_string_lossy().into_owned()
}

fn good_tum(dir: &Path, name: &str, start: f64) -> String {
    let mut text = String::new();
    for i in 0..20 {
        let t = start + i as f64 * 0.1;
        text += &format!(
            "{t:.4} {} {} 0.5 0 0 0 1\n",
            0.1 * i as f64,
            (0.3 * i as f64).sin()
        );
    }
    write(&dir.join(name), &text)
}

#[test]
fn eval_reports_bad_input_clearly() {
    let dir = common::temp_dir("cli-bad");
    let gt = good_tum(&dir, "gt.txt", 100.0);

    let malformed = write(
        &dir.join("malformed.txt"),
        "100.0 0 0 0 0 0 0 1\n100.1 0 0 0 0 0 1\n",
    );
    let (ok, _, err) = dopslam(&["eval", &gt, &malformed]);
    assert!(
        !ok && err.contains("malformed.txt:2") && err.contains("expected 8 numbers"),
        "{err}"
    );

    let unsorted = write(
        &dir.join("unsorted.txt"),
        "100.2 0 0 0 0 0 0 1\n100.1 0 0 0 0 0 0 1\n",
    );
    let (ok, _, err) = dopslam(&["eval", &gt, &unsorted]);
    assert!(
        !ok && err.contains("unsorted.txt:2") && err.contains("not sorted"),
        "{err}"
    );

    let elsewhere = good_tum(&dir, "elsewhere.txt", 500.0);
    let (ok, _, err) = dopslam(&["eval", &gt, &elsewhere]);
    assert!(!ok && err.contains("no matching timestamps"), "{err}");

    let partial = good_tum(&dir, "partial.txt", 101.5);
    let (ok, _, err) = dopslam(&["eval", &gt, &partial, "--min-coverage", "0.9"]);
    assert!(!ok && err.contains("only 5 of 20 poses"), "{err}");

    let kitti_gt = write(
        &dir.join("kitti_gt.txt"),
        "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1 0\n",
    );
    let kitti_bad = write(
        &dir.join("kitti_bad.txt"),
        "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 1 0 1 0 0 0 0 1\n",
    );
    let (ok, _, err) = dopslam(&["eval", "--format", "kitti", &kitti_gt, &kitti_bad]);
    assert!(
        !ok && err.contains("kitti_bad.txt:2") && err.contains("expected 12 numbers"),
        "{err}"
    );

    let config = write(
        &dir.join("bad.toml"),
        "[eval]\nalign = \"se3\"\nmin_coverag = 0.3\n",
    );
    let (ok, _, err) = dopslam(&["eval", &gt, &gt, "--config", &config]);
    assert!(
        !ok && err.contains("bad.toml") && err.contains("min_coverag"),
        "{err}"
    );

    let missing = dir.join("no_such_sequence");
    let (ok, _, err) = dopslam(&["info", &missing.to_string_lossy()]);
    assert!(
        !ok && err.contains("no_such_sequence") && err.contains("not found"),
        "{err}"
    );

    let (ok, _, err) = dopslam(&["eval", &gt, &dir.join("absent.txt").to_string_lossy()]);
    assert!(!ok && err.contains("absent.txt"), "{err}");
}

#[test]
fn eval_prints_table_json_and_plots() {
    let dir = common::temp_dir("cli-good");
    let gt = good_tum(&dir, "gt.txt", 100.0);
    let est = good_tum(&dir, "est.txt", 100.003);
    let (ok, out, err) = dopslam(&["eval", &gt, &est, "--rpe", "1f", "--rpe", "0.5s"]);
    assert!(ok, "{err}");
    assert!(
        out.contains("matched 20 of 20 poses")
            && out.contains("SE(3) Umeyama")
            && out.contains("rmse"),
        "{out}"
    );
    let plots = dir.join("plots");
    let (ok, out, err) = dopslam(&[
        "eval",
        &gt,
        &est,
        "--json",
        "--plot",
        &plots.to_string_lossy(),
    ]);
    assert!(ok, "{err}");
    let json: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(json["ape"]["statistics"]["rmse"].as_f64().unwrap() < 1e-9);
    assert!(plots.join("trajectory.svg").exists() && plots.join("ape.svg").exists());
}

#[test]
fn demo_runs_end_to_end() {
    let dir = common::temp_dir("cli-demo");
    let (ok, out, err) = dopslam(&["demo", "--out", &dir.to_string_lossy()]);
    assert!(ok, "{err}");
    assert!(
        out.contains("APE")
            && dir.join("report.json").exists()
            && dir.join("plots/trajectory.svg").exists(),
        "{out}"
    );
}

#[test]
fn info_reads_a_tum_layout() {
    let Some(data) = common::shared_data("info_reads_a_tum_layout") else {
        return;
    };
    let (ok, out, err) = dopslam(&["info", &data.join("tum-timing/fr1_xyz").to_string_lossy()]);
    assert!(ok, "{err}");
    assert!(out.contains("798 / 798, paired: 792"), "{out}");
    assert!(out.contains("ground truth: 3000 poses"), "{out}");
}

#[test]
fn bundled_default_config_is_valid() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/default.toml");
    let config = dopslam::config::Config::load(&path).unwrap();
    assert_eq!(config, dopslam::config::Config::default());
}

#[test]
fn dense_commands_report_bad_input_clearly() {
    let dir = common::temp_dir("cli-dense");
    // compare-maps: a file that is not a PLY, a missing file, nothing to compare with.
    let fake = write(&dir.join("map.ply"), "solid cube\nendsolid\n");
    let (ok, _, err) = dopslam(&["compare-maps", &fake, "--reference", &fake]);
    assert!(
        !ok && err.contains("map.ply") && err.contains("not a readable PLY"),
        "{err}"
    );
    let missing = dir.join("absent.ply").to_string_lossy().into_owned();
    let (ok, _, err) = dopslam(&["compare-maps", &missing, &missing]);
    assert!(!ok && err.contains("absent.ply"), "{err}");
    let (ok, _, err) = dopslam(&["compare-maps", &fake]);
    assert!(!ok && err.contains("--reference"), "{err}");
    let (ok, _, err) = dopslam(&["compare-maps"]);
    assert!(!ok && err.contains("MAPS"), "{err}");
    let (ok, _, err) = dopslam(&["compare-maps", &fake, &fake, "--threshold=0"]);
    assert!(!ok && err.contains("--threshold"), "{err}");
    // fuse: a folder that is not a run, a run that names no sequence.
    let (ok, _, err) = dopslam(&["fuse", &dir.to_string_lossy()]);
    assert!(!ok && err.contains("not a finished run"), "{err}");
    // Any JSON is not a run report.
    write(&dir.join("report.json"), "{\"mode\": \"dop\"}");
    let (ok, _, err) = dopslam(&["fuse", &dir.to_string_lossy()]);
    assert!(
        !ok && err.contains("not a dopslam run report") && err.contains("report.json"),
        "{err}"
    );
    // A report of this layout version with parts missing: the first one is named.
    write(
        &dir.join("report.json"),
        "{\"schema\": 1, \"mode\": \"dop\", \"totals\": {\"frames\": 1, \"tracked\": 1, \"coverage_percent\": 100.0, \"keyframes\": 1, \"map_points\": 1, \"median_tracking_ms\": 1.0, \"mean_tracking_ms\": 1.0}}",
    );
    let (ok, _, err) = dopslam(&["fuse", &dir.to_string_lossy()]);
    assert!(
        !ok && err.contains("not a dopslam run report") && err.contains("missing field"),
        "{err}"
    );
    // Another layout version: named, with what to do.
    write(&dir.join("report.json"), "{\"schema\": 7}");
    let (ok, _, err) = dopslam(&["fuse", &dir.to_string_lossy()]);
    assert!(!ok && err.contains("layout version 7"), "{err}");
    // A [dense] section with an impossible voxel, named by key.
    let config = write(&dir.join("bad.toml"), "[dense]\nvoxel = 0.0\n");
    let (ok, _, err) = dopslam(&["fuse", &dir.to_string_lossy(), "--config", &config]);
    assert!(!ok && err.contains("dense.voxel"), "{err}");
    let config = write(&dir.join("typo.toml"), "[dense]\nvoxels = 0.01\n");
    let (ok, _, err) = dopslam(&["fuse", &dir.to_string_lossy(), "--config", &config]);
    assert!(!ok && err.contains("voxels"), "{err}");
}

#[test]
fn a_closed_pipe_ends_quietly() {
    let dir = common::temp_dir("cli-pipe");
    let reference = good_tum(&dir, "ref.txt", 0.0);
    let estimate = good_tum(&dir, "est.txt", 0.0);
    let mut child = Command::new(env!("CARGO_BIN_EXE_dopslam"))
        .args(["eval", &reference, &estimate, "--json", "--rpe", "1f"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // The reader goes away before reading anything, as `| head -0` would.
    drop(child.stdout.take());
    let output = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(
        !err.contains("panicked") && !err.contains("Broken pipe"),
        "{err}"
    );
}

#[test]
fn a_sequence_without_calibration_takes_settings_or_a_camera() {
    let base = common::temp_dir("cli-settings");
    // A recording whose folder name says nothing about the sensor.
    let seq = base.join("my_lab_recording");
    common::synth_static_room(&seq, 12);
    std::fs::remove_file(seq.join("calibration.yaml")).unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec![
            "run",
            seq.to_str().unwrap(),
            "--frames",
            "8",
            "--detections",
            "none",
            "--no-dense",
        ];
        let out = base.join(format!("out{}", extra.len()));
        let out = out.to_string_lossy().into_owned();
        args.extend(["--out", &out]);
        args.extend(extra);
        dopslam(&args)
    };
    let (ok, _, err) = run(&[]);
    assert!(
        !ok && err.contains("--settings") && err.contains("--camera"),
        "{err}"
    );
    let settings =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/calibration/RGB-D_TUM3.yaml");
    let (ok, out, err) = run(&["--settings", &settings.to_string_lossy()]);
    assert!(ok && out.contains("tracked 8 of 8"), "{out}{err}");
    // `fuse` takes the settings file the run names.
    let fused = base.join("out2");
    let (ok, out, err) = dopslam(&["fuse", fused.to_str().unwrap()]);
    assert!(ok && out.contains("frames fused"), "{out}{err}");
    let (ok, out, err) = run(&["--camera", "535.4,539.2,320.1,247.6", "--deterministic"]);
    assert!(ok && out.contains("tracked 8 of 8"), "{out}{err}");
    let (ok, _, err) = run(&["--camera", "535.4,539.2,320.1"]);
    assert!(!ok && err.contains("--camera"), "{err}");
}

/// SIGINT during `run`: the trajectory so far and the report (marked stopped) are
/// written, the exit status is non-zero.
#[cfg(unix)]
#[test]
fn an_interrupted_run_writes_what_it_has() {
    let base = common::temp_dir("cli-sigint");
    let seq = base.join("seq");
    common::synth_static_room(&seq, 300);
    let out = base.join("run");
    let frames = base.join("frames");
    let child = Command::new(env!("CARGO_BIN_EXE_dopslam"))
        .args([
            "run",
            &seq.to_string_lossy(),
            "--out",
            &out.to_string_lossy(),
        ])
        .args(["--detections", "none", "--deterministic"])
        .args(["--debug-frames", &frames.to_string_lossy()])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Wait until a few frames are tracked (the debug pictures show progress).
    let started = std::time::Instant::now();
    while std::fs::read_dir(&frames).map_or(0, |d| d.count()) < 10 {
        assert!(started.elapsed().as_secs() < 120, "the run never got going");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    // SAFETY: kill only sends a signal to the child we spawned.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGINT);
    }
    let output = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success(), "{err}");
    assert!(err.contains("interrupted"), "{err}");
    let trajectory = std::fs::read_to_string(out.join("trajectory.txt")).unwrap();
    let tracked = trajectory.lines().filter(|l| !l.starts_with('#')).count();
    assert!((5..300).contains(&tracked), "{tracked} poses");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert!(
        report["stopped"].as_str().unwrap().contains("interrupted"),
        "{report}"
    );
    assert!(
        !out.join("dense_mesh.ply").exists(),
        "no dense pass after an interruption"
    );
}

/// From another working folder: with `DOPSLAM_DATA` naming a folder without the
/// runtime data, a run that needs the detector (or the vocabulary) fails before any
/// work, names the missing file and the fix, and writes nothing; `--detections none
/// --no-loops` runs; `dopslam doctor` says what is missing. With the data directory
/// that setup installed (when present), the same run uses the detector and the
/// vocabulary and the report names the files.
#[test]
fn runs_from_any_folder_and_never_downgrades_silently() {
    let base = common::temp_dir("cli-anywhere");
    let seq = base.join("seq");
    common::synth_static_room(&seq, 12);
    let empty = base.join("no-data");
    std::fs::create_dir_all(&empty).unwrap();
    let run = |data: &Path, out: &Path, extra: &[&str]| {
        let output = Command::new(env!("CARGO_BIN_EXE_dopslam"))
            .current_dir(&base)
            .env("DOPSLAM_DATA", data)
            .args([
                "run",
                "seq",
                "--frames",
                "10",
                "--no-dense",
                "--deterministic",
                "--out",
            ])
            .arg(out)
            .args(extra)
            .output()
            .unwrap();
        (
            output.status.success(),
            String::from_utf8_lossy(&output.stderr).into_owned(),
        )
    };
    let out = base.join("out-missing");
    let (ok, err) = run(&empty, &out, &[]);
    assert!(!ok, "{err}");
    assert!(
        err.contains("yolov4-tiny-320x256.onnx")
            && err.contains("tools/setup.sh")
            && err.contains("--detections none"),
        "{err}"
    );
    assert!(!out.exists(), "nothing is written before the check");
    let (ok, err) = run(&empty, &out, &["--detections", "none"]);
    assert!(
        !ok && err.contains("vocabulary.dbow") && err.contains("--no-loops"),
        "{err}"
    );
    assert!(!out.exists(), "nothing is written before the check");
    let (ok, err) = run(&empty, &out, &["--detections", "none", "--no-loops"]);
    assert!(ok, "{err}");
    assert!(out.join("trajectory.txt").exists());
    let doctor = Command::new(env!("CARGO_BIN_EXE_dopslam"))
        .current_dir(&base)
        .env("DOPSLAM_DATA", &empty)
        .arg("doctor")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&doctor.stdout);
    assert!(!doctor.status.success());
    assert!(
        text.contains("MISSING") && text.contains("DOPSLAM_DATA"),
        "{text}"
    );
    // DOPSLAM_DATA naming a file; an install record that is a folder, or unreadable.
    let xdg = base.join("xdg");
    let record = xdg.join("dopslam/data-dir");
    std::fs::create_dir_all(&record).unwrap();
    let doctor_says = |data: &Path| {
        let output = Command::new(env!("CARGO_BIN_EXE_dopslam"))
            .current_dir(&base)
            .env("DOPSLAM_DATA", data)
            .env("XDG_DATA_HOME", &xdg)
            .arg("doctor")
            .output()
            .unwrap();
        String::from_utf8_lossy(&output.stdout).into_owned()
    };
    let file = base.join("a-file");
    std::fs::write(&file, "x").unwrap();
    let text = doctor_says(&file);
    assert!(text.contains("it names a file, not a folder"), "{text}");
    assert!(text.contains("skipped: a folder, not the file"), "{text}");
    std::fs::remove_dir(&record).unwrap();
    std::fs::write(&record, [0xff, 0xfe, 0x00]).unwrap();
    let text = doctor_says(&empty);
    assert!(text.contains("skipped: it cannot be read"), "{text}");
    // The checkout's data directory, when setup installed the detector into it.
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    if !data.join("ort/libonnxruntime.so").exists()
        || !data.join("models/yolov4-tiny-320x256.onnx").exists()
    {
        eprintln!(
            "skipping the detector half: bash tools/setup.sh has not installed it into {}",
            data.display()
        );
        return;
    }
    let out = base.join("out-installed");
    let (ok, err) = run(&data, &out, &[]);
    assert!(ok, "{err}");
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let setup = &report["setup"];
    assert_eq!(setup["detections"], "onnx", "{setup}");
    assert!(
        setup["detector_files"][0]
            .as_str()
            .unwrap()
            .ends_with("models/yolov4-tiny-320x256.onnx"),
        "{setup}"
    );
    assert!(
        setup["vocabulary"]
            .as_str()
            .unwrap()
            .ends_with("vocabulary.dbow"),
        "{setup}"
    );
    assert!(
        setup["data_dir"].as_str().unwrap().contains("DOPSLAM_DATA"),
        "{setup}"
    );
}

/// `dopslam doctor` loads each file as a run would: a truncated model, a truncated
/// vocabulary and a library that is no library are each BROKEN, with the reason, and
/// the doctor fails; with the installed data everything loads. Skips, saying why,
/// where setup has not installed the data.
#[test]
fn the_doctor_finds_corrupt_files() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("data");
    let model = data.join("models/yolov4-tiny-320x256.onnx");
    if !data.join("ort/libonnxruntime.so").exists()
        || !model.exists()
        || !data.join("vocabulary.dbow").exists()
    {
        eprintln!("skipping the_doctor_finds_corrupt_files: bash tools/setup.sh has not installed the data into {}", data.display());
        return;
    }
    let doctor = |dir: &Path| {
        let output = Command::new(env!("CARGO_BIN_EXE_dopslam"))
            .env("DOPSLAM_DATA", dir)
            .arg("doctor")
            .output()
            .unwrap();
        (
            output.status.success(),
            String::from_utf8_lossy(&output.stdout).into_owned(),
            String::from_utf8_lossy(&output.stderr).into_owned(),
        )
    };
    let (ok, stdout, stderr) = doctor(&data);
    assert!(
        ok && stdout.contains("in place and loads"),
        "{stdout}{stderr}"
    );
    let base = common::temp_dir("cli-doctor");
    std::fs::create_dir_all(base.join("models")).unwrap();
    std::fs::create_dir_all(base.join("ort")).unwrap();
    let head = |from: &Path, to: &Path, bytes: usize| {
        let all = std::fs::read(from).unwrap();
        std::fs::write(to, &all[..bytes.min(all.len())]).unwrap();
    };
    head(
        &model,
        &base.join("models/yolov4-tiny-320x256.onnx"),
        100_000,
    );
    head(
        &data.join("vocabulary.dbow"),
        &base.join("vocabulary.dbow"),
        1000,
    );
    std::fs::write(base.join("ort/libonnxruntime.so"), b"not a shared library").unwrap();
    let (ok, stdout, stderr) = doctor(&base);
    assert!(!ok, "{stdout}");
    assert_eq!(stdout.matches("BROKEN").count(), 3, "{stdout}");
    assert!(
        stdout.contains("truncated") && stderr.contains("cannot be loaded"),
        "{stdout}{stderr}"
    );
    // The install record that was skipped says why.
    let home = base.join("home");
    std::fs::create_dir_all(home.join("dopslam")).unwrap();
    std::fs::write(home.join("dopslam/data-dir"), "/nowhere/data\n").unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_dopslam"))
        .env_remove("DOPSLAM_DATA")
        .env("XDG_DATA_HOME", &home)
        .arg("doctor")
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(
        text.contains("/nowhere/data (skipped: no such directory"),
        "{text}"
    );
}
