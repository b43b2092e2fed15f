//! The dataset readers on small folders laid out exactly as TUM RGB-D and KITTI
//! odometry publish them.

use crate::common;

use std::path::Path;

use dopslam::io::image_files::{depth_to_png16, DepthImage};
use dopslam::io::kitti::KittiSequence;
use dopslam::io::sequence::{frames, FrameImages, Sequence};
use dopslam::io::tum::{TumOptions, TumSequence};

fn write_tum_folder(root: &Path, frames: usize) {
    std::fs::create_dir_all(root.join("rgb")).unwrap();
    std::fs::create_dir_all(root.join("depth")).unwrap();
    let mut rgb_txt = String::from("# color images\n# file: 'test.bag'\n# timestamp filename\n");
    let mut depth_txt = String::from("# depth maps\n# file: 'test.bag'\n# timestamp filename\n");
    for i in 0..frames {
        let t_rgb = 1305031102.175304 + i as f64 / 30.0;
        let t_depth = t_rgb + 0.004;
        let rgb_name = format!("rgb/{t_rgb:.6}.png");
        let depth_name = format!("depth/{t_depth:.6}.png");
        image::RgbImage::from_pixel(8, 6, image::Rgb([i as u8, 10, 20]))
            .save(root.join(&rgb_name))
            .unwrap();
        let mut depth = DepthImage::new(8, 6);
        depth
            .metres
            .iter_mut()
            .for_each(|d| *d = 1.0 + 0.1 * i as f32);
        depth_to_png16(&depth, 5000.0)
            .save(root.join(&depth_name))
            .unwrap();
        rgb_txt += &format!("{t_rgb:.6} {rgb_name}\n");
        depth_txt += &format!("{t_depth:.6} {depth_name}\n");
    }
    std::fs::write(root.join("rgb.txt"), rgb_txt).unwrap();
    std::fs::write(root.join("depth.txt"), depth_txt).unwrap();
}

#[test]
fn tum_layout_loads_lazily_with_scaled_depth() {
    let root = common::temp_dir("tum-layout").child("rgbd_dataset_freiburg3_test");
    write_tum_folder(&root, 5);
    let sequence = TumSequence::open(&root, &TumOptions::default()).unwrap();
    assert_eq!(sequence.len(), 5);
    assert_eq!(
        sequence.calibration().unwrap().camera.fx,
        535.4,
        "fr3 intrinsics from the folder name"
    );
    let loaded: Vec<_> = frames(&sequence).collect::<Result<_, _>>().unwrap();
    match &loaded[3].images {
        FrameImages::Rgbd { rgb, depth } => {
            assert_eq!(rgb.get_pixel(0, 0)[0], 3);
            assert!((depth.at(2, 2) - 1.3).abs() < 1e-3);
        }
        FrameImages::Stereo { .. } => panic!("expected RGB-D"),
    }
    // A missing image in the middle: the error names it when that frame is loaded.
    let victim = sequence.entries()[2].rgb_path.clone();
    std::fs::remove_file(&victim).unwrap();
    assert!(sequence.load(1).is_ok());
    let message = sequence.load(2).unwrap_err().to_string();
    assert!(
        message.contains(&victim.file_name().unwrap().to_string_lossy().into_owned()),
        "{message}"
    );
}

#[test]
fn tum_layout_errors_name_the_file() {
    let root = common::temp_dir("tum-missing");
    let message = TumSequence::open(&root, &TumOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("rgb.txt") && message.contains("not found"),
        "{message}"
    );
    let message = TumSequence::open(&root.join("nope"), &TumOptions::default())
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("nope") && message.contains("TUM layout"),
        "{message}"
    );
}

#[test]
fn kitti_layout_reads_calibration_times_and_poses() {
    let base = common::temp_dir("kitti-layout");
    let root = base.join("sequences/04");
    for side in ["image_0", "image_1"] {
        std::fs::create_dir_all(root.join(side)).unwrap();
        for i in 0..3 {
            image::GrayImage::from_pixel(12, 4, image::Luma([i as u8 * 40]))
                .save(root.join(side).join(format!("{i:06}.png")))
                .unwrap();
        }
    }
    std::fs::write(
        root.join("calib.txt"),
        "P0: 7.070912e+02 0.000000e+00 6.018873e+02 0.000000e+00 0.000000e+00 7.070912e+02 1.831104e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00\n\
         P1: 7.070912e+02 0.000000e+00 6.018873e+02 -3.798145e+02 0.000000e+00 7.070912e+02 1.831104e+02 0.000000e+00 0.000000e+00 0.000000e+00 1.000000e+00 0.000000e+00\n",
    )
    .unwrap();
    std::fs::write(
        root.join("times.txt"),
        "0.000000e+00\n1.036000e-01\n2.073000e-01\n",
    )
    .unwrap();
    std::fs::create_dir_all(base.join("poses")).unwrap();
    std::fs::write(
        base.join("poses/04.txt"),
        "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0.8\n1 0 0 0 0 1 0 0 0 0 1 1.6\n",
    )
    .unwrap();
    let sequence = KittiSequence::open(&root, None).unwrap();
    assert_eq!(sequence.len(), 3);
    let calibration = sequence.calibration().unwrap();
    assert!((calibration.bf.unwrap() - 379.8145).abs() < 1e-9);
    assert_eq!(
        (calibration.camera.width, calibration.camera.height),
        (12, 4)
    );
    let gt = sequence.ground_truth().unwrap();
    assert!((gt.timestamps[2] - 0.2073).abs() < 1e-12 && (gt.path_length() - 1.6).abs() < 1e-12);
    match sequence.load(2).unwrap().images {
        FrameImages::Stereo { left, right } => {
            assert_eq!((left.get_pixel(0, 0)[0], right.width()), (80, 12))
        }
        FrameImages::Rgbd { .. } => panic!("expected stereo"),
    }
}
