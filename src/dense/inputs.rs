//! What the dense pass reads: the run folder's trajectory, keyframes, segments,
//! detections and dynamic keypoints ([`read_run`]), and each frame's depth and colour
//! from the sequence.

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use rayon::prelude::*;

use super::disparity::{stereo_depth, StereoDepth};
use super::keypoint_feed::KeypointFeed;
use super::masks::FrameKeypoints;
use super::{interrupted, Chosen};
use crate::detect::FrameDetections;
use crate::dop::{DopConfig, Mode};
use crate::geometry::camera::PinholeCamera;
use crate::geometry::se3::Se3;
use crate::io::image_files::DepthImage;
use crate::io::run_dir::RunDir;
use crate::io::sequence::{FrameImages, Sequence};
use crate::io::trajectory::TrajectoryFormat;
use crate::io::{IoError, Trajectory};

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
pub(super) struct RunInputs {
    /// The final trajectory (`trajectory.txt`).
    pub trajectory: Trajectory,
    /// The final poses (`camera_from_world`) by time, of the largest map segment.
    pub poses: HashMap<i64, Se3>,
    /// Tracked frames left out: they lie in another map segment.
    pub other_segment_frames: usize,
    pub keyframe_times: HashSet<i64>,
    /// The keyframes' detections and the frames' dynamic keypoints (none when the
    /// masking is off).
    pub detections: Vec<FrameDetections>,
    pub keypoints: KeypointFeed,
}

/// Reads the run folder `run` for a dense pass masking with `masking`.
pub(super) fn read_run(run: &RunDir, masking: Mode) -> Result<RunInputs, IoError> {
    let trajectory = Trajectory::read(&run.trajectory(), TrajectoryFormat::Tum)?;
    let keyframes = Trajectory::read(&run.keyframes(), TrajectoryFormat::Tum).unwrap_or_default();
    let mut poses = poses_by_time(&trajectory);
    let mut other_segment_frames = 0;
    if let Some(keep) = largest_segment(run)? {
        let before = poses.len();
        poses.retain(|t, _| keep.contains(t));
        other_segment_frames = before - poses.len();
    }
    let (detections, keypoints) = if masking == Mode::Off {
        (Vec::new(), KeypointFeed::default())
    } else {
        (
            read_detections(&run.detections())?,
            KeypointFeed::from_file(&run.dynamic_keypoints())?,
        )
    };
    Ok(RunInputs {
        keyframe_times: keyframes.timestamps.iter().map(|&t| key(t)).collect(),
        trajectory,
        poses,
        other_segment_frames,
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

/// Timestamps as keys (microseconds, as the file names carry them).
pub(super) fn key(t: f64) -> i64 {
    (t * 1e6).round() as i64
}

/// The timestamps of the frames in the largest segment of the run's `segments.txt`
/// ([`RunDir::segments`]: each tracked frame's timestamp and map segment after the
/// loops' merges), when it lists more than one (`None`: fuse every frame; also for runs
/// written before the file existed). Segments that no loop merged have unrelated
/// frames of reference, so only the largest is fused.
pub(super) fn largest_segment(run: &RunDir) -> Result<Option<HashSet<i64>>, IoError> {
    let Some(lines) = crate::io::run_dir::read_segments(&run.segments())? else {
        return Ok(None);
    };
    let mut frames: HashMap<usize, Vec<i64>> = HashMap::new();
    for (t, segment) in lines {
        frames.entry(segment).or_default().push(key(t));
    }
    if frames.len() < 2 {
        return Ok(None);
    }
    // The most frames; ties go to the older segment.
    let largest = frames
        .into_iter()
        .max_by(|a, b| a.1.len().cmp(&b.1.len()).then(b.0.cmp(&a.0)))
        .map(|(_, times)| times.into_iter().collect());
    Ok(largest)
}

/// The frames' final poses (`camera_from_world`) by timestamp.
pub(super) fn poses_by_time(trajectory: &Trajectory) -> HashMap<i64, Se3> {
    trajectory
        .timestamps
        .iter()
        .zip(&trajectory.poses)
        .map(|(&t, pose)| (key(t), pose.inverse()))
        .collect()
}

/// Reads the keyframe detections a run cached (`detections/*.json`).
pub fn read_detections(dir: &Path) -> Result<Vec<FrameDetections>, IoError> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Ok(Vec::new());
    };
    let mut frames = Vec::new();
    for entry in entries.flatten() {
        let path = entry.path();
        if path.extension().is_some_and(|e| e == "json") {
            let frame = crate::detect::read_cache_file(&path)
                .map_err(|e| IoError::invalid(&path, e.to_string()))?;
            frames.push(frame);
        }
    }
    Ok(frames)
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
    poses: &'a HashMap<i64, Se3>,
    index_of: HashMap<i64, usize>,
    matched: std::sync::Mutex<HashMap<usize, DepthImage>>,
}

impl<'a> FrameLookup<'a> {
    /// The frames of `inputs` with their final `poses` (`camera_from_world`).
    pub fn new(inputs: &'a DenseInputs<'a>, poses: &'a HashMap<i64, Se3>) -> Self {
        let sequence = inputs.sequence;
        Self {
            inputs,
            poses,
            index_of: (0..sequence.len())
                .map(|i| (key(sequence.timestamp(i)), i))
                .collect(),
            matched: Default::default(),
        }
    }

    /// The final `camera_from_world` of the frame at time `t`.
    pub fn pose(&self, t: f64) -> Option<Se3> {
        self.poses.get(&key(t)).copied()
    }

    /// The depth of the frame at time `t` (`None` when unreadable); a stereo pair's
    /// is kept for fusion.
    pub fn depth(&self, t: f64) -> Option<DepthImage> {
        let i = *self.index_of.get(&key(t))?;
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

/// The chosen frames in groups of two per thread: each group is decoded in parallel,
/// then used in order.
pub(super) fn groups(chosen: &[Chosen]) -> std::slice::Chunks<'_, Chosen> {
    chosen.chunks(rayon::current_num_threads().max(1) * 2)
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::run_dir::names;

    #[test]
    fn only_the_largest_unmerged_segment_is_fused() {
        let dir = std::env::temp_dir().join(format!("dopslam-segments-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let run = RunDir::new(&dir);
        let with = |text: &str| {
            std::fs::write(run.segments(), text).unwrap();
            largest_segment(&run)
        };
        let keep = with("# t s\n1.0 0\n1.1 0\n2.0 1\n2.1 1\n2.2 1\n")
            .unwrap()
            .expect("two segments");
        let expected: std::collections::HashSet<i64> = [2.0, 2.1, 2.2].map(key).into();
        assert_eq!(keep, expected);
        // One segment (or no file): every frame.
        assert_eq!(with("1.0 0\n1.1 0\n").unwrap(), None);
        assert_eq!(
            largest_segment(&RunDir::new(dir.join("absent"))).unwrap(),
            None
        );
        let error = with("1.0 0\n1.1 zero\n").unwrap_err().to_string();
        assert!(
            error.contains("line 2") && error.contains(names::SEGMENTS),
            "{error}"
        );
        let _ = std::fs::remove_dir_all(&dir);
    }
}
