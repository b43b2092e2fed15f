//! The ONNX detector: one or several models (YOLOv4, YOLOX, DEIMv2 layouts) run by ONNX
//! Runtime through `ort`, their boxes pooled into one class-wise NMS, with the runtime
//! library loaded at run time (`load-dynamic`) from the path in the config, else
//! `ORT_DYLIB_PATH`, else `ort/libonnxruntime.so` in the runtime data directory (what
//! `tools/setup.sh` installs; [`crate::io::data_dir`]).

use std::path::{Path, PathBuf};

use image::RgbImage;
use ort::session::Session;
use ort::value::Tensor;

use super::yolo::{decode_end_to_end, keep_confident, non_maximum_suppression, Layout};
use super::{DetectError, Detection, Detector};
use crate::geometry::camera::ImageSize;

/// Where the ONNX Runtime library is: `configured`, else `ORT_DYLIB_PATH`, else
/// `ort/libonnxruntime.so` in the runtime data directory.
pub fn runtime_library(configured: Option<&Path>) -> PathBuf {
    let explicit = configured
        .map(Path::to_path_buf)
        .or_else(|| std::env::var_os("ORT_DYLIB_PATH").map(PathBuf::from));
    crate::io::data_dir::resolve(explicit.as_deref(), crate::io::data_dir::ORT_LIBRARY)
}

static RUNTIME: std::sync::OnceLock<Result<ort::environment::Environment, String>> =
    std::sync::OnceLock::new();

fn environment(library: &Path) -> Result<&'static ort::environment::Environment, DetectError> {
    let result = RUNTIME.get_or_init(|| {
        if !library.is_file() {
            return Err(format!(
                "the ONNX Runtime library {} is missing: {}",
                library.display(),
                crate::io::data_dir::INSTALL_HINT
            ));
        }
        ort::init_from(library)
            .map_err(|e| {
                format!(
                    "cannot load the ONNX Runtime library {}: {e}",
                    library.display()
                )
            })?
            .with_name("dopslam")
            .build()
            .map_err(|e| format!("cannot start ONNX Runtime from {}: {e}", library.display()))
    });
    result.as_ref().map_err(|m| DetectError::Runtime(m.clone()))
}

/// Loads the ONNX Runtime library (once a process), for `dopslam doctor`: the error
/// says why it cannot be used (missing, not a library, the wrong version).
pub fn check_runtime(library: &Path) -> Result<(), DetectError> {
    environment(library).map(|_| ())
}

/// One network: a model file in an ONNX Runtime session, with its fixed input size,
/// its layout and its own score threshold (else the detector's).
struct Network {
    session: Session,
    width: u32,
    height: u32,
    model: PathBuf,
    layout: Layout,
    score_threshold: Option<f32>,
}

/// A model of a pool: its file, layout, and score threshold (`None`: the detector's).
#[derive(Debug, Clone, PartialEq)]
pub struct PoolModel {
    /// The model file.
    pub path: PathBuf,
    /// Its output layout.
    pub layout: Layout,
    /// Its own score threshold; unset: the detector's.
    pub score_threshold: Option<f32>,
}

/// Models in ONNX Runtime sessions: one network, or several (the same weights at
/// several input sizes, or models of different families, each with its threshold)
/// whose candidate boxes are pooled before one class-wise NMS.
pub struct OnnxDetector {
    networks: Vec<Network>,
    /// Boxes below this score are dropped.
    pub score_threshold: f32,
    /// A narrow box touching the image's left or right border is kept from this share
    /// of its network's threshold ([`keep_confident`]).
    pub border_score_factor: f32,
    /// Intersection over union above which NMS drops the weaker box.
    pub nms_threshold: f32,
    /// Each network's time on the last image, milliseconds.
    last_ms: Vec<f64>,
}

impl OnnxDetector {
    /// Loads `model` with `threads` intra-op threads and checks that its input is
    /// `[1, 3, H, W]` and its output `[1, N, 85]` as `layout` expects.
    pub fn load(
        model: &Path,
        layout: Layout,
        library: &Path,
        threads: usize,
    ) -> Result<Self, DetectError> {
        Self::load_all(&[model.to_path_buf()], layout, library, threads)
    }

