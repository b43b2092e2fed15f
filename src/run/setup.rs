//! The run's set-up, resolved once before any work: the sequence opened and checked,
//! the config for its sensor, the calibration (config, settings file or the
//! sequence's own), the detection source (a missing model is an error here), the
//! vocabulary, the stereo camera, the ORB extractor, how moving objects are treated,
//! the detection weight \(\alpha\) of the sensor and the close-depth limit.

use std::path::{Path, PathBuf};

use super::error::RunError;
use crate::config::Config;
use crate::dop::Mode;
use crate::features::OrbExtractor;
use crate::geometry::camera::{ImageSize, PinholeCamera};
use crate::geometry::depth_noise::DepthNoise;
use crate::geometry::stereo_camera::StereoCamera;
use crate::io::kitti::KittiSequence;
use crate::io::orbslam_settings::{Calibration, OrbSlamSettings};
use crate::io::recording::RecordingSequence;
use crate::io::sequence::{SensorKind, Sequence};
use crate::io::tum::TumSequence;
use crate::io::IoError;
use crate::records::{ProfileApplied, RigOffset, RunSetup};
use crate::system::worker::Execution;
use crate::system::SystemSetup;

/// Everything a run is set up with (see the module doc).
#[derive(Clone)]
pub struct Setup {
    /// The config for the sequence's sensor, with the detection source resolved.
    pub config: Config,
    /// RGB-D or stereo.
    pub sensor: SensorKind,
    /// The camera, its baseline and depth scale.
    pub calibration: Calibration,
    /// The camera and its baseline.
    pub camera: StereoCamera,
    /// The ORB extractor.
    pub extractor: OrbExtractor,
    /// DOP, mask boxes or none.
    pub mode: Mode,
    /// The sensor's weight of a detection (the paper: 0.3 RGB-D, 0.5 stereo).
    pub alpha: f32,
    /// RGB-D close/far limit in metres: `ThDepth` baselines, \(z_{close} = t_d\,b\).
    pub close_depth: f32,
    /// Stereo: keypoints farther than this (metres; `[stereo] bearing_baselines`
    /// baselines) are bearings only ([`crate::frame::stereo::bearings_beyond`]).
    pub bearing_depth: f32,
    /// Loop closing's vocabulary ([`loop_vocabulary`]).
    pub vocabulary: LoopVocabulary,
    /// Stereo: the rig's disparity offset added to every match, known
    /// (`[stereo] disparity_offset_px`) or estimated ([`super::rig_offset`]).
    pub disparity_offset: Option<RigOffset>,
    /// The sensor profile applied to the config (`[stereo]`), if any.
    pub profile: Option<ProfileApplied>,
}

impl Setup {
    /// Resolves the set-up of a run of `config` over `sequence`; every error here comes
    /// before any output is touched.
    pub fn resolve(sequence: &dyn Sequence, config: &Config) -> Result<Self, RunError> {
        if sequence.is_empty() {
            return Err(RunError::Input(format!(
                "sequence {} has no frames",
                sequence.name()
            )));
        }
        // The detector's files first, then the vocabulary: a fresh install misses both,
        // and the detector is what a user sets up first.
        let (mut config, profile) = config.for_sensor(sequence.sensor());
        config.detector.source = detection_source(&config)?;
        let vocabulary = loop_vocabulary(&config.global)?;
        // The first frame, read once: it decides the image size and shows a swapped pair.
        let first = sequence.load(0).ok();
        let (calibration, size_warning) =
            calibration_and_warning(sequence, &config, first.as_ref())?;
        if let Some(warning) = size_warning {
            eprintln!("warning: {warning}");
        }
        let camera = StereoCamera::new(&calibration.camera, stereo_bf(&calibration));
        let extractor = OrbExtractor::new(&config.orb);
        warn_if_swapped(sequence.name(), first.as_ref(), &extractor, &camera);
        let sensor = sequence.sensor();
        let disparity_offset = RigOffset::known(&config, sensor);
        for warning in profile.iter().flat_map(ProfileApplied::warnings) {
            eprintln!("{warning}");
        }
        Ok(Self {
            mode: effective_mode(&config),
            alpha: match sensor {
                SensorKind::Rgbd => config.dop.alpha_rgbd,
                SensorKind::Stereo => config.dop.alpha_stereo,
            },
            close_depth: (config.tracking.th_depth * camera.bf / camera.fx) as f32,
            bearing_depth: (config.stereo.bearing_baselines * camera.bf / camera.fx) as f32,
            config,
            sensor,
            calibration,
            camera,
            disparity_offset,
            extractor,
            vocabulary,
            profile,
        })
    }

