//! What the dense pass reads: the run folder's trajectory, keyframes, segments,
//! detections and dynamic keypoints ([`read_run`]), and each frame's depth and colour
//! from the sequence.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::detection_feed::DetectionFeed;
use super::disparity::{stereo_depth, StereoDepth};
use super::frame_table::FrameTable;
use super::keypoint_feed::KeypointFeed;
use super::masks::FrameKeypoints;
use super::outputs::CameraPaths;
use super::{interrupted, Chosen};
use crate::dop::{DopConfig, Mode};
use crate::geometry::camera::PinholeCamera;
use crate::geometry::se3::Se3;
use crate::io::image_files::DepthImage;
use crate::io::run_dir::RunDir;
use crate::io::sequence::{FrameImages, Sequence};
use crate::io::IoError;

/// Where the dense pass finds its inputs.
pub struct DenseInputs<'a> {
    /// The sequence.
    pub sequence: &'a dyn Sequence,
    /// The undistorted colour camera.
    pub camera: PinholeCamera,
    /// The run folder (inputs).
    pub run_dir: &'a Path,
    /// Where the dense outputs go (usually the run folder).
    pub out_dir: &'a Path,
    /// DOP, mask boxes or none.
    pub masking: Mode,
    /// The DOP model's settings.
    pub dop: &'a DopConfig,
    /// The COCO classes that move.
    pub dynamic_classes: &'a [String],
    /// A synthetic sequence's `masks/` folder, to count what was fused.
    pub truth_masks: Option<PathBuf>,
    /// Show progress bars.
    pub progress: bool,
    /// How stereo pairs become depth (stereo sequences only).
    pub stereo: Option<StereoDepth>,
    /// The detector for `detect_every` (DOP masks only).
    pub detector: Option<(std::sync::Mutex<Box<dyn crate::detect::Detector>>, String)>,
    /// The run's keyframe detections came from the same detector (its description):
    /// a frame next to a detected keyframe is not detected again
    /// ([`super::more_detections::Schedule`]).
    pub keyframe_boxes_alike: bool,
}

/// What the dense pass reads from a finished run.
pub(super) struct RunInputs<'a> {
    /// The frames with their final poses (`trajectory.txt`), keyframes and segments.
    pub table: FrameTable<'a>,
    /// The trajectory files the pictures' viewpoint comes from.
    pub cameras: CameraPaths,
    /// The keyframes' detections and the frames' dynamic keypoints (none when the
    /// masking is off).
    pub detections: DetectionFeed,
    pub keypoints: KeypointFeed,
}

/// Reads the run folder `run` of `sequence` for a dense pass masking with `masking`;
/// the frame table's spill file goes into `spill_dir`.
pub(super) fn read_run<'a>(
    run: &RunDir,
    sequence: &'a dyn Sequence,
    masking: Mode,
    spill_dir: &Path,
) -> Result<RunInputs<'a>, IoError> {
    let table = FrameTable::read(run, sequence, spill_dir)?;
    let mut detections = DetectionFeed::default();
    let mut keypoints = KeypointFeed::default();
    if masking != Mode::Off {
        detections.add_folder(&run.detections())?;
        keypoints = KeypointFeed::from_file(&run.dynamic_keypoints())?;
    }
    Ok(RunInputs {
        table,
        cameras: CameraPaths(vec![run.trajectory()]),
        detections,
        keypoints,
    })
}

/// A frame's depth and colour: an RGB-D frame's own, or a stereo pair's SGBM depth
/// and its left image in grey.
pub(super) fn depth_and_colour(
    images: FrameImages,
    stereo: Option<&StereoDepth>,
    what: &Path,
) -> Result<(DepthImage, image::RgbImage), IoError> {
    match images {
        FrameImages::Rgbd { rgb, depth } => Ok((depth, rgb)),
        FrameImages::Stereo { left, right } => {
            let stereo = stereo.ok_or_else(|| {
                IoError::invalid(what, "a stereo frame, but no stereo calibration was given")
            })?;
            let depth =
                stereo_depth(&left, &right, stereo).map_err(|m| IoError::invalid(what, m))?;
            Ok((depth, image::DynamicImage::ImageLuma8(left).to_rgb8()))
        }
    }
}

/// Reads `dynamic_keypoints.json` (empty when the run had no DOP model).
pub fn read_keypoints(path: &Path) -> Result<Vec<FrameKeypoints>, IoError> {
    if !path.exists() {
        return Ok(Vec::new());
    }
    let text = crate::io::errors::read_text(path)?;
    serde_json::from_str(&text).map_err(|e| IoError::invalid(path, format!("malformed: {e}")))
}

