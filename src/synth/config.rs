//! The synth config: TOML files in `configs/synth/`, one per preset.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::motion::MotionConfig;
use super::movers::{ObjectsConfig, PeopleConfig, SeatedConfig};
use super::oracle::OracleConfig;
use super::render::SensorConfig;
use super::street::StreetConfig;
use crate::checks::{self, BadValue};
use crate::config::{read_checked, ConfigError};
use crate::geometry::camera::PinholeCamera;

/// How many frames, how fast, from which seed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SequenceConfig {
    /// Frames rendered.
    pub frames: usize,
    /// Frame rate when no timing file is given.
    pub fps: f64,
    /// The seed of everything random.
    pub seed: u64,
    /// Real frame timing: a TUM association file or rgb.txt (the first column is used).
    pub timing: Option<PathBuf>,
    /// Render the same room and camera path with the movers left out: the control that
    /// shows what the movers cost the tracker (the room is laid out around the movers'
    /// paths either way, so only the movers differ).
    pub without_movers: bool,
}

impl Default for SequenceConfig {
    fn default() -> Self {
        Self {
            frames: 300,
            fps: 30.0,
            seed: 1,
            timing: None,
            without_movers: false,
        }
    }
}

/// The room and its furniture.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneConfig {
    /// Distance from the camera path's bounding box to the walls, in metres.
    pub room_margin: f64,
    /// Pieces of furniture.
    pub furniture: usize,
    /// Furniture keeps at least this far from every camera position, in metres.
    pub clearance: f64,
    /// How the surfaces look: `blocks` (every face its own noise and coloured blocks)
    /// or `room` (a wooden floor, plaster walls with framed pictures, a tiled ceiling).
    pub look: SceneLook,
    /// A table in the middle of the camera path, standing on the floor: `[length,
    /// width, height]` in metres (the length along the mean viewing direction); none
    /// when absent. A camera circling it looks down at it, as in TUM's fr2_desk.
    pub table: Option<[f64; 3]>,
    /// Render the room of another synth config (its walls and furniture, as its own
    /// camera path and movers shaped them; relative to this file) instead of one laid
    /// out around this config's path: a second recording of the same room, with
    /// movers of its own. The other config must not name a room of its own.
    pub room_of: Option<PathBuf>,
}

/// `[scene] look`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SceneLook {
    #[default]
    /// Textured blocks in a plain room.
    Blocks,
    /// A furnished room.
    Room,
}

impl Default for SceneConfig {
    fn default() -> Self {
        Self {
            room_margin: 2.5,
            furniture: 14,
            clearance: 0.9,
            look: SceneLook::Blocks,
            table: None,
            room_of: None,
        }
    }
}

/// Stereo output: a second, right camera `baseline` metres along the left camera's x
/// axis, written in the KITTI odometry layout under `kitti/`; 0 turns it off.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct StereoConfig {
    /// The stereo baseline, metres.
    pub baseline: f64,
    /// A real rig's rectification error, in pixels: the right camera is rendered with
    /// its principal point this far right of the one `calib.txt` states, so every
    /// measured disparity is this much smaller than the geometry's, \(d = d_0 -
    /// \delta\) (depth too far by a share \(z\delta / bf\) that grows with the
    /// distance, as on the real KITTI 01 clip; `docs/design.md`). 0: a perfect rig.
    pub rectification_error_px: f64,
    /// A real rig's focal-length error: the right camera is rendered with focal
    /// lengths this share larger than `calib.txt` states, so a disparity is off by
    /// \(\epsilon (u_R - c_x)\): an error of opposite signs at the image's two sides
    /// that no single offset takes out (0.001 is 0.6 px at KITTI's sides). 0: none.
    pub rectification_scale_error: f64,
}

/// A depth camera of its own beside the colour camera, as RealSense and Azure Kinect
/// sensors are built: its depth is also written unregistered, under `depth_camera/`
/// with `depth_camera.yaml` (for the recording readers' registration tests).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DepthCameraConfig {
    /// Its intrinsics and image size (a pinhole: `distortion` must be zeros).
    pub camera: PinholeCamera,
    /// Its position in the colour camera's frame (metres; no rotation), i.e. the
    /// translation of \(T_{cd}\) (`colour_from_depth`).
    pub offset: [f64; 3],
}

