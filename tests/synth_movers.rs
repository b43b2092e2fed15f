//! Synth movers beyond boxes and the optional sensor effects: real cut-outs on
//! billboards, pushed objects of static classes, stereo output in the KITTI layout,
//! motion blur and exposure drift.

use crate::common;

use std::path::Path;

use dopslam::detect::FrameDetections;
use dopslam::io::kitti::KittiSequence;
use dopslam::io::sequence::{FrameImages, Sequence};
use dopslam::synth::scene::Shape;
use dopslam::synth::writer::World;
use dopslam::synth::{generate, SynthConfig};
use nalgebra::{Point3, Vector2};

fn preset(name: &str, frames: usize) -> SynthConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("configs/synth/{name}.toml"));
    let mut config = SynthConfig::load(&path).unwrap();
    config.sequence.frames = frames;
    config.sequence.timing = None;
    config
}

/// Cut-out pixels lie on their billboard (exact depth), their mask pixels fall inside the
/// oracle box, and the seated cut-out is shown while the person sits.
#[test]
fn cut_outs_stand_on_billboards_with_consistent_depth_and_masks() {
    let Some(shared) = common::shared_data("cut_outs_stand_on_billboards") else {
        return;
    };
    let mut config = preset("people_from_photos", 90);
    config.people.sprite = Some(shared.join("sprites/person_0.png"));
    config.seated.sprite = Some(shared.join("sprites/person_1.png"));
    let world = World::new(&config).unwrap();
    assert_eq!(world.movers.len(), 3);
    let camera = world.camera;
    let mut checked = 0;
    for index in [0, 45, 89] {
        let rendered = world.render(index);
        let pose = world.poses[index];
        let view = world.view(world.times[index], pose);
        let boxes =
            dopslam::synth::writer::oracle_detections(&rendered.mask, camera.width, &world.movers);
        for v in (0..camera.height).step_by(4) {
            for u in (0..camera.width).step_by(4) {
                let i = (v * camera.width + u) as usize;
                let id = rendered.mask[i];
                if id == 0 {
                    continue;
                }
                let z = rendered.exact_depth.metres[i] as f64;
                let p = pose * Point3::from(camera.unproject(&Vector2::new(u as f64, v as f64), z));
                let (shape, _) = view.movers.iter().find(|(_, m)| *m == id).unwrap();
                let Shape::Billboard(board) = shape else {
                    panic!("people are billboards in this preset")
                };
                assert!(board.plane_distance(&p.coords) < 1e-4);
                let b = boxes.iter().find(|d| d.instance == Some(id)).unwrap();
                assert!(b.bbox[0] <= u as f32 && (u as f32) < b.bbox[2]);
                assert!(b.bbox[1] <= v as f32 && (v as f32) < b.bbox[3]);
                checked += 1;
            }
        }
    }
    assert!(checked > 1000, "people must be in view: {checked} pixels");
    let seated = world.movers.iter().find(|m| m.seated_at(0.0)).unwrap();
    let Shape::Billboard(board) = seated.shape_at(0.0, &world.poses[0].translation.vector) else {
        panic!("billboard expected")
    };
    assert!(board.sprite.path.ends_with("person_1.png"));
}

#[test]
fn a_missing_cut_out_is_named() {
    let mut config = preset("people_from_photos", 3);
    config.people.sprite = Some("no/such/person.png".into());
    let message = World::new(&config).err().unwrap().to_string();
    assert!(
        message.contains("no/such/person.png") && message.contains("cut-out"),
        "{message}"
    );
}

/// The pushed chair is a mover of class chair: masked, boxed and labelled.
#[test]
fn pushed_objects_carry_their_class() {
    let out = common::temp_dir("synth-chair");
    let mut config = preset("moving_chair", 20);
    config.sensor.exposure_time = 0.0;
    generate(&config, &out, false).unwrap();
    let mut chairs = 0;
    for entry in std::fs::read_dir(out.join("detections_oracle")).unwrap() {
        let text = std::fs::read_to_string(entry.unwrap().path()).unwrap();
        let frame: FrameDetections = serde_json::from_str(&text).unwrap();
        chairs += frame
            .detections
            .iter()
            .filter(|d| d.class == "chair" && d.class_id == 56)
            .count();
    }
    assert!(
        chairs >= 15,
        "the chair is in view in most frames: {chairs}"
    );
    let mut bad = preset("moving_chair", 3);
    bad.objects.class = "spaceship".into();
    let bad = bad.validate().unwrap_err();
    assert!(
        bad.key == "objects.class" && bad.problem.contains("spaceship"),
        "{bad}"
    );
}

