//! Sessions (`dopslam run --map`): a second recording of a room is placed in the map
//! of the first and tracked in its world frame, frozen or continued, and the first
//! run's folder is never written; a recording of another place stops with an error.

use crate::common;

use std::path::{Path, PathBuf};

use dopslam::config::Config;
use dopslam::eval::report::{evaluate, AlignMode, EvalOptions};
use dopslam::io::trajectory::TrajectoryFormat;
use dopslam::io::Trajectory;
use dopslam::run::{base_map, open_sequence, run_sequence, RunError, RunOptions, StopReason};
use dopslam::synth::{generate, SynthConfig};

/// The first recording (revisit_a at 10 fps for 34 s: a full turn and 4 s more, so
/// that its loop closes) rendered and run, and the second (revisit_b in its room, 5 s
/// at 30 fps from a quarter turn on: a place the first mapped, though not where it
/// started): (first sequence, first run, second sequence). Shared by the tests,
/// which only read them.
fn recordings() -> &'static (PathBuf, PathBuf, PathBuf) {
    static MADE: std::sync::OnceLock<(common::TestDir, PathBuf, PathBuf, PathBuf)> =
        std::sync::OnceLock::new();
    let made = MADE.get_or_init(|| {
        let presets = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth");
        let dir = common::temp_dir("sessions");
        let mut first = SynthConfig::load(&presets.join("revisit_a.toml")).unwrap();
        (first.sequence.frames, first.sequence.fps) = (340, 10.0);
        let first_config = dir.join("first.toml");
        std::fs::write(&first_config, toml::to_string(&first).unwrap()).unwrap();
        let mut second = SynthConfig::load(&presets.join("revisit_b.toml")).unwrap();
        (second.sequence.frames, second.motion.start) = (150, 7.5);
        second.scene.room_of = Some(first_config);
        let (a, b) = (dir.join("a"), dir.join("b"));
        generate(&first, &a, false).unwrap();
        generate(&second, &b, false).unwrap();
        let run_a = dir.join("run_a");
        run(&a, &run_a, None).unwrap();
        (dir, a, run_a, b)
    });
    static PATHS: std::sync::OnceLock<(PathBuf, PathBuf, PathBuf)> = std::sync::OnceLock::new();
    PATHS.get_or_init(|| (made.1.clone(), made.2.clone(), made.3.clone()))
}

fn config() -> Config {
    let mut config = Config::default();
    config.detector.source = dopslam::detect::Source::Oracle;
    config.dense.enabled = false;
    config
}

fn run(
    seq: &Path,
    out: &Path,
    map: Option<dopslam::run::BaseMap>,
) -> Result<dopslam::run::RunReport, RunError> {
    let config = config();
    let sequence = open_sequence(seq, &config).unwrap();
    let options = RunOptions {
        deterministic: true,
        sequence_dir: Some(seq.to_path_buf()),
        base_map: map,
        ..RunOptions::default()
    };
    run_sequence(sequence.as_ref(), &config, out, &options)
}

/// Every file under `dir` (and its folders) with its bytes' hash.
fn contents(dir: &Path) -> Vec<(PathBuf, String)> {
    let mut found = Vec::new();
    for path in common::sorted_files(dir) {
        if path.is_dir() {
            found.extend(contents(&path));
        } else {
            let bytes = std::fs::read(&path).unwrap();
            found.push((path, dopslam::io::content_hash(&bytes)));
        }
    }
    found
}

/// The APE of `trajectory` against the second recording's ground truth in the first
/// recording's world frame (its first camera: `inv(GT_a(0)) GT_b`), without
/// alignment.
fn ate_in_first_frame(first: &Path, second: &Path, trajectory: &Path) -> f64 {
    let read = |p: &Path| Trajectory::read(p, TrajectoryFormat::Tum).unwrap();
    let origin = read(&first.join("groundtruth.txt")).poses[0].inverse();
    let mut truth = read(&second.join("groundtruth.txt"));
    truth.poses.iter_mut().for_each(|p| *p = origin * *p);
    let options = EvalOptions {
        align: AlignMode::None,
        ..EvalOptions::default()
    };
    evaluate(&truth, &read(trajectory), &options)
        .unwrap()
        .ape
        .statistics
        .rmse
}

