//! `dopslam batch` end to end on small synthetic sequences: the tables, the figures,
//! the ATE equal to `dopslam eval` on the same files, a corrupt sequence recorded as
//! failed while the rest complete, and resuming after an interruption.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use common::{dopslam, synth_static_room, temp_dir};

/// A manifest of two generated presets and `extra` entries; the second has dense maps
/// when `dense` (only the test of the tables needs them: a dense pass and its
/// comparison with the static scene are most of a run's time, so they are made at
/// 2 cm instead of 1).
fn manifest(dir: &Path, repetitions: usize, dense: bool, extra: &str) -> PathBuf {
    let path = dir.join("manifest.toml");
    let mut coarse = String::new();
    if dense {
        let config = dir.join("coarse_dense.toml");
        std::fs::write(
            &config,
            "[dense]\nvoxel = 0.02\ntruncation = 0.06\ncloud_voxel = 0.02\n",
        )
        .unwrap();
        coarse = format!("config = \"{}\"\n", config.display());
    }
    let text = format!(
        "[batch]\nmodes = [\"dop\", \"no-dop\"]\nrepetitions = {repetitions}\ndeterministic = true\n\
         detections = \"oracle\"\njobs = 2\n\n\
         [[sequence]]\npreset = \"demo_walking\"\nsynth_frames = 40\nseeds = [3]\ndense = false\n\n\
         [[sequence]]\npreset = \"static_room\"\nsynth_frames = 20\ndense = {dense}\n{coarse}{extra}"
    );
    std::fs::write(&path, text).unwrap();
    path
}

/// A sequence whose second colour image is not a PNG.
fn corrupt_sequence(dir: &Path) -> PathBuf {
    let seq = dir.join("corrupt");
    synth_static_room(&seq, 6);
    let mut images = common::sorted_files(&seq.join("rgb"));
    images.retain(|p| p.extension().is_some_and(|e| e == "png"));
    std::fs::write(&images[0], b"this is not a png").unwrap();
    seq
}

/// `dopslam batch MANIFEST --out OUT --quiet`: its standard output and error (it must succeed).
fn batch(manifest: &Path, out: &Path) -> (String, String) {
    let (ok, stdout, stderr) = dopslam(&[
        "batch",
        &manifest.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--quiet",
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    (stdout, stderr)
}

fn csv_rows(path: &Path) -> Vec<Vec<String>> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .skip(1)
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

fn finished_runs(out: &Path) -> usize {
    walk(&out.join("runs"))
        .into_iter()
        .filter(|p| p.file_name().is_some_and(|n| n == "run.json"))
        .count()
}

fn walk(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut files = Vec::new();
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            files.extend(walk(&path));
        } else {
            files.push(path);
        }
    }
    files
}

