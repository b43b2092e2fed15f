//! The real detectors on real photos (reference boxes from the issue, computed with
//! Python's ONNX Runtime and Pillow), and their errors. Tests that need the ONNX
//! Runtime library (data/ort, from tools/setup.sh), the converted YOLOv4-tiny model
//! (data/models) or the shared data skip, saying why, when those are absent.

use crate::common;

use std::path::{Path, PathBuf};

use dopslam::detect::onnx::{runtime_library, OnnxDetector, PoolModel};
use dopslam::detect::yolo::Layout;
use dopslam::detect::{DetectError, Detection, Detector, DetectorConfig, Model, Models, Source};

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

fn library() -> Option<PathBuf> {
    let path = runtime_library(Some(&repo("data/ort/libonnxruntime.so")));
    if path.is_file() {
        Some(path)
    } else {
        eprintln!(
            "skipping: no ONNX Runtime library at {} (bash tools/setup.sh installs it)",
            path.display()
        );
        None
    }
}

/// `(model file, layout)` of both models where present.
fn models(shared: &Path) -> Vec<(PathBuf, Layout)> {
    let mut found = Vec::new();
    for (path, layout) in [
        (repo("data/models/yolov4-tiny.onnx"), Layout::Yolov4),
        (shared.join("../models/yolox_nano.onnx"), Layout::Yolox),
        (
            shared.join("../models/deimv2_hgnetv2_femto_coco.onnx"),
            Layout::Deimv2,
        ),
    ] {
        if path.is_file() {
            found.push((path, layout));
        } else {
            eprintln!("skipping {}: not present", path.display());
        }
    }
    found
}

fn load(path: &Path, layout: Layout, library: &Path) -> OnnxDetector {
    OnnxDetector::load(path, layout, library, 1).unwrap()
}

fn detect(detector: &mut OnnxDetector, image: &Path) -> Vec<Detection> {
    let image = image::open(image).unwrap().to_rgb8();
    detector.detect(0.0, &image).unwrap()
}

/// Checks a reference detection: a detection of the class within 3 px and 0.01.
fn assert_found(found: &[Detection], class: &str, score: f32, bbox: Option<[f32; 4]>) {
    let hit = found.iter().any(|d| {
        d.class == class
            && (d.score - score).abs() <= 0.01
            && bbox.is_none_or(|b| d.bbox.iter().zip(b).all(|(x, y)| (x - y).abs() <= 3.0))
    });
    assert!(hit, "{class} {score} {bbox:?} not in {found:#?}");
}

#[test]
fn both_models_reproduce_the_reference_boxes_on_bus_jpg() {
    let Some(shared) = common::shared_data("bus.jpg references") else {
        return;
    };
    let Some(library) = library() else { return };
    let bus = shared.join("frames/photos/bus.jpg");
    for (path, layout) in models(&shared) {
        let found = detect(&mut load(&path, layout, &library), &bus);
        match layout {
            Layout::Yolov4 => {
                assert_found(&found, "person", 0.99, Some([52.0, 392.0, 221.0, 909.0]));
                assert_found(&found, "person", 0.90, Some([673.0, 380.0, 809.0, 875.0]));
                assert_found(&found, "person", 0.89, Some([214.0, 409.0, 350.0, 847.0]));
                assert_found(&found, "bus", 0.74, Some([0.0, 170.0, 707.0, 780.0]));
            }
            Layout::Yolox => {
                assert_found(&found, "bus", 0.91, None);
                assert_found(&found, "person", 0.85, Some([56.0, 388.0, 211.0, 900.0]));
                assert_found(&found, "person", 0.82, Some([218.0, 404.0, 350.0, 855.0]));
                assert_found(&found, "person", 0.68, Some([682.0, 447.0, 810.0, 876.0]));
            }
            Layout::Deimv2 => {
                // Python's ONNX Runtime 1.23 with Pillow's bilinear resize: the same
                // boxes within 1 px.
                assert_found(&found, "bus", 0.88, Some([24.0, 231.0, 804.0, 730.0]));
                assert_found(&found, "person", 0.86, Some([46.0, 390.0, 236.0, 906.0]));
                assert_found(&found, "person", 0.85, Some([668.0, 396.0, 810.0, 879.0]));
                assert_found(&found, "person", 0.82, Some([221.0, 405.0, 350.0, 858.0]));
            }
        }
        if layout == Layout::Deimv2 {
            // Also the man cut by the left border (and, at 0.30 exactly, a dog there).
            let people = found.iter().filter(|d| d.class == "person").count();
            assert_eq!(people, 4, "{found:#?}");
        } else {
            assert_eq!(found.len(), 4, "{found:#?}");
        }
    }
}

