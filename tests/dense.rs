//! The dense pass on a short synthetic walking sequence with the oracle detections:
//! with DOP masks the walkers stay out of the fused map, without them they are in it;
//! the files read back; the comparison tells the two apart.

use crate::common;

use std::path::{Path, PathBuf};

use dopslam::config::Config;
use dopslam::dense::compare_maps::{compare_maps, CompareInputs};
use dopslam::dense::map_figures::CompareSettings;
use dopslam::dense::DenseConfig;
use dopslam::detect::Source;
use dopslam::dop::Mode;
use dopslam::io::ply::{read_ply, write_ply, PlyEncoding};
use dopslam::io::sequence::Sequence;
use dopslam::records::run_alignment;
use dopslam::run::{dense_pass, open_sequence, run_sequence, DenseSetup, RunOptions, RunReport};
use dopslam::synth::{generate, SynthConfig};

/// The first `frames` frames of synth preset `name` (without its frame timing), in a
/// new folder `seq` under a temporary folder named `dir`: (that folder, `seq`).
fn preset_sequence(name: &str, frames: usize, dir: &str) -> (common::TestDir, PathBuf) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("configs/synth/{name}.toml"));
    let mut synth = SynthConfig::load(&path).unwrap();
    synth.sequence.timing = None;
    synth.sequence.frames = frames;
    let base = common::temp_dir(dir);
    let seq = base.join("seq");
    generate(&synth, &seq, false).unwrap();
    (base, seq)
}

/// A deterministic run of the sequence in `seq` into `run_dir`, with or without the
/// dense pass: the opened sequence and the run's report.
fn deterministic_run(
    seq: &Path,
    config: &Config,
    run_dir: &Path,
    dense: bool,
) -> (Box<dyn Sequence>, RunReport) {
    let sequence = open_sequence(seq, config).unwrap();
    let options = RunOptions {
        deterministic: true,
        sequence_dir: Some(seq.to_path_buf()),
        dense,
        ..RunOptions::default()
    };
    let report = run_sequence(sequence.as_ref(), config, run_dir, &options).unwrap();
    (sequence, report)
}

/// A run's folder fused again: the sequence (opened, and its folder), the config and
/// the run.
#[derive(Clone, Copy)]
struct Fused<'a> {
    sequence: &'a dyn Sequence,
    seq: &'a Path,
    config: &'a Config,
    run_dir: &'a Path,
}

/// The dense pass of `fused` into `out_dir`, masked as `masking` asks.
fn fuse_again(
    fused: Fused,
    out_dir: &Path,
    masking: Mode,
) -> Result<dopslam::dense::DenseReport, dopslam::run::RunError> {
    dense_pass(&dopslam::run::DensePass {
        sequence: fused.sequence,
        setup: &DenseSetup::resolve(fused.sequence, fused.config).unwrap(),
        run_dir: fused.run_dir,
        out_dir,
        masking,
        sequence_dir: Some(fused.seq),
        progress: false,
    })
}

/// A pass that keeps its state (`keep_state`, under `budgets`), then passes into the
/// same folder: with other output settings the state is reused (not fused again) and
/// the files equal a pass that fuses with those settings; with another fusion setting
/// it is fused again. The kept files are never written.
fn kept_states_are_reused_when_only_the_outputs_change(run: Fused, budgets: &Config, base: &Path) {
    let state_files = |dir: &Path| {
        let mut files: Vec<(PathBuf, Vec<u8>)> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .map(|p| (p.clone(), std::fs::read(p).unwrap()))
            .collect();
        files.sort();
        files
    };
    let mut keeping = budgets.clone();
    keeping.dense.outputs.keep_state = true;
    let kept_dir = base.join("kept");
    let pass =
        |config: &Config, dir: &Path| fuse_again(Fused { config, ..run }, dir, Mode::Dop).unwrap();
    let first = pass(&keeping, &kept_dir);
    let state = kept_dir.join("dense_state");
    assert_eq!(first.kept_state.as_deref(), Some(state.as_path()));
    assert!(first.reused_state.is_none());
    let kept = state_files(&state);
    assert_eq!(
        kept.len(),
        5,
        "state.json, the volume's and the cloud's files and tables"
    );

    let mut other = budgets.clone();
    let outputs = &mut other.dense.outputs;
    (outputs.mesh_min_piece_area, outputs.ply_encoding) = (0.01, PlyEncoding::Ascii);
    other.dense.cloud.outlier_neighbours = 4;
    let reused = pass(&other, &kept_dir);
    let from = reused
        .reused_state
        .as_ref()
        .expect("the kept state reused")
        .from
        .clone();
    assert_eq!(from, state);
    assert_eq!(
        (reused.frames_fused, reused.masked_percent),
        (first.frames_fused, first.masked_percent)
    );
    let fresh_dir = base.join("fresh");
    assert!(pass(&other, &fresh_dir).reused_state.is_none());
    for name in ["dense_mesh.ply", "dense_mesh.obj", "dense_points.ply"] {
        let same = std::fs::read(kept_dir.join(name)).unwrap()
            == std::fs::read(fresh_dir.join(name)).unwrap();
        assert!(same, "{name}: the kept state's differs from a fresh pass's");
    }
    assert!(state_files(&state) == kept, "the kept state was written to");

    // Another fusion setting: fused again, nothing kept or reused, the state as it was.
    other.dense.tsdf.max_depth -= 0.5;
    let again = pass(&other, &kept_dir);
    assert!(again.reused_state.is_none() && again.kept_state.is_none());
    assert!(state_files(&state) == kept, "the kept state was written to");
}