    /// The same set-up with the rig's disparity offset `found` (given, or found by the
    /// tracking pass).
    pub fn with_disparity_offset(&self, found: RigOffset) -> Self {
        Self {
            disparity_offset: Some(found),
            ..self.clone()
        }
    }

    /// What the global pass of a run of this set-up works with (also the tracking
    /// pass's search for the rig's offset, [`super::rig_offset`]).
    pub fn global_inputs(&self) -> crate::global::GlobalInputs<'_> {
        let camera = &self.calibration.camera;
        crate::global::GlobalInputs {
            camera: &self.camera,
            pyramid: &self.extractor.pyramid,
            stereo: self.sensor == SensorKind::Stereo,
            size: (camera.width as f32, camera.height as f32),
            removal_threshold: self.mode.removal_threshold(&self.config.dop),
            prediction_gate_share: if self.mode == Mode::Dop {
                self.config.tracking.prediction_gate_share
            } else {
                0.0
            },
        }
    }

    /// The rig's disparity offset added to every stereo match, pixels (0: none).
    pub fn disparity_offset_px(&self) -> f64 {
        self.disparity_offset.as_ref().map_or(0.0, |o| o.offset_px)
    }

    /// What the online system is built from, its helpers run as `execution` says and
    /// its detections cached in `detection_cache`.
    pub fn system(&self, execution: Execution, detection_cache: PathBuf) -> SystemSetup<'_> {
        SystemSetup {
            config: &self.config,
            camera: self.camera,
            pinhole: self.calibration.camera,
            pyramid: self.extractor.pyramid.clone(),
            mode: self.mode,
            alpha: self.alpha,
            close_depth: self.close_depth,
            depth_noise: match self.sensor {
                SensorKind::Rgbd => DepthNoise::Rgbd,
                SensorKind::Stereo => DepthNoise::Stereo { bf: self.camera.bf },
            },
            execution,
            detection_cache,
        }
    }
}

/// For a stereo sequence, a warning when its first pair looks swapped (see
/// [`crate::frame::stereo::looks_swapped`]): such a pair still tracks, badly.
fn warn_if_swapped(
    name: &str,
    first: Option<&crate::io::sequence::Frame>,
    extractor: &OrbExtractor,
    camera: &StereoCamera,
) {
    let Some(crate::io::sequence::FrameImages::Stereo { left, right }) = first.map(|f| &f.images)
    else {
        return;
    };
    let pair = crate::frame::stereo::StereoPair { left, right };
    if let Some((positive, negative)) =
        crate::frame::stereo::looks_swapped(pair, extractor, camera.fx)
    {
        eprintln!(
            "warning: the stereo pair of {name} looks swapped: {negative} keypoints match at a negative disparity and {positive} at a positive one (image_0 must be the left camera, image_1 the right)"
        );
    }
}

/// Says what is wrong when `root` is no sequence folder: missing, a file, a loop of
/// symbolic links, or a KITTI dataset's root instead of one of its sequences.
pub fn check_sequence_folder(root: &Path) -> Result<(), IoError> {
    crate::io::errors::check_exists(root, "sequence folder")?;
    if !root.is_dir() {
        return Err(IoError::invalid(
            root,
            "a file, not a sequence folder (TUM/Bonn: the folder holding rgb.txt and depth.txt; KITTI: sequences/NN)",
        ));
    }
    if root.join("sequences").is_dir()
        && !root.join("image_0").is_dir()
        && !root.join("rgb.txt").exists()
    {
        return Err(IoError::invalid(
            root,
            format!(
                "a KITTI dataset's root: run one of its sequences, e.g. {}",
                root.join("sequences/00").display()
            ),
        ));
    }
    Ok(())
}

