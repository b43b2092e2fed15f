//! `dopslam eval` equals evo 1.38 on the real trajectories in `../shared/data`: every
//! statistic of APE and RPE (delta 1 frame) to 1e-6, with SE(3) and Sim(3) alignment.
//! The golden figures were computed by evo itself (`tools/evo_golden.py`).

use crate::common;

use dopslam::eval::associate::AssociationRule;
use dopslam::eval::ate::PoseRelation;
use dopslam::eval::report::{AlignMode, RpeSpec};
use dopslam::eval::rpe::DeltaUnit;
use dopslam::eval::{evaluate, EvalOptions};
use dopslam::io::trajectory::TrajectoryFormat;
use dopslam::io::Trajectory;
use serde_json::Value;

fn check(name: &str, ours: &dopslam::eval::stats::Statistics, golden: &Value, tolerance: f64) {
    for (stat, value) in ours.rows() {
        let expected = golden[stat].as_f64().unwrap();
        let allowed = tolerance * expected.abs().max(1.0);
        assert!(
            (value - expected).abs() <= allowed,
            "{name} {stat}: ours {value} evo {expected}"
        );
    }
}

#[test]
fn equals_evo_on_every_shared_pair() {
    let Some(data) = common::shared_data("equals_evo_on_every_shared_pair") else {
        return;
    };
    let golden: Value = serde_json::from_str(include_str!("golden/evo_1.38.json")).unwrap();
    for entry in golden["results"].as_array().unwrap() {
        let format = if entry["format"] == "kitti" {
            TrajectoryFormat::Kitti
        } else {
            TrajectoryFormat::Tum
        };
        let reference =
            Trajectory::read(&data.join(entry["reference"].as_str().unwrap()), format).unwrap();
        let estimate =
            Trajectory::read(&data.join(entry["estimate"].as_str().unwrap()), format).unwrap();
        let mut options = EvalOptions {
            association: if format == TrajectoryFormat::Kitti {
                AssociationRule::ByIndex
            } else {
                AssociationRule::Evo
            },
            align: if entry["align"] == "sim3" {
                AlignMode::Sim3
            } else {
                AlignMode::Se3
            },
            rpe: vec![RpeSpec {
                delta: 1.0,
                unit: DeltaUnit::Frames,
            }],
            ..EvalOptions::default()
        };
        let name = format!(
            "{} vs {} ({})",
            entry["estimate"], entry["reference"], entry["align"]
        );
        let report = evaluate(&reference, &estimate, &options).unwrap();
        assert_eq!(
            report.matched_poses as u64,
            entry["matched"].as_u64().unwrap(),
            "{name}"
        );
        check(
            &format!("{name} APE"),
            &report.ape.statistics,
            &entry["ape"],
            1e-6,
        );
        check(
            &format!("{name} RPE"),
            &report.rpe[0].statistics,
            &entry["rpe_1f"],
            1e-6,
        );
        options.rpe_relation = PoseRelation::AngleDeg;
        let report = evaluate(&reference, &estimate, &options).unwrap();
        check(
            &format!("{name} RPE deg"),
            &report.rpe[0].statistics,
            &entry["rpe_1f_deg"],
            1e-6,
        );
    }
}

/// The reference figures printed in `../shared/data/README.md` (evo 1.38, SE(3)).
#[test]
fn matches_the_readme_reference_figures() {
    let Some(data) = common::shared_data("matches_the_readme_reference_figures") else {
        return;
    };
    let cases = [
        (
            TrajectoryFormat::Tum,
            "freiburg1_xyz-groundtruth.txt",
            "freiburg1_xyz-rgbdslam.txt",
            0.013470,
            Some(0.006071),
        ),
        (
            TrajectoryFormat::Tum,
            "fr2_desk_groundtruth.txt",
            "fr2_desk_ORB.txt",
            0.008119,
            Some(0.003129),
        ),
        (
            TrajectoryFormat::Kitti,
            "KITTI_00_gt.txt",
            "KITTI_00_ORB.txt",
            1.303450,
            Some(0.600282),
        ),
        (
            TrajectoryFormat::Kitti,
            "KITTI_00_gt.txt",
            "KITTI_00_SPTAM.txt",
            3.738488,
            None,
        ),
        (
            TrajectoryFormat::Tum,
            "bonn_clip_groundtruth.txt",
            "bonn_clip_amosslam_estimate.txt",
            0.007083,
            None,
        ),
    ];
    for (format, reference, estimate, rmse, std) in cases {
        let dir = data.join("trajectories");
        let reference = Trajectory::read(&dir.join(reference), format).unwrap();
        let estimate = Trajectory::read(&dir.join(estimate), format).unwrap();
        let options = EvalOptions {
            association: if format == TrajectoryFormat::Kitti {
                AssociationRule::ByIndex
            } else {
                AssociationRule::Evo
            },
            ..EvalOptions::default()
        };
        let report = evaluate(&reference, &estimate, &options).unwrap();
        assert!(
            (report.ape.statistics.rmse - rmse).abs() < 5e-7,
            "{} vs {rmse}",
            report.ape.statistics.rmse
        );
        if let Some(std) = std {
            assert!((report.ape.statistics.std - std).abs() < 5e-7);
        }
    }
    // RPE, fr1_xyz RGBDSLAM, delta 1 frame, translation, SE(3)-aligned: 0.005764 m.
    let reference =
        Trajectory::read_tum(&data.join("trajectories/freiburg1_xyz-groundtruth.txt")).unwrap();
    let estimate =
        Trajectory::read_tum(&data.join("trajectories/freiburg1_xyz-rgbdslam.txt")).unwrap();
    let report = evaluate(&reference, &estimate, &EvalOptions::default()).unwrap();
    assert!((report.rpe[0].statistics.rmse - 0.005764).abs() < 5e-7);
}

/// KITTI's relative errors of ORB-SLAM2's stereo estimate on KITTI 00 are the figures
/// its paper reports (Mur-Artal and Tardós 2017, Table II: 0.70 %, 0.25 deg/100 m),
/// which the devkit computed.
#[test]
fn kitti_relative_errors_equal_the_published_orb_slam2_figures() {
    let Some(data) =
        common::shared_data("kitti_relative_errors_equal_the_published_orb_slam2_figures")
    else {
        return;
    };
    let read = |name: &str| {
        Trajectory::read(
            &data.join("trajectories").join(name),
            TrajectoryFormat::Kitti,
        )
        .unwrap()
    };
    let (truth, orb) = (read("KITTI_00_gt.txt"), read("KITTI_00_ORB.txt"));
    let errors = dopslam::eval::kitti_odometry::kitti_errors(&truth.poses, &orb.poses).unwrap();
    assert_eq!(errors.segments, 3283);
    assert!(
        (errors.translation_percent - 0.70).abs() < 0.005,
        "{errors:?}"
    );
    assert!(
        (errors.rotation_deg_per_100m - 0.25).abs() < 0.005,
        "{errors:?}"
    );
}
