//! The dense pass over a finished run (see [`crate::dense`]): the static depth of
//! every frame fused into a TSDF mesh and a point cloud, the movers masked.

use std::path::Path;

use super::setup::resolve_calibration;
use super::RunError;
use crate::config::Config;
use crate::dense::disparity::StereoDepth;
use crate::dense::{fuse_run, DenseInputs, DenseReport};
use crate::dop::Mode;
use crate::io::sequence::{SensorKind, Sequence};

/// The dense pass over the run in `run_dir`, outputs into `out_dir` (see
/// [`crate::dense`]); with `sequence_dir`'s ground-truth `masks/`, when it has them,
/// the fused pixels are counted against them.
pub fn dense_pass(
    sequence: &dyn Sequence,
    config: &Config,
    (run_dir, out_dir): (&Path, &Path),
    masking: Mode,
    sequence_dir: Option<&Path>,
    progress: bool,
) -> Result<DenseReport, RunError> {
    let config = &config.for_sensor(sequence.sensor());
    let calibration = resolve_calibration(sequence, config)?;
    let dense_detector = config.dense.detector(&config.detector);
    let detector = match masking {
        Mode::Dop if config.dense.detect_every > 0 => dense_detector
            .open(sequence_dir)
            .map_err(|e| RunError::Input(e.to_string()))?,
        _ => None,
    };
    let inputs = DenseInputs {
        sequence,
        camera: calibration.camera,
        run_dir,
        out_dir,
        masking,
        dop: &config.dop,
        dynamic_classes: &config.detector.dynamic_classes,
        truth_masks: sequence_dir.map(|d| d.join("masks")).filter(|d| d.is_dir()),
        progress,
        stereo: (sequence.sensor() == SensorKind::Stereo).then(|| StereoDepth {
            bf: calibration.bf.unwrap_or(40.0),
            sgbm: config.stereo.sgbm(),
        }),
        detector: detector.map(|d| (std::sync::Mutex::new(d), dense_detector.describe())),
    };
    Ok(fuse_run(&inputs, &config.dense)?)
}