#[test]
fn a_batch_writes_its_tables_equal_to_eval_and_records_a_corrupt_sequence() {
    let dir = temp_dir("batch-main");
    let corrupt = corrupt_sequence(&dir);
    let extra = format!(
        "\n[[sequence]]\npath = \"{}\"\nmodes = [\"no-dop\"]\n",
        corrupt.display()
    );
    let manifest = manifest(&dir, 2, true, &extra);
    let out = dir.join("out");
    let (stdout, stderr) = batch(&manifest, &out);
    assert!(
        stdout.contains("10 runs: 0 finished before, 8 done now, 2 failed now"),
        "{stdout}"
    );

    // results.csv: one row per sequence and mode; the corrupt one failed with its file named.
    let rows = csv_rows(&out.join("results.csv"));
    let keys: Vec<(String, String, String, String)> = rows
        .iter()
        .map(|r| (r[0].clone(), r[1].clone(), r[2].clone(), r[3].clone()))
        .collect();
    let key = |s: &str, m: &str, n: &str, f: &str| {
        (s.to_string(), m.to_string(), n.to_string(), f.to_string())
    };
    assert_eq!(
        keys,
        [
            key("demo_walking-s3", "dop", "2", "0"),
            key("demo_walking-s3", "no-dop", "2", "0"),
            key("static_room", "dop", "2", "0"),
            key("static_room", "no-dop", "2", "0"),
            key("corrupt", "no-dop", "2", "2"),
        ]
    );
    let md = std::fs::read_to_string(out.join("results.md")).unwrap();
    assert!(
        md.contains("corrupt / no-dop") && md.contains(".png"),
        "{md}"
    );
    // The dense maps of the sequence that has them, against its static scene.
    let dense_row = md
        .lines()
        .find(|l| l.starts_with("| static_room | dop | 0.0"))
        .unwrap_or_default();
    assert!(
        md.contains("## Dense maps") && !dense_row.is_empty(),
        "{md}"
    );

    // Every successful run's ATE equals `dopslam eval` on its files; the median in the
    // table is the median of the runs.
    let truth = out.join("sequences/demo_walking-s3/groundtruth.txt");
    let mut ates = Vec::new();
    for r in 1..=2 {
        let run = out.join(format!("runs/demo_walking-s3/dop/r{r}"));
        let record: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(run.join("run.json")).unwrap()).unwrap();
        let ate = record["figures"]["ate_rmse"].as_f64().unwrap();
        let (ok, json, err) = dopslam(&[
            "eval",
            &truth.to_string_lossy(),
            &run.join("trajectory.txt").to_string_lossy(),
            "--rpe",
            "1s",
            "--json",
            "--min-coverage",
            "0",
        ]);
        assert!(ok, "{err}");
        let eval: serde_json::Value = serde_json::from_str(&json).unwrap();
        assert_eq!(eval["ape"]["statistics"]["rmse"].as_f64().unwrap(), ate);
        let rpe = record["figures"]["rpe_translation"].as_f64().unwrap();
        assert_eq!(eval["rpe"][0]["statistics"]["rmse"].as_f64().unwrap(), rpe);
        ates.push(ate);
    }
    let median: f64 = rows[0][4].parse().unwrap();
    assert!(
        (median - 0.5 * (ates[0] + ates[1])).abs() < 1e-6,
        "{median} vs {ates:?}"
    );

    // Figures and the report.
    let html = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(html.contains("demo_walking-s3") && html.contains("corrupt"));
    if out.join("plots/demo_walking-s3/trajectories.png").exists() {
        for name in ["trajectories", "ape_time", "ape_box"] {
            let png = out.join(format!("plots/demo_walking-s3/{name}.png"));
            let image = image::open(&png).unwrap();
            assert_eq!(
                (image.width(), image.height()),
                (900, 640),
                "{}",
                png.display()
            );
        }
        assert!(html.contains("data:image/png;base64,"));
    } else {
        assert!(
            stderr.contains("font"),
            "no plots and no word why: {stderr}"
        );
    }

    // Again: nothing left to do. Without one run's record: that run alone.
    let (stdout, _) = batch(&manifest, &out);
    assert!(
        stdout.contains("10 runs: 10 finished before, 0 done now, 0 failed now"),
        "{stdout}"
    );
    std::fs::remove_file(out.join("runs/static_room/dop/r2/run.json")).unwrap();
    let (stdout, _) = batch(&manifest, &out);
    assert!(
        stdout.contains("10 runs: 9 finished before, 1 done now, 0 failed now"),
        "{stdout}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_interrupted_batch_finishes_only_the_missing_runs_when_started_again() {
    let dir = temp_dir("batch-resume");
    let manifest = manifest(&dir, 3, false, "");
    let out = dir.join("out");
    let mut child = Command::new(env!("CARGO_BIN_EXE_dopslam"))
        .args([
            "batch",
            &manifest.to_string_lossy(),
            "--out",
            &out.to_string_lossy(),
            "--quiet",
            "--jobs",
            "1",
        ])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while finished_runs(&out) < 2 && start.elapsed() < Duration::from_secs(300) {
        std::thread::sleep(Duration::from_millis(50));
    }
    // SAFETY: kill takes a pid and a signal number.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGINT);
    }
    let status = child.wait().unwrap();
    let before = finished_runs(&out);
    assert!(
        !status.success(),
        "an interrupted batch exits with an error"
    );
    assert!(
        (2..12).contains(&before),
        "{before} runs finished before the stop"
    );
    let (stdout, _) = batch(&manifest, &out);
    let expected = format!(
        "12 runs: {before} finished before, {} done now, 0 failed now, 0 not run",
        12 - before
    );
    assert!(stdout.contains(&expected), "{stdout}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Three shards started at once as separate processes on one output folder, then
/// `--collect`: the same tables as one process running the whole manifest
/// (deterministic runs), each generated sequence made once, and `--collect --strict`
/// fails while a run is missing.
#[test]
fn shards_started_together_then_collected_equal_one_batch() {
    let base = temp_dir("batch-shards");
    let manifest = manifest(&base, 1, false, "");
    let out = base.join("sharded");
    let children: Vec<_> = (1..=3)
        .map(|k| {
            Command::new(env!("CARGO_BIN_EXE_dopslam"))
                .args([
                    "batch",
                    &manifest.to_string_lossy(),
                    "--out",
                    &out.to_string_lossy(),
                ])
                .args(["--shard", &format!("{k}/3"), "--jobs", "1"])
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::piped())
                .spawn()
                .unwrap()
        })
        .collect();
    let mut generated = 0;
    for child in children {
        let output = child.wait_with_output().unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert!(output.status.success(), "{stderr}");
        generated += stderr.matches("generating ").count();
        assert!(String::from_utf8_lossy(&output.stdout).contains("shard "));
    }
    assert_eq!(generated, 2, "each of the two sequences is generated once");
    assert!(
        !out.join("results.csv").exists(),
        "a shard writes no tables"
    );
    assert_eq!(finished_runs(&out), 4);
    let (ok, stdout, stderr) = dopslam(&[
        "batch",
        &manifest.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--collect",
        "--strict",
    ]);
    assert!(ok, "{stdout}{stderr}");
    assert!(
        stdout.contains("4 of 4 runs finished (0 failed), 0 missing"),
        "{stdout}"
    );
    let single = base.join("single");
    batch(&manifest, &single);
    // Every column but the tracking times (which real clocks give).
    let deterministic = |rows: Vec<Vec<String>>| -> Vec<Vec<String>> {
        rows.into_iter()
            .map(|r| {
                r.iter()
                    .enumerate()
                    .filter(|(i, _)| *i != 11 && *i != 12)
                    .map(|(_, c)| c.clone())
                    .collect()
            })
            .collect()
    };
    assert_eq!(
        deterministic(csv_rows(&out.join("results.csv"))),
        deterministic(csv_rows(&single.join("results.csv")))
    );
    // A run gone missing: --collect says which, and --strict fails.
    let gone = out.join("runs/static_room/no-dop/r1/run.json");
    std::fs::remove_file(&gone).unwrap();
    let (ok, stdout, _) = dopslam(&[
        "batch",
        &manifest.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--collect",
        "--strict",
    ]);
    assert!(
        !ok && stdout.contains("missing: static_room/no-dop/r1"),
        "{stdout}"
    );
}

