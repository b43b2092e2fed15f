//! Detections between keyframes, for the dense masks only (`[dense] detect_every`).
//!
//! The tracking pass detects on keyframes (6-12 % of the frames of the people
//! presets). A person the detector misses on the keyframes around a stretch of frames
//! is fused into the map there, and stays where the camera never sees through them
//! later. The dense pass is offline, so it can afford the detector on every
//! `detect_every`-th fused frame as well: more chances to find each person, and shorter
//! gaps for the followed objects to be predicted across. These detections only make
//! masks; the trajectory is already final. The detector is `[dense] detect_model` (a
//! better one than the tracking pass can afford, see docs/design.md). They are cached in `detections_dense/`
//! ([`crate::io::run_dir::RunDir::dense_detections`]) of the output folder in the detection cache's format, so `dopslam fuse` runs the
//! detector once per frame.

use std::collections::HashSet;
use std::path::Path;
use std::time::Instant;

use super::detection_feed::DetectionFeed;
use crate::detect::{write_cache, Detector, FrameDetections};
use crate::eval::stats::MedianSample;
use crate::io::atomic::write_atomic;
use crate::io::output::{move_previous_outputs, RUN_OUTPUTS};
use crate::io::run_dir::names;
use crate::io::sequence::{FrameImages, Sequence};
use crate::io::IoError;

/// What the extra detections cost.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExtraDetections {
    /// Frames detected now, and frames whose detections came from the cache.
    pub detected: usize,
    /// Frames whose detections came from the cache.
    pub cached: usize,
    /// Median detection time, milliseconds.
    pub median_ms: f64,
    /// Frames the detector failed on (a `cache` source has keyframes only): their
    /// masks come from the keyframes, as without `detect_every`; the first message.
    pub failed: usize,
    /// The first failure's message.
    pub first_error: Option<String>,
    /// Frames not detected because a keyframe within `detect_every / 2` frames was
    /// detected by the same detector in the tracking pass ([`Schedule`]).
    #[serde(default)]
    pub near_keyframes: usize,
}

/// Which frames the dense pass detects on.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Schedule {
    /// Every `every`-th fused frame (0: none).
    pub every: usize,
    /// The keyframes' detections came from the detector the dense pass runs: a frame
    /// within `every / 2` frames of a detected keyframe takes its boxes (the same
    /// detector on nearly the same image) and is not detected again.
    pub reuse_keyframes: bool,
}

/// The detector the dense pass runs, and how it describes itself (kept in a cache's
/// `detector.txt`).
pub struct Described<'a> {
    /// The detector.
    pub detector: &'a mut dyn Detector,
    /// Its description.
    pub describe: &'a str,
}

/// Adds the dense pass's own detections to `detections` (the keyframes'): those cached
/// in `cache` by the same detector (`describe`, kept in `cache/detector.txt`), then
/// every `every`-th of the `fused` frames that has none yet and no keyframe near it
/// detected alike ([`Schedule`]), detected now and cached; the feed reads them from
/// `cache`. A keyframe's own boxes stay, joined by the new ones that overlap none of
/// its boxes of their class ([`super::detection_feed::join`]). Frames the detector
/// fails on keep the keyframes' masks, with a warning.
pub fn add(
    sequence: &dyn Sequence,
    detector: Described,
    fused: &[usize],
    schedule: Schedule,
    cache: &Path,
    detections: &mut DetectionFeed,
    progress: bool,
) -> Result<ExtraDetections, IoError> {
    let Described { detector, describe } = detector;
    let cached = cached_by(cache, describe)?;
    let known = cached.keys();
    let keyframes: HashSet<i64> = match schedule.reuse_keyframes {
        true => detections.keys(),
        false => HashSet::new(),
    };
    let timestamp = |i: usize| sequence.timestamp(i);
    let wanted = frames_to_detect(fused, schedule.every, timestamp, &known);
    let near = KeyframesNear {
        reach: schedule.every / 2,
        frames: sequence.len(),
        keyframes: &keyframes,
    };
    let todo = near.others(&wanted, timestamp);
    let mut extra = ExtraDetections {
        cached: cached.len(),
        near_keyframes: wanted.len() - todo.len(),
        ..Default::default()
    };
    detect_frames(sequence, detector, &todo, cache, progress, &mut extra)?;
    if let Some(first) = &extra.first_error {
        eprintln!(
            "warning: the detector failed on {} of {} frames of the dense masks (first: {first}); their masks come from the keyframes",
            extra.failed,
            todo.len()
        );
    }
    detections.add_folder(cache)?;
    Ok(extra)
}

/// The detections cached in `cache` by the detector `describe`. A cache of another
/// detector (or of none named) is not used, nor mixed with the new boxes: it moves into
/// the run folder's `previous/` ([`move_previous_outputs`], nothing is deleted), and a
/// new `detector.txt` names the detector of the boxes detected now.
fn cached_by(cache: &Path, describe: &str) -> Result<DetectionFeed, IoError> {
    let stamp = cache.join("detector.txt");
    let same = std::fs::read_to_string(&stamp).is_ok_and(|s| s.trim_end() == describe);
    let mut cached = DetectionFeed::default();
    if same {
        cached.add_folder(cache)?;
        return Ok(cached);
    }
    if let Some(run) = cache.parent().filter(|_| cache.exists()) {
        let others: Vec<&str> = RUN_OUTPUTS
            .into_iter()
            .filter(|name| *name != names::DENSE_DETECTIONS)
            .collect();
        if let (_, Some(to)) = move_previous_outputs(run, &others)? {
            eprintln!(
                "note: the dense-pass detections in {} were made by another detector: moved to {}, detecting again",
                cache.display(),
                to.display()
            );
        }
    }
    std::fs::create_dir_all(cache).map_err(|source| IoError::Write {
        path: cache.to_path_buf(),
        source,
    })?;
    write_atomic(&stamp, format!("{describe}\n").as_bytes())?;
    Ok(cached)
}