/// The default config with the oracle boxes and the DOP model.
fn oracle_config() -> Config {
    let mut config = Config::default();
    config.detector.source = Source::Oracle;
    config.dop.mode = Mode::Dop;
    config
}

#[test]
fn dop_masks_keep_the_walkers_out_of_the_dense_map() {
    let (base, seq) = preset_sequence("walking_xyz", 150, "dense-walking");
    let mut config = oracle_config();
    config.dense.tsdf.voxel = 0.02;
    config.dense.tsdf.truncation = 0.06;
    config.dense.cloud.stride = 4;
    config.dense.cloud.normal_neighbours = 8;
    // The masks alone: no piece of either mesh dropped (that filter is judged below).
    config.dense.outputs.mesh_min_piece_area = 0.0;
    let run_dir = base.join("run");
    let (sequence, report) = deterministic_run(&seq, &config, &run_dir, true);
    let run = Fused {
        sequence: sequence.as_ref(),
        seq: &seq,
        config: &config,
        run_dir: &run_dir,
    };
    let dense = report.dense.clone().expect("the dense pass ran");
    // Frames where the camera barely moved are left out (each fused frame counts for
    // those before it): this slow camera fuses fewer than half.
    assert_eq!(
        dense.frames_fused + dense.frames_left_still,
        report.totals.tracked
    );
    assert!(dense.frames_fused < report.totals.tracked, "{dense:?}");
    // It moves: only where it turns back does it stand still for a few frames, fused
    // closer together there ([dense] frame_still_gap).
    assert!(
        dense.frames_fused_still <= report.totals.tracked / 10,
        "{dense:?}"
    );
    // report.json ends with the dense pass and each stage's time against the
    // recording's (150 frames at 30 fps: 5 s).
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("report.json")).unwrap())
            .unwrap();
    assert_eq!(written["dense"]["frames_fused"], dense.frames_fused);
    let times = report.times.as_ref().expect("the run's times");
    assert!((times.recording_s.unwrap() - 5.0).abs() < 0.01, "{times:?}");
    let stages: Vec<&str> = times.stages.iter().map(|s| s.stage.as_str()).collect();
    assert_eq!(stages, ["tracking", "global", "outputs", "dense"]);
    let dense_time = &times.stages[3];
    assert!(dense_time.seconds >= dense.total_s, "{times:?}");
    assert!(
        (dense_time.real_time_factor.unwrap() - dense_time.seconds / 5.0).abs() < 0.01,
        "{times:?}"
    );
    assert!(written["times"]["real_time_factor"].as_f64().unwrap() > 0.0);
    // Each mask source is counted against the truth: the boxes mask the walkers,
    // and what the static map's check releases is the static scene.
    let sources = &dense.truth.as_ref().expect("truth").sources;
    let source = |name: &str| sources.iter().find(|s| s.source == name).unwrap();
    assert!(source("objects").mover_pixels > 0, "{sources:?}");
    let released = source("map_agrees");
    assert!(released.pixels > 0, "{sources:?}");
    assert!(
        released.mover_pixels * 100 <= released.pixels,
        "{sources:?}"
    );
    assert_eq!(dense.released_on_map, released.pixels);
    assert!(sources
        .iter()
        .all(|s| s.mover_pixels <= s.pixels && s.only_pixels <= s.pixels));
    assert!(dense.masked_fusable_percent > 0.0);
    // dense.json reads back whole as the type it was written from: nothing lost,
    // nothing added.
    let read = dopslam::records::read_dense(&dopslam::io::run_dir::RunDir::new(&run_dir))
        .unwrap()
        .expect("dense.json");
    let file: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run_dir.join("dense.json")).unwrap())
            .unwrap();
    assert_eq!(serde_json::to_value(&read).unwrap(), file);
    assert_eq!(read.frames_fused, dense.frames_fused);
    // Every 5th frame detected for the masks, beside the keyframes, except those
    // next to a keyframe the same detector found its boxes on.
    let extra = dense.extra_detections.clone().expect("detect_every is on");
    assert!(extra.detected > 0, "{extra:?}");
    assert!(
        extra.detected + extra.near_keyframes >= 150 / 5 - report.totals.keyframes,
        "{extra:?}"
    );
    assert_eq!(extra.cached, 0);
    assert!(
        dense.mesh_triangles > 10_000,
        "{} triangles",
        dense.mesh_triangles
    );
    assert!(dense.cloud_points > 1_000);
    let truth = dense.truth.expect("ground-truth masks were counted");
    eprintln!("DOP masks: {truth:?}");
    assert!(truth.dynamic_removed > 0.9, "{truth:?}");
    assert!(truth.static_kept > 0.8, "{truth:?}");
    for name in [
        "dense_mesh.ply",
        "dense_mesh.obj",
        "dense_points.ply",
        "dense.json",
        "dense_top.png",
        "dense_perspective.png",
        "dynamic_keypoints.json",
    ] {
        assert!(run_dir.join(name).exists(), "{name} missing");
    }
    let mesh = read_ply(&run_dir.join("dense_mesh.ply")).unwrap();
    assert_eq!(mesh.len(), dense.mesh_vertices);
    assert_eq!(mesh.triangles.len(), dense.mesh_triangles);
    let cloud = read_ply(&run_dir.join("dense_points.ply")).unwrap();
    assert_eq!(cloud.normals.len(), cloud.len());

    // Re-fused on one thread: the same bytes (the dense pass does not depend on the
    // thread count).
    let one_dir = base.join("one-thread");
    rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap()
        .install(|| fuse_again(run, &one_dir, Mode::Dop))
        .unwrap();
    // Fused again into the run's folder: the detections come from its cache.
    let again = fuse_again(run, &run_dir, Mode::Dop)
        .unwrap()
        .extra_detections
        .unwrap();
    assert_eq!((again.detected, again.cached), (0, extra.detected));
    for name in ["dense_mesh.ply", "dense_points.ply", "dense_mesh.obj"] {
        let (a, b) = (
            std::fs::read(run_dir.join(name)).unwrap(),
            std::fs::read(one_dir.join(name)).unwrap(),
        );
        assert!(a == b, "{name} differs between thread counts");
    }

    // Under budgets small enough to send most blocks and chunks to their spill files:
    // the same mesh (bytes) and cloud (the same rows, in another order), and no
    // temporary file left behind.
    let mut small = config.clone();
    small.dense.tsdf.memory_mb = 0.5;
    small.dense.cloud.memory_mb = 0.02;
    let spilled_dir = base.join("spilled");
    let spilled = fuse_again(
        Fused {
            config: &small,
            ..run
        },
        &spilled_dir,
        Mode::Dop,
    )
    .unwrap();
    assert!(
        spilled.tsdf_spill.blocks_reloaded > 0 && spilled.cloud_spill.chunks_reloaded > 0,
        "{:?} {:?}",
        spilled.tsdf_spill,
        spilled.cloud_spill
    );
    for name in ["dense_mesh.ply", "dense_mesh.obj"] {
        let same = std::fs::read(run_dir.join(name)).unwrap()
            == std::fs::read(spilled_dir.join(name)).unwrap();
        assert!(same, "{name} differs under small budgets");
    }
    let rows = |dir: &Path| {
        let cloud = read_ply(&dir.join("dense_points.ply")).unwrap();
        let mut rows: Vec<String> = (0..cloud.len())
            .map(|i| {
                let (v, n, c) = (cloud.vertices[i], cloud.normals[i], cloud.colours[i]);
                format!("{v:?} {n:?} {c:?}")
            })
            .collect();
        rows.sort();
        rows
    };
    assert!(rows(&run_dir) == rows(&spilled_dir), "the cloud differs");
    let left: Vec<_> = std::fs::read_dir(&spilled_dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|name| name.starts_with('.') && name != ".dopslam.lock")
        .collect();
    assert!(left.is_empty(), "left behind: {left:?}");
    kept_states_are_reused_when_only_the_outputs_change(run, &small, &base);

    // The same poses without masks: the walkers come in.
    let unmasked_dir = base.join("unmasked");
    let unmasked = fuse_again(run, &unmasked_dir, Mode::Off).unwrap();
    assert_eq!(unmasked.truth.unwrap().dynamic_removed, 0.0);

    let align = run_alignment(&run_dir);
    assert!(
        align.is_some(),
        "the run was evaluated against its ground truth"
    );
    // The unmasked mesh without its small pieces (the default filter): the walkers'
    // fragments that float apart from the room go.
    let (pruned, dropped) = read_ply(&unmasked_dir.join("dense_mesh.ply"))
        .unwrap()
        .without_small_pieces(DenseConfig::default().outputs.mesh_min_piece_area);
    assert!(dropped.pieces > 0, "{dropped:?}");
    let pruned_path = base.join("unmasked_pruned.ply");
    write_ply(&pruned_path, &pruned, None, PlyEncoding::Binary, "pruned").unwrap();
    let maps = [
        ("dop".to_string(), run_dir.join("dense_mesh.ply")),
        ("pruned".to_string(), pruned_path),
        // The last map is the baseline of the others' static accuracy.
        ("unmasked".to_string(), unmasked_dir.join("dense_mesh.ply")),
    ];
    let comparison = compare_maps(&CompareInputs {
        maps: &maps,
        alignments: &[align, align, align],
        reference: &seq.join("static_scene.ply"),
        movers: Some(&seq.join("movers.ply")),
        cameras: None,
        settings: CompareSettings::default(),
        out: &base.join("compare"),
    })
    .unwrap();
    eprintln!("{}", comparison.table());
    let (dop, all) = (&comparison.maps[0], &comparison.maps[2]);
    let (dop_movers, all_movers) = (dop.mover_points.unwrap(), all.mover_points.unwrap());
    // Carving, blocks allocated first and the image margin keep most of them out even
    // unmasked (169 on this sequence when the margin came).
    assert!(
        all_movers > 100,
        "the unmasked map holds the walkers ({all_movers})"
    );
    assert!(
        dop_movers * 10 <= all_movers,
        "DOP keeps {dop_movers} mover points, unmasked {all_movers}"
    );
    assert!(dop.dynamic_accuracy.unwrap() > all.dynamic_accuracy.unwrap());
    // Without masks the walkers' ghosts are mostly fragments apart from the room:
    // dropping the small pieces takes most of them and keeps the static surfaces.
    let pruned = &comparison.maps[1];
    assert!(
        pruned.mover_points.unwrap() * 2 < all_movers,
        "small pieces dropped: {:?} mover points, unmasked {all_movers}",
        pruned.mover_points
    );
    assert!(
        pruned.static_accuracy.unwrap() > 0.98,
        "SA {:?} of the unmasked map's static surfaces",
        pruned.static_accuracy
    );
    assert!(
        dop.static_accuracy.unwrap() > 0.9,
        "SA {:?}",
        dop.static_accuracy
    );
    assert!(
        dop.accuracy_median < 0.04,
        "median error {}",
        dop.accuracy_median
    );
    for name in [
        "compare.md",
        "compare.json",
        "dop_distance.ply",
        "compare_top.png",
    ] {
        assert!(base.join("compare").join(name).exists(), "{name} missing");
    }
}

