//! The typed configuration: TOML files in `configs/`, every key with a default, unknown
//! keys refused by name, values validated. ORB-SLAM2 settings YAML files can supply the
//! calibration and ORB parameters (see [`crate::io::orbslam_settings`]).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use thiserror::Error;

use crate::checks::{self, BadValue};
use crate::records::{ProfileApplied, SettingsApplied};

pub use crate::dense::DenseConfig;
pub use crate::detect::DetectorConfig;
pub use crate::dop::DopConfig;
use crate::eval::associate::AssociationRule;
use crate::eval::report::AlignMode;
pub use crate::features::orb::OrbConfig;
use crate::geometry::camera::PinholeCamera;
use crate::io::orbslam_settings::OrbSlamSettings;
use crate::io::recording::{RecordingOptions, TopicChoice};
use crate::io::tum::TumOptions;
pub use crate::mapping::MappingConfig;
pub use crate::tracking::TrackerConfig;

/// Why a config file cannot be used: each names the file.
#[derive(Debug, Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    /// The file cannot be read.
    Read {
        /// The config file.
        path: PathBuf,
        /// The reason.
        source: std::io::Error,
    },
    #[error("config {path}: {problem}")]
    /// The file says something without meaning.
    Invalid {
        /// The config file.
        path: PathBuf,
        /// What is wrong.
        problem: ConfigProblem,
    },
    /// The ORB-SLAM2 settings file that a config names (`[dataset] settings`) failed.
    #[error("config {config}: [dataset] settings: {source}")]
    NamedSettings {
        /// The config file that names the settings file.
        config: PathBuf,
        /// What went wrong with the settings file.
        source: Box<ConfigError>,
    },
    #[error(transparent)]
    /// An ORB-SLAM2 settings file that cannot be read.
    Settings(#[from] crate::io::IoError),
}

/// What is wrong with a config's text.
#[derive(Debug, Error)]
pub enum ConfigProblem {
    /// Not TOML, an unknown key or a value of the wrong type (toml's message, which
    /// names the key and the line).
    #[error("{}", .0.to_string().trim_end())]
    Syntax(#[from] toml::de::Error),
    /// A value out of its range.
    #[error(transparent)]
    Value(#[from] BadValue),
}

/// How a sequence is read.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DatasetConfig {
    /// Raw depth units per metre (TUM: 5000). Unset: the sequence's calibration, else 5000.
    pub depth_scale: Option<f64>,
    /// Tolerance in seconds for pairing rgb.txt and depth.txt (TUM associate.py: 0.02).
    pub max_difference: f64,
    /// An ORB-SLAM-style association file to use instead of pairing by timestamp.
    pub association_file: Option<PathBuf>,
    /// An ORB-SLAM2 settings YAML file with the calibration (overrides the sequence's).
    pub settings: Option<PathBuf>,
    /// Camera intrinsics (override both the settings file and the sequence's).
    pub camera: Option<PinholeCamera>,
    /// A recording's colour topic (`sensor_msgs/Image` or `CompressedImage`); unset:
    /// found from the messages ([`crate::io::recording::topics`]).
    pub rgb_topic: Option<String>,
    /// A recording's depth topic (registered to the colour camera); unset: found.
    pub depth_topic: Option<String>,
    /// A recording's `sensor_msgs/CameraInfo` topic; unset: the colour topic's.
    pub camera_info_topic: Option<String>,
    /// A recording's pose topic to read as the ground truth (`PoseStamped`,
    /// `Odometry`, `TransformStamped`); unset: none.
    pub ground_truth_topic: Option<String>,
    /// A TUM trajectory file to evaluate a recording's run against, for a recording
    /// that carries no pose topic (relative paths: from the config's folder).
    pub ground_truth_file: Option<PathBuf>,
    /// What applying `settings` did (set by [`Config::apply_orbslam_settings`]).
    #[serde(skip)]
    pub settings_applied: Option<SettingsApplied>,
}

impl DatasetConfig {
    /// How to read a TUM/Bonn folder under this config.
    pub fn tum_options(&self) -> TumOptions {
        TumOptions {
            depth_scale: self.depth_scale,
            max_difference: self.max_difference,
            association_file: self.association_file.clone(),
        }
    }

    /// The recording topics this config names.
    pub fn topics(&self) -> TopicChoice {
        TopicChoice {
            rgb: self.rgb_topic.clone(),
            depth: self.depth_topic.clone(),
            camera_info: self.camera_info_topic.clone(),
            ground_truth: self.ground_truth_topic.clone(),
        }
    }

    /// Each topic `given` names replaces this config's (command-line options, batch
    /// entries).
    pub fn override_topics(&mut self, given: &TopicChoice) {
        let keys = [
            (&given.rgb, &mut self.rgb_topic),
            (&given.depth, &mut self.depth_topic),
            (&given.camera_info, &mut self.camera_info_topic),
            (&given.ground_truth, &mut self.ground_truth_topic),
        ];
        for (given, key) in keys {
            if given.is_some() {
                key.clone_from(given);
            }
        }
    }

