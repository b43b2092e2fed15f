//! ORB-SLAM2 settings files from real setups (`../shared/data/calibration`).

use crate::common;

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

/// A user's ORB-SLAM2 settings file: every key with a meaning here reaches the run
/// (`--settings` and `[dataset] settings` take one path), `report.json` records the
/// effective ORB parameters and the keys ignored, and a key given twice is refused.
#[test]
fn settings_files_set_the_orb_parameters_and_the_report_shows_them() {
    let base = common::temp_dir("settings-orb");
    let settings = base.join("my_camera.yaml");
    std::fs::write(
        &settings,
        "%YAML:1.0\nCamera.fx: 535.4\nCamera.fy: 539.2\nCamera.cx: 320.1\nCamera.cy: 247.6\n\
         Camera.width: 640\nCamera.height: 480\nCamera.fps: 20.0\nCamera.bf: 40.0\nCamera.RGB: 1\n\
         ThDepth: 45.0\nDepthMapFactor: 5000.0\nORBextractor.nFeatures: 1500\n\
         ORBextractor.scaleFactor: 1.1\nORBextractor.nLevels: 8\nORBextractor.iniThFAST: 18\n\
         ORBextractor.minThFAST: 6\nViewer.KeyFrameSize: 0.05\nMyLab.exposure: 3\n",
    )
    .unwrap();
    // The library path: a config naming the file.
    let config_file = base.join("config.toml");
    std::fs::write(
        &config_file,
        format!("[dataset]\nsettings = {:?}\n", settings.to_string_lossy()),
    )
    .unwrap();
    let config = Config::load(&config_file).unwrap();
    assert_eq!(config.orb.n_features, 1500);
    assert_eq!(config.orb.scale_factor, 1.1);
    assert_eq!((config.orb.ini_th_fast, config.orb.min_th_fast), (18, 6));
    assert_eq!(config.tracking.th_depth, 45.0);
    assert_eq!(config.tracking.max_frames_between_keyframes, 20);
    let applied = config.dataset.settings_applied.clone().unwrap();
    assert_eq!(applied.unknown, vec!["MyLab.exposure".to_string()]);
    assert!(applied
        .no_meaning
        .contains(&"Viewer.KeyFrameSize".to_string()));
    // The command line: `run --settings`.
    let seq = base.join("seq");
    common::synth_static_room(&seq, 10);
    let out = base.join("run");
    let (ok, _, err) = common::dopslam(&[
        "run",
        &seq.to_string_lossy(),
        "--out",
        &out.to_string_lossy(),
        "--settings",
        &settings.to_string_lossy(),
        "--detections",
        "none",
        "--no-dense",
        "--no-global",
        "--deterministic",
    ]);
    assert!(ok, "{err}");
    assert!(
        err.contains("MyLab.exposure") && err.contains("Viewer.KeyFrameSize"),
        "{err}"
    );
    let report: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    let setup = &report["setup"];
    assert_eq!(setup["orb"]["n_features"], 1500, "{setup}");
    assert_eq!(setup["orb"]["scale_factor"], 1.1, "{setup}");
    assert_eq!(setup["th_depth"], 45.0, "{setup}");
    assert_eq!(setup["calibration"]["camera"]["fx"], 535.4, "{setup}");
    assert_eq!(setup["settings"]["unknown"][0], "MyLab.exposure", "{setup}");
    // A key given twice names both lines.
    let twice = base.join("twice.yaml");
    std::fs::write(
        &twice,
        "%YAML:1.0\nCamera.fx: 535.4\nCamera.fy: 539.2\nCamera.cx: 320.1\nCamera.cy: 247.6\nCamera.fx: 500\n",
    )
    .unwrap();
    let error = OrbSlamSettings::read(&twice).unwrap_err().to_string();
    assert!(
        error.contains("Camera.fx") && error.contains("line 2"),
        "{error}"
    );
}