#[test]
fn every_model_finds_both_people_in_the_real_walking_frame() {
    let Some(shared) = common::shared_data("TUM walking frame") else {
        return;
    };
    let Some(library) = library() else { return };
    let frame = shared.join("frames/tum/fr3_walking_xyz_1341846313.553992.png");
    // Also YOLOv4-tiny at 320x256, the default network size.
    let mut all = models(&shared);
    let small = repo("data/models/yolov4-tiny-320x256.onnx");
    if small.is_file() {
        all.push((small, Layout::Yolov4));
    }
    for (path, layout) in all {
        let found = detect(&mut load(&path, layout, &library), &frame);
        let people: Vec<&Detection> = found.iter().filter(|d| d.class == "person").collect();
        assert_eq!(people.len(), 2, "{layout:?}: {people:#?}");
        // One on each side of the image (the two walkers).
        assert!(
            people.iter().any(|p| p.bbox[2] < 320.0) && people.iter().any(|p| p.bbox[0] > 320.0)
        );
    }
}

#[test]
fn bad_models_and_a_missing_runtime_say_what_to_do() {
    let dir = common::temp_dir("detect-bad");
    // No runtime library (a fresh process, so nothing is loaded yet): the message
    // names the file and the fix, and the exit status is non-zero.
    let config = dir.join("config.toml");
    std::fs::write(
        &config,
        format!(
            "[detector]\nort_library = \"{}\"\n",
            dir.join("libonnxruntime.so").display()
        ),
    )
    .unwrap();
    let image = dir.join("blank.png");
    image::RgbImage::new(64, 48).save(&image).unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_dopslam"))
        .args(["detect", image.to_str().unwrap(), "--config"])
        .arg(&config)
        .arg("--out")
        .arg(dir.join("out"))
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(!output.status.success());
    assert!(
        stderr.contains("tools/setup.sh")
            && stderr.contains("libonnxruntime.so")
            && stderr.contains("is missing"),
        "{stderr}"
    );
    let Some(library) = library() else { return };
    let Some(shared) = common::shared_data("bad models") else {
        return;
    };
    // A corrupt model file.
    let corrupt = dir.join("corrupt.onnx");
    std::fs::write(&corrupt, b"not an onnx model").unwrap();
    let error = OnnxDetector::load(&corrupt, Layout::Yolov4, &library, 1)
        .err()
        .unwrap();
    assert!(matches!(error, DetectError::Model { .. }), "{error}");
    assert!(error.to_string().contains("corrupt.onnx"), "{error}");
    // A model whose output does not match the layout asked for.
    for (path, layout) in models(&shared) {
        if layout == Layout::Yolov4 {
            let error = OnnxDetector::load(&path, Layout::Yolox, &library, 1)
                .err()
                .unwrap();
            let text = error.to_string();
            assert!(
                text.contains("matches neither layout") && text.contains("3549"),
                "{text}"
            );
        }
    }
}

#[test]
fn missing_model_and_cache_errors_name_the_path() {
    let dir = common::temp_dir("detect-missing");
    let config = DetectorConfig {
        source: Source::Cache,
        cache_dir: Some(dir.join("nowhere")),
        ..DetectorConfig::default()
    };
    let error = config.open(None).err().unwrap().to_string();
    assert!(error.contains("nowhere"), "{error}");
    if library().is_some() {
        let config = DetectorConfig {
            source: Source::Onnx,
            models: Models::One {
                model: Model::Yolov4Tiny,
                path: Some(dir.join("absent.onnx")),
            },
            ort_library: Some(repo("data/ort/libonnxruntime.so")),
            ..DetectorConfig::default()
        };
        let error = config.open(None).err().unwrap().to_string();
        assert!(error.contains("absent.onnx"), "{error}");
    }
}

