//! A keyframe detection as a job: the image in, the detections (or the detector's
//! error) and the inference time out. The system's detection worker
//! (`system::detection`) runs jobs beside tracking; in real-time mode it detects only
//! the newest waiting keyframe and returns the older ones [`skipped`] (their boxes
//! reach them through the newer keyframe's, see [`crate::dynamics::keyframes`]).

use std::time::Instant;

use image::RgbImage;

use super::{Detection, Detector};

/// A keyframe image to detect in; `id` is the caller's (a frame index).
pub struct Job {
    /// The caller's identifier (a frame index).
    pub id: usize,
    /// The frame's time, seconds.
    pub timestamp: f64,
    /// The image.
    pub image: RgbImage,
}

/// The detections of a job (or the detector's error) and the inference time.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The job's identifier.
    pub id: usize,
    /// The frame's time, seconds.
    pub timestamp: f64,
    /// The boxes, or why the detector failed.
    pub detections: Result<Vec<Detection>, String>,
    /// The detector's time on the image.
    pub milliseconds: f64,
    /// Each model's share of it (a pool of models), name and milliseconds.
    pub model_milliseconds: Vec<(String, f64)>,
    /// Not detected: a newer keyframe was waiting (real-time mode only).
    pub skipped: bool,
}

/// Detects in one job's image, timed.
pub fn run(detector: &mut dyn Detector, job: Job) -> Outcome {
    let start = Instant::now();
    let detections = detector
        .detect(job.timestamp, &job.image)
        .map_err(|e| e.to_string());
    Outcome {
        id: job.id,
        timestamp: job.timestamp,
        detections,
        milliseconds: start.elapsed().as_secs_f64() * 1e3,
        model_milliseconds: detector.model_times(),
        skipped: false,
    }
}

/// The outcome of a job that was dropped for a newer one.
pub fn skipped(job: &Job) -> Outcome {
    Outcome {
        id: job.id,
        timestamp: job.timestamp,
        detections: Ok(Vec::new()),
        milliseconds: 0.0,
        model_milliseconds: Vec::new(),
        skipped: true,
    }
}