/// Opens a TUM/Bonn folder, a KITTI sequence folder (`image_0/` inside) or a recording
/// (ROS 1 `.bag`, ROS 2 bag folder, `.mcap`, `.db3`; see [`crate::io::recording`]), whose
/// warnings (no index, cut short, stamps out of order) are printed here.
pub fn open_sequence(root: &Path, config: &Config) -> Result<Box<dyn Sequence>, IoError> {
    if crate::io::recording::is_recording(root) {
        let recording = RecordingSequence::open(root, &config.dataset.recording_options())?;
        for warning in &recording.description.warnings {
            eprintln!("warning: {warning}");
        }
        return Ok(Box::new(recording));
    }
    check_sequence_folder(root)?;
    if root.join("image_0").is_dir() {
        return Ok(Box::new(KittiSequence::open(root, None)?));
    }
    Ok(Box::new(TumSequence::open(
        root,
        &config.dataset.tum_options(),
    )?))
}

/// The baseline times focal length (pixel-metres) a run uses: the calibration's,
/// else ORB-SLAM2's virtual 40 px·m for RGB-D.
pub fn stereo_bf(calibration: &Calibration) -> f64 {
    calibration.bf.unwrap_or(40.0)
}

/// The calibration to use: the config's camera, else its settings file, else the
/// sequence's own; RGB-D without a baseline gets ORB-SLAM2's virtual 40 px·m
/// ([`stereo_bf`]). Its image size is the images' ([`fit_to_images`];
/// [`Setup::resolve`] prints the warning when they differ).
pub fn resolve_calibration(
    sequence: &dyn Sequence,
    config: &Config,
) -> Result<Calibration, RunError> {
    let first = sequence.load(0).ok();
    Ok(calibration_and_warning(sequence, config, first.as_ref())?.0)
}

/// [`resolve_calibration`] with the sequence's `first` frame (its size decides), and
/// the warning of [`fit_to_images`], when there is one.
fn calibration_and_warning(
    sequence: &dyn Sequence,
    config: &Config,
    first: Option<&crate::io::sequence::Frame>,
) -> Result<(Calibration, Option<String>), RunError> {
    let mut calibration = match (&config.dataset.settings, sequence.calibration(), config.dataset.camera) {
        (Some(path), _, _) => OrbSlamSettings::read(path)?.calibration,
        (None, Some(own), _) => own.clone(),
        (None, None, Some(camera)) => Calibration {
            camera,
            bf: None,
            depth_scale: None,
            th_depth: None,
            fps: None,
        },
        (None, None, None) => {
            return Err(RunError::Input(format!(
                "sequence {} has no calibration (no calibration.yaml, and its folder name says no freiburg1/2/3): pass --settings configs/calibration/RGB-D_TUM3.yaml (or another ORB-SLAM2 settings file) or --camera fx,fy,cx,cy; in a config, [dataset] settings or [dataset.camera]",
                sequence.name()
            )))
        }
    };
    if let Some(camera) = config.dataset.camera {
        calibration.camera = camera;
    }
    if calibration.bf.is_none() {
        if sequence.sensor() == SensorKind::Stereo {
            return Err(RunError::Input(format!(
                "stereo sequence {}: no baseline in its calibration (a stereo pair needs the right camera's CameraInfo in the recording, or Camera.bf in an ORB-SLAM2 settings file given with --settings)",
                sequence.name()
            )));
        }
        calibration.bf = Some(40.0);
    }
    if let Some(size) = first.map(image_size) {
        let from = match (&config.dataset.settings, config.dataset.camera) {
            (_, Some(_)) => "the camera given (--camera, [dataset.camera])".to_owned(),
            (Some(path), None) => format!("the settings file {}", path.display()),
            (None, None) => format!("the calibration of sequence {}", sequence.name()),
        };
        let warning = fit_to_images(&mut calibration.camera, size, &from)?;
        return Ok((calibration, warning));
    }
    Ok((calibration, None))
}

