//! ORB-SLAM2 settings files from real setups (`../shared/data/calibration`).

mod common;

use dopslam::config::Config;
use dopslam::io::orbslam_settings::OrbSlamSettings;

#[test]
fn reads_every_shared_settings_file() {
    let Some(data) = common::shared_data("reads_every_shared_settings_file") else {
        return;
    };
    let tum3 = OrbSlamSettings::read(&data.join("calibration/RGB-D_TUM3.yaml")).unwrap();
    assert_eq!(
        (tum3.calibration.camera.fx, tum3.calibration.camera.cy),
        (535.4, 247.6)
    );
    assert_eq!(tum3.calibration.depth_scale, Some(5000.0));
    assert_eq!(tum3.calibration.bf, Some(40.0));
    assert_eq!(tum3.orb.n_features, Some(1000));
    let kitti = OrbSlamSettings::read(&data.join("calibration/Stereo_KITTI00-02.yaml")).unwrap();
    assert_eq!(kitti.calibration.bf, Some(386.1448));
    assert_eq!(
        (
            kitti.calibration.camera.width,
            kitti.calibration.camera.height
        ),
        (1241, 376)
    );
    let mut config = Config::default();
    config
        .apply_orbslam_settings(&data.join("calibration/Stereo_KITTI00-02.yaml"))
        .unwrap();
    assert_eq!(config.orb.n_features, 2000);
    for entry in std::fs::read_dir(data.join("calibration")).unwrap() {
        let path = entry.unwrap().path();
        let settings = OrbSlamSettings::read(&path).unwrap_or_else(|e| panic!("{e}"));
        assert!(settings.calibration.camera.fx > 100.0, "{}", path.display());
    }
}

/// The settings shipped in `configs/calibration/` parse, and equal the real setups'
/// files beside the checkout where those exist (read there, never copied).
#[test]
fn shipped_settings_match_the_published_ones() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/calibration");
    let names = [
        "RGB-D_TUM1",
        "RGB-D_TUM2",
        "RGB-D_TUM3",
        "RGB-D_Bonn",
        "Stereo_KITTI00-02",
        "Stereo_KITTI03",
        "Stereo_KITTI04-12",
    ];
    for name in names {
        let ours = OrbSlamSettings::read(&dir.join(format!("{name}.yaml"))).unwrap();
        assert!(ours.calibration.camera.validate().is_ok(), "{name}");
        assert_eq!(ours.orb.n_levels, Some(8), "{name}");
    }
    let Some(data) = common::shared_data("shipped_settings_match_the_published_ones") else {
        return;
    };
    for name in names {
        let path = data.join(format!("calibration/{name}.yaml"));
        if !path.exists() {
            continue;
        }
        let theirs = OrbSlamSettings::read(&path).unwrap();
        let ours = OrbSlamSettings::read(&dir.join(format!("{name}.yaml"))).unwrap();
        assert_eq!(ours.calibration, theirs.calibration, "{name}");
        assert_eq!(ours.orb.n_features, theirs.orb.n_features, "{name}");
    }
}