    /// How to read a recording (ROS bag, MCAP) under this config.
    pub fn recording_options(&self) -> RecordingOptions {
        RecordingOptions {
            topics: self.topics(),
            depth_scale: self.depth_scale,
            max_difference: self.max_difference,
            ground_truth_file: self.ground_truth_file.clone(),
        }
    }
}

impl Default for DatasetConfig {
    fn default() -> Self {
        Self {
            depth_scale: None,
            max_difference: 0.02,
            association_file: None,
            settings: None,
            camera: None,
            rgb_topic: None,
            depth_topic: None,
            camera_info_topic: None,
            ground_truth_topic: None,
            ground_truth_file: None,
            settings_applied: None,
        }
    }
}

/// Defaults of `dopslam eval` and of the evaluations the pipeline writes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct EvalConfig {
    /// How estimated and reference poses are paired (evo's or TUM's rule).
    pub association: AssociationRule,
    /// Seconds; unset: the rule's own default (evo 0.01, TUM 0.02).
    pub max_diff: Option<f64>,
    /// The alignment before the ATE (SE(3), Sim(3), none).
    pub align: AlignMode,
    /// Fail below this fraction of matched poses.
    pub min_coverage: f64,
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self {
            association: AssociationRule::Evo,
            max_diff: None,
            align: AlignMode::Se3,
            min_coverage: 0.5,
        }
    }
}

/// The whole configuration.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct Config {
    /// `[orb]`: the feature extractor.
    pub orb: OrbConfig,
    /// `[tracking]`: the tracker.
    pub tracking: TrackerConfig,
    /// `[mapping]`: local mapping.
    pub mapping: MappingConfig,
    /// `[detector]`: the keyframe detector.
    pub detector: DetectorConfig,
    /// `[dop]`: the DOP model.
    pub dop: DopConfig,
    /// `[dataset]`: how a sequence is read.
    pub dataset: DatasetConfig,
    /// `[eval]`: the evaluation against ground truth.
    pub eval: EvalConfig,
    /// `[dense]`: the dense pass.
    pub dense: DenseConfig,
    /// `[global]`: loops, full BA, the frames refined.
    pub global: crate::global::GlobalConfig,
    /// `[stereo]`: what changes for a stereo sequence.
    pub stereo: StereoConfig,
    /// `[output]`: what a run writes beside its fixed outputs (the Rerun recording).
    pub output: crate::view::OutputConfig,
}

/// What a stereo sequence (a street at 10 Hz, 1241x376) runs with instead of the
/// RGB-D values above: ORB-SLAM2's KITTI settings and a street-scale TSDF.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StereoConfig {
    /// Keypoints per image (`orb.n_features`; ORB-SLAM2 KITTI: 2000).
    pub n_features: usize,
    /// Close/far threshold in baselines (`tracking.th_depth`; ORB-SLAM2 KITTI: 35).
    pub th_depth: f64,
    /// A keyframe at least this often (`tracking.max_frames_between_keyframes`: the fps).
    pub max_frames_between_keyframes: usize,
    /// TSDF voxel edge, truncation and farthest fused depth, metres.
    pub voxel: f64,
    /// TSDF truncation, metres.
    pub truncation: f64,
    /// The farthest fused depth, metres.
    pub max_depth: f64,
    /// Point-cloud voxel edge, metres.
    pub cloud_voxel: f64,
    /// `dense.allocate_first`: off by default, since its first pass would match every
    /// stereo pair twice.
    pub allocate_first: bool,
    /// `dense.far_carves`: off by default, since a disparity below the one of
    /// `max_depth` is a pixel or two, where a mismatch on a blank wall would carve the
    /// wall.
    pub far_carves: bool,
    /// `dense.mask_map_min_weight`: 0 (off) by default, since it was measured on
    /// RGB-D only.
    pub mask_map_min_weight: f32,
    /// `dense.mask_free_space_seconds`: off by default, since each fused pair would
    /// need two more pairs matched, and the depth tolerance is a depth sensor's.
    pub mask_free_space_seconds: f64,
    /// `dense.mask_free_space_no_return`: off, since a pixel SGBM leaves without a
    /// disparity found no match there, which says nothing of what is there.
    pub mask_free_space_no_return: f32,
    /// `dense.frame_still_gap`: 0 (off) by default, since a car waiting at a light
    /// would have every pair matched for the little of the street its movers uncover.
    pub frame_still_gap: usize,
    /// `tracking.wait_near_boxes_only`: on by default, since at street speed a
    /// keyframe's new points are the ones that matter.
    pub wait_near_boxes_only: bool,
    /// OpenCV StereoSGBM: disparities searched (a multiple of 16) and block size (odd).
    pub sgbm_disparities: i32,
    /// The SGBM block size (odd).
    pub sgbm_block: i32,
    /// SGBM matches the pair at 1/this of its size (1, 2 or 4), with this many times
    /// fewer disparities: a quarter of the pixels and half the disparities at 2.
    pub sgbm_downscale: u32,
    /// Keypoints farther than this many baselines are bearings only: their disparity
    /// still places new points, but adds no residual to the pose or bundle adjustment
    /// (0: every matched keypoint keeps its disparity residual). See
    /// [`crate::frame::stereo::bearings_beyond`].
    pub bearing_baselines: f64,
    /// The rig's known disparity offset, pixels, added to every disparity (tracking's
    /// matches and the dense pass's). Unset: estimated while tracking the first
    /// `disparity_offset_frames` frames ([`crate::run::rig_offset`]).
    pub disparity_offset_px: Option<f64>,
    /// With no known offset: tracking looks for it within its first this many frames
    /// and, once an estimate passes the confidence test, takes it out of the map and
    /// adds it to every later frame's matches ([`crate::run::rig_offset`]); 0: only the
    /// global pass's estimate.
    pub disparity_offset_frames: usize,
}

