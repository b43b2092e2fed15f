//! `dopslam synth` on the static room: determinism, readability through the TUM
//! reader, and depth consistent with the ground-truth poses and the scene.

use crate::common;

use std::path::{Path, PathBuf};

use dopslam::io::sequence::{FrameImages, Sequence};
use dopslam::io::tum::{TumOptions, TumSequence};
use dopslam::synth::writer::World;
use dopslam::synth::{generate, SynthConfig};

fn small_config(frames: usize) -> SynthConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/static_room.toml");
    let mut config = SynthConfig::load(&path).unwrap();
    config.sequence.frames = frames;
    config
}

fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    for sub in ["", "rgb", "depth"] {
        let mut entries: Vec<_> = std::fs::read_dir(dir.join(sub))
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| p.is_file())
            .collect();
        entries.sort();
        for path in entries {
            let bytes = std::fs::read(&path).unwrap();
            out.push((path.strip_prefix(dir).unwrap().to_path_buf(), bytes));
        }
    }
    out
}

#[test]
fn same_seed_gives_identical_files_and_refuses_to_overwrite() {
    let base = common::temp_dir("synth-determinism");
    let config = small_config(3);
    generate(&config, &base.join("a"), false).unwrap();
    generate(&config, &base.join("b"), false).unwrap();
    assert_eq!(files(&base.join("a")), files(&base.join("b")));
    let message = generate(&config, &base.join("a"), false)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("not empty") && message.contains("--force"),
        "{message}"
    );
    generate(&config, &base.join("a"), true).unwrap();
}

#[test]
fn depth_back_projects_onto_the_scene() {
    let out = common::temp_dir("synth-consistency").child("static_room");
    let mut config = small_config(4);
    config.sensor.depth_noise = false;
    config.sensor.disparity_step = 0.0;
    generate(&config, &out, false).unwrap();
    let sequence = TumSequence::open(&out, &TumOptions::default()).unwrap();
    assert_eq!(sequence.len(), 4);
    let gt = sequence.ground_truth().unwrap().clone();
    let camera = sequence.calibration().unwrap().camera;
    // Rebuild the scene exactly as generate() did.
    let scene = World::new(&config).unwrap().scene;
    for index in 0..sequence.len() {
        let FrameImages::Rgbd { depth, .. } = sequence.load(index).unwrap().images else {
            panic!("RGB-D expected")
        };
        assert!(depth.valid_fraction() > 0.8, "{}", depth.valid_fraction());
        let world_from_camera = gt.poses[index];
        let mut worst: f64 = 0.0;
        for v in (0..camera.height).step_by(7) {
            for u in (0..camera.width).step_by(7) {
                let z = depth.at(u, v) as f64;
                if z > 0.0 {
                    let p_world = world_from_camera
                        * nalgebra::Point3::from(
                            camera.unproject(&nalgebra::Vector2::new(u as f64, v as f64), z),
                        );
                    worst = worst.max(scene.distance_to_surface(&p_world.coords));
                }
            }
        }
        // Quantisation to 1/5000 m, six-decimal timestamps and pose round trips: well under 1 mm.
        assert!(
            worst < 1e-3,
            "frame {index}: a depth pixel lands {worst} m off the surface"
        );
    }
}

#[test]
fn bad_input_is_refused() {
    let base = common::temp_dir("synth-bad");
    let path = base.join("bad.toml");
    std::fs::write(&path, "[sequence]\nframez = 3\n").unwrap();
    let message = SynthConfig::load(&path).unwrap_err().to_string();
    assert!(
        message.contains("framez") && message.contains("bad.toml"),
        "{message}"
    );
    for (text, key) in [
        ("[street]\nfollowing_cars = 2\n", "street.following_cars"),
        (
            "[stereo]\nrectification_scale_error = 0.5\n",
            "stereo.rectification_scale_error",
        ),
        ("[motion]\nstart = -3.0\n", "motion.start"),
    ] {
        std::fs::write(&path, text).unwrap();
        let message = SynthConfig::load(&path).unwrap_err().to_string();
        assert!(message.contains(key), "{text}: {message}");
    }
    let mut config = small_config(50);
    config.sequence.timing = Some(base.join("short_rgb.txt"));
    std::fs::write(
        base.join("short_rgb.txt"),
        "1.0 rgb/1.png\n1.033 rgb/2.png\n",
    )
    .unwrap();
    let message = generate(&config, &base.join("out"), false)
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("short_rgb.txt") && message.contains("2 frame times"),
        "{message}"
    );
}

