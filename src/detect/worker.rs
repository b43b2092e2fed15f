//! Detection beside tracking: keyframe images go to a worker thread through a channel
//! and their detections come back through another, so tracking never waits for the
//! detector (real-time mode). In deterministic mode the detector runs inline when a
//! keyframe is submitted, so results arrive in a fixed order.
//!
//! In real-time mode the detector must not fall behind: when several keyframes wait,
//! only the newest is detected and the older ones come back marked `skipped` (their
//! boxes reach them through the newer keyframe's, see [`crate::mapping::dynamic`]).
//! Without this a detector slower than the keyframe rate answers seconds late.
//! A simulated latency makes an instant source (the synthetic oracle) answer as late
//! as the real detector would.

use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;
use std::time::Instant;

use image::RgbImage;

use super::{Detection, Detector};

/// A keyframe image to detect in; `id` is the caller's (a frame index).
pub struct Job {
    pub id: usize,
    pub timestamp: f64,
    pub image: RgbImage,
}

/// The detections of a job (or the detector's error) and the inference time.
#[derive(Debug, Clone)]
pub struct Outcome {
    pub id: usize,
    pub timestamp: f64,
    pub detections: Result<Vec<Detection>, String>,
    pub milliseconds: f64,
    /// Not detected: a newer keyframe was waiting (real-time mode only).
    pub skipped: bool,
}

fn run(detector: &mut dyn Detector, job: Job) -> Outcome {
    let start = Instant::now();
    let detections = detector
        .detect(job.timestamp, &job.image)
        .map_err(|e| e.to_string());
    Outcome {
        id: job.id,
        timestamp: job.timestamp,
        detections,
        milliseconds: start.elapsed().as_secs_f64() * 1e3,
        skipped: false,
    }
}

/// The outcome of a job that was dropped for a newer one.
fn skipped(job: &Job) -> Outcome {
    Outcome {
        id: job.id,
        timestamp: job.timestamp,
        detections: Ok(Vec::new()),
        milliseconds: 0.0,
        skipped: true,
    }
}

/// What waits for which job's detection (a keyframe's new points, by keyframe id).
/// A skipped job's waiters go on waiting for the next job that is detected: the worker
/// skipped it for that newer one, whose boxes reach it.
#[derive(Debug, Default)]
pub struct Waiting {
    by_job: std::collections::HashMap<usize, usize>,
    skipped: Vec<usize>,
}

impl Waiting {
    /// `waiter` waits for job `job`.
    pub fn insert(&mut self, job: usize, waiter: usize) {
        self.by_job.insert(job, waiter);
    }

    /// The waiters an outcome releases: none for a skipped job (its waiter joins the
    /// next detected job's), else the job's own and those of the jobs skipped for it.
    pub fn release(&mut self, outcome: &Outcome) -> Vec<usize> {
        let waiter = self.by_job.remove(&outcome.id);
        if outcome.skipped {
            self.skipped.extend(waiter);
            return Vec::new();
        }
        waiter.into_iter().chain(self.skipped.drain(..)).collect()
    }
}

/// The detection worker.
pub enum DetectionWorker {
    Inline {
        detector: Box<dyn Detector>,
        done: Vec<Outcome>,
    },
    Thread {
        jobs: Sender<Job>,
        outcomes: Receiver<Outcome>,
        handle: JoinHandle<()>,
    },
}

impl DetectionWorker {
    /// Starts the worker; `latency` is added to each detection in real-time mode (a
    /// simulated detector time for instant sources).
    pub fn start(
        detector: Box<dyn Detector>,
        deterministic: bool,
        latency: std::time::Duration,
    ) -> Self {
        if deterministic {
            return Self::Inline {
                detector,
                done: Vec::new(),
            };
        }
        let (jobs, job_receiver) = channel::<Job>();
        let (outcome_sender, outcomes) = channel::<Outcome>();
        let handle = std::thread::Builder::new()
            .name("detection".into())
            .spawn(move || {
                crate::threads::lower_priority(10);
                let mut detector = detector;
                while let Ok(mut job) = job_receiver.recv() {
                    // Only the newest waiting keyframe is detected.
                    while let Ok(newer) = job_receiver.try_recv() {
                        if outcome_sender.send(skipped(&job)).is_err() {
                            return;
                        }
                        job = newer;
                    }
                    let outcome = run(detector.as_mut(), job);
                    let elapsed = std::time::Duration::from_secs_f64(outcome.milliseconds / 1e3);
                    if let Some(rest) = latency.checked_sub(elapsed) {
                        std::thread::sleep(rest);
                    }
                    if outcome_sender.send(outcome).is_err() {
                        break;
                    }
                }
            })
            .expect("spawn the detection thread");
        Self::Thread {
            jobs,
            outcomes,
            handle,
        }
    }

    /// Hands a keyframe image over (detected at once when inline).
    pub fn submit(&mut self, job: Job) {
        match self {
            Self::Inline { detector, done } => done.push(run(detector.as_mut(), job)),
            Self::Thread { jobs, .. } => {
                // Fails only if the thread panicked, which `finish` reports.
                let _ = jobs.send(job);
            }
        }
    }

