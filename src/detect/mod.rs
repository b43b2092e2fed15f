//! Object detections: the one JSON format shared by the detector cache, the oracle
//! detections that `synth` writes, and detections brought from other detectors.
//!
//! A file per frame holds `{"timestamp": t, "detections": [{"class": "person",
//! "class_id": 0, "score": 0.97, "box": [x1, y1, x2, y2], "instance": 3}]}` with boxes in
//! image pixels (x2, y2 exclusive) and `instance` present only for oracle detections.

pub mod coco;
pub mod draw;
pub mod job;
pub mod models;
pub mod onnx;
pub mod tiles;
pub mod yolo;

use std::path::{Path, PathBuf};

use image::RgbImage;
use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::checks::{self, non_negative, unit_interval, BadValue};
use crate::io::data_dir::{DataDir, INSTALL_HINT};
pub use models::{Models, PoolEntry};
use yolo::Layout;

/// What can go wrong when detecting.
#[derive(Debug, Error)]
pub enum DetectError {
    #[error("detector model {path}: {message}")]
    /// The model file cannot be loaded or run.
    Model {
        /// The model file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    #[error("{0}")]
    /// ONNX Runtime cannot be loaded or started.
    Runtime(String),
    /// Files an ONNX source needs that are not there, each with what it is.
    #[error("{}: {hint}", missing_list(.0), hint = INSTALL_HINT)]
    Missing(Vec<(&'static str, PathBuf)>),
    #[error("detection cache {path}: {message}")]
    /// A detection cache cannot be read.
    Cache {
        /// The cache folder or file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    #[error("detector config: {0}")]
    /// The detector's settings have no meaning.
    Config(String),
}

/// `the X /a is missing; the Y /b is missing`.
fn missing_list(missing: &[(&'static str, PathBuf)]) -> String {
    missing
        .iter()
        .map(|(what, path)| format!("the {what} {} is missing", path.display()))
        .collect::<Vec<_>>()
        .join("; ")
}

/// A source of detections for a frame: a model, a cache, or the synthetic oracle.
pub trait Detector: Send {
    /// The detections in `image`, taken at `timestamp`.
    fn detect(&mut self, timestamp: f64, image: &RgbImage) -> Result<Vec<Detection>, DetectError>;

    /// Each model's time on the last image (name, milliseconds), for a detector that
    /// runs several.
    fn model_times(&self) -> Vec<(String, f64)> {
        Vec::new()
    }
}

/// Where detections come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
pub enum Source {
    /// The ONNX model when the run uses detections (`--dop`, `--mask-boxes`); none
    /// with `--no-dop` (the default). A missing model or runtime is an error.
    Auto,
    /// No detection (ORB-SLAM2 behaviour).
    None,
    /// The ONNX model.
    Onnx,
    /// A folder of per-frame JSON files (`cache_dir`), from an earlier run or any detector.
    Cache,
    /// The ground-truth boxes `dopslam synth` writes (`detections_oracle/` in the sequence).
    Oracle,
}

/// Which model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Model {
    /// The paper's family: YOLOv4-tiny converted from Darknet by tools/setup.sh.
    Yolov4Tiny,
    /// YOLOX-nano (Apache-2.0): `tools/setup.sh` installs it from `../shared/models`
    /// where that folder exists, else the user brings the file.
    YoloxNano,
    /// DEIMv2-femto (Apache-2.0, end to end, 416x416): `tools/setup.sh` installs it
    /// (sha256 checked) from `../shared/models` or its public source.
    Deimv2Femto,
}

impl Model {
    /// How the model's output tensor is laid out.
    pub fn layout(self) -> Layout {
        match self {
            Model::Yolov4Tiny => Layout::Yolov4,
            Model::YoloxNano => Layout::Yolox,
            Model::Deimv2Femto => Layout::Deimv2,
        }
    }

    /// The model's own score threshold, where the detector's (tuned for YOLOv4-tiny)
    /// does not fit it: DEIMv2's scores put person boxes on people-free frames below
    /// 0.3.
    pub fn own_threshold(self) -> Option<f32> {
        match self {
            Model::Deimv2Femto => Some(0.3),
            Model::Yolov4Tiny | Model::YoloxNano => None,
        }
    }

    /// The model files used when neither `model_path` nor `model_paths` is set.
    /// YOLOv4-tiny runs at 320x256, not its cfg's 416x416: squeezed to that size the
    /// person who passes close to the camera (half the image, cut by its border) looks
    /// like the people COCO has, and is found (cut-out presets: person recall on
    /// keyframes 0.79-0.88 -> 0.87-0.91 in half the time; README "Detector").
    /// They live in the runtime data directory ([`crate::io::data_dir`]).
    pub fn default_paths(self) -> Vec<PathBuf> {
        let data = DataDir::locate();
        match self {
            Model::Yolov4Tiny => vec![data.file("models/yolov4-tiny-320x256.onnx")],
            Model::YoloxNano => vec![data.file("models/yolox_nano.onnx")],
            Model::Deimv2Femto => vec![data.file("models/deimv2_hgnetv2_femto_coco.onnx")],
        }
    }
}

/// The `[detector]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "models::DetectorFile", into = "models::DetectorFile")]
pub struct DetectorConfig {
    /// Where detections come from (a model, a cache, the oracle, none).
    pub source: Source,
    /// The models an ONNX source runs (the file's `model`, `model_path`,
    /// `model_paths` and `[[detector.pool]]` keys, [`models::DetectorFile`]).
    pub models: Models,
    /// The ONNX Runtime library (default: `ORT_DYLIB_PATH`, else `ort/libonnxruntime.so`
    /// in the data directory).
    pub ort_library: Option<PathBuf>,
    /// ONNX Runtime intra-op threads.
    pub threads: usize,
    /// Boxes below this score are dropped.
    pub score_threshold: f32,
    /// A box touching the image's left or right border, at most 0.3 of the image wide,
    /// is kept from this share of the score threshold (each model's own in a pool): a
    /// person cut by the border scores lower. 1 holds border boxes to the same
    /// threshold.
    pub border_score_factor: f32,
    /// Intersection over union above which NMS drops the weaker box.
    pub nms_threshold: f32,
    /// The folder of a detection cache (`source = "cache"`).
    pub cache_dir: Option<PathBuf>,
    /// Classes that move (COCO names); the DOP model treats their boxes as dynamic.
    pub dynamic_classes: Vec<String>,
    /// Classes known to be static (their boxes can refine dynamic ones).
    pub static_classes: Vec<String>,
    /// In real-time mode the `oracle` and `cache` sources answer this late (ms), as a
    /// real detector would (YOLOv4-tiny at 320x256: 26 ms a keyframe alone on 2 cores,
    /// 44-62 ms beside tracking); 0 answers at once.
    pub simulated_latency_ms: f64,
    /// An ONNX source also runs on `tiles` x `tiles` overlapping tiles of each image
    /// and merges all boxes by one NMS ([`tiles::Tiled`]): far people reach the
    /// network larger, at `tiles`² + 1 inferences an image. 1: the whole image only.
    pub tiles: u32,
}

impl Default for DetectorConfig {
    fn default() -> Self {
        Self {
            source: Source::Auto,
            models: Models::One {
                model: Model::Yolov4Tiny,
                path: None,
            },
            ort_library: None,
            threads: 1,
            score_threshold: 0.15,
            border_score_factor: 0.5,
            nms_threshold: 0.45,
            cache_dir: None,
            dynamic_classes: ["person", "bicycle", "car", "motorcycle", "bus", "truck"]
                .map(String::from)
                .to_vec(),
            static_classes: Vec::new(),
            simulated_latency_ms: 60.0,
            tiles: 1,
        }
    }
}

impl DetectorConfig {
    /// Checks thresholds and class names.
    pub fn validate(&self) -> Result<(), BadValue> {
        checks::each(
            "detector",
            unit_interval,
            &[
                ("score_threshold", self.score_threshold),
                ("border_score_factor", self.border_score_factor),
                ("nms_threshold", self.nms_threshold),
            ],
        )?;
        non_negative("detector.simulated_latency_ms", self.simulated_latency_ms)?;
        tiles::check_grid("detector.tiles", self.tiles)?;
        self.models.validate()?;
        for (key, classes) in [
            ("detector.dynamic_classes", &self.dynamic_classes),
            ("detector.static_classes", &self.static_classes),
        ] {
            coco::check_class_names(key, classes)?;
        }
        Ok(())
    }

    /// The model files this config uses.
    pub fn model_files(&self) -> Vec<PathBuf> {
        self.pool_models().into_iter().map(|m| m.path).collect()
    }

    /// The files an ONNX source needs (the models, then the runtime library), each
    /// with what it is.
    pub fn onnx_files(&self) -> Vec<(PathBuf, &'static str)> {
        self.model_files()
            .into_iter()
            .map(|path| (path, "detector model"))
            .chain([(
                onnx::runtime_library(self.ort_library.as_deref()),
                "ONNX Runtime library",
            )])
            .collect()
    }

    /// The source `auto` stands for: the ONNX model. A missing model or runtime library
    /// of an ONNX source is an error that names the file and the fix (never a silent
    /// run without detections: `source = "none"` / `--detections none` is the way).
    pub fn resolved_source(&self) -> Result<Source, DetectError> {
        let source = match self.source {
            Source::Auto => Source::Onnx,
            other => other,
        };
        if source == Source::Onnx {
            let missing: Vec<(&'static str, PathBuf)> = self
                .onnx_files()
                .into_iter()
                .filter(|(path, _)| !path.is_file())
                .map(|(path, what)| (what, path))
                .collect();
            if !missing.is_empty() {
                return Err(DetectError::Missing(missing));
            }
        }
        Ok(source)
    }

    /// What this detector is, in one line (source, model files, tiles, thresholds): a
    /// cache of its boxes is reused only by the same detector.
    pub fn describe(&self) -> String {
        match self.source {
            Source::Onnx | Source::Auto => {
                let models: Vec<String> = self
                    .pool_models()
                    .iter()
                    .map(|m| {
                        format!(
                            "{} ({:?}, threshold {:?})",
                            m.path.display(),
                            m.layout,
                            m.score_threshold
                        )
                    })
                    .collect();
                format!(
                    "onnx: {}; tiles {}; score_threshold {}; border_score_factor {}; nms_threshold {}",
                    models.join(", "),
                    self.tiles,
                    self.score_threshold,
                    self.border_score_factor,
                    self.nms_threshold
                )
            }
            Source::Cache => format!("cache: {:?}", self.cache_dir),
            Source::Oracle => "oracle".into(),
            Source::None => "none".into(),
        }
    }

    /// The models an ONNX source runs, each file with its layout and threshold.
    pub fn pool_models(&self) -> Vec<onnx::PoolModel> {
        self.models.files()
    }

    /// The latency added to the source's answers in real-time mode.
    pub fn latency(&self) -> std::time::Duration {
        match self.source {
            Source::Oracle | Source::Cache => {
                std::time::Duration::from_secs_f64(self.simulated_latency_ms / 1e3)
            }
            _ => std::time::Duration::ZERO,
        }
    }

    /// Opens the configured source; `sequence` is the sequence folder (for the oracle).
    /// `None` when detection is off.
    pub fn open(&self, sequence: Option<&Path>) -> Result<Option<Box<dyn Detector>>, DetectError> {
        Ok(Some(match self.resolved_source()? {
            Source::None | Source::Auto => return Ok(None),
            Source::Onnx => {
                let mut detector = onnx::OnnxDetector::load_pool(
                    &self.pool_models(),
                    &onnx::runtime_library(self.ort_library.as_deref()),
                    self.threads,
                )?;
                detector.score_threshold = self.score_threshold;
                detector.border_score_factor = self.border_score_factor;
                detector.nms_threshold = self.nms_threshold;
                if self.tiles > 1 {
                    Box::new(tiles::Tiled::new(
                        Box::new(detector),
                        self.tiles,
                        TILE_OVERLAP,
                        self.nms_threshold,
                    ))
                } else {
                    Box::new(detector)
                }
            }
            Source::Cache => {
                let dir = self.cache_dir.clone().ok_or_else(|| {
                    DetectError::Config("source = \"cache\" needs cache_dir".into())
                })?;
                Box::new(CacheDetector::open(&dir)?)
            }
            Source::Oracle => {
                let dir = sequence
                    .ok_or_else(|| {
                        DetectError::Config("the oracle needs a sequence folder".into())
                    })?
                    .join("detections_oracle");
                Box::new(CacheDetector::open(&dir)?)
            }
        }))
    }
}

/// How much neighbouring tiles overlap (a share of a tile's side): a person of up to
/// a fifth of the image's width lies whole in some tile of a 2 x 2 grid.
const TILE_OVERLAP: f32 = 0.25;

/// The cache file name of a frame: its timestamp with 6 decimals.
pub fn cache_file(dir: &Path, timestamp: f64) -> PathBuf {
    dir.join(format!("{timestamp:.6}.json"))
}

/// Detections read back from a folder of per-frame JSON files.
pub struct CacheDetector {
    dir: PathBuf,
}

impl CacheDetector {
    /// Opens the cache folder `dir` (one JSON file per frame).
    pub fn open(dir: &Path) -> Result<Self, DetectError> {
        if !dir.is_dir() {
            return Err(DetectError::Cache {
                path: dir.to_path_buf(),
                message: "no such folder".into(),
            });
        }
        Ok(Self {
            dir: dir.to_path_buf(),
        })
    }
}

impl Detector for CacheDetector {
    fn detect(&mut self, timestamp: f64, _image: &RgbImage) -> Result<Vec<Detection>, DetectError> {
        Ok(read_cache_file(&cache_file(&self.dir, timestamp))?.detections)
    }
}

/// Reads one frame's cached detections.
pub fn read_cache_file(path: &Path) -> Result<FrameDetections, DetectError> {
    let text = std::fs::read_to_string(path).map_err(|e| DetectError::Cache {
        path: path.to_path_buf(),
        message: format!("cannot read: {e}"),
    })?;
    serde_json::from_str(&text).map_err(|e| DetectError::Cache {
        path: path.to_path_buf(),
        message: format!("not a detections file: {e}"),
    })
}

/// Writes one frame's detections into a cache folder (atomically).
pub fn write_cache(dir: &Path, frame: &FrameDetections) -> Result<(), DetectError> {
    let path = cache_file(dir, frame.timestamp);
    let text = serde_json::to_string_pretty(frame).expect("detections serialise");
    std::fs::create_dir_all(dir)
        .and_then(|_| {
            crate::io::atomic::write_atomic(&path, text.as_bytes()).map_err(std::io::Error::other)
        })
        .map_err(|e| DetectError::Cache {
            path,
            message: format!("cannot write: {e}"),
        })
}

/// One detected object.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Detection {
    /// COCO class name.
    pub class: String,
    /// COCO class index (0 = person).
    pub class_id: u32,
    /// The class score, in [0, 1].
    pub score: f32,
    /// `[x1, y1, x2, y2]` in image pixels.
    #[serde(rename = "box")]
    pub bbox: [f32; 4],
    /// The ground-truth instance id (oracle detections only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub instance: Option<u16>,
}

/// The detections of one frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameDetections {
    /// The frame's time, seconds.
    pub timestamp: f64,
    /// Its boxes.
    pub detections: Vec<Detection>,
}