/// Movers no detector knows (a box slid across the floor, a balloon; the oracle boxes
/// only the walker) are kept out by the free space they leave: fused with the
/// free-space evidence, far more of their pixels stay out of the map than without it,
/// more again with the far neighbours (the box stands still for two seconds), and the
/// static scene loses no more of its pixels.
#[test]
fn free_space_keeps_movers_no_detector_knows_out_of_the_map() {
    let (base, seq) = preset_sequence("unknown_movers", 150, "dense-free-space");
    let mut config = oracle_config();
    config.dense.tsdf.voxel = 0.03;
    config.dense.tsdf.truncation = 0.09;
    config.dense.outputs.cloud = false;
    config.dense.outputs.pictures = false;
    config.dense.detections.every = 0;
    let run_dir = base.join("run");
    let (sequence, _) = deterministic_run(&seq, &config, &run_dir, false);
    let fuse = |(seconds, far_seconds): (f64, f64), name: &str| {
        let mut config = config.clone();
        config.dense.masks.free_space_seconds = seconds;
        config.dense.masks.free_space_far_seconds = far_seconds;
        let out = base.join(name);
        let run = Fused {
            sequence: sequence.as_ref(),
            seq: &seq,
            config: &config,
            run_dir: &run_dir,
        };
        let report = fuse_again(run, &out, Mode::Dop).unwrap();
        report.truth.expect("ground-truth masks were counted")
    };
    let without = fuse((0.0, 0.0), "without");
    let with = fuse((0.5, 0.0), "with");
    let far = fuse((0.5, 4.0), "far");
    eprintln!("without free space: {without:?}\nwith free space: {with:?}\nfar too: {far:?}");
    let unknown =
        |t: &dopslam::dense::FusedTruth| t.unknown_removed.expect("unknown movers in view");
    assert!(
        unknown(&with) > unknown(&without) + 0.1,
        "unknown movers kept out: {} without, {} with",
        unknown(&without),
        unknown(&with)
    );
    assert!(with.dynamic_removed > without.dynamic_removed);
    assert!(
        with.static_kept >= without.static_kept - 0.01,
        "static pixels fused: {} without, {} with",
        without.static_kept,
        with.static_kept
    );
    assert!(
        unknown(&far) > unknown(&with) + 0.1,
        "unknown movers kept out: {} near only, {} with far neighbours",
        unknown(&with),
        unknown(&far)
    );
    assert!(
        far.static_kept >= with.static_kept - 0.01,
        "static pixels fused: {} near only, {} with far neighbours",
        with.static_kept,
        far.static_kept
    );
}