impl Default for StereoConfig {
    fn default() -> Self {
        Self {
            n_features: 2000,
            th_depth: 35.0,
            max_frames_between_keyframes: 10,
            voxel: 0.1,
            truncation: 0.4,
            max_depth: 25.0,
            cloud_voxel: 0.1,
            allocate_first: false,
            far_carves: false,
            mask_map_min_weight: 0.0,
            mask_free_space_seconds: 0.0,
            mask_free_space_no_return: 0.0,
            frame_still_gap: 0,
            wait_near_boxes_only: true,
            sgbm_disparities: 128,
            sgbm_block: 5,
            sgbm_downscale: 1,
            bearing_baselines: 22.0,
            disparity_offset_px: None,
            disparity_offset_frames: 150,
        }
    }
}

/// The largest rig disparity offset accepted, pixels: a rectification that far off is
/// a wrong calibration, not an offset.
const MAX_DISPARITY_OFFSET_PX: f64 = 20.0;

impl StereoConfig {
    /// The semi-global matcher's settings for the dense depth of stereo pairs.
    pub fn sgbm(&self) -> crate::dense::disparity::SgbmSettings {
        crate::dense::disparity::SgbmSettings {
            disparities: self.sgbm_disparities,
            block: self.sgbm_block,
            downscale: self.sgbm_downscale,
        }
    }

    /// Sets the keys of other sections this profile names in `config`: what it set, and
    /// which of the config's own values it replaced.
    fn apply(&self, config: &mut Config) -> ProfileApplied {
        let default = Config::default();
        let mut p = ProfileApplied::new("stereo");
        let (orb, d_orb) = (&mut config.orb, &default.orb);
        p.set(
            "orb.n_features",
            &mut orb.n_features,
            self.n_features,
            d_orb.n_features,
        );
        let (t, dt) = (&mut config.tracking, &default.tracking);
        p.set(
            "tracking.th_depth",
            &mut t.th_depth,
            self.th_depth,
            dt.th_depth,
        );
        p.set(
            "tracking.max_frames_between_keyframes",
            &mut t.max_frames_between_keyframes,
            self.max_frames_between_keyframes,
            dt.max_frames_between_keyframes,
        );
        p.set(
            "tracking.wait_near_boxes_only",
            &mut t.wait_near_boxes_only,
            self.wait_near_boxes_only,
            dt.wait_near_boxes_only,
        );
        let (tsdf, d_tsdf) = (&mut config.dense.tsdf, &default.dense.tsdf);
        p.set("dense.voxel", &mut tsdf.voxel, self.voxel, d_tsdf.voxel);
        p.set(
            "dense.truncation",
            &mut tsdf.truncation,
            self.truncation,
            d_tsdf.truncation,
        );
        p.set(
            "dense.max_depth",
            &mut tsdf.max_depth,
            self.max_depth,
            d_tsdf.max_depth,
        );
        let first = (self.allocate_first, d_tsdf.allocate_first);
        p.set(
            "dense.allocate_first",
            &mut tsdf.allocate_first,
            first.0,
            first.1,
        );
        p.set(
            "dense.far_carves",
            &mut tsdf.far_carves,
            self.far_carves,
            d_tsdf.far_carves,
        );
        p.set(
            "dense.frame_still_gap",
            &mut config.dense.frames.still_gap,
            self.frame_still_gap,
            default.dense.frames.still_gap,
        );
        let (cloud, d_cloud) = (&mut config.dense.cloud, &default.dense.cloud);
        p.set(
            "dense.cloud_voxel",
            &mut cloud.voxel,
            self.cloud_voxel,
            d_cloud.voxel,
        );
        self.apply_masks(&mut config.dense.masks, &default.dense.masks, &mut p);
        p
    }

