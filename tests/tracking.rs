//! `dopslam run` on short synthetic sequences: accuracy on a static room, and bad input
//! (no depth, a missing image mid-sequence, an empty sequence) ends with a clear error
//! and keeps the outputs of the frames already done.

use crate::common;

use std::path::Path;
use std::process::Command;

use dopslam::config::Config;
use dopslam::run::{open_sequence, run_sequence, RunOptions};
use dopslam::synth::{generate, SynthConfig};

fn static_room(frames: usize, name: &str) -> common::TestDir {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/static_room.toml");
    let mut config = SynthConfig::load(&path).unwrap();
    config.sequence.frames = frames;
    let out = common::temp_dir(name).child("seq");
    generate(&config, &out, false).unwrap();
    out
}

/// The default config without the detector (`auto` would use it where installed).
fn without_detector() -> Config {
    let mut config = Config::default();
    config.detector.source = dopslam::detect::Source::None;
    config
}

/// `dopslam run SEQ --detections none`.
fn run_without_detector(seq: &Path) -> Command {
    let mut command = dopslam();
    command.arg("run").arg(seq).args(["--detections", "none"]);
    command
}

fn dopslam() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dopslam"))
}

#[test]
fn tracks_a_static_room_within_a_centimetre() {
    let seq = static_room(90, "track-static");
    let out = seq.parent().unwrap().join("run");
    let config = without_detector();
    let sequence = open_sequence(&seq, &config).unwrap();
    let report = run_sequence(sequence.as_ref(), &config, &out, &RunOptions::default()).unwrap();
    assert_eq!(report.totals.frames, 90);
    assert_eq!(report.totals.coverage_percent, 100.0);
    assert!(report.totals.keyframes >= 2);
    let ate = report
        .ate
        .as_ref()
        .expect("synth sequences have ground truth");
    assert!(
        ate.ape.statistics.rmse < 0.01,
        "ATE RMSE {} m",
        ate.ape.statistics.rmse
    );
    for file in [
        "trajectory.txt",
        "trajectory_tracking.txt",
        "keyframes.txt",
        "report.json",
        "map.ply",
    ] {
        assert!(out.join(file).is_file(), "{file}");
    }
    // report.json reads back whole as the type it was written from: nothing lost,
    // nothing added.
    let read = dopslam::records::read_report(&dopslam::io::run_dir::RunDir::new(&out)).unwrap();
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(serde_json::to_value(&read).unwrap(), file);
    assert_eq!(read.totals.frames, report.totals.frames);
    // The global pass ran: no loop on a still camera, full BA over every keyframe.
    let global = report
        .global
        .as_ref()
        .expect("the global pass runs by default");
    assert!(global.note.is_none(), "{:?}", global.note);
    assert!(global.loops.is_empty());
    let ba = global.full_ba.as_ref().expect("full BA");
    assert_eq!(ba.keyframes, report.totals.keyframes);
    assert!(ba.final_cost <= ba.initial_cost);
    let tracking = report.ate_tracking.as_ref().expect("tracking ATE");
    assert!(tracking.ape.statistics.rmse < 0.01);
    let trajectory = std::fs::read_to_string(out.join("trajectory.txt")).unwrap();
    assert_eq!(
        trajectory.lines().filter(|l| !l.starts_with('#')).count(),
        90
    );
}