    /// Loads every file of `models` (one layout), each checked as [`Self::load`] does;
    /// each keyframe runs them all.
    pub fn load_all(
        models: &[PathBuf],
        layout: Layout,
        library: &Path,
        threads: usize,
    ) -> Result<Self, DetectError> {
        let pool: Vec<PoolModel> = models
            .iter()
            .map(|path| PoolModel {
                path: path.clone(),
                layout,
                score_threshold: None,
            })
            .collect();
        Self::load_pool(&pool, library, threads)
    }

    /// Loads a pool of models of any layouts, each checked as [`Self::load`] does;
    /// each keyframe runs them all, one after the other, on the detector's thread.
    pub fn load_pool(
        models: &[PoolModel],
        library: &Path,
        threads: usize,
    ) -> Result<Self, DetectError> {
        let environment = environment(library)?;
        let mut detector = Self {
            networks: Vec::with_capacity(models.len()),
            score_threshold: 0.3,
            border_score_factor: 1.0,
            nms_threshold: 0.45,
            last_ms: Vec::new(),
        };
        for model in models {
            detector
                .networks
                .push(Network::load(environment, model, threads)?);
        }
        if detector.networks.is_empty() {
            return Err(DetectError::Config("no model file given".into()));
        }
        // One blank image checks the output layouts now rather than on the first keyframe.
        for i in 0..detector.networks.len() {
            let network = &detector.networks[i];
            let blank = RgbImage::new(network.width, network.height);
            detector.candidates(i, &blank)?;
        }
        Ok(detector)
    }

    /// The models' files, for the report.
    pub fn models(&self) -> Vec<&Path> {
        self.networks.iter().map(|n| n.model.as_path()).collect()
    }

    /// The decoded boxes of network `index` above its score threshold, before NMS.
    fn candidates(
        &mut self,
        index: usize,
        image: &RgbImage,
    ) -> Result<Vec<Detection>, DetectError> {
        let default_threshold = self.score_threshold;
        let Network {
            session,
            width,
            height,
            model,
            layout,
            score_threshold,
        } = &mut self.networks[index];
        let (layout, threshold) = (*layout, score_threshold.unwrap_or(default_threshold));
        // Decoded down to the border boxes' threshold, then the others are held to theirs.
        let lowest = threshold * self.border_score_factor;
        let keep = |found: Vec<Detection>| keep_confident(found, threshold, lowest, image.width());
        if layout == Layout::Deimv2 {
            return end_to_end(session, (*width, *height), model, image, lowest).map(keep);
        }
        let size = (*width as usize, *height as usize);
        let mut input = layout.prepare(image, *width, *height);
        let shape = [1usize, 3, size.1, size.0];
        // The tensor takes the pixels; decoding needs only the scales.
        let tensor = Tensor::from_array((shape, std::mem::take(&mut input.data)))
            .map_err(|e| DetectError::Runtime(e.to_string()))?;
        // The path is cloned only for an error (this runs on every keyframe).
        let outputs = session
            .run(ort::inputs![tensor])
            .map_err(|e| DetectError::Runtime(format!("{}: {e}", model.display())))?;
        let (shape, data) = outputs[0]
            .try_extract_tensor::<f32>()
            .map_err(|e| DetectError::Runtime(e.to_string()))?;
        let dims: Vec<i64> = shape.iter().copied().collect();
        let expected = layout.predictions(size.0, size.1);
        let fits = dims.len() == 3
            && dims[0] == 1
            && dims[2] == 85
            && expected.is_none_or(|n| dims[1] as usize == n);
        if !fits {
            return Err(DetectError::Model {
                path: model.clone(),
                message: format!(
                    "output shape {dims:?} matches neither layout: {layout:?} expects [1, {}, 85]",
                    expected.map_or("N".to_string(), |n| n.to_string())
                ),
            });
        }
        let found = layout.decode(data, dims[1] as usize, size.0, size.1, &input, lowest);
        Ok(keep(found))
    }

    fn infer(&mut self, image: &RgbImage) -> Result<Vec<Detection>, DetectError> {
        let mut found = Vec::new();
        self.last_ms.clear();
        for i in 0..self.networks.len() {
            let start = std::time::Instant::now();
            found.extend(self.candidates(i, image)?);
            self.last_ms.push(start.elapsed().as_secs_f64() * 1e3);
        }
        Ok(non_maximum_suppression(
            found,
            self.nms_threshold,
            (image.width(), image.height()),
        ))
    }
}