/// `--slurm` writes the array and collection scripts with the manifest's resources.
#[test]
fn slurm_scripts_name_the_shards_and_the_resources() {
    let base = temp_dir("batch-slurm-scripts");
    let manifest = manifest(&base, 1, false, "");
    let out = base.join("out");
    let (ok, stdout, stderr) = dopslam(&[
        "batch",
        &manifest.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--slurm",
        "--partition",
        "short",
        "--time",
        "1:00:00",
        "--max-parallel",
        "2",
    ]);
    assert!(ok, "{stderr}");
    assert!(stdout.contains("4 array tasks for 4 runs"), "{stdout}");
    let array = std::fs::read_to_string(out.join("slurm/array.sbatch")).unwrap();
    for line in [
        "#SBATCH --array=1-4%2",
        "#SBATCH --partition=short",
        "#SBATCH --time=1:00:00",
        "#SBATCH --cpus-per-task=2",
        "#SBATCH --mem=3072M",
        "--shard \"$SLURM_ARRAY_TASK_ID/4\"",
    ] {
        assert!(array.contains(line), "{line} not in\n{array}");
    }
    let collect = std::fs::read_to_string(out.join("slurm/collect.sbatch")).unwrap();
    assert!(collect.contains("--collect"), "{collect}");
    assert!(!out.join("runs").exists(), "--slurm runs nothing");
    let (ok, _, stderr) = dopslam(&[
        "batch",
        &manifest.to_string_lossy(),
        "--slurm",
        "--partition",
        "a b",
    ]);
    assert!(!ok && stderr.contains("--partition"), "{stderr}");
}

