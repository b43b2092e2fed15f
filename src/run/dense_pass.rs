//! The dense pass over a finished run (see [`crate::dense`]): the static depth of
//! every frame fused into a TSDF mesh and a point cloud, the movers masked.

use std::path::Path;

use super::error::RunError;
use super::setup::{resolve_calibration, stereo_bf, Setup};
use crate::config::Config;
use crate::dense::disparity::StereoDepth;
use crate::dense::{fuse_run, DenseInputs, DenseReport};
use crate::dop::Mode;
use crate::geometry::camera::PinholeCamera;
use crate::io::sequence::{SensorKind, Sequence};

/// What the dense pass runs with, resolved once: the config for the sequence's
/// sensor, the camera, and for a stereo sequence how its pairs become depth.
#[derive(Debug, Clone)]
pub struct DenseSetup {
    /// The run's config.
    pub config: Config,
    /// The undistorted colour camera.
    pub camera: PinholeCamera,
    /// For a stereo sequence: how its depth is made.
    pub stereo: Option<StereoDepth>,
}

impl DenseSetup {
    /// The dense pass of a run: from the run's set-up, nothing resolved again.
    pub fn of_run(setup: &Setup) -> Self {
        Self::new(
            setup.config.clone(),
            setup.calibration.camera,
            setup.sensor,
            setup.camera.bf,
        )
    }

    /// For `dopslam fuse` (no tracking pass before it): the sensor's config and the
    /// calibration of `sequence` under `config`.
    pub fn resolve(sequence: &dyn Sequence, config: &Config) -> Result<Self, RunError> {
        let (config, _) = config.for_sensor(sequence.sensor());
        let calibration = resolve_calibration(sequence, &config)?;
        let bf = stereo_bf(&calibration);
        Ok(Self::new(config, calibration.camera, sequence.sensor(), bf))
    }

    /// The same with the rig's disparity offset `offset_px` (pixels) that the sparse
    /// disparities had added (tracking's and the global pass's,
    /// [`super::RunReport::disparity_offset_px`]) added to the dense ones too.
    pub fn with_disparity_offset(mut self, offset_px: f64) -> Self {
        if let Some(stereo) = &mut self.stereo {
            stereo.offset = offset_px;
        }
        self
    }

    fn new(config: Config, camera: PinholeCamera, sensor: SensorKind, bf: f64) -> Self {
        let stereo = (sensor == SensorKind::Stereo).then(|| StereoDepth {
            bf,
            offset: 0.0,
            sgbm: config.stereo.sgbm(),
        });
        Self {
            config,
            camera,
            stereo,
        }
    }
}

/// A dense pass over a finished run: what it reads, where it writes, how it masks.
pub struct DensePass<'a> {
    /// The sequence the run tracked.
    pub sequence: &'a dyn Sequence,
    /// The dense set-up.
    pub setup: &'a DenseSetup,
    /// The run folder read (poses, keypoints, detections).
    pub run_dir: &'a Path,
    /// Where the dense map goes.
    pub out_dir: &'a Path,
    /// How movers are masked.
    pub masking: Mode,
    /// The sequence's folder: its ground-truth `masks/`, when it has them, count the
    /// fused pixels; the oracle detections.
    pub sequence_dir: Option<&'a Path>,
    /// Show a progress bar.
    pub progress: bool,
}

/// The dense pass of `pass` (see [`crate::dense`]).
pub fn dense_pass(pass: &DensePass) -> Result<DenseReport, RunError> {
    let inputs = inputs_of(pass)?;
    Ok(fuse_run(&inputs, &pass.setup.config.dense)?)
}

/// One dense map of the runs of `passes` (one place, tracked in one map's frame:
/// `dopslam merge`) in `out_dir`, with the first's `[dense]` settings (see
/// [`crate::dense::merge`]); each pass's `out_dir` takes its side files.
pub fn merge_pass(
    passes: &[DensePass],
    out_dir: &Path,
) -> Result<crate::dense::merge::MergeReport, RunError> {
    let inputs = passes
        .iter()
        .map(inputs_of)
        .collect::<Result<Vec<_>, _>>()?;
    let Some(first) = passes.first() else {
        return Err(RunError::Input("no run to merge".into()));
    };
    Ok(crate::dense::merge::merge(
        &inputs,
        out_dir,
        &first.setup.config.dense,
    )?)
}

/// What the dense pass of `pass` reads, its dense detector opened (DOP masks).
fn inputs_of<'a>(pass: &DensePass<'a>) -> Result<DenseInputs<'a>, RunError> {
    let DensePass {
        sequence,
        setup,
        run_dir,
        out_dir,
        masking,
        sequence_dir,
        progress,
    } = *pass;
    let config = &setup.config;
    let dense_detector = config.dense.detector(&config.detector);
    let detector = match masking {
        Mode::Dop if config.dense.detections.every > 0 => dense_detector
            .open(sequence_dir)
            .map_err(|e| RunError::Input(e.to_string()))?,
        _ => None,
    };
    Ok(DenseInputs {
        sequence,
        camera: setup.camera,
        run_dir,
        out_dir,
        masking,
        dop: &config.dop,
        dynamic_classes: &config.detector.dynamic_classes,
        truth_masks: sequence_dir.map(|d| d.join("masks")).filter(|d| d.is_dir()),
        progress,
        stereo: setup.stereo,
        detector: detector.map(|d| (std::sync::Mutex::new(d), dense_detector.describe())),
        keyframe_boxes_alike: dense_detector.describe() == config.detector.describe(),
    })
}
