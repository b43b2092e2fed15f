//! The DOP model in the tracking pass, on a short synthetic walking sequence with the
//! oracle detections: it must beat ORB-SLAM2 behaviour (--no-dop) clearly, and the
//! naive box masking must also run to the end.

mod common;

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
    let sequence = open_sequence(seq, &config).unwrap();
    let options = RunOptions {
        deterministic: true,
        sequence_dir: Some(seq.to_path_buf()),
        ..RunOptions::default()
    };
    run_sequence(sequence.as_ref(), &config, out, &options).unwrap()
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
    assert!(off.frames.iter().all(|f| f.tracking.dynamic_keypoints == 0));
    assert!(mask.detection.map_points_removed > 0);
}