    /// The profile's `[dense]` mask keys.
    fn apply_masks(
        &self,
        masks: &mut crate::dense::config::DenseMasks,
        default: &crate::dense::config::DenseMasks,
        p: &mut ProfileApplied,
    ) {
        p.set(
            "dense.mask_free_space_seconds",
            &mut masks.free_space_seconds,
            self.mask_free_space_seconds,
            default.free_space_seconds,
        );
        p.set(
            "dense.mask_free_space_no_return",
            &mut masks.free_space_no_return,
            self.mask_free_space_no_return,
            default.free_space_no_return,
        );
        p.set(
            "dense.mask_map_min_weight",
            &mut masks.map_min_weight,
            self.mask_map_min_weight,
            default.map_min_weight,
        );
    }

    fn validate(&self) -> Result<(), BadValue> {
        checks::at_least_one("stereo.n_features", self.n_features as u64)?;
        checks::each(
            "stereo",
            checks::positive,
            &[
                ("th_depth", self.th_depth),
                ("voxel", self.voxel),
                ("truncation", self.truncation),
                ("max_depth", self.max_depth),
                ("cloud_voxel", self.cloud_voxel),
            ],
        )?;
        checks::each(
            "stereo",
            checks::non_negative,
            &[
                ("mask_free_space_seconds", self.mask_free_space_seconds),
                (
                    "mask_free_space_no_return",
                    self.mask_free_space_no_return.into(),
                ),
                ("mask_map_min_weight", self.mask_map_min_weight.into()),
                ("bearing_baselines", self.bearing_baselines),
            ],
        )?;
        if let Some(offset) = self.disparity_offset_px {
            if offset.abs() > MAX_DISPARITY_OFFSET_PX {
                return Err(BadValue::new(
                    "stereo.disparity_offset_px",
                    format!("must be within ±{MAX_DISPARITY_OFFSET_PX} pixels, got {offset}"),
                ));
            }
        }
        if !(16..=1024).contains(&self.sgbm_disparities) || self.sgbm_disparities % 16 != 0 {
            return Err(BadValue::new(
                "stereo.sgbm_disparities",
                format!(
                    "must be a multiple of 16 from 16 to 1024, got {}",
                    self.sgbm_disparities
                ),
            ));
        }
        if self.sgbm_block < 1 || self.sgbm_block % 2 == 0 || self.sgbm_block > 21 {
            return Err(BadValue::new(
                "stereo.sgbm_block",
                format!("must be odd, 1 to 21, got {}", self.sgbm_block),
            ));
        }
        if ![1, 2, 4].contains(&self.sgbm_downscale) {
            return Err(BadValue::new(
                "stereo.sgbm_downscale",
                format!("must be 1, 2 or 4, got {}", self.sgbm_downscale),
            ));
        }
        Ok(())
    }
}