#[test]
fn auto_with_a_missing_model_is_an_error_that_names_it_and_the_fix() {
    let dir = common::temp_dir("detect-auto");
    let config = DetectorConfig {
        models: Models::One {
            model: Model::Yolov4Tiny,
            path: Some(dir.join("absent.onnx")),
        },
        ..DetectorConfig::default()
    };
    assert_eq!(config.source, Source::Auto);
    let error = config.resolved_source().unwrap_err().to_string();
    assert!(
        error.contains("absent.onnx")
            && error.contains("tools/setup.sh")
            && error.contains("doctor"),
        "{error}"
    );
    assert!(
        config.open(None).is_err(),
        "never a silent run without detections"
    );
    // An explicit source is taken as it is.
    let explicit = DetectorConfig {
        source: Source::Oracle,
        ..config.clone()
    };
    assert_eq!(explicit.resolved_source().unwrap(), Source::Oracle);
    let none = DetectorConfig {
        source: Source::None,
        ..config
    };
    assert!(none.open(None).unwrap().is_none());
}

/// `dopslam detect IMAGE` writes the per-image JSON (the detection cache's format) and
/// prints the detections as JSON with `--json`.
#[test]
fn detect_writes_json_for_an_image() {
    let (Some(_), Some(data)) = (
        library(),
        common::shared_data("detect_writes_json_for_an_image"),
    ) else {
        return;
    };
    // The default model files (what `dopslam detect` loads without --model-path).
    for model in DetectorConfig::default().model_files() {
        if !repo(&model.to_string_lossy()).is_file() {
            eprintln!(
                "skipping: no {} (bash tools/setup.sh converts it)",
                model.display()
            );
            return;
        }
    }
    let image = data.join("frames/photos/bus.jpg");
    let out = common::temp_dir("detect-json");
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_dopslam"))
        .args([
            "detect",
            &image.to_string_lossy(),
            "--json",
            "--out",
            &out.to_string_lossy(),
        ])
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let printed: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let first = &printed[0];
    assert_eq!(first["name"], "bus");
    assert!(first["detections"]
        .as_array()
        .unwrap()
        .iter()
        .any(|d| d["class"] == "person"));
    let written: dopslam::detect::FrameDetections =
        serde_json::from_str(&std::fs::read_to_string(out.join("bus.json")).unwrap()).unwrap();
    assert_eq!(
        written.detections.len(),
        first["detections"].as_array().unwrap().len()
    );
    assert!(out.join("bus.png").exists());
}

/// Several networks (YOLOv4-tiny's weights at 416x416 and 320x256) pool their boxes
/// before one NMS: every box either network finds alone is in the merged result, or
/// suppressed there by a same-class box that overlaps it beyond the NMS threshold.
#[test]
fn several_networks_pool_their_boxes_before_one_nms() {
    let Some(shared) = common::shared_data("multi-scale detection") else {
        return;
    };
    let Some(library) = library() else { return };
    let files = [
        repo("data/models/yolov4-tiny.onnx"),
        repo("data/models/yolov4-tiny-320x256.onnx"),
    ];
    if let Some(absent) = files.iter().find(|f| !f.is_file()) {
        eprintln!(
            "skipping: no {} (bash tools/setup.sh converts it)",
            absent.display()
        );
        return;
    }
    let image = image::open(shared.join("frames/photos/bus.jpg"))
        .unwrap()
        .to_rgb8();
    let threshold = 0.15;
    let run = |models: &[PathBuf]| {
        let mut detector = OnnxDetector::load_all(models, Layout::Yolov4, &library, 1).unwrap();
        detector.score_threshold = threshold;
        detector.detect(0.0, &image).unwrap()
    };
    let merged = run(&files);
    let alone: Vec<Vec<Detection>> = files.iter().map(|f| run(std::slice::from_ref(f))).collect();
    assert_ne!(
        alone[0], alone[1],
        "the two sizes should see the image differently"
    );
    assert!(merged.len() <= alone[0].len() + alone[1].len());
    for d in alone.iter().flatten() {
        let kept = merged.iter().any(|m| {
            m.class_id == d.class_id
                && m.score >= d.score - 1e-6
                && (m == d || dopslam::detect::yolo::iou(&m.bbox, &d.bbox) > 0.4)
        });
        assert!(kept, "{d:?} neither kept nor suppressed in {merged:#?}");
    }
    // The merged boxes are a subset of what the two found.
    for m in &merged {
        assert!(
            alone.iter().flatten().any(|d| d == m),
            "{m:?} came from nowhere"
        );
    }
}