/// The size of a frame (its colour or left image).
fn image_size(frame: &crate::io::sequence::Frame) -> (u32, u32) {
    match &frame.images {
        crate::io::sequence::FrameImages::Rgbd { rgb, .. } => rgb.dimensions(),
        crate::io::sequence::FrameImages::Stereo { left, .. } => left.dimensions(),
    }
}

/// The images decide the size, as in ORB-SLAM2: a camera whose `Camera.width/height`
/// differ from the images' (ORB-SLAM2's own KITTI 03 and 04-12 settings say 1241x376
/// for images of 1242x375 and 1226x370) takes the images' size, and the warning naming
/// both is returned. An error only where the principal point falls outside the image:
/// such intrinsics belong to other images.
pub fn fit_to_images(
    camera: &mut PinholeCamera,
    size: impl Into<ImageSize>,
    from: &str,
) -> Result<Option<String>, RunError> {
    let ImageSize { width, height } = size.into();
    let inside = |c: f64, size: u32| c >= 0.0 && c < size as f64;
    if !inside(camera.cx, width) || !inside(camera.cy, height) {
        return Err(RunError::Input(format!(
            "{from}: its principal point ({}, {}) lies outside the images, which are {width}x{height}: the calibration is for another camera",
            camera.cx, camera.cy
        )));
    }
    if (camera.width, camera.height) == (width, height) {
        return Ok(None);
    }
    let warning = format!(
        "{from} says {}x{} but the images are {width}x{height}: using the images' size (the intrinsics as given)",
        camera.width, camera.height
    );
    camera.width = width;
    camera.height = height;
    Ok(Some(warning))
}

/// A fingerprint of a sequence: FNV-1a (64 bits, hex) of its first frame's colour (or
/// left) pixels; `None` when the frame cannot be read.
pub fn first_frame_hash(sequence: &dyn Sequence) -> Option<String> {
    let frame = sequence.load(0).ok()?;
    let bytes: &[u8] = match &frame.images {
        crate::io::sequence::FrameImages::Rgbd { rgb, .. } => rgb.as_raw(),
        crate::io::sequence::FrameImages::Stereo { left, .. } => left.as_raw(),
    };
    Some(content_hash(bytes))
}

pub use crate::io::content_hash;

impl RunSetup {
    /// What `sequence` runs with under `config` and `calibration`.
    pub fn new(sequence: &dyn Sequence, setup: &Setup) -> Self {
        let (config, calibration) = (&setup.config, &setup.calibration);
        let data = crate::io::data_dir::DataDir::locate();
        let absolute = |p: PathBuf| std::path::absolute(&p).unwrap_or(p);
        Self {
            calibration: calibration.clone(),
            orb: config.orb.clone(),
            th_depth: config.tracking.th_depth,
            max_frames_between_keyframes: config.tracking.max_frames_between_keyframes,
            settings: config.dataset.settings_applied.clone(),
            sensor_profile: setup.profile.clone(),
            data_dir: format!("{} ({})", absolute(data.path).display(), data.origin),
            detections: config.detector.source,
            detector_files: match config.detector.source {
                crate::detect::Source::Onnx => config
                    .detector
                    .onnx_files()
                    .into_iter()
                    .map(|(p, _)| absolute(p))
                    .collect(),
                _ => Vec::new(),
            },
            vocabulary: (config.global.enabled && config.global.loops.enabled)
                .then(|| absolute(config.global.vocabulary_file())),
            first_frame_hash: first_frame_hash(sequence),
            disparity_offset: setup.disparity_offset.clone(),
            input_warnings: sequence.warnings().to_vec(),
        }
    }
}

/// How moving objects are treated in a run of `config`: without detections the DOP
/// model runs on its geometric check alone (when on), else every mode is ORB-SLAM2's.
pub fn effective_mode(config: &Config) -> Mode {
    match config.detector.source {
        crate::detect::Source::None if config.dop.mode == Mode::Dop && config.dop.geometric => {
            Mode::Dop
        }
        crate::detect::Source::None => Mode::Off,
        _ => config.dop.mode,
    }
}