/// The detected frames' poses and depth maps for placing their objects
/// ([`super::masks::MaskSource::place_through`]), as fusion comes near them. A stereo
/// pair matched for that is kept until fusion takes it ([`Self::take_matched`]), so
/// each pair is matched once; what fusion passes by unfused is let go.
pub(super) struct FrameLookup<'a> {
    inputs: &'a DenseInputs<'a>,
    table: &'a FrameTable<'a>,
    matched: std::sync::Mutex<HashMap<usize, DepthImage>>,
}

impl<'a> FrameLookup<'a> {
    /// The frames of `inputs` with their final poses in `table`.
    pub fn new(inputs: &'a DenseInputs<'a>, table: &'a FrameTable<'a>) -> Self {
        Self {
            inputs,
            table,
            matched: Default::default(),
        }
    }

    /// The final `camera_from_world` of the frame at time `t`.
    pub fn pose(&self, t: f64) -> Result<Option<Se3>, IoError> {
        self.table.pose_at(t)
    }

    /// The depth of the frame at time `t` (`None` when unreadable); a stereo pair's
    /// is kept for fusion.
    pub fn depth(&self, t: f64) -> Option<DepthImage> {
        let i = self.table.index_at(t)?;
        let depth = frame_depth(self.inputs, i).ok()?;
        if self.inputs.stereo.is_some() {
            self.matched_frames().insert(i, depth.clone());
        }
        Some(depth)
    }

    /// Frame `i`'s depth if it was matched for the placement, let go with those of
    /// the frames before it.
    pub fn take_matched(&self, i: usize) -> Option<DepthImage> {
        let mut matched = self.matched_frames();
        let depth = matched.remove(&i);
        matched.retain(|&j, _| j > i);
        depth
    }

    fn matched_frames(&self) -> std::sync::MutexGuard<'_, HashMap<usize, DepthImage>> {
        self.matched
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }
}

/// Frame `i`'s depth alone: an RGB-D reader skips the colour image; a stereo pair is
/// matched.
pub(super) fn frame_depth(inputs: &DenseInputs, i: usize) -> Result<DepthImage, IoError> {
    match inputs.sequence.load_depth(i)? {
        Some(depth) => Ok(depth),
        None => sequence_frame(inputs, i, None).map(|(_, depth, _)| depth),
    }
}

/// A decoded frame: timestamp, depth and colour.
pub(super) type LoadedFrame = (f64, DepthImage, image::RgbImage);

/// Frame `i` of the sequence; a stereo pair whose depth was `matched` already is not
/// matched again.
pub(super) fn sequence_frame(
    inputs: &DenseInputs,
    i: usize,
    matched: Option<DepthImage>,
) -> Result<LoadedFrame, IoError> {
    let frame = inputs.sequence.load(i)?;
    let timestamp = frame.timestamp;
    match (frame.images, matched) {
        (FrameImages::Stereo { left, .. }, Some(depth)) => Ok((
            timestamp,
            depth,
            image::DynamicImage::ImageLuma8(left).to_rgb8(),
        )),
        (images, _) => depth_and_colour(images, inputs.stereo.as_ref(), inputs.run_dir)
            .map(|(depth, rgb)| (timestamp, depth, rgb)),
    }
}

/// Hands the `chosen` frames to `each` in groups of two per thread: each group is
/// decoded in parallel ([`load_group`]), then used in order.
pub(super) fn for_each_group(
    chosen: impl Iterator<Item = Result<Chosen, IoError>>,
    mut each: impl FnMut(&[Chosen]) -> Result<(), IoError>,
) -> Result<(), IoError> {
    let size = rayon::current_num_threads().max(1) * 2;
    let mut group = Vec::with_capacity(size);
    for frame in chosen {
        group.push(frame?);
        if group.len() == size {
            each(&group)?;
            group.clear();
        }
    }
    match group.is_empty() {
        true => Ok(()),
        false => each(&group),
    }
}

/// A group of chosen frames, each loaded by `load` in parallel (after an interrupt
/// check, see [`check_interrupt`]).
pub(super) fn load_group<T: Send>(
    inputs: &DenseInputs,
    group: &[Chosen],
    load: impl Fn(&DenseInputs, usize) -> Result<T, IoError> + Sync,
) -> Result<Vec<Result<T, IoError>>, IoError> {
    check_interrupt(inputs)?;
    Ok(group.par_iter().map(|&(i, _, _)| load(inputs, i)).collect())
}

/// `Err` once an interrupt was asked for: the dense map is then not written.
pub(super) fn check_interrupt(inputs: &DenseInputs) -> Result<(), IoError> {
    interrupted(inputs.out_dir, "the dense map was not written")
}