impl Config {
    /// Reads and validates a TOML config file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let mut config = read_checked(path, Self::validate)?;
        config.resolve_paths(path.parent().unwrap_or(Path::new("")));
        if let Some(settings) = config.dataset.settings.clone() {
            // The error names the config that named the settings file.
            config
                .apply_orbslam_settings(&settings)
                .map_err(|e| ConfigError::NamedSettings {
                    config: path.to_path_buf(),
                    source: Box::new(e),
                })?;
        }
        Ok(config)
    }

    /// Takes the config's relative file paths from `base`, the folder of the config
    /// file (as a synth preset's are): `[dataset] settings`, `ground_truth_file`,
    /// `[detector] model_path`,
    /// `model_paths`, each pool entry's `path`, `ort_library`, `cache_dir` and
    /// `[global] vocabulary`. `[dataset] association_file` stays relative to the
    /// sequence folder, where such files live.
    pub fn resolve_paths(&mut self, base: &Path) {
        let from = |path: &mut PathBuf| {
            if path.is_relative() && !base.as_os_str().is_empty() {
                *path = base.join(&*path);
            }
        };
        let detector = &mut self.detector;
        let optional = [
            &mut self.dataset.settings,
            &mut self.dataset.ground_truth_file,
            &mut detector.ort_library,
            &mut detector.cache_dir,
            &mut self.global.vocabulary,
        ];
        optional.into_iter().flatten().for_each(from);
        detector.models.named_paths_mut().into_iter().for_each(from);
    }

    /// Parses and validates TOML text; the message names the offending key.
    pub fn from_toml(text: &str) -> Result<Self, ConfigProblem> {
        let config: Config = toml::from_str(text)?;
        config.validate()?;
        Ok(config)
    }

    /// The config a sequence of `sensor` runs with, and the sensor profile applied:
    /// for stereo, `[stereo]`'s values take the place of the RGB-D ones they name, and
    /// the profile says which (and which values the config had set there).
    pub fn for_sensor(
        &self,
        sensor: crate::io::sequence::SensorKind,
    ) -> (Self, Option<ProfileApplied>) {
        let mut config = self.clone();
        if sensor != crate::io::sequence::SensorKind::Stereo {
            return (config, None);
        }
        let profile = self.stereo.apply(&mut config);
        (config, Some(profile))
    }

    /// Checks every value's range; the error names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        self.check_numbers()?;
        self.orb.validate()?;
        self.stereo.validate()?;
        self.detector.validate()?;
        self.dop.validate()?;
        let never_static = &self.dop.never_static_classes;
        crate::detect::coco::check_class_names("dop.never_static_classes", never_static)?;
        crate::detect::coco::check_class_names("dop.track_classes", &self.dop.track_classes)?;
        self.dense.validate()?;
        self.output.validate()?;
        self.global.smoothing.validate()?;
        checks::non_negative(
            "global.disparity_offset_min_px",
            self.global.disparity_offset_min_px,
        )?;
        checks::unit_interval(
            "tracking.prediction_gate_share",
            self.tracking.prediction_gate_share,
        )?;
        checks::unit_interval("mapping.redundancy", self.mapping.redundancy)?;
        checks::at_least_one(
            "tracking.place_within_frames",
            self.tracking.place_within_frames as u64,
        )?;
        checks::at_least_one(
            "mapping.local_ba_keyframes",
            self.mapping.local_ba_keyframes as u64,
        )?;
        if let Some(scale) = self.dataset.depth_scale {
            checks::positive("dataset.depth_scale", scale)?;
        }
        checks::positive("dataset.max_difference", self.dataset.max_difference)?;
        if let Some(camera) = &self.dataset.camera {
            camera.validate().map_err(|bad| bad.within("dataset"))?;
        }
        checks::unit_interval("eval.min_coverage", self.eval.min_coverage)?;
        if let Some(max_diff) = self.eval.max_diff {
            checks::non_negative("eval.max_diff", max_diff)?;
        }
        Ok(())
    }

    /// Applies an ORB-SLAM2 settings file: every key with a meaning here
    /// ([`crate::io::orbslam_settings::APPLIED_KEYS`]). The camera (`Camera.*`) is read
    /// from the file by the run ([`Self::dataset`]`.settings`); `ThDepth`, `Camera.fps`
    /// (ORB-SLAM2's most frames between keyframes) and the `ORBextractor.*` values go
    /// into the tracking, stereo and ORB sections; `DepthMapFactor` sets the depth scale
    /// unless the config sets one. This is the one path for `--settings` and
    /// `[dataset] settings`; what it did is kept in `dataset.settings_applied`.
    pub fn apply_orbslam_settings(&mut self, path: &Path) -> Result<OrbSlamSettings, ConfigError> {
        let settings = OrbSlamSettings::read(path)?;
        let mut replaced = Replaced::default();
        self.settle_orb(&settings.orb, &mut replaced);
        self.settle_calibration(&settings.calibration, &mut replaced);
        let calibration = &settings.calibration;
        if self.dataset.depth_scale.is_none() {
            self.dataset.depth_scale = calibration.depth_scale;
        }
        self.dataset.settings = Some(path.to_path_buf());
        let (applied, no_meaning, unknown) = settings.sort_keys();
        self.dataset.settings_applied = Some(SettingsApplied {
            file: path.to_path_buf(),
            applied,
            no_meaning,
            unknown,
            replaced: replaced.0,
        });
        self.validate().map_err(|bad| ConfigError::Invalid {
            path: path.to_path_buf(),
            problem: bad.into(),
        })?;
        Ok(settings)
    }

    /// The settings file's ORB extractor over the config's `[orb]` (and `[stereo]`'s
    /// feature count).
    fn settle_orb(
        &mut self,
        orb: &crate::io::orbslam_settings::OrbSettings,
        replaced: &mut Replaced,
    ) {
        let d = Config::default();
        if let Some(v) = orb.n_features {
            let key = "ORBextractor.nFeatures";
            replaced.settle(
                &mut self.orb.n_features,
                d.orb.n_features,
                v,
                "orb.n_features",
                key,
            );
            replaced.settle(
                &mut self.stereo.n_features,
                d.stereo.n_features,
                v,
                "stereo.n_features",
                key,
            );
        }
        if let Some(v) = orb.scale_factor {
            let key = "ORBextractor.scaleFactor";
            replaced.settle(
                &mut self.orb.scale_factor,
                d.orb.scale_factor,
                v,
                "orb.scale_factor",
                key,
            );
        }
        if let Some(v) = orb.n_levels {
            replaced.settle(
                &mut self.orb.n_levels,
                d.orb.n_levels,
                v,
                "orb.n_levels",
                "ORBextractor.nLevels",
            );
        }
        if let Some(v) = orb.ini_th_fast {
            let key = "ORBextractor.iniThFAST";
            replaced.settle(
                &mut self.orb.ini_th_fast,
                d.orb.ini_th_fast,
                v,
                "orb.ini_th_fast",
                key,
            );
        }
        if let Some(v) = orb.min_th_fast {
            let key = "ORBextractor.minThFAST";
            replaced.settle(
                &mut self.orb.min_th_fast,
                d.orb.min_th_fast,
                v,
                "orb.min_th_fast",
                key,
            );
        }
    }

    /// The settings file's `ThDepth` and `Camera.fps` over `[tracking]` and `[stereo]`.
    fn settle_calibration(
        &mut self,
        calibration: &crate::io::orbslam_settings::Calibration,
        replaced: &mut Replaced,
    ) {
        let d = Config::default();
        if let Some(v) = calibration.th_depth {
            replaced.settle(
                &mut self.tracking.th_depth,
                d.tracking.th_depth,
                v,
                "tracking.th_depth",
                "ThDepth",
            );
            replaced.settle(
                &mut self.stereo.th_depth,
                d.stereo.th_depth,
                v,
                "stereo.th_depth",
                "ThDepth",
            );
        }
        if let Some(fps) = calibration.fps {
            // ORB-SLAM2's most frames between keyframes is the frame rate.
            let v = fps.round().max(1.0) as usize;
            let (tracking, stereo) = (&mut self.tracking, &mut self.stereo);
            replaced.settle(
                &mut tracking.max_frames_between_keyframes,
                d.tracking.max_frames_between_keyframes,
                v,
                "tracking.max_frames_between_keyframes",
                "Camera.fps",
            );
            replaced.settle(
                &mut stereo.max_frames_between_keyframes,
                d.stereo.max_frames_between_keyframes,
                v,
                "stereo.max_frames_between_keyframes",
                "Camera.fps",
            );
        }
    }
}