#[test]
fn a_second_recording_is_tracked_in_the_first_ones_map_and_frame() {
    let (a, run_a, b) = recordings();
    let before = contents(run_a);
    let first_keyframes = std::fs::read_to_string(run_a.join("keyframes.txt"))
        .unwrap()
        .lines()
        .filter(|l| !l.starts_with('#'))
        .count();
    let own_ate = ate_in_first_frame(a, a, &run_a.join("trajectory.txt"));
    let dir = common::temp_dir("sessions-continued");
    for frozen in [false, true] {
        let out = dir.join(if frozen { "frozen" } else { "continued" });
        let report = run(b, &out, Some(base_map(run_a, frozen).unwrap())).unwrap();
        let maps = report.slam_map.expect("the map loaded");
        let loaded = maps.loaded.expect("loaded");
        assert!(
            loaded.placed_at_frame.is_some_and(|f| f <= 30),
            "{loaded:?}"
        );
        assert_eq!(
            report.totals.tracked,
            150 - loaded.placed_at_frame.unwrap() - report.totals.lost
        );
        // The second recording's error in the first one's frame is the first map's
        // own (its trajectory's, unaligned) and little more.
        let ate = ate_in_first_frame(a, b, &out.join("trajectory.txt"));
        assert!(
            ate < 0.015 && ate < own_ate + 0.005,
            "frozen {frozen}: {ate} m in the first recording's frame (its own: {own_ate} m)"
        );
        if frozen {
            assert!(maps.saved.is_none() && !out.join("slam_map.bin").exists());
            assert_eq!(report.totals.keyframes, loaded.keyframes);
        } else {
            let saved = maps.saved.expect("a continued map is saved");
            assert_eq!(saved.recordings, vec!["a", "b"]);
            assert!(saved.keyframes > loaded.keyframes, "{saved:?}");
            // keyframes.txt lists this recording's keyframes only.
            let own = std::fs::read_to_string(out.join("keyframes.txt")).unwrap();
            let own = own.lines().filter(|l| !l.starts_with('#')).count();
            assert!(
                own > 0 && own < saved.keyframes,
                "{own} of {}",
                saved.keyframes
            );
        }
    }
    assert_eq!(
        contents(run_a),
        before,
        "the loaded map's folder is never written"
    );
    assert!(first_keyframes > 0);
}

#[test]
fn a_recording_of_another_place_is_never_placed_and_stops() {
    let (_, run_a, _) = recordings();
    let dir = common::temp_dir("sessions-elsewhere");
    // Another room that also looks otherwise: every blocks-look room of the
    // synthesiser papers its walls alike (a texture of the wall's own coordinates),
    // which relocalisation rightly takes for the same place.
    let preset = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/static_room.toml");
    let mut room = SynthConfig::load(&preset).unwrap();
    room.sequence.frames = 40;
    room.scene.look = dopslam::synth::config::SceneLook::Room;
    let other = dir.join("other");
    generate(&room, &other, false).unwrap();
    let mut config = config();
    config.tracking.place_within_frames = 25;
    let sequence = open_sequence(&other, &config).unwrap();
    let options = RunOptions {
        deterministic: true,
        sequence_dir: Some(other.clone()),
        base_map: Some(base_map(run_a, false).unwrap()),
        ..RunOptions::default()
    };
    let out = dir.join("run");
    let error = run_sequence(sequence.as_ref(), &config, &out, &options).unwrap_err();
    match &error {
        RunError::Stopped {
            reason: StopReason::NotPlaced(why),
            done,
            ..
        } => {
            assert_eq!(*done, 25);
            assert!(why.contains("place_within_frames"), "{why}");
        }
        other => panic!("expected NotPlaced, got {other}"),
    }
    assert!(
        !out.join("slam_map.bin").exists(),
        "nothing of its own to save"
    );
    // A map made with another camera is refused before any work.
    let (ok, _, err) = common::dopslam(&[
        "run",
        &other.to_string_lossy(),
        "--out",
        &dir.join("camera").to_string_lossy(),
        "--detections",
        "none",
        "--map",
        &run_a.to_string_lossy(),
        "--camera",
        "500,500,320,240",
    ]);
    assert!(!ok && err.contains("another camera"), "{err}");
    assert!(!dir.join("camera").exists(), "nothing is written");
    // Nor is anything written inside the loaded map's run folder.
    let inside = run_a.join("inside");
    let (ok, _, err) = common::dopslam(&[
        "run",
        &other.to_string_lossy(),
        "--out",
        &inside.to_string_lossy(),
        "--detections",
        "none",
        "--map",
        &run_a.to_string_lossy(),
    ]);
    assert!(!ok && err.contains("inside the input"), "{err}");
    assert!(!inside.exists());
}

/// `dopslam compare-maps MAP --json --align` against the static scene and the movers
/// of `seq` (the map moved into its frame by its run, or by the first run its
/// `merge.json` names): (map vertices, vertices on the movers).
fn movers_in(map: &Path, seq: &Path, out: &Path) -> (f64, f64) {
    let (ok, json, err) = common::dopslam(&[
        "compare-maps",
        &map.to_string_lossy(),
        "--reference",
        &seq.join("static_scene.ply").to_string_lossy(),
        "--movers",
        &seq.join("movers.ply").to_string_lossy(),
        "--align",
        "--json",
        "--out",
        &out.to_string_lossy(),
    ]);
    assert!(ok, "{err}");
    let json: serde_json::Value = serde_json::from_str(&json).unwrap();
    let map = &json["maps"][0];
    (
        map["points"].as_f64().unwrap(),
        map["mover_points"].as_f64().unwrap(),
    )
}