/// A whole synth preset.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SynthConfig {
    /// The preset's name (written into scene.toml).
    pub name: String,
    /// `[sequence]`: frames, rate, seed, timing.
    pub sequence: SequenceConfig,
    /// The camera (TUM fr3 when unset).
    pub camera: Option<PinholeCamera>,
    /// `[motion]`: the camera's path.
    pub motion: MotionConfig,
    /// `[scene]`: the room and its furniture.
    pub scene: SceneConfig,
    /// `[people]`: walking people.
    pub people: PeopleConfig,
    /// `[seated]`: seated people who get up.
    pub seated: SeatedConfig,
    /// `[objects]`: moving objects of a COCO class.
    pub objects: ObjectsConfig,
    /// `[[unknown]]`: movers of no COCO class (a box slid across the floor, a balloon
    /// drifting), which no detector knows: only the geometric check can find them.
    pub unknown: Vec<ObjectsConfig>,
    /// `[oracle]`: the synthetic detector.
    pub oracle: OracleConfig,
    /// `[sensor]`: depth noise, exposure, blur.
    pub sensor: SensorConfig,
    /// `[stereo]`: the right camera.
    pub stereo: StereoConfig,
    /// `[depth_camera]`: a depth camera apart from the colour one.
    pub depth_camera: Option<DepthCameraConfig>,
    /// `[street]`: the street instead of the room.
    pub street: StreetConfig,
}

impl SynthConfig {
    /// Reads a preset; relative paths inside it are taken from the current folder.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let mut config = read_checked(path, Self::validate)?;
        config.resolve_paths(path.parent().unwrap_or(Path::new("")));
        Ok(config)
    }

    /// Relative file names in the config (timing, sprites, a trajectory to follow) are
    /// taken from the config file's folder, so a preset works from any folder.
    fn resolve_paths(&mut self, base: &Path) {
        for path in [
            &mut self.sequence.timing,
            &mut self.people.sprite,
            &mut self.seated.sprite,
            &mut self.motion.file,
            &mut self.scene.room_of,
        ]
        .into_iter()
        .flatten()
        {
            if path.is_relative() {
                *path = base.join(&*path);
            }
        }
    }

    /// The camera intrinsics (TUM fr3 unless the config gives others).
    pub fn camera(&self) -> PinholeCamera {
        self.camera.unwrap_or_else(PinholeCamera::tum_fr3)
    }

    /// Checks each value's range; the error names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        checks::at_least_one("sequence.frames", self.sequence.frames as u64)?;
        checks::positive("sequence.fps", self.sequence.fps)?;
        self.camera().validate()?;
        self.oracle.validate()?;
        self.sensor.validate()?;
        self.objects.validate("objects", true)?;
        for objects in &self.unknown {
            objects.validate("unknown", false)?;
        }
        self.street.validate()?;
        if !(self.motion.start.is_finite() && self.motion.start >= 0.0) {
            return Err(BadValue::new(
                "motion.start",
                format!("must be 0 or more, got {}", self.motion.start),
            ));
        }
        if let Some(table) = self.scene.table {
            if !table
                .iter()
                .all(|s| s.is_finite() && *s > 0.0 && *s <= 10.0)
            {
                return Err(BadValue::new(
                    "scene.table",
                    format!("must be [length, width, height], each above 0 and at most 10 m, got {table:?}"),
                ));
            }
        }
        let error_px = self.stereo.rectification_error_px;
        if !(error_px.is_finite() && error_px.abs() <= 5.0) {
            return Err(BadValue::new(
                "stereo.rectification_error_px",
                format!("must be -5 to 5 pixels, got {error_px}"),
            ));
        }
        let scale = self.stereo.rectification_scale_error;
        if !(scale.is_finite() && scale.abs() <= 0.05) {
            return Err(BadValue::new(
                "stereo.rectification_scale_error",
                format!("must be -0.05 to 0.05, got {scale}"),
            ));
        }
        if !(0.0..=2.0).contains(&self.stereo.baseline) {
            return Err(BadValue::new(
                "stereo.baseline",
                format!("must be 0 (off) to 2 m, got {}", self.stereo.baseline),
            ));
        }
        if let Some(depth) = &self.depth_camera {
            depth
                .camera
                .validate()
                .map_err(|bad| bad.within("depth_camera"))?;
            if !depth.camera.is_undistorted() {
                return Err(BadValue::new(
                    "depth_camera.camera.distortion",
                    "must be zeros (a pinhole is rendered)",
                ));
            }
            if depth
                .offset
                .iter()
                .any(|v| !(v.is_finite() && v.abs() <= 0.5))
            {
                return Err(BadValue::new(
                    "depth_camera.offset",
                    format!("must be within 0.5 m, got {:?}", depth.offset),
                ));
            }
        }
        Ok(())
    }
}