/// Runs an end-to-end model (DEIMv2 layout) on `image`: its detections above
/// `threshold`, boxes in image pixels.
fn end_to_end(
    session: &mut Session,
    size: impl Into<ImageSize>,
    model: &Path,
    image: &RgbImage,
    threshold: f32,
) -> Result<Vec<Detection>, DetectError> {
    let ImageSize { width, height } = size.into();
    let runtime = |e: ort::Error| DetectError::Runtime(format!("{}: {e}", model.display()));
    let input = Layout::Deimv2.prepare(image, width, height);
    let pixels = Tensor::from_array(([1usize, 3, height as usize, width as usize], input.data))
        .map_err(runtime)?;
    let size = Tensor::from_array((
        [1usize, 2],
        vec![image.width() as i64, image.height() as i64],
    ))
    .map_err(runtime)?;
    let outputs = session
        .run(ort::inputs!["images" => pixels, "orig_target_sizes" => size])
        .map_err(runtime)?;
    let output = |name: &str| {
        outputs.get(name).ok_or_else(|| DetectError::Model {
            path: model.to_path_buf(),
            message: format!("no output {name:?}: not the DEIMv2 layout (labels, boxes, scores)"),
        })
    };
    let (_, labels) = output("labels")?
        .try_extract_tensor::<i64>()
        .map_err(runtime)?;
    let (_, boxes) = output("boxes")?
        .try_extract_tensor::<f32>()
        .map_err(runtime)?;
    let (_, scores) = output("scores")?
        .try_extract_tensor::<f32>()
        .map_err(runtime)?;
    if boxes.len() != 4 * labels.len() || scores.len() != labels.len() {
        return Err(DetectError::Model {
            path: model.to_path_buf(),
            message: format!(
                "outputs of {} labels, {} box values and {} scores do not match the DEIMv2 layout",
                labels.len(),
                boxes.len(),
                scores.len()
            ),
        });
    }
    Ok(decode_end_to_end(labels, boxes, scores, threshold))
}

impl Network {
    fn load(
        environment: &ort::environment::Environment,
        pooled: &PoolModel,
        threads: usize,
    ) -> Result<Self, DetectError> {
        let model = pooled.path.as_path();
        if !model.is_file() {
            return Err(DetectError::Model {
                path: model.to_path_buf(),
                message: format!("no such file: {}", crate::io::data_dir::INSTALL_HINT),
            });
        }
        let bad = |message: String| DetectError::Model {
            path: model.to_path_buf(),
            message,
        };
        let session = Session::builder(environment)
            .and_then(|b| Ok(b.with_intra_threads(threads.max(1))?))
            .and_then(|mut b| b.commit_from_file(model))
            .map_err(|e| bad(format!("not a loadable ONNX model: {e}")))?;
        let input = session
            .inputs()
            .first()
            .ok_or_else(|| bad("the model has no input".into()))?;
        let shape = match input.dtype() {
            ort::value::ValueType::Tensor { shape, .. } => shape.to_vec(),
            other => return Err(bad(format!("input is {other:?}, not a tensor"))),
        };
        if shape.len() != 4 || shape[1] != 3 || shape[2] <= 0 || shape[3] <= 0 {
            return Err(bad(format!(
                "input shape {shape:?} is not [1, 3, H, W] with a fixed size"
            )));
        }
        Ok(Self {
            session,
            width: shape[3] as u32,
            height: shape[2] as u32,
            model: model.to_path_buf(),
            layout: pooled.layout,
            score_threshold: pooled.score_threshold,
        })
    }
}

impl Detector for OnnxDetector {
    fn detect(&mut self, _timestamp: f64, image: &RgbImage) -> Result<Vec<Detection>, DetectError> {
        self.infer(image)
    }

    fn model_times(&self) -> Vec<(String, f64)> {
        self.networks
            .iter()
            .zip(&self.last_ms)
            .map(|(n, &ms)| (model_name(&n.model), ms))
            .collect()
    }
}

/// A model's name in the report: its file name.
fn model_name(path: &Path) -> String {
    path.file_name().map_or_else(
        || path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    )
}