/// The settings file at `path` (a config, a synth preset) read, parsed and checked with
/// `validate`; the error names the file.
pub fn read_checked<T: serde::de::DeserializeOwned>(
    path: &Path,
    validate: impl FnOnce(&T) -> Result<(), BadValue>,
) -> Result<T, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let parsed: Result<T, ConfigProblem> = toml::from_str(&text)
        .map_err(ConfigProblem::from)
        .and_then(|value| Ok(validate(&value).map(|()| value)?));
    parsed.map_err(|problem| ConfigError::Invalid {
        path: path.to_path_buf(),
        problem,
    })
}

/// Whether a key's number may be negative: `dense.cloud_free_space` and the lens
/// distortion; every other number of a config is a size, a time, a weight, a
/// threshold or a probability, and is never below 0.
fn may_be_negative(key: &str) -> bool {
    key == "dense.cloud_free_space"
        || key.starts_with("dataset.camera.distortion")
        || key.starts_with("dataset.camera.rational")
}

impl Config {
    /// Every number of the config, wherever it is: finite (no NaN, no infinity, which
    /// TOML accepts) and, but for [`may_be_negative`] keys, not below 0. The sections' own
    /// checks then narrow the ranges.
    fn check_numbers(&self) -> Result<(), BadValue> {
        let value = toml::Value::try_from(self)
            .map_err(|e| BadValue::new("config", format!("cannot be written as TOML: {e}")))?;
        check_value(&value, "")
    }
}

fn check_value(value: &toml::Value, key: &str) -> Result<(), BadValue> {
    let child = |name: &str| {
        if key.is_empty() {
            name.to_string()
        } else {
            format!("{key}.{name}")
        }
    };
    match value {
        toml::Value::Float(x) if !x.is_finite() => Err(BadValue::new(
            key,
            format!("must be a finite number, got {x}"),
        )),
        toml::Value::Float(x) if *x < 0.0 && !may_be_negative(key) => {
            Err(BadValue::new(key, format!("must not be negative, got {x}")))
        }
        toml::Value::Integer(x) if *x < 0 && !may_be_negative(key) => {
            Err(BadValue::new(key, format!("must not be negative, got {x}")))
        }
        toml::Value::Table(table) => table
            .iter()
            .try_for_each(|(k, v)| check_value(v, &child(k))),
        toml::Value::Array(items) => items
            .iter()
            .enumerate()
            .try_for_each(|(i, v)| check_value(v, &format!("{key}[{i}]"))),
        _ => Ok(()),
    }
}

/// The config keys a settings file replaced, as a run says them.
#[derive(Default)]
struct Replaced(Vec<String>);