/// A run made with other settings is never taken for one of the batch's: after the
/// manifest's frames change, the run is made again with a line saying why, and the old
/// run is kept aside; with `--keep-stale` it stays and is marked stale in the tables;
/// `--collect` with a manifest that is not the folder's own is refused.
#[test]
fn runs_made_with_other_settings_are_run_again_or_kept_marked_stale() {
    let dir = temp_dir("batch-stale");
    let path = dir.join("frames.toml");
    let write = |frames: usize| {
        let text = format!(
            "[batch]\nmodes = [\"no-dop\"]\ndeterministic = true\nframes = {frames}\n\n\
             [[sequence]]\npreset = \"static_room\"\nsynth_frames = 24\n"
        );
        std::fs::write(&path, text).unwrap();
    };
    let frames_of = |run: &Path| -> u64 {
        let text = std::fs::read_to_string(run.join("run.json")).unwrap();
        let record: serde_json::Value = serde_json::from_str(&text).unwrap();
        record["figures"]["frames"].as_u64().unwrap()
    };
    let out = dir.join("out");
    let run = out.join("runs/static_room/no-dop/r1");
    write(10);
    batch(&path, &out);
    assert_eq!(frames_of(&run), 10);
    write(20);
    let (_, stderr) = batch(&path, &out);
    assert!(
        stderr.contains("static_room/no-dop/r1: made with other settings (frames 10 -> 20)"),
        "{stderr}"
    );
    assert_eq!(frames_of(&run), 20, "the run was made again");
    let aside = common::sorted_files(&out.join("stale/static_room/no-dop"));
    assert_eq!(aside.len(), 1, "the 10-frame run is kept aside: {aside:?}");
    assert_eq!(frames_of(&aside[0]), 10);
    // --keep-stale: the 20-frame run stays, marked stale in the tables.
    write(15);
    let (ok, stdout, stderr) = dopslam(&[
        "batch",
        &path.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--quiet",
        "--keep-stale",
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    assert_eq!(frames_of(&run), 20, "kept");
    let rows = csv_rows(&out.join("runs.csv"));
    assert_eq!(rows[0][3], "stale", "{rows:?}");
    let text = std::fs::read_to_string(out.join("results.csv")).unwrap();
    let header: Vec<&str> = text.lines().next().unwrap().split(',').collect();
    let column = header.iter().position(|c| *c == "stale_runs").unwrap();
    assert_eq!(csv_rows(&out.join("results.csv"))[0][column], "1", "{text}");
    let results = std::fs::read_to_string(out.join("results.md")).unwrap();
    assert!(
        results.contains("Stale runs") && results.contains("frames 20 -> 15"),
        "{results}"
    );
    // The sequence's own calibration counts by its content.
    let calibration = out.join("sequences/static_room/calibration.yaml");
    let mut text = std::fs::read_to_string(&calibration).unwrap();
    text.push_str("# edited\n");
    std::fs::write(&calibration, text).unwrap();
    let (ok, stdout, stderr) = dopslam(&[
        "batch",
        &path.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--quiet",
        "--keep-stale",
    ]);
    assert!(ok, "{stdout}\n{stderr}");
    let results = std::fs::read_to_string(out.join("results.md")).unwrap();
    assert!(
        results.contains("sequence calibration changed"),
        "{results}"
    );
    // --collect with another manifest than the folder's own.
    let other = dir.join("other.toml");
    std::fs::write(
        &other,
        "[batch]\nmodes = [\"dop\"]\n\n[[sequence]]\npreset = \"static_room\"\n",
    )
    .unwrap();
    let (ok, _, stderr) = dopslam(&[
        "batch",
        &other.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--collect",
    ]);
    assert!(!ok);
    assert!(
        stderr.contains("another manifest")
            && stderr.contains("other.toml")
            && stderr.contains("manifest.toml"),
        "{stderr}"
    );
    let copy = std::fs::read_to_string(out.join("manifest.toml")).unwrap();
    assert!(
        copy.contains("frames = 15"),
        "the folder's manifest stays: {copy}"
    );
}

/// At the batch level: a second batch on the same folder waits for no one and is
/// refused, an output folder inside an input sequence is refused, and `--slurm
/// --submit` with every run finished submits nothing.
#[test]
fn a_batch_is_alone_on_its_folder_never_in_its_inputs_and_submits_no_empty_array() {
    let dir = temp_dir("batch-level");
    let seq = dir.join("room");
    synth_static_room(&seq, 8);
    let path = dir.join("room.toml");
    let text = format!(
        "[batch]\nmodes = [\"no-dop\"]\ndeterministic = true\n\n[[sequence]]\npath = \"{}\"\nname = \"room\"\n",
        seq.display()
    );
    std::fs::write(&path, text).unwrap();
    let (ok, _, stderr) = dopslam(&[
        "batch",
        &path.to_string_lossy(),
        "--out",
        &seq.join("results").to_string_lossy(),
    ]);
    assert!(
        !ok && stderr.contains("inside the input sequence"),
        "{stderr}"
    );
    assert!(
        !seq.join("results").exists(),
        "nothing written into the input"
    );
    let out = dir.join("out");
    std::fs::create_dir_all(&out).unwrap();
    let held = std::fs::File::create(out.join(".dopslam-batch.lock")).unwrap();
    held.lock().unwrap();
    let (ok, _, stderr) = dopslam(&[
        "batch",
        &path.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--quiet",
    ]);
    assert!(!ok && stderr.contains("another dopslam batch"), "{stderr}");
    drop(held);
    batch(&path, &out);
    let (ok, stdout, stderr) = dopslam(&[
        "batch",
        &path.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--slurm",
        "--submit",
    ]);
    assert!(
        ok && stdout.contains("nothing to submit"),
        "{stdout}\n{stderr}"
    );
}

/// A group tracked in one map (`map_from`): the second sequence's runs load the first's
/// map, the third's the second's, frozen. Two at a time, each starts after the run whose
/// map it loads; the tables give each one's ATE in the map's frame, and one merged map
/// of the three is made. When the first is made again, the two are made again after it
/// (their old runs and the old merged map set aside, never deleted).
#[test]
fn a_group_in_one_map_runs_in_order_is_evaluated_in_its_frame_and_merged() {
    let dir = temp_dir("batch-maps");
    let coarse = dir.join("coarse.toml");
    std::fs::write(
        &coarse,
        "[dense]\nvoxel = 0.02\ntruncation = 0.06\ncloud_voxel = 0.02\n",
    )
    .unwrap();
    let room = "preset = \"static_room\"\nsynth_frames = 16\n";
    let path = dir.join("group.toml");
    std::fs::write(
        &path,
        format!(
            "[batch]\nmodes = [\"dop\"]\ndeterministic = true\ndetections = \"oracle\"\njobs = 2\n\
             config = \"{}\"\n\n\
             [[sequence]]\n{room}name = \"first\"\nseeds = [1]\n\n\
             [[sequence]]\n{room}name = \"second\"\nseeds = [2]\nmap_from = \"first\"\n\n\
             [[sequence]]\n{room}name = \"third\"\nseeds = [3]\nmap_from = \"second\"\nmap_frozen = true\n",
            coarse.display()
        ),
    )
    .unwrap();
    let out = dir.join("out");
    let (stdout, _) = batch(&path, &out);
    assert!(stdout.contains("3 done now, 0 failed"), "{stdout}");
    let run = |name: &str| out.join(format!("runs/{name}/dop/r1"));
    let loaded = |name: &str| {
        let text = std::fs::read_to_string(run(name).join("report.json")).unwrap();
        let report: serde_json::Value = serde_json::from_str(&text).unwrap();
        report["slam_map"]["loaded"].clone()
    };
    let second = loaded("second");
    assert_eq!(
        second["file"].as_str().unwrap(),
        run("first").join("slam_map.bin").to_string_lossy()
    );
    assert_eq!(loaded("third")["frozen"], serde_json::json!(true));
    assert!(loaded("first").is_null());
    let text = std::fs::read_to_string(out.join("results.json")).unwrap();
    let results: serde_json::Value = serde_json::from_str(&text).unwrap();
    let in_map = results["in_map"].as_array().unwrap();
    assert_eq!(in_map.len(), 2, "{in_map:?}");
    for row in in_map {
        let ate = row["ate_map_frame_rmse"]["median"].as_f64().unwrap();
        assert!(ate < 0.02, "{row}");
        assert!(
            row["placed_at_frame"]["median"].as_f64().unwrap() < 5.0,
            "{row}"
        );
    }
    let merged = &results["merged"][0];
    assert_eq!(
        merged["sequences"],
        serde_json::json!(["first", "second", "third"])
    );
    assert!(merged["error"].is_null(), "{merged}");
    assert!(merged["mesh_vertices"].as_u64().unwrap() > 1000, "{merged}");
    let merge_json = out.join("merged/first/dop/r1/merge.json");
    let text = std::fs::read_to_string(&merge_json).unwrap();
    let report: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(report["recordings"].as_array().unwrap().len(), 3);
    // Nothing changed: nothing runs, the merged map stays.
    let (stdout, _) = batch(&path, &out);
    assert!(stdout.contains("3 finished before, 0 done now"), "{stdout}");
    assert!(!out.join("stale").exists());
    // The first made again: so are the two in its map, after it.
    std::fs::remove_file(run("first").join("run.json")).unwrap();
    let (stdout, stderr) = batch(&path, &out);
    assert!(stdout.contains("0 finished before, 3 done now"), "{stdout}");
    assert!(
        stderr.contains(
            "second/dop/r1: made with other settings (the run whose map it loads is made again)"
        ),
        "{stderr}"
    );
    for kept in [
        "stale/second/dop",
        "stale/third/dop",
        "stale/merged/first/dop",
    ] {
        assert_eq!(common::sorted_files(&out.join(kept)).len(), 1, "{kept}");
    }
    assert!(merge_json.exists());
}