/// The frames among `fused` (sequence indices, in order) to detect on: every
/// `every`-th index, skipping those whose timestamp (`timestamp(i)`, in whole
/// microseconds) is in `known`.
pub fn frames_to_detect(
    fused: &[usize],
    every: usize,
    timestamp: impl Fn(usize) -> f64,
    known: &HashSet<i64>,
) -> Vec<usize> {
    if every == 0 {
        return Vec::new();
    }
    fused
        .iter()
        .copied()
        .filter(|&i| i % every == 0 && !known.contains(&super::key(timestamp(i))))
        .collect()
}

/// Which frames are near a detected keyframe ([`Schedule::reuse_keyframes`]).
struct KeyframesNear<'a> {
    /// Frames either side that count as near.
    reach: usize,
    /// The sequence's length.
    frames: usize,
    /// The detected keyframes' times ([`super::key`]).
    keyframes: &'a HashSet<i64>,
}

impl KeyframesNear<'_> {
    /// The `wanted` frames with no detected keyframe within `reach` frames.
    fn others(&self, wanted: &[usize], timestamp: impl Fn(usize) -> f64) -> Vec<usize> {
        let last = self.frames.saturating_sub(1);
        let near = |i: usize| {
            (i.saturating_sub(self.reach)..=(i + self.reach).min(last))
                .any(|j| self.keyframes.contains(&super::key(timestamp(j))))
        };
        wanted.iter().copied().filter(|&i| !near(i)).collect()
    }
}

/// Detects on `frames` of `sequence` and writes each result to `cache`; frames the
/// detector fails on are counted in `report` and left out.
pub fn detect_frames(
    sequence: &dyn Sequence,
    detector: &mut dyn Detector,
    frames: &[usize],
    cache: &Path,
    progress: bool,
    report: &mut ExtraDetections,
) -> Result<(), IoError> {
    let bar = super::frames_bar("detect ", frames.len(), progress);
    let mut milliseconds = MedianSample::default();
    for &i in frames {
        if crate::interrupt::requested() {
            break;
        }
        let frame = sequence.load(i)?;
        let image = match frame.images {
            FrameImages::Rgbd { rgb, .. } => rgb,
            FrameImages::Stereo { left, .. } => image::DynamicImage::ImageLuma8(left).to_rgb8(),
        };
        let start = Instant::now();
        match detector.detect(frame.timestamp, &image) {
            Ok(detections) => {
                milliseconds.push(start.elapsed().as_secs_f64() * 1e3);
                let frame = FrameDetections {
                    timestamp: frame.timestamp,
                    detections,
                };
                write_cache(cache, &frame).map_err(|e| IoError::invalid(cache, e.to_string()))?;
                report.detected += 1;
            }
            Err(e) => {
                report.failed += 1;
                report
                    .first_error
                    .get_or_insert_with(|| format!("frame {i}: {e}"));
            }
        }
        bar.inc(1);
    }
    bar.finish_and_clear();
    report.median_ms = milliseconds.median();
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::detection_feed::frame;
    use super::*;

    #[test]
    fn a_cache_of_another_detector_is_not_used() {
        let dir = std::env::temp_dir().join(format!("dopslam-dense-cache-{}", std::process::id()));
        let cache = dir.join("detections_dense");
        std::fs::create_dir_all(&cache).unwrap();
        crate::detect::write_cache(&cache, &frame(1.0, &[[0.0, 0.0, 5.0, 5.0]])).unwrap();
        assert!(
            cached_by(&cache, "model a").unwrap().is_empty(),
            "no name: not used"
        );
        crate::detect::write_cache(&cache, &frame(1.0, &[[0.0, 0.0, 5.0, 5.0]])).unwrap();
        assert_eq!(cached_by(&cache, "model a").unwrap().len(), 1);
        assert!(cached_by(&cache, "model b").unwrap().is_empty());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn every_nth_fused_frame_is_detected_unless_known() {
        let time = |i: usize| 100.0 + i as f64 / 30.0;
        let fused: Vec<usize> = (0..20).filter(|i| i % 3 != 2).collect();
        let known: HashSet<i64> = [crate::dense::key(time(5))].into();
        assert_eq!(frames_to_detect(&fused, 5, time, &known), vec![0, 10, 15]);
        assert!(frames_to_detect(&fused, 0, time, &known).is_empty());
        assert_eq!(frames_to_detect(&fused, 1, time, &HashSet::new()), fused);
    }

    /// A frame within `every / 2` frames of a detected keyframe takes its boxes.
    #[test]
    fn frames_next_to_a_detected_keyframe_are_not_detected_again() {
        let time = |i: usize| 100.0 + i as f64 / 30.0;
        let keyframes: HashSet<i64> = [7, 19].map(|i| crate::dense::key(time(i))).into();
        let near = |reach| KeyframesNear {
            reach,
            frames: 20,
            keyframes: &keyframes,
        };
        let wanted = [0, 5, 10, 15, 19];
        assert_eq!(near(2).others(&wanted, time), vec![0, 10, 15]);
        assert_eq!(near(0).others(&wanted, time), vec![0, 5, 10, 15]);
        let none = HashSet::new();
        let near_none = KeyframesNear {
            keyframes: &none,
            ..near(2)
        };
        assert_eq!(near_none.others(&wanted, time), wanted);
    }
}