impl Replaced {
    /// Sets `slot` to `value`, the settings file's (its `key`), noting the config key
    /// `name` when the config had set it (to another value than its `default`) and
    /// the file changes it: the file's values come last and win, and a run says so.
    fn settle<T: PartialEq + std::fmt::Display + Copy>(
        &mut self,
        slot: &mut T,
        default: T,
        value: T,
        name: &str,
        key: &str,
    ) {
        if *slot != default && *slot != value {
            self.0.push(format!("{name} {} -> {value} ({key})", *slot));
        }
        *slot = value;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_and_partial_files() {
        let config = Config::from_toml("[orb]\nn_features = 1500\n").unwrap();
        assert_eq!(config.orb.n_features, 1500);
        assert_eq!(config.orb.scale_factor, 1.2);
        assert_eq!(config.eval.min_coverage, 0.5);
    }

    #[test]
    fn unknown_keys_are_named() {
        let message = Config::from_toml("[orb]\nn_featurez = 1500\n")
            .unwrap_err()
            .to_string();
        assert!(message.contains("n_featurez"), "{message}");
        let message = Config::from_toml("[nonsense]\n").unwrap_err().to_string();
        assert!(message.contains("nonsense"), "{message}");
    }

    #[test]
    fn every_number_is_finite_and_sizes_are_not_negative() {
        for (text, key) in [
            ("[tracking]\nth_depth = nan\n", "tracking.th_depth"),
            (
                "[tracking]\nmotion_search_radius = -1.0\n",
                "tracking.motion_search_radius",
            ),
            (
                "[tracking]\nprediction_gate_share = 1.5\n",
                "tracking.prediction_gate_share",
            ),
            (
                "[tracking]\nprediction_gate_share = nan\n",
                "tracking.prediction_gate_share",
            ),
            ("[dop]\ngamma = inf\n", "dop.gamma"),
            ("[dense]\nvoxel = nan\n", "dense.voxel"),
            (
                "[dense]\nmask_segment_radius_metres = -0.6\n",
                "dense.mask_segment_radius_metres",
            ),
            (
                "[dense]\nmask_segment_radius_metres = inf\n",
                "dense.mask_segment_radius_metres",
            ),
            (
                "[global.smoothing]\nacceleration = -1.0\n",
                "global.smoothing.acceleration",
            ),
            (
                "[stereo]\nsgbm_disparities = -16\n",
                "stereo.sgbm_disparities",
            ),
            ("[stereo]\nsgbm_downscale = 3\n", "stereo.sgbm_downscale"),
            (
                "[stereo]\nbearing_baselines = -1.0\n",
                "stereo.bearing_baselines",
            ),
            (
                "[stereo]\nbearing_baselines = inf\n",
                "stereo.bearing_baselines",
            ),
            (
                "[stereo]\ndisparity_offset_px = 40.0\n",
                "stereo.disparity_offset_px",
            ),
            (
                "[stereo]\ndisparity_offset_px = nan\n",
                "stereo.disparity_offset_px",
            ),
            (
                "[global]\ndisparity_offset_min_px = -1.0\n",
                "global.disparity_offset_min_px",
            ),
        ] {
            match Config::from_toml(text) {
                Err(ConfigProblem::Value(bad)) => assert_eq!(bad.key, key, "{text}: {bad}"),
                other => panic!("{text}: {other:?}"),
            }
        }
        assert!(Config::from_toml("[dense]\ncloud_free_space = -0.5\n").is_ok());
        let distorted = "[dataset.camera]\nfx = 517.3\nfy = 516.5\ncx = 318.6\ncy = 255.3\nwidth = 640\nheight = 480\ndistortion = [0.26, -0.95, -0.005, 0.003, 1.16]\n";
        assert!(
            Config::from_toml(distorted).is_ok(),
            "{:?}",
            Config::from_toml(distorted)
        );
    }

    /// Relative paths are the config file's, wherever the command runs.
    #[test]
    fn relative_paths_are_taken_from_the_config_folder() {
        let dir = std::env::temp_dir().join(format!("dopslam-config-paths-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("cams")).unwrap();
        std::fs::write(
            dir.join("cams/cam.yaml"),
            "%YAML:1.0\nCamera.fx: 500.0\nCamera.fy: 500.0\nCamera.cx: 320.0\nCamera.cy: 240.0\n",
        )
        .unwrap();
        let text = "[dataset]\nsettings = \"cams/cam.yaml\"\n[detector]\nmodel_paths = [\"m/a.onnx\", \"/abs/b.onnx\"]\n[global]\nvocabulary = \"voc.dbow\"\n";
        std::fs::write(dir.join("my.toml"), text).unwrap();
        let config = Config::load(&dir.join("my.toml")).unwrap();
        assert_eq!(config.dataset.settings, Some(dir.join("cams/cam.yaml")));
        assert_eq!(
            config.detector.model_files(),
            [dir.join("m/a.onnx"), PathBuf::from("/abs/b.onnx")]
        );
        assert_eq!(config.global.vocabulary, Some(dir.join("voc.dbow")));
        assert!(
            config.dataset.settings_applied.is_some(),
            "the settings file was read"
        );
        std::fs::write(
            dir.join("missing.toml"),
            "[dataset]\nsettings = \"nope.yaml\"\n",
        )
        .unwrap();
        let e = Config::load(&dir.join("missing.toml"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("missing.toml")
                && e.contains("[dataset] settings")
                && e.contains("nope.yaml"),
            "{e}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A settings file's values come after the config's and win; each config value it
    /// replaces (set, and to another value) is named with both values.
    #[test]
    fn a_settings_file_names_the_config_values_it_replaces() {
        let dir = std::env::temp_dir().join(format!("dopslam-config-over-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let settings = dir.join("cam.yaml");
        let yaml = "%YAML:1.0\nCamera.fx: 500.0\nCamera.fy: 500.0\nCamera.cx: 320.0\nCamera.cy: 240.0\nCamera.fps: 10.0\nORBextractor.nFeatures: 1000\n";
        std::fs::write(&settings, yaml).unwrap();
        let text = "[stereo]\nmax_frames_between_keyframes = 1\n[orb]\nn_features = 1000\nscale_factor = 1.3\n";
        let mut config = Config::from_toml(text).unwrap();
        config.apply_orbslam_settings(&settings).unwrap();
        assert_eq!(config.stereo.max_frames_between_keyframes, 10);
        let applied = config.dataset.settings_applied.clone().unwrap();
        // The same value (n_features), a key the file lacks (scale_factor) and the
        // defaults the file changes are not replacements.
        assert_eq!(
            applied.replaced,
            ["stereo.max_frames_between_keyframes 1 -> 10 (Camera.fps)"]
        );
        let notes = applied.notes();
        assert!(
            notes
                .iter()
                .any(|n| n.contains("replaces") && n.contains("1 -> 10")),
            "{notes:?}"
        );
        assert_eq!(config.orb.scale_factor, 1.3);
        let mut plain = Config::default();
        plain.apply_orbslam_settings(&settings).unwrap();
        assert!(plain.dataset.settings_applied.unwrap().replaced.is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_values_are_named() {
        for (text, key) in [
            ("[orb]\nscale_factor = 0.5\n", "orb.scale_factor"),
            ("[dataset]\ndepth_scale = -5000.0\n", "dataset.depth_scale"),
            (
                "[dataset.camera]\nfx = 0.0\nfy = 1.0\ncx = 1.0\ncy = 1.0\nwidth = 2\nheight = 2\n",
                "dataset.camera.fx",
            ),
            (
                "[dop]\nnever_static_classes = [\"ghost\"]\n",
                "dop.never_static_classes",
            ),
            ("[dop]\ntrack_classes = [\"lorry\"]\n", "dop.track_classes"),
            (
                "[dense]\nmask_free_space_tolerance_growth = -0.01\n",
                "dense.mask_free_space_tolerance_growth",
            ),
            (
                "[dense]\nmask_free_space_no_return = nan\n",
                "dense.mask_free_space_no_return",
            ),
            ("[dense]\nmask_map_band = -0.01\n", "dense.mask_map_band"),
        ] {
            let message = Config::from_toml(text).unwrap_err().to_string();
            assert!(message.starts_with(key), "{message}");
        }
    }

    #[test]
    fn the_stereo_profile_states_what_it_sets_and_what_it_replaced() {
        use crate::io::sequence::SensorKind;
        let config = Config::from_toml("[dense]\nvoxel = 0.02\n[stereo]\nvoxel = 0.2\n").unwrap();
        let (rgbd, none) = config.for_sensor(SensorKind::Rgbd);
        assert!(none.is_none());
        assert_eq!(rgbd.dense.tsdf.voxel, 0.02);
        let (stereo, profile) = config.for_sensor(SensorKind::Stereo);
        let profile = profile.expect("a stereo profile");
        assert_eq!(stereo.dense.tsdf.voxel, 0.2);
        assert_eq!(stereo.orb.n_features, config.stereo.n_features);
        assert_eq!(profile.set.len(), 14, "{:?}", profile.set);
        assert!(profile
            .set
            .contains(&"dense.frame_still_gap = 0".to_string()));
        assert_eq!(stereo.dense.frames.still_gap, 0);
        assert_eq!(rgbd.dense.frames.still_gap, 1);
        assert!(profile
            .set
            .contains(&"dense.far_carves = false".to_string()));
        assert!(profile.set.contains(&"dense.voxel = 0.2".to_string()));
        assert!(profile
            .set
            .contains(&"dense.mask_free_space_no_return = 0".to_string()));
        // The config's own [dense] voxel is named; the defaults it never set are not.
        assert_eq!(
            profile.replaced,
            ["dense.voxel = 0.02 replaced by stereo.voxel = 0.2"]
        );
        assert!(profile.warnings()[0].contains("[stereo] applies"));
    }
}
