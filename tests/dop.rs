//! The DOP model in the tracking pass, on a short synthetic walking sequence with the
//! oracle detections: it must beat ORB-SLAM2 behaviour (--no-dop) clearly, and the
//! naive box masking must also run to the end.

use crate::common;

use std::path::Path;

use dopslam::config::Config;
use dopslam::detect::Source;
use dopslam::dop::Mode;
use dopslam::run::{open_sequence, run_sequence, RunOptions, RunReport};
use dopslam::synth::{generate, SynthConfig};

fn run(seq: &Path, mode: Mode, out: &Path) -> RunReport {
    let mut config = Config::default();
    config.detector.source = Source::Oracle;
    config.dop.mode = mode;
    run_with(seq, &config, out)
}

fn run_with(seq: &Path, config: &Config, out: &Path) -> RunReport {
    let sequence = open_sequence(seq, config).unwrap();
    let options = RunOptions {
        deterministic: true,
        sequence_dir: Some(seq.to_path_buf()),
        ..RunOptions::default()
    };
    run_sequence(sequence.as_ref(), config, out, &options).unwrap()
}

#[test]
fn dop_removes_the_walkers_and_beats_orb_slam2_behaviour() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/walking_xyz.toml");
    let mut synth = SynthConfig::load(&path).unwrap();
    // Regular 30 Hz timing instead of the recorded one (which lives in ../shared).
    synth.sequence.timing = None;
    synth.sequence.frames = 240;
    let base = common::temp_dir("dop-walking");
    let seq = base.join("seq");
    generate(&synth, &seq, false).unwrap();
    let rmse = |r: &RunReport| r.ate.as_ref().unwrap().ape.statistics.rmse;
    let off = run(&seq, Mode::Off, &base.join("off"));
    let dop = run(&seq, Mode::Dop, &base.join("dop"));
    let mask = run(&seq, Mode::MaskBoxes, &base.join("mask"));
    eprintln!(
        "ATE RMSE: no-dop {:.4} m, mask-boxes {:.4} m, dop {:.4} m",
        rmse(&off),
        rmse(&mask),
        rmse(&dop)
    );
    for r in [&off, &dop, &mask] {
        assert_eq!(r.totals.coverage_percent, 100.0);
    }
    assert!(rmse(&dop) < 0.02, "DOP ATE {} m", rmse(&dop));
    assert!(
        rmse(&dop) * 2.0 < rmse(&off),
        "DOP {} vs no-dop {}",
        rmse(&dop),
        rmse(&off)
    );
    // The model did act: keypoints were removed, map points updated and culled.
    let removed: usize = dop
        .frames
        .to_vec()
        .unwrap()
        .iter()
        .map(|f| f.tracking.dynamic_keypoints)
        .sum();
    assert!(removed > 1000, "{removed} keypoints removed over the run");
    assert!(dop.detection.map_points_updated > 0);
    // Keyframes are for the camera: the walkers make none (the camera moves slowly).
    let share = dop.totals.keyframes as f64 / dop.totals.frames as f64;
    assert!(
        share <= 0.25,
        "keyframes on {:.0} % of frames",
        100.0 * share
    );
    let off_frames = off.frames.to_vec().unwrap();
    assert!(off_frames.iter().all(|f| f.tracking.dynamic_keypoints == 0));
    assert!(mask.detection.map_points_removed > 0);
}

/// A box carried close to the camera from the first frame, in front of a flat wall
/// that hardly tells a sideways step from a turn (no detector knows a box). Without
/// the rigidity test and the prediction gate the pose follows the box, so its points
/// stay pose inliers. The rigidity test, which needs no pose, sees them move; the
/// prediction gate keeps them out of the pose from their first frame of motion; each
/// alone and both together keep the box from dragging the pose.
#[test]
fn the_rigidity_test_and_the_prediction_gate_keep_a_box_out_of_the_pose() {
    let path =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/unknown_movers_close.toml");
    let mut synth = SynthConfig::load(&path).unwrap();
    synth.sequence.frames = 90;
    let base = common::temp_dir("dop-rigidity");
    let seq = base.join("seq");
    generate(&synth, &seq, false).unwrap();
    let run = |rigidity: bool, gate: bool, name: &str| {
        let mut config = Config::default();
        config.detector.source = Source::None;
        config.global.enabled = false;
        if !rigidity {
            config.dop.rigidity_sigmas = 0.0;
        }
        if !gate {
            config.tracking.prediction_gate_share = 0.0;
        }
        run_with(&seq, &config, &base.join(name))
    };
    let neither = run(false, false, "neither");
    let rigidity = run(true, false, "rigidity");
    let gate = run(false, true, "gate");
    let both = run(true, true, "both");
    let rmse = |r: &RunReport| r.ate.as_ref().unwrap().ape.statistics.rmse;
    let moved = |r: &RunReport| -> usize {
        let frames = r.frames.to_vec().unwrap();
        frames.iter().map(|f| f.tracking.rigidity_outliers).sum()
    };
    eprintln!(
        "ATE RMSE: neither {:.4} m, rigidity test {:.4} m ({} points found moved), \
         prediction gate {:.4} m, both {:.4} m",
        rmse(&neither),
        rmse(&rigidity),
        moved(&rigidity),
        rmse(&gate),
        rmse(&both)
    );
    assert_eq!(moved(&neither), 0);
    assert!(moved(&rigidity) > 0 && moved(&both) > 0);
    assert!(
        rmse(&neither) > 0.05,
        "the box no longer drags the pose: {}",
        rmse(&neither)
    );
    for (name, report) in [
        ("rigidity test", &rigidity),
        ("prediction gate", &gate),
        ("both", &both),
    ] {
        assert!(rmse(report) < 0.03, "with the {name}: {} m", rmse(report));
    }
}