    /// The outcomes finished so far, without waiting.
    pub fn poll(&mut self) -> Vec<Outcome> {
        match self {
            Self::Inline { done, .. } => std::mem::take(done),
            Self::Thread { outcomes, .. } => outcomes.try_iter().collect(),
        }
    }

    /// Waits up to `timeout` for the next outcome, then returns it with any others
    /// finished (at once when inline).
    pub fn wait(&mut self, timeout: std::time::Duration) -> Vec<Outcome> {
        match self {
            Self::Inline { done, .. } => std::mem::take(done),
            Self::Thread { outcomes, .. } => match outcomes.recv_timeout(timeout) {
                Ok(first) => std::iter::once(first).chain(outcomes.try_iter()).collect(),
                Err(_) => Vec::new(),
            },
        }
    }

    /// Waits for every submitted job and returns the outcomes not yet polled.
    pub fn finish(self) -> Vec<Outcome> {
        match self {
            Self::Inline { done, .. } => done,
            Self::Thread {
                jobs,
                outcomes,
                handle,
            } => {
                drop(jobs);
                handle.join().expect("detection thread panicked");
                outcomes.try_iter().collect()
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::DetectError;

    /// Finds one "person" whose box is the image's size, slowly.
    struct Slow;

    impl Detector for Slow {
        fn detect(
            &mut self,
            timestamp: f64,
            image: &RgbImage,
        ) -> Result<Vec<Detection>, DetectError> {
            std::thread::sleep(std::time::Duration::from_millis(20));
            if timestamp < 0.0 {
                return Err(DetectError::Runtime("negative time".into()));
            }
            Ok(vec![Detection {
                class: "person".into(),
                class_id: 0,
                score: 1.0,
                bbox: [0.0, 0.0, image.width() as f32, image.height() as f32],
                instance: None,
            }])
        }
    }

    fn job(id: usize) -> Job {
        Job {
            id,
            timestamp: if id == 2 { -1.0 } else { id as f64 },
            image: RgbImage::new(4 + id as u32, 3),
        }
    }

    #[test]
    fn thread_and_inline_give_the_same_outcomes_in_order() {
        for deterministic in [false, true] {
            let mut worker =
                DetectionWorker::start(Box::new(Slow), deterministic, Default::default());
            let mut outcomes = Vec::new();
            for id in 0..4 {
                worker.submit(job(id));
                // One at a time, so that none is skipped.
                while outcomes.len() <= id {
                    outcomes.extend(worker.poll());
                    std::thread::yield_now();
                }
            }
            outcomes.extend(worker.finish());
            let ids: Vec<usize> = outcomes.iter().map(|o| o.id).collect();
            assert_eq!(ids, vec![0, 1, 2, 3]);
            assert_eq!(outcomes[3].detections.as_ref().unwrap()[0].bbox[2], 7.0);
            assert!(outcomes[2]
                .detections
                .as_ref()
                .unwrap_err()
                .contains("negative"));
            assert!(outcomes.iter().all(|o| !o.skipped));
        }
    }

    #[test]
    fn waiters_of_a_skipped_job_wait_for_the_next_detection() {
        let mut waiting = Waiting::default();
        for (job, waiter) in [(10, 3), (11, 4), (12, 5)] {
            waiting.insert(job, waiter);
        }
        let outcome = |id, skipped| Outcome {
            id,
            timestamp: 0.0,
            detections: Ok(Vec::new()),
            milliseconds: 0.0,
            skipped,
        };
        assert!(waiting.release(&outcome(10, true)).is_empty());
        assert!(waiting.release(&outcome(11, true)).is_empty());
        assert_eq!(waiting.release(&outcome(12, false)), vec![5, 3, 4]);
        // An unknown job releases nothing; a detected one with no waiter nothing more.
        assert!(waiting.release(&outcome(13, false)).is_empty());
    }

    #[test]
    fn a_busy_thread_detects_only_the_newest_waiting_keyframe() {
        let mut worker =
            DetectionWorker::start(Box::new(Slow), false, std::time::Duration::from_millis(50));
        let start = Instant::now();
        worker.submit(job(0));
        // Let the thread take job 0 before the others arrive.
        std::thread::sleep(std::time::Duration::from_millis(10));
        let submitting = Instant::now();
        for id in [1, 3, 4] {
            worker.submit(job(id));
        }
        // Submitting does not wait for the detector.
        assert!(submitting.elapsed().as_millis() < 10);
        let outcomes = worker.finish();
        let detected: Vec<usize> = outcomes
            .iter()
            .filter(|o| !o.skipped)
            .map(|o| o.id)
            .collect();
        let skipped: Vec<usize> = outcomes
            .iter()
            .filter(|o| o.skipped)
            .map(|o| o.id)
            .collect();
        // Job 0 starts at once; 1 and 3 wait behind it and give way to 4.
        assert_eq!(detected, vec![0, 4]);
        assert_eq!(skipped, vec![1, 3]);
        // The simulated latency: two detections of at least 50 ms each.
        assert!(start.elapsed().as_millis() >= 100);
    }
}