#[test]
fn bad_input_fails_clearly_and_keeps_what_was_done() {
    let seq = static_room(12, "track-bad");
    let base = seq.parent().unwrap().to_path_buf();
    // A missing colour image in the middle: the error names it; frames before it are kept.
    let names = common::sorted_files(&seq.join("rgb"));
    std::fs::remove_file(&names[8]).unwrap();
    let output = run_without_detector(&seq)
        .arg("--out")
        .arg(base.join("run-missing"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains(names[8].file_name().unwrap().to_str().unwrap())
            && stderr.contains("frame 8"),
        "{stderr}"
    );
    let trajectory = std::fs::read_to_string(base.join("run-missing/trajectory.txt")).unwrap();
    assert_eq!(
        trajectory.lines().filter(|l| !l.starts_with('#')).count(),
        8
    );

    // Depth read with a wrong scale: every depth beyond reach, so tracking never starts.
    let config_path = base.join("wrong-scale.toml");
    std::fs::write(&config_path, "[dataset]\ndepth_scale = 1.0\n").unwrap();
    let output = run_without_detector(&seq)
        .args(["--frames", "6", "--config"])
        .arg(&config_path)
        .arg("--out")
        .arg(base.join("run-scale"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("median depth") && stderr.contains("depth_scale"),
        "{stderr}"
    );
    assert!(base.join("run-scale/report.json").is_file());

    // Depth maps that hold no depth at all.
    let depths = common::sorted_files(&seq.join("depth"));
    for path in &depths {
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(640, 480)
            .save(path)
            .unwrap();
    }
    let output = run_without_detector(&seq)
        .args(["--frames", "8", "--out"])
        .arg(base.join("run-zero"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(stderr.contains("never started"), "{stderr}");

    // An empty sequence.
    let empty = base.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    std::fs::write(empty.join("rgb.txt"), "# nothing\n").unwrap();
    std::fs::write(empty.join("depth.txt"), "# nothing\n").unwrap();
    let output = run_without_detector(&empty)
        .arg("--out")
        .arg(base.join("run-empty"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("no frames") || stderr.contains("empty"),
        "{stderr}"
    );
}

#[test]
fn deterministic_runs_repeat_exactly_with_local_mapping() {
    let seq = static_room(90, "track-deterministic");
    let base = seq.parent().unwrap().to_path_buf();
    let config = without_detector();
    let sequence = open_sequence(&seq, &config).unwrap();
    let options = RunOptions {
        deterministic: true,
        ..RunOptions::default()
    };
    let first = run_sequence(sequence.as_ref(), &config, &base.join("a"), &options).unwrap();
    run_sequence(sequence.as_ref(), &config, &base.join("b"), &options).unwrap();
    // And on one thread and on three: the thread count changes nothing.
    for threads in [1, 3] {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                let out = base.join(format!("threads-{threads}"));
                run_sequence(sequence.as_ref(), &config, &out, &options).unwrap();
            });
    }
    for file in ["trajectory.txt", "keyframes.txt", "map.ply"] {
        let a = std::fs::read(base.join("a").join(file)).unwrap();
        for other in ["b", "threads-1", "threads-3"] {
            let b = std::fs::read(base.join(other).join(file)).unwrap();
            assert!(
                a == b,
                "{file} differs between deterministic runs (a, {other})"
            );
        }
    }
    // Local mapping ran on every keyframe and connected them: duplicates were fused,
    // bundle adjustment ran, and the map is still accurate.
    let m = &first.mapping;
    assert_eq!(
        m.keyframes_processed,
        first.totals.keyframes + m.keyframes_culled
    );
    assert!(m.fusions > 100, "{m:?}");
    assert!(m.ba_ms > 0.0);
    let rmse = first.ate.unwrap().ape.statistics.rmse;
    assert!(rmse < 0.01, "ATE RMSE {rmse} m");
}

#[test]
fn relocalises_after_a_blackout() {
    let seq = static_room(120, "track-blackout");
    let base = seq.parent().unwrap().to_path_buf();
    // Frames 60..70 are black: no features, tracking is lost; the camera moves on
    // meanwhile, so only relocalisation (EPnP RANSAC against keyframes) can recover.
    let names = common::sorted_files(&seq.join("rgb"));
    for path in &names[60..70] {
        image::RgbImage::new(640, 480).save(path).unwrap();
    }
    let config = without_detector();
    let sequence = open_sequence(&seq, &config).unwrap();
    let options = RunOptions {
        deterministic: true,
        ..RunOptions::default()
    };
    let report = run_sequence(sequence.as_ref(), &config, &base.join("run"), &options).unwrap();
    let spans = &report.totals.lost_spans;
    assert_eq!(spans.len(), 1, "{spans:?}");
    assert_eq!(spans[0].0, 60);
    assert!(spans[0].1 >= 69 && spans[0].1 <= 72, "{spans:?}");
    assert_eq!(report.totals.tracked, 120 - (spans[0].1 - 59));
    let rmse = report.ate.unwrap().ape.statistics.rmse;
    assert!(rmse < 0.01, "ATE RMSE {rmse} m after relocalisation");
}

#[test]
fn a_covered_lens_starts_a_map_segment_that_the_loop_merges() {
    // loop_room at 10 fps: the camera turns once around in 30 s. From 8 s to 14 s the
    // lens is covered (black colour, no depth) while it turns 72 degrees on: past
    // `new_map_after_seconds` (3 s) with relocalisation failing on a view no keyframe
    // has, a new segment starts at the last tracked pose; when the camera comes back
    // to its start, the loop moves that segment onto the first and merges them.
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/loop_room.toml");
    let mut synth = SynthConfig::load(&path).unwrap();
    synth.sequence.frames = 300;
    synth.sequence.fps = 10.0;
    let seq = common::temp_dir("track-segments").child("seq");
    generate(&synth, &seq, false).unwrap();
    let colour = common::sorted_files(&seq.join("rgb"));
    let depth = common::sorted_files(&seq.join("depth"));
    for (c, d) in colour[80..140].iter().zip(&depth[80..140]) {
        image::RgbImage::new(640, 480).save(c).unwrap();
        image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(640, 480)
            .save(d)
            .unwrap();
    }
    let config = without_detector();
    let sequence = open_sequence(&seq, &config).unwrap();
    let options = RunOptions {
        deterministic: true,
        ..RunOptions::default()
    };
    let out = seq.parent().unwrap().join("run");
    let report = run_sequence(sequence.as_ref(), &config, &out, &options).unwrap();
    let totals = &report.totals;
    assert_eq!(totals.lost_spans, vec![(80, 139)]);
    assert_eq!(totals.segments.len(), 2, "{:?}", totals.segments);
    let (first, second) = (&totals.segments[0], &totals.segments[1]);
    assert_eq!((first.first_frame, first.last_frame), (0, 79));
    assert_eq!(first.merged_into, None);
    assert_eq!((second.segment, second.first_frame), (1, 140));
    assert_eq!(second.merged_into, Some(0));
    assert_eq!(totals.largest_segment_percent, 80.0);
    let global = report.global.as_ref().unwrap();
    assert!(
        global.loops.iter().any(|l| l.merged.is_some()),
        "{:?}",
        global.candidates
    );
    // Before the merge the second segment sits where the first was lost, 72 degrees
    // off; after it, both are in one frame.
    let tracking = report.ate_tracking.as_ref().unwrap().ape.statistics.rmse;
    let merged = report.ate.as_ref().unwrap().ape.statistics.rmse;
    assert!(tracking > 0.1, "ATE {tracking} m before the merge");
    assert!(merged < 0.02, "ATE {merged} m after the merge");
    // segments.txt gives the dense pass every tracked frame in the one merged segment.
    let segments = std::fs::read_to_string(out.join("segments.txt")).unwrap();
    let rows: Vec<&str> = segments.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(rows.len(), 240);
    assert!(rows.iter().all(|r| r.ends_with(" 0")), "{rows:?}");
}

#[test]
fn keyframes_get_their_detections_from_the_detection_worker() {
    let seq = static_room(40, "track-detections");
    let base = seq.parent().unwrap().to_path_buf();
    let mut config = Config::default();
    config.detector.source = dopslam::detect::Source::Oracle;
    let sequence = open_sequence(&seq, &config).unwrap();
    for deterministic in [true, false] {
        let out = base.join(format!("run-{deterministic}"));
        let options = RunOptions {
            deterministic,
            sequence_dir: Some(seq.to_path_buf()),
            ..RunOptions::default()
        };
        let report = run_sequence(sequence.as_ref(), &config, &out, &options).unwrap();
        let d = &report.detection;
        assert!(d.submitted >= 2, "{d:?}");
        assert_eq!(d.detected, d.submitted, "{d:?}");
        assert!(d.errors.is_empty(), "{d:?}");
        // One cache file per keyframe, named by its timestamp, readable back.
        assert_eq!(
            common::sorted_files(&out.join("detections")).len(),
            d.submitted
        );
        if deterministic {
            // A deterministic run makes the same keyframes, so the cache it wrote
            // serves a second run completely.
            let cached = Config {
                detector: dopslam::detect::DetectorConfig {
                    source: dopslam::detect::Source::Cache,
                    cache_dir: Some(out.join("detections")),
                    ..Default::default()
                },
                ..Config::default()
            };
            let again =
                run_sequence(sequence.as_ref(), &cached, &base.join("again"), &options).unwrap();
            assert_eq!(again.detection.detected, d.submitted);
            assert!(again.detection.errors.is_empty(), "{:?}", again.detection);
        }
    }
    // Without the oracle folder the error names it.
    let bad = RunOptions {
        sequence_dir: Some(base.join("elsewhere")),
        ..RunOptions::default()
    };
    let error = run_sequence(sequence.as_ref(), &config, &base.join("bad"), &bad)
        .err()
        .unwrap()
        .to_string();
    assert!(error.contains("detections_oracle"), "{error}");
}