#[test]
fn model_path_and_model_paths_exclude_each_other_and_missing_files_are_named() {
    let dir = common::temp_dir("detect-paths");
    // The file's keys are read into one of the models, or refused.
    let error =
        toml::from_str::<DetectorConfig>("model_path = \"a.onnx\"\nmodel_paths = [\"b.onnx\"]\n")
            .unwrap_err()
            .to_string();
    assert!(
        error.contains("detector.model_path") && error.contains("model_paths"),
        "{error}"
    );
    let sizes: DetectorConfig = toml::from_str("model_paths = [\"a.onnx\", \"b.onnx\"]\n").unwrap();
    assert!(
        matches!(sizes.models, Models::Sizes { model: Model::Yolov4Tiny, ref paths } if paths.len() == 2)
    );
    // Written back as the same keys.
    let written = toml::to_string(&sizes).unwrap();
    assert_eq!(toml::from_str::<DetectorConfig>(&written).unwrap(), sizes);
    let present = dir.join("present.onnx");
    std::fs::write(&present, b"x").unwrap();
    let several = DetectorConfig {
        models: Models::Sizes {
            model: Model::Yolov4Tiny,
            paths: vec![present.clone(), dir.join("second-absent.onnx")],
        },
        ort_library: Some(present.clone()),
        ..DetectorConfig::default()
    };
    assert!(several.validate().is_ok());
    assert_eq!(several.model_files().len(), 2);
    let error = several.resolved_source().unwrap_err().to_string();
    assert!(error.contains("second-absent.onnx"), "{error}");
    // The default is YOLOv4-tiny at 320x256, in the runtime data directory.
    let default = DetectorConfig::default().model_files();
    assert_eq!(default.len(), 1);
    assert!(
        default[0].ends_with("models/yolov4-tiny-320x256.onnx"),
        "{}",
        default[0].display()
    );
}

/// DEIMv2-femto (end to end: two inputs, labels / boxes / scores out) finds the bus and
/// the four people of bus.jpg, boxes in image pixels; pooled with YOLOv4-tiny at its
/// own threshold, every person either finds is in the pool's result after one NMS,
/// and the report names each model's time.
#[test]
fn deimv2_finds_the_people_of_bus_jpg_and_pools_with_yolo() {
    let Some(shared) = common::shared_data("DEIMv2 on bus.jpg") else {
        return;
    };
    let Some(library) = library() else { return };
    let deim = shared.join("../models/deimv2_hgnetv2_femto_coco.onnx");
    let yolo = repo("data/models/yolov4-tiny-320x256.onnx");
    if let Some(absent) = [&deim, &yolo].into_iter().find(|f| !f.is_file()) {
        eprintln!("skipping: no {}", absent.display());
        return;
    }
    let image = image::open(shared.join("frames/photos/bus.jpg"))
        .unwrap()
        .to_rgb8();
    let pooled = |models: &[(PathBuf, Layout, f32)]| {
        let pool: Vec<PoolModel> = models
            .iter()
            .map(|(path, layout, t)| PoolModel {
                path: path.clone(),
                layout: *layout,
                score_threshold: Some(*t),
            })
            .collect();
        let mut detector = OnnxDetector::load_pool(&pool, &library, 1).unwrap();
        let found = detector.detect(0.0, &image).unwrap();
        (found, detector.model_times())
    };
    let (alone, _) = pooled(&[(deim.clone(), Layout::Deimv2, 0.3)]);
    let people: Vec<&Detection> = alone.iter().filter(|d| d.class == "person").collect();
    assert!(people.len() >= 4, "{alone:#?}");
    assert_found(&alone, "bus", 0.88, Some([24.0, 231.0, 804.0, 730.0]));
    assert_found(&alone, "person", 0.86, Some([46.0, 390.0, 236.0, 906.0]));
    let (yolo_alone, _) = pooled(&[(yolo.clone(), Layout::Yolov4, 0.1)]);
    let (both, times) = pooled(&[(yolo, Layout::Yolov4, 0.1), (deim, Layout::Deimv2, 0.3)]);
    assert_eq!(times.len(), 2);
    assert!(times
        .iter()
        .all(|(name, ms)| name.ends_with(".onnx") && *ms > 0.0));
    for person in alone
        .iter()
        .chain(&yolo_alone)
        .filter(|d| d.class == "person")
    {
        let kept = both.iter().any(|b| {
            b.class == "person" && dopslam::detect::yolo::iou(&b.bbox, &person.bbox) > 0.45
        });
        assert!(kept, "{person:?} lost in the pool: {both:#?}");
    }
}

