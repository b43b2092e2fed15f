//! Detections between keyframes, for the dense masks only (`[dense] detect_every`).
//!
//! The tracking pass detects on keyframes (6-12 % of the frames of the people
//! presets). A person the detector misses on the keyframes around a stretch of frames
//! is fused into the map there, and stays where the camera never sees through them
//! later. The dense pass is offline, so it can afford the detector on every
//! `detect_every`-th fused frame as well: more chances to find each person, and shorter
//! gaps for the followed objects to be predicted across. These detections only make
//! masks; the trajectory is already final. They are cached in `detections_dense/`
//! ([`crate::io::run_dir::RunDir::dense_detections`]) of the output folder in the detection cache's format, so `dopslam fuse` runs the
//! detector once per frame.

use std::collections::HashSet;
use std::path::Path;
use std::time::Instant;

use crate::detect::{write_cache, Detector, FrameDetections};
use crate::io::sequence::{FrameImages, Sequence};
use crate::io::IoError;

/// What the extra detections cost.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ExtraDetections {
    /// Frames detected now, and frames whose detections came from the cache.
    pub detected: usize,
    pub cached: usize,
    pub median_ms: f64,
    /// Frames the detector failed on (a `cache` source has keyframes only): their
    /// masks come from the keyframes, as without `detect_every`; the first message.
    pub failed: usize,
    pub first_error: Option<String>,
}

/// Adds the dense pass's own detections to `detections` (the keyframes'): those cached
/// in `cache` from an earlier fusion, then every `every`-th of the `fused` frames that
/// has none yet, detected now and cached. Frames the detector fails on keep the
/// keyframes' masks, with a warning.
pub fn add(
    sequence: &dyn Sequence,
    detector: &mut dyn Detector,
    (fused, every): (&[usize], usize),
    cache: &Path,
    detections: &mut Vec<FrameDetections>,
    progress: bool,
) -> Result<ExtraDetections, IoError> {
    let cached = crate::dense::read_detections(cache)?;
    let known: HashSet<i64> = detections
        .iter()
        .chain(&cached)
        .map(|f| super::key(f.timestamp))
        .collect();
    let todo = frames_to_detect(fused, every, |i| sequence.timestamp(i), &known);
    let mut extra = ExtraDetections {
        cached: cached.len(),
        ..Default::default()
    };
    let found = detect_frames(sequence, detector, &todo, cache, progress, &mut extra)?;
    if let Some(first) = &extra.first_error {
        eprintln!(
            "warning: the detector failed on {} of {} frames of the dense masks (first: {first}); their masks come from the keyframes",
            extra.failed,
            todo.len()
        );
    }
    detections.extend(cached);
    detections.extend(found);
    Ok(extra)
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

/// Detects on `frames` of `sequence` and writes each result to `cache`; frames the
/// detector fails on are counted in `report` and left out.
pub fn detect_frames(
    sequence: &dyn Sequence,
    detector: &mut dyn Detector,
    frames: &[usize],
    cache: &Path,
    progress: bool,
    report: &mut ExtraDetections,
) -> Result<Vec<FrameDetections>, IoError> {
    let bar = super::frames_bar("detect ", frames.len(), progress);
    let mut found = Vec::with_capacity(frames.len());
    let mut milliseconds = Vec::with_capacity(frames.len());
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
                found.push(frame);
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
    report.detected = found.len();
    report.median_ms = crate::eval::stats::median(&mut milliseconds);
    Ok(found)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_nth_fused_frame_is_detected_unless_known() {
        let time = |i: usize| 100.0 + i as f64 / 30.0;
        let fused: Vec<usize> = (0..20).filter(|i| i % 3 != 2).collect();
        let known: HashSet<i64> = [crate::dense::key(time(5))].into();
        assert_eq!(frames_to_detect(&fused, 5, time, &known), vec![0, 10, 15]);
        assert!(frames_to_detect(&fused, 0, time, &known).is_empty());
        assert_eq!(frames_to_detect(&fused, 1, time, &HashSet::new()), fused);
    }
}