/// The detection source a run of `config` uses: `auto` needs no detector in ORB-SLAM2
/// mode (`--no-dop`) and the ONNX model otherwise; a missing model or runtime library
/// is an error here, before any work, never a silent run without detections.
pub fn detection_source(config: &Config) -> Result<crate::detect::Source, RunError> {
    use crate::detect::Source;
    if config.detector.source == Source::Auto && config.dop.mode == Mode::Off {
        return Ok(Source::None);
    }
    let source = config.detector.resolved_source().map_err(|e| {
        RunError::Input(format!(
            "{e}; or run without a detector: --detections none (config: [detector] source = \"none\")"
        ))
    })?;
    let dense = &config.dense;
    if dense.enabled && config.dop.mode == Mode::Dop && dense.detections.every > 0 {
        dense.detector(&config.detector).resolved_source().map_err(|e| {
            RunError::Input(format!(
                "the dense pass's detector ([dense] detect_model): {e}; or use the tracking pass's: [dense] detect_model = \"tracking\""
            ))
        })?;
    }
    Ok(source)
}

/// What loop closing runs with: see [`loop_vocabulary`].
pub type LoopVocabulary =
    Option<Result<std::sync::Arc<crate::bow::vocabulary::Vocabulary>, crate::global::NoLoops>>;

/// The vocabulary of loop closing: `None` without a global pass, `Some(Err(why))` when
/// loop closing is off (the global pass runs without loops). A vocabulary that cannot
/// be read while loop closing is on is an error before any work.
pub fn loop_vocabulary(config: &crate::global::GlobalConfig) -> Result<LoopVocabulary, RunError> {
    if !config.enabled {
        return Ok(None);
    }
    if !config.loops.enabled {
        return Ok(Some(Err(crate::global::NoLoops::TurnedOff)));
    }
    crate::global::load_vocabulary(config)
        .map(|v| Some(Ok(v)))
        .map_err(RunError::NoLoops)
}

impl RigOffset {
    /// The offset `config` gives a `sensor`'s run, when it gives one (stereo only).
    pub fn known(config: &Config, sensor: SensorKind) -> Option<Self> {
        let offset_px = config.stereo.disparity_offset_px?;
        (sensor == SensorKind::Stereo).then_some(Self {
            offset_px,
            source: "config".into(),
            frames: None,
            estimate: None,
            taken: Vec::new(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera(width: u32, height: u32) -> PinholeCamera {
        PinholeCamera {
            fx: 707.09,
            fy: 707.09,
            cx: 601.89,
            cy: 183.11,
            width,
            height,
            distortion: [0.0; 5],
            rational: [0.0; 3],
        }
    }

    #[test]
    fn the_images_decide_the_size() {
        // ORB-SLAM2's Stereo_KITTI04-12.yaml says 1241x376; KITTI 06 is 1226x370.
        let mut settings = camera(1241, 376);
        let warning = fit_to_images(&mut settings, (1226, 370), "the settings file K.yaml")
            .unwrap()
            .expect("a warning");
        assert!(
            warning.contains("K.yaml")
                && warning.contains("1241x376")
                && warning.contains("1226x370"),
            "{warning}"
        );
        assert_eq!((settings.width, settings.height), (1226, 370));
        assert_eq!(settings.fx, 707.09);
        let mut same = camera(1226, 370);
        assert_eq!(fit_to_images(&mut same, (1226, 370), "x").unwrap(), None);
    }

    #[test]
    fn a_principal_point_outside_the_images_is_refused() {
        let mut settings = camera(1241, 376);
        let error = fit_to_images(&mut settings, (480, 360), "the settings file K.yaml")
            .unwrap_err()
            .to_string();
        assert!(
            error.contains("K.yaml")
                && error.contains("principal point")
                && error.contains("480x360"),
            "{error}"
        );
    }
}
