//! The models an ONNX detector runs ([`Models`]: one model, one model at several sizes,
//! or a pool of models), and the `[detector]` section as the file spells it
//! ([`DetectorFile`]: `model`, `model_path`, `model_paths`, `[[detector.pool]]`), read
//! into one of them or refused when the keys contradict each other.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::onnx::PoolModel;
use super::{DetectorConfig, Model, Source};
use crate::checks::{unit_interval, BadValue};

/// One model of a pool (`[[detector.pool]]`): the model, its file (default: the
/// model's own), and its score threshold (default: the model's own, else the
/// detector's).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoolEntry {
    /// The model.
    pub model: Model,
    #[serde(default)]
    /// Its file; unset: the installed one.
    pub path: Option<PathBuf>,
    #[serde(default)]
    /// Its score threshold; unset: the detector's.
    pub score_threshold: Option<f32>,
}

impl PoolEntry {
    /// The file of this entry.
    pub fn file(&self) -> PathBuf {
        self.path
            .clone()
            .unwrap_or_else(|| self.model.default_paths().remove(0))
    }
}

/// The models an ONNX source runs on each keyframe.
#[derive(Debug, Clone, PartialEq)]
pub enum Models {
    /// One model, from its file (`model_path`; unset: the installed one).
    One {
        /// The model.
        model: Model,
        /// Its file.
        path: Option<PathBuf>,
    },
    /// One model in several files (the same weights at several input sizes, say,
    /// `model_paths`): each keyframe runs them all and one NMS merges their boxes.
    Sizes {
        /// The model.
        model: Model,
        /// Its files.
        paths: Vec<PathBuf>,
    },
    /// Several models of any families, each with its file and threshold
    /// (`[[detector.pool]]`): each keyframe runs them all and one class-wise NMS
    /// merges their boxes.
    Pool(Vec<PoolEntry>),
}

impl Models {
    /// Each file with its model's layout and own score threshold.
    pub fn files(&self) -> Vec<PoolModel> {
        let of = |model: Model, path: PathBuf| PoolModel {
            path,
            layout: model.layout(),
            score_threshold: model.own_threshold(),
        };
        match self {
            Models::One { model, path } => {
                let paths = path
                    .clone()
                    .map_or_else(|| model.default_paths(), |p| vec![p]);
                paths.into_iter().map(|p| of(*model, p)).collect()
            }
            Models::Sizes { model, paths } => paths.iter().map(|p| of(*model, p.clone())).collect(),
            Models::Pool(entries) => entries
                .iter()
                .map(|entry| PoolModel {
                    path: entry.file(),
                    layout: entry.model.layout(),
                    score_threshold: entry.score_threshold.or(entry.model.own_threshold()),
                })
                .collect(),
        }
    }

    /// The one model family, when this is not a pool.
    pub fn model(&self) -> Option<Model> {
        match self {
            Models::One { model, .. } | Models::Sizes { model, .. } => Some(*model),
            Models::Pool(_) => None,
        }
    }

    /// The files the config names (not the installed defaults), to resolve from the
    /// config's folder.
    pub fn named_paths_mut(&mut self) -> Vec<&mut PathBuf> {
        match self {
            Models::One { path, .. } => path.iter_mut().collect(),
            Models::Sizes { paths, .. } => paths.iter_mut().collect(),
            Models::Pool(entries) => entries.iter_mut().filter_map(|e| e.path.as_mut()).collect(),
        }
    }

    /// Checks the pool's thresholds.
    pub fn validate(&self) -> Result<(), BadValue> {
        if let Models::Pool(entries) = self {
            for (i, entry) in entries.iter().enumerate() {
                if let Some(t) = entry.score_threshold {
                    unit_interval(&format!("detector.pool[{i}].score_threshold"), t)?;
                }
            }
        }
        Ok(())
    }
}

/// The `[detector]` section as the file spells it; [`DetectorConfig`] is what it means.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DetectorFile {
    source: Source,
    model: Model,
    model_path: Option<PathBuf>,
    model_paths: Vec<PathBuf>,
    pool: Vec<PoolEntry>,
    ort_library: Option<PathBuf>,
    threads: usize,
    score_threshold: f32,
    border_score_factor: f32,
    nms_threshold: f32,
    cache_dir: Option<PathBuf>,
    dynamic_classes: Vec<String>,
    static_classes: Vec<String>,
    simulated_latency_ms: f64,
    tiles: u32,
}

impl Default for DetectorFile {
    fn default() -> Self {
        DetectorConfig::default().into()
    }
}

impl TryFrom<DetectorFile> for DetectorConfig {
    type Error = BadValue;

    /// The models the keys name: a pool, else several files, else one; a pool beside
    /// files, or one file beside several, is refused.
    fn try_from(file: DetectorFile) -> Result<Self, BadValue> {
        let DetectorFile {
            model,
            model_path,
            model_paths,
            pool,
            ..
        } = &file;
        let models = match (pool.is_empty(), model_path, model_paths.is_empty()) {
            (false, None, true) => Models::Pool(pool.clone()),
            (false, _, _) => {
                return Err(BadValue::new(
                    "detector.pool",
                    "is set beside detector.model_path / model_paths: set several models or a path, not both",
                ))
            }
            (true, Some(_), false) => {
                return Err(BadValue::new(
                    "detector.model_path",
                    "is set beside detector.model_paths: set one file or several, not both",
                ))
            }
            (true, None, false) => Models::Sizes {
                model: *model,
                paths: model_paths.clone(),
            },
            (true, path, true) => Models::One {
                model: *model,
                path: path.clone(),
            },
        };
        Ok(DetectorConfig {
            source: file.source,
            models,
            ort_library: file.ort_library,
            threads: file.threads,
            score_threshold: file.score_threshold,
            border_score_factor: file.border_score_factor,
            nms_threshold: file.nms_threshold,
            cache_dir: file.cache_dir,
            dynamic_classes: file.dynamic_classes,
            static_classes: file.static_classes,
            simulated_latency_ms: file.simulated_latency_ms,
            tiles: file.tiles,
        })
    }
}

impl From<DetectorConfig> for DetectorFile {
    fn from(config: DetectorConfig) -> Self {
        let (model, model_path, model_paths, pool) = match config.models {
            Models::One { model, path } => (model, path, Vec::new(), Vec::new()),
            Models::Sizes { model, paths } => (model, None, paths, Vec::new()),
            Models::Pool(pool) => (Model::Yolov4Tiny, None, Vec::new(), pool),
        };
        Self {
            source: config.source,
            model,
            model_path,
            model_paths,
            pool,
            ort_library: config.ort_library,
            threads: config.threads,
            score_threshold: config.score_threshold,
            border_score_factor: config.border_score_factor,
            nms_threshold: config.nms_threshold,
            cache_dir: config.cache_dir,
            dynamic_classes: config.dynamic_classes,
            static_classes: config.static_classes,
            simulated_latency_ms: config.simulated_latency_ms,
            tiles: config.tiles,
        }
    }
}