/// Movers of no COCO class are in the masks and named in `masks/instances.txt`, but
/// get no oracle box (no detector knows them); the balloon floats at its lift; a COCO
/// class under `[[unknown]]` is an error naming the key.
#[test]
fn unknown_movers_are_masked_and_named_but_never_boxed() {
    let out = common::temp_dir("synth-unknown");
    let mut config = preset("unknown_movers", 12);
    config.sensor.exposure_time = 0.0;
    generate(&config, &out, false).unwrap();
    let classes = dopslam::io::image_files::read_instance_classes(&out.join("masks"))
        .unwrap()
        .expect("instances.txt");
    assert_eq!(
        classes,
        vec![
            (1, "person".into()),
            (2, "box".into()),
            (3, "balloon".into())
        ]
    );
    let (mut boxed, mut seen) = (
        std::collections::BTreeSet::new(),
        std::collections::BTreeSet::new(),
    );
    for entry in std::fs::read_dir(out.join("detections_oracle")).unwrap() {
        let path = entry.unwrap().path();
        let frame: FrameDetections =
            serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        boxed.extend(frame.detections.iter().filter_map(|d| d.instance));
        let stem = path.file_stem().unwrap().to_string_lossy().into_owned();
        let mask =
            dopslam::io::image_files::read_instance_mask(&out.join(format!("masks/{stem}.png")))
                .expect("a mask per frame");
        seen.extend(mask.as_raw().iter().copied().filter(|&id| id > 0));
    }
    assert!(
        seen.contains(&2) && seen.contains(&3),
        "both in view: {seen:?}"
    );
    assert!(
        boxed.iter().all(|&id| id == 1),
        "only the person is boxed: {boxed:?}"
    );
    let world = World::new(&config).unwrap();
    let (up, sign) = world.movers[0].up;
    let bottom = |m: &dopslam::synth::movers::Mover| {
        let c = m.cuboid_at(0.0);
        if sign > 0.0 {
            c.min[up]
        } else {
            -c.max[up]
        }
    };
    let lift = bottom(&world.movers[2]) - bottom(&world.movers[1]);
    assert!(
        (lift - 1.35).abs() < 1e-9,
        "the balloon floats 1.35 m up: {lift}"
    );
    let mut bad = config.clone();
    bad.unknown[0].class = "suitcase".into();
    let bad = bad.validate().unwrap_err();
    assert!(
        bad.key == "unknown.class" && bad.problem.contains("suitcase"),
        "{bad}"
    );
}

/// Stereo output reads back through the KITTI reader with the right baseline, and the
/// right image shows each point at the disparity \(f_x b / z\).
#[test]
fn stereo_pairs_follow_the_kitti_layout_and_disparity() {
    let out = common::temp_dir("synth-stereo");
    let mut config = preset("static_room", 3);
    config.stereo.baseline = 0.1;
    config.sensor.rgb_noise = 0.0;
    generate(&config, &out, false).unwrap();
    let sequence = KittiSequence::open(&out.join("kitti/sequences/00"), None).unwrap();
    assert_eq!(sequence.len(), 3);
    let calibration = sequence.calibration().unwrap();
    let bf = calibration.bf.unwrap();
    assert!((bf - 535.4 * 0.1).abs() < 1e-6, "{bf}");
    let gt = sequence.ground_truth().expect("poses/00.txt is found");
    assert!(gt.poses[0].translation.vector.norm() < 1e-9);
    let FrameImages::Stereo { left, right } = sequence.load(1).unwrap().images else {
        panic!("stereo expected")
    };
    let world = World::new(&config).unwrap();
    let exact = world.render(1).exact_depth;
    // Sum of absolute differences of 7x7 patches at the predicted disparity and one
    // 3 pixels off: the prediction wins nearly everywhere.
    let sad = |u: i64, v: i64, d: i64| -> u32 {
        let mut sum = 0;
        for dv in -3..=3 {
            for du in -3..=3 {
                let a = left.get_pixel((u + du) as u32, (v + dv) as u32)[0] as i32;
                let b = right.get_pixel((u + du - d) as u32, (v + dv) as u32)[0] as i32;
                sum += (a - b).unsigned_abs();
            }
        }
        sum
    };
    let (mut wins, mut total) = (0, 0);
    for v in (20..460).step_by(20) {
        for u in (120..620).step_by(20) {
            let z = exact.at(u, v) as f64;
            if z <= 0.0 {
                continue;
            }
            let d = (bf / z).round() as i64;
            total += 1;
            if sad(u as i64, v as i64, d) < sad(u as i64, v as i64, d + 3) {
                wins += 1;
            }
        }
    }
    assert!(total > 300 && wins * 10 >= total * 9, "{wins}/{total}");
}

/// Motion blur smooths the image of a moving camera; exposure drift changes brightness
/// by the configured gain.
#[test]
fn blur_and_exposure_change_the_colour_image_only() {
    let mut config = preset("walking_xyz", 60);
    config.sensor.rgb_noise = 0.0;
    config.motion.speed = 4.0;
    let sharp = World::new(&config).unwrap().render(30);
    config.sensor.exposure_time = 0.05;
    config.sensor.blur_samples = 5;
    let blurred = World::new(&config).unwrap().render(30);
    let gradient = |image: &image::RgbImage| -> f64 {
        let grey = image::DynamicImage::ImageRgb8(image.clone()).to_luma8();
        let mut sum = 0.0;
        for y in 0..grey.height() {
            for x in 1..grey.width() {
                sum += (grey.get_pixel(x, y)[0] as f64 - grey.get_pixel(x - 1, y)[0] as f64).abs();
            }
        }
        sum
    };
    let (g_blur, g_sharp) = (gradient(&blurred.rgb), gradient(&sharp.rgb));
    assert!(g_blur < 0.95 * g_sharp, "{g_blur} vs {g_sharp}");
    assert_eq!(
        blurred.exact_depth, sharp.exact_depth,
        "depth is not blurred"
    );
    config.sensor.exposure_time = 0.0;
    config.sensor.exposure_variation = 0.3;
    let world = World::new(&config).unwrap();
    let gain = config.sensor.gain(world.times[55]);
    assert!((gain - 1.0).abs() > 0.1, "{gain}");
    let changed = world.render(55);
    config.sensor.exposure_variation = 0.0;
    let sharp = World::new(&config).unwrap().render(55);
    let mean = |image: &image::RgbImage| {
        image.as_raw().iter().map(|&b| b as f64).sum::<f64>() / image.as_raw().len() as f64
    };
    let ratio = mean(&changed.rgb) / mean(&sharp.rgb);
    assert!((ratio - gain).abs() < 0.03, "{ratio} vs gain {gain}");
}
