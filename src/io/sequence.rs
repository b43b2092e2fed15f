//! The `Sequence` abstraction: an indexed, timestamped source of frames that loads
//! each frame's images only when asked (a sequence is never held in memory).

use image::{GrayImage, RgbImage};

use super::image_files::DepthImage;
use super::orbslam_settings::Calibration;
use super::{IoError, Trajectory};

/// The images of one frame.
#[derive(Debug, Clone)]
pub enum FrameImages {
    /// A colour image and a registered depth map in metres.
    Rgbd {
        /// The colour image.
        rgb: RgbImage,
        /// The depth map.
        depth: DepthImage,
    },
    /// A rectified stereo pair.
    Stereo {
        /// The left image.
        left: GrayImage,
        /// The right image.
        right: GrayImage,
    },
}

/// One frame of a sequence.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The frame's index.
    pub index: usize,
    /// Seconds.
    pub timestamp: f64,
    /// Its images.
    pub images: FrameImages,
}

/// Which sensor a sequence comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum SensorKind {
    /// A colour camera with a registered depth map.
    Rgbd,
    /// A rectified stereo pair.
    Stereo,
}

/// A recorded sequence of frames.
pub trait Sequence: Send + Sync {
    /// A short name (the folder's name).
    fn name(&self) -> &str;
    /// RGB-D or stereo.
    fn sensor(&self) -> SensorKind;
    /// The number of frames.
    fn len(&self) -> usize;
    /// Whether it has no frame.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// The timestamp of frame `index` in seconds.
    fn timestamp(&self, index: usize) -> f64;
    /// Loads frame `index` from disk.
    fn load(&self, index: usize) -> Result<Frame, IoError>;
    /// Loads only the depth of frame `index`: `None` for a stereo pair, whose depth
    /// is matched from the pair. The default loads the whole frame; readers that can
    /// skip the colour image do.
    fn load_depth(&self, index: usize) -> Result<Option<DepthImage>, IoError> {
        Ok(match self.load(index)?.images {
            FrameImages::Rgbd { depth, .. } => Some(depth),
            FrameImages::Stereo { .. } => None,
        })
    }
    /// The ground-truth trajectory, when the sequence has one.
    fn ground_truth(&self) -> Option<&Trajectory>;
    /// The calibration the sequence carries, when it has one.
    fn calibration(&self) -> Option<&Calibration>;
    /// What the reader found wrong with the input and read past (a recording cut
    /// short, without index, with stamps out of order): `report.json` keeps it.
    fn warnings(&self) -> &[String] {
        &[]
    }
}

/// The seconds frames `first` to `last` of `sequence` span, one mean frame interval
/// included (each frame stands for its interval): the recording's duration.
/// `None` for fewer than two frames or times out of order.
pub fn duration_of(sequence: &dyn Sequence, first: usize, last: usize) -> Option<f64> {
    if last <= first || last >= sequence.len() {
        return None;
    }
    let span = sequence.timestamp(last) - sequence.timestamp(first);
    let frames = (last - first) as f64;
    (span > 0.0 && span.is_finite()).then(|| span * (frames + 1.0) / frames)
}

/// Iterates over all frames, loading each one lazily.
pub fn frames(sequence: &dyn Sequence) -> impl Iterator<Item = Result<Frame, IoError>> + '_ {
    (0..sequence.len()).map(move |i| sequence.load(i))
}
