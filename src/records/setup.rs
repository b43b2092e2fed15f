//! `report.json`'s `setup` section: what a run was set up with.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::io::orbslam_settings::Calibration;

/// What a run was set up with: the effective camera and ORB parameters after the
/// config, the settings file and `--camera`, and the runtime files it loaded.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RunSetup {
    /// The camera, its baseline and depth scale.
    pub calibration: Calibration,
    /// The ORB settings.
    pub orb: crate::features::orb::OrbConfig,
    /// `ThDepth` and ORB-SLAM2's most frames between keyframes (`Camera.fps`).
    pub th_depth: f64,
    /// The most frames between keyframes.
    pub max_frames_between_keyframes: usize,
    /// The ORB-SLAM2 settings file and which of its keys were applied.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub settings: Option<SettingsApplied>,
    /// The sensor profile (`[stereo]`) and the keys it set.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor_profile: Option<ProfileApplied>,
    /// The runtime data directory and why it was chosen (`dopslam doctor`).
    pub data_dir: String,
    /// Where detections came from.
    pub detections: crate::detect::Source,
    /// The detector's files (models, then the ONNX Runtime library) when it is ONNX.
    pub detector_files: Vec<PathBuf>,
    /// The vocabulary file, when loop closing ran.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub vocabulary: Option<PathBuf>,
    /// `run::first_frame_hash` of the sequence: `dopslam fuse` checks that it fuses the
    /// sequence the run tracked.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub first_frame_hash: Option<String>,
    /// Stereo: the rig's disparity offset added to every disparity, and where it came
    /// from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub disparity_offset: Option<RigOffset>,
    /// What the reader found wrong with the input and read past (a recording cut short
    /// at a byte, without index): the run is of what could be read.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub input_warnings: Vec<String>,
}

/// The rig's disparity offset a run adds to every stereo match (`report.json`,
/// `setup.disparity_offset`; estimated by `run::rig_offset`).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RigOffset {
    /// Pixels added to every disparity (0: the estimate did not pass its confidence
    /// test).
    pub offset_px: f64,
    /// `"config"` (`[stereo] disparity_offset_px`) or `"estimated"`.
    pub source: String,
    /// Estimated: the frames tracked when the tracking pass made its last estimate.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frames: Option<usize>,
    /// Estimated: the last estimate (its rounds, as the global pass reports them) and
    /// the confidence test's verdict on it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub estimate: Option<crate::global::disparity_offset::OffsetReport>,
    /// Estimated: each correction the tracking pass made (the first, then what it
    /// left); `offset_px` is their sum.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub taken: Vec<TakenOut>,
}

/// One correction of the rig's offset by the tracking pass.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct TakenOut {
    /// Frames tracked when it was made.
    pub frames: usize,
    /// Pixels taken out of every disparity then.
    pub offset_px: f64,
}

impl RigOffset {
    /// One line for the console.
    pub fn summary(&self) -> String {
        match (&self.estimate, self.frames) {
            (Some(estimate), Some(frames)) if self.offset_px != 0.0 => {
                let taken: Vec<String> = self
                    .taken
                    .iter()
                    .map(|t| format!("{:.3} px at frame {}", t.offset_px, t.frames))
                    .collect();
                format!(
                    "stereo disparity offset: {:.3} px, taken out of the map by tracking ({}) and added to every later match; last estimate at frame {frames}: {}",
                    self.offset_px,
                    taken.join(", then "),
                    estimate.verdict
                )
            }
            (Some(estimate), _) if estimate.rounds.is_empty() => format!(
                "stereo disparity offset: none taken out by tracking ({})",
                estimate.verdict
            ),
            (Some(estimate), Some(frames)) => format!(
                "stereo disparity offset: none taken out by tracking (last estimate at frame {frames}: {})",
                estimate.verdict
            ),
            _ => format!(
                "stereo disparity offset: {:.3} px added to every disparity ([stereo] disparity_offset_px)",
                self.offset_px
            ),
        }
    }
}

/// What a sensor profile (`[stereo]` for a stereo sequence) set in place of other
/// sections' keys (`report.json`, `setup.sensor_profile`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ProfileApplied {
    /// The profile's section: `stereo`.
    pub profile: String,
    /// Each key it set and its value: `dense.voxel = 0.1`.
    pub set: Vec<String>,
    /// Keys the config had set (away from their defaults) to another value, which the
    /// profile replaced: `dense.voxel = 0.05 replaced by stereo.voxel = 0.1`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub replaced: Vec<String>,
}

impl ProfileApplied {
    /// A profile of section `profile` that has set nothing yet.
    pub fn new(profile: &str) -> Self {
        Self {
            profile: profile.to_string(),
            ..Self::default()
        }
    }

    /// Sets `slot` (key `key`, whose default is `default`) to the profile's `value`,
    /// noting a value the config had set there.
    pub fn set<T: PartialEq + std::fmt::Display>(
        &mut self,
        key: &str,
        slot: &mut T,
        value: T,
        default: T,
    ) {
        let name = key.rsplit('.').next().unwrap_or(key);
        if *slot != default && *slot != value {
            self.replaced.push(format!(
                "{key} = {slot} replaced by {}.{name} = {value}",
                self.profile
            ));
        }
        self.set.push(format!("{key} = {value}"));
        *slot = value;
    }

    /// The warnings to print once: the config's values the profile replaced.
    pub fn warnings(&self) -> Vec<String> {
        self.replaced
            .iter()
            .map(|r| format!("warning: [{}] applies to this sequence: {r} (set the [{}] key to change it here)", self.profile, self.profile))
            .collect()
    }
}

/// What applying an ORB-SLAM2 settings file did (in `report.json`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SettingsApplied {
    /// The settings file.
    pub file: PathBuf,
    /// Keys that set something here.
    pub applied: Vec<String>,
    /// ORB-SLAM2 keys known to have no meaning here (`Viewer.*`, `Camera.RGB`).
    pub no_meaning: Vec<String>,
    /// Keys this tool does not know (a typo, or another system's).
    pub unknown: Vec<String>,
    /// Config values the file replaced: set (not to their defaults) by the config
    /// before the settings file was applied, each with the two values and the file's key.
    #[serde(default)]
    pub replaced: Vec<String>,
}

impl SettingsApplied {
    /// The lines to print once about the keys not applied.
    pub fn notes(&self) -> Vec<String> {
        let mut notes = Vec::new();
        if !self.no_meaning.is_empty() {
            notes.push(format!(
                "settings {}: no meaning here, ignored: {}",
                self.file.display(),
                self.no_meaning.join(", ")
            ));
        }
        if !self.unknown.is_empty() {
            notes.push(format!(
                "warning: settings {}: unknown keys, ignored: {}",
                self.file.display(),
                self.unknown.join(", ")
            ));
        }
        if !self.replaced.is_empty() {
            notes.push(format!(
                "warning: settings {} replaces what the config set: {}",
                self.file.display(),
                self.replaced.join(", ")
            ));
        }
        notes
    }
}