#[test]
fn a_merged_map_carves_a_person_who_sat_through_one_recording_and_left() {
    let presets = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth");
    let dir = common::temp_dir("sessions-merge");
    // Recording A: two people sit still through it (the `sitting` preset); B: the
    // same room with nobody, starting elsewhere on the camera's path.
    let mut first = SynthConfig::load(&presets.join("sitting.toml")).unwrap();
    first.sequence.frames = 120;
    let first_config = dir.join("first.toml");
    std::fs::write(&first_config, toml::to_string(&first).unwrap()).unwrap();
    let mut second = first.clone();
    second.name = "empty".into();
    second.motion.start = 12.0;
    second.seated.count = 0;
    second.scene.room_of = Some(first_config);
    let (a, b) = (dir.join("a"), dir.join("b"));
    generate(&first, &a, false).unwrap();
    generate(&second, &b, false).unwrap();
    let path = |p: &Path| p.to_string_lossy().into_owned();
    let (run_a, run_b, merged) = (dir.join("run_a"), dir.join("run_b"), dir.join("merged"));
    // No detector: nothing tells A that its sitters are people, as a detector that
    // misses a still sitter (or takes him for furniture) would not.
    let run = |args: &[&str]| {
        let mut all = vec!["run", "--deterministic", "--detections", "none"];
        all.extend(args);
        let (ok, _, err) = common::dopslam(&all);
        assert!(ok, "{err}");
    };
    run(&[&path(&a), "--out", &path(&run_a)]);
    run(&[
        &path(&b),
        "--out",
        &path(&run_b),
        "--map",
        &path(&run_a),
        "--no-dense",
    ]);
    let (ok, _, err) = common::dopslam(&[
        "merge",
        &path(&run_a),
        &path(&run_b),
        "--out",
        &path(&merged),
    ]);
    assert!(ok, "{err}");
    let (own, own_on_people) = movers_in(&run_a.join("dense_mesh.ply"), &a, &dir.join("c1"));
    // A's own map keeps the people: nothing in A says they are not furniture.
    assert!(own_on_people > 0.01 * own, "{own_on_people} of {own}");
    let (all, on_people) = movers_in(&merged.join("dense_mesh.ply"), &a, &dir.join("c2"));
    assert!(
        on_people <= 0.001 * all,
        "merged: {on_people} of {all} vertices on the people"
    );
    assert!(
        all > 0.8 * own,
        "the static scene stays: {all} against {own}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(merged.join("merge.json")).unwrap()).unwrap();
    assert_eq!(report["recordings"].as_array().unwrap().len(), 2);
    view_merged(&merged, &dir.join("merged.rrd"));
    // A run of its own frame is refused, and so is an output folder that is a run.
    let alone = dir.join("alone");
    run(&[&path(&b), "--out", &path(&alone), "--no-dense"]);
    let (ok, _, err) = common::dopslam(&[
        "merge",
        &path(&run_a),
        &path(&alone),
        "--out",
        &path(&dir.join("m2")),
    ]);
    assert!(!ok && err.contains("not tracked in the same map"), "{err}");
    let (ok, _, err) = common::dopslam(&[
        "merge",
        &path(&run_a),
        &path(&run_b),
        "--out",
        &path(&run_b),
    ]);
    assert!(!ok && err.contains("inside"), "{err}");
}

/// `dopslam view` of a merged folder: each recording under its own entity path, the
/// merged map under `world/merged`, read back by rerun-sdk (tools/read_rerun.py).
fn view_merged(merged: &Path, rrd: &Path) {
    let (ok, stdout, err) = common::dopslam(&[
        "view",
        &merged.to_string_lossy(),
        "-o",
        &rrd.to_string_lossy(),
    ]);
    assert!(ok, "{err}");
    assert!(stdout.contains("2 recordings"), "{stdout}");
    let test = "a_merged_map_carves_a_person_who_sat_through_one_recording_and_left";
    let Some(python) = common::test_python(test, "rerun, datafusion") else {
        return;
    };
    let read = common::read_rerun(&python, rrd).unwrap();
    let entities: Vec<&str> = read["static_entities"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|v| v.as_str())
        .collect();
    for entity in [
        "world/merged/dense/mesh",
        "world/merged/dense/cloud",
        "world/recordings/1_a/trajectory/final",
        "world/recordings/1_a/dense/mesh",
        "world/recordings/2_b/trajectory/final",
    ] {
        assert!(
            entities.contains(&entity),
            "{entity} missing from {entities:?}"
        );
    }
}