#[test]
fn masks_match_the_movers_and_detections_box_them() {
    let out = common::temp_dir("synth-movers").child("walking");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/walking_xyz.toml");
    let mut config = SynthConfig::load(&path).unwrap();
    config.sequence.frames = 30;
    config.sequence.timing = None;
    config.oracle = dopslam::synth::oracle::OracleConfig::exact();
    config.sensor.depth_noise = false;
    config.sensor.disparity_step = 0.0;
    generate(&config, &out, false).unwrap();
    let sequence = TumSequence::open(&out, &TumOptions::default()).unwrap();
    let camera = sequence.calibration().unwrap().camera;
    let World {
        times,
        poses,
        scene,
        movers,
        ..
    } = World::new(&config).unwrap();
    assert_eq!(movers.len(), 2);
    let mut mover_pixels = 0;
    for index in (0..sequence.len()).step_by(5) {
        let FrameImages::Rgbd { depth, .. } = sequence.load(index).unwrap().images else {
            panic!("RGB-D expected")
        };
        let stamp = sequence.timestamp(index);
        let mask = image::open(out.join(format!("masks/{stamp:.6}.png")))
            .unwrap()
            .to_luma8();
        let json = std::fs::read_to_string(out.join(format!("detections_oracle/{stamp:.6}.json")))
            .unwrap();
        let detections: dopslam::detect::FrameDetections = serde_json::from_str(&json).unwrap();
        for v in (0..camera.height).step_by(5) {
            for u in (0..camera.width).step_by(5) {
                let z = depth.at(u, v) as f64;
                let id = mask.get_pixel(u, v)[0] as u16;
                if id > 0 {
                    let d = detections
                        .detections
                        .iter()
                        .find(|d| d.instance == Some(id))
                        .expect("a box for every visible mover");
                    assert!(
                        d.bbox[0] <= u as f32
                            && (u as f32) < d.bbox[2]
                            && d.bbox[1] <= v as f32
                            && (v as f32) < d.bbox[3]
                    );
                }
                if z <= 0.0 {
                    continue;
                }
                let p = poses[index]
                    * nalgebra::Point3::from(
                        camera.unproject(&nalgebra::Vector2::new(u as f64, v as f64), z),
                    );
                let distance = if id == 0 {
                    scene.distance_to_surface(&p.coords)
                } else {
                    mover_pixels += 1;
                    let mover = movers.iter().find(|m| m.instance == id).unwrap();
                    let cuboid = mover.cuboid_at(times[index]);
                    let single = dopslam::synth::scene::Scene {
                        room: cuboid,
                        furniture: vec![],
                        look: Default::default(),
                    };
                    single.distance_to_surface(&p.coords)
                };
                assert!(
                    distance < 1e-3,
                    "frame {index} pixel ({u}, {v}) id {id}: {distance} m off"
                );
            }
        }
    }
    assert!(
        mover_pixels > 100,
        "the people must be in view: {mover_pixels} sampled pixels"
    );
}

#[test]
fn every_preset_loads_and_validates() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth");
    let mut names = Vec::new();
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let config = SynthConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(
            Some(config.name.as_str()),
            path.file_stem().and_then(|s| s.to_str()),
            "{}",
            path.display()
        );
        names.push(config.name);
    }
    names.sort();
    assert_eq!(
        names,
        [
            "cutout_halfsphere",
            "cutout_rpy",
            "cutout_seated_leaves",
            "cutout_static",
            "cutout_xyz",
            "demo",
            "demo_walking",
            "desk_far_people",
            "fr1_xyz_room",
            "fr2_desk_room",
            "highway_kitti01",
            "loop_room",
            "loop_walking",
            "moving_chair",
            "people_from_photos",
            "revisit_a",
            "revisit_b",
            "seated_leaves",
            "sitting",
            "sitting_empty",
            "static_room",
            "street_demo",
            "street_kitti00",
            "street_kitti04",
            "street_kitti04_rig",
            "unknown_movers",
            "unknown_movers_close",
            "walking_halfsphere",
            "walking_rpy",
            "walking_static",
            "walking_xyz"
        ]
    );
}