/// A static camera's recording (a wall 2 m away; a block 1.2 m away in one frame):
/// `tools/static_camera_truth.py` marks the block's pixels in that frame as a mover and
/// nothing else, clears exactly those from that frame's depth in the recording it
/// writes `--without-movers`, leaves the recording as it was, and refuses to write
/// into a folder that holds something.
#[test]
fn the_static_camera_truth_marks_what_stands_before_the_background() {
    let Some(python) = common::test_python("static_camera_truth", "numpy, PIL") else {
        return;
    };
    let dir = common::temp_dir("static-camera-truth");
    let seq = dir.join("seq");
    std::fs::create_dir_all(seq.join("depth")).unwrap();
    let (mut rgb, mut depth) = (String::from("# rgb\n"), String::from("# depth\n"));
    for k in 0..8 {
        let image = image::ImageBuffer::from_fn(32, 24, |u, v| {
            let block = k == 3 && (8..16).contains(&u) && (6..14).contains(&v);
            let metres = if block { 1.2 } else { 2.0 };
            image::Luma([(metres * 5000.0) as u16])
        });
        image.save(seq.join(format!("depth/{k}.png"))).unwrap();
        rgb.push_str(&format!("{:.6} rgb/{k}.png\n", 0.1 * k as f64));
        depth.push_str(&format!("{:.6} depth/{k}.png\n", 0.1 * k as f64));
    }
    std::fs::write(seq.join("rgb.txt"), rgb).unwrap();
    std::fs::write(seq.join("depth.txt"), depth).unwrap();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/static_camera_truth.py");
    let (out, without) = (dir.join("truth"), dir.join("without"));
    let truth = || {
        std::process::Command::new(&python)
            .arg(&script)
            .arg(&seq)
            .arg(&out)
            .arg("--without-movers")
            .arg(&without)
            .output()
            .unwrap()
    };
    let status = truth();
    assert!(
        status.status.success(),
        "{}",
        String::from_utf8_lossy(&status.stderr)
    );
    for k in 0..8 {
        let mask = image::open(out.join(format!("masks/{:.6}.png", 0.1 * k as f64)))
            .unwrap()
            .to_luma8();
        let movers = mask.pixels().filter(|p| p[0] > 0).count();
        assert_eq!(movers, if k == 3 { 64 } else { 0 }, "frame {k}");
        if k == 3 {
            assert!(mask.get_pixel(10, 8)[0] > 0 && mask.get_pixel(20, 8)[0] == 0);
        }
        let cleared = image::open(without.join(format!("depth/{k}.png")))
            .unwrap()
            .to_luma16();
        let original = image::open(seq.join(format!("depth/{k}.png")))
            .unwrap()
            .to_luma16();
        for (u, v, p) in cleared.enumerate_pixels() {
            let expected = match mask.get_pixel(u, v)[0] {
                0 => original.get_pixel(u, v)[0],
                _ => 0,
            };
            assert_eq!(p[0], expected, "frame {k} pixel {u} {v}");
        }
    }
    assert!(without.join("depth.txt").exists() && without.join("masks").exists());
    assert!(out.join("depth.txt").exists(), "the recording is linked");
    assert!(
        !seq.join("masks").exists(),
        "nothing written into the recording"
    );
    let again = truth();
    assert!(!again.status.success());
    assert!(String::from_utf8_lossy(&again.stderr).contains("is not empty"));
}