/// A pool in the config: its files are what the source needs, thresholds are checked,
/// and it does not go with model_path.
#[test]
fn a_pool_config_names_its_files_and_is_checked() {
    let config: DetectorConfig = toml::from_str(
        "[[pool]]\nmodel = \"yolov4-tiny\"\nscore_threshold = 0.1\n[[pool]]\nmodel = \"deimv2-femto\"\npath = \"/nowhere/d.onnx\"\n",
    )
    .unwrap();
    config.validate().unwrap();
    let files = config.model_files();
    assert_eq!(files.len(), 2);
    assert_eq!(files[1], PathBuf::from("/nowhere/d.onnx"));
    let models = config.pool_models();
    assert_eq!(models[0].score_threshold, Some(0.1));
    // DEIMv2's own threshold when the entry gives none.
    assert_eq!(models[1].score_threshold, Some(0.3));
    assert_eq!(models[1].layout, Layout::Deimv2);
    let mut bad = config.clone();
    if let Models::Pool(pool) = &mut bad.models {
        pool[0].score_threshold = Some(1.5);
    }
    assert!(bad.validate().unwrap_err().key == "detector.pool[0].score_threshold");
    let mut factor = config.clone();
    factor.border_score_factor = -0.5;
    assert!(factor.validate().unwrap_err().key == "detector.border_score_factor");
    let both = toml::from_str::<DetectorConfig>(
        "model_path = \"/x.onnx\"\n[[pool]]\nmodel = \"yolov4-tiny\"\n",
    )
    .unwrap_err()
    .to_string();
    assert!(both.contains("detector.pool is set beside"), "{both}");
    let mut onnx = config;
    onnx.source = Source::Onnx;
    let error = onnx.resolved_source().unwrap_err().to_string();
    assert!(error.contains("/nowhere/d.onnx"), "{error}");
}

/// `[detector] border_score_factor`: with it, the boxes of the plain threshold are all
/// still there, and every box more touches the image's left or right border, is at
/// most 0.3 of the image wide and scores between the two thresholds (people cut by the
/// border, in crops of real photos that cut them).
#[test]
fn border_boxes_are_kept_from_the_lower_threshold_only() {
    let Some(shared) = common::shared_data("border score threshold") else {
        return;
    };
    let Some(library) = library() else { return };
    let model = repo("data/models/yolov4-tiny-320x256.onnx");
    if !model.is_file() {
        eprintln!(
            "skipping: no {} (bash tools/setup.sh converts it)",
            model.display()
        );
        return;
    }
    let (threshold, factor) = (0.15, 0.5);
    let mut detector = load(&model, Layout::Yolov4, &library);
    detector.score_threshold = threshold;
    let mut more = 0;
    for name in ["bus.jpg", "zidane.jpg", "person.jpg"] {
        let photo = image::open(shared.join("frames/photos").join(name))
            .unwrap()
            .to_rgb8();
        let (w, h) = photo.dimensions();
        // Windows of two thirds of the width, from the left to the right edge.
        for step in 0..5 {
            let x = step * (w / 3) / 4;
            let crop = image::imageops::crop_imm(&photo, x, 0, 2 * w / 3, h).to_image();
            detector.border_score_factor = 1.0;
            let plain = detector.detect(0.0, &crop).unwrap();
            detector.border_score_factor = factor;
            let with = detector.detect(0.0, &crop).unwrap();
            for d in &plain {
                assert!(with.contains(d), "{name} at {x}: {d:?} lost");
            }
            for d in with.iter().filter(|d| !plain.contains(d)) {
                more += 1;
                let width = crop.width() as f32;
                let touches = d.bbox[0] <= 2.0 || d.bbox[2] >= width - 2.0;
                let narrow = d.bbox[2] - d.bbox[0] <= 0.3 * width;
                assert!(
                    touches && narrow && d.score >= threshold * factor && d.score < threshold,
                    "{name} at {x}: {d:?}"
                );
            }
        }
    }
    assert!(more > 0, "no crop gave a border box between the thresholds");
}
