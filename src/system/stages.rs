//! The system's three helpers as [`Stage`]s: local mapping, place recognition (fed by
//! local mapping, as ORB-SLAM2's local mapping hands keyframes to loop closing) and the
//! keyframe detector.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use super::worker::Stage;
use crate::bow::Vocabulary;
use crate::detect::job::{run, skipped, Job, Outcome};
use crate::detect::Detector;
use crate::global::loop_closing::LoopState;
use crate::map::{KeyFrameKey, SharedMap};
use crate::mapping::LocalMapper;

/// Local mapping on the shared map ([`LocalMapper::process`]'s six steps per keyframe).
pub struct LocalMapping {
    /// The mapper.
    pub mapper: LocalMapper,
    /// The shared map.
    pub map: SharedMap,
}

impl Stage for LocalMapping {
    type Job = KeyFrameKey;
    type Output = ();
    const NAME: &'static str = "local-mapping";
    const NICE: i32 = 5;

    fn process(&mut self, key: KeyFrameKey, _: &mut Vec<()>) {
        self.mapper.process(&self.map, key);
    }

    fn attach_pending(&mut self, pending: Arc<AtomicUsize>) {
        self.mapper.set_pending(pending);
    }
}

/// Place recognition on each keyframe local mapping finished: the keyframe's
/// descriptors are read under the map's read lock, its words computed without the
/// lock, then the database query and the consistency check take the read lock again
/// (they need the covisibility graph) and then loop closing's lock (always in that
/// order: the system takes both to close a loop). When loops are closed during
/// tracking, the loops found are verified here too
/// ([`crate::global::loop_closing::LoopCloser::screen`]), and the system corrects the
/// map once one verifies; otherwise the global pass does both.
pub struct Recognition {
    /// Place recognition and the closer, shared with the system.
    pub state: Arc<Mutex<LoopState>>,
    /// With loops closed during tracking: the loops found are verified here, and this
    /// flag is raised when one waits for the system to close it (which reads it every
    /// frame without taking loop closing's lock).
    pub ready: Option<Arc<AtomicBool>>,
    /// The vocabulary.
    pub vocabulary: Arc<Vocabulary>,
    /// The shared map.
    pub map: SharedMap,
}

impl Stage for Recognition {
    type Job = KeyFrameKey;
    type Output = ();
    const NAME: &'static str = "loop-detection";
    const NICE: i32 = 5;

    fn process(&mut self, key: KeyFrameKey, _: &mut Vec<()>) {
        let descriptors = {
            let m = self.map.read().expect("map lock poisoned");
            match m.keyframes().get(key) {
                Some(kf) => kf.frame.descriptors.clone(),
                None => return,
            }
        };
        let start = std::time::Instant::now();
        let words = self.vocabulary.transform(&descriptors);
        let elapsed = start.elapsed().as_secs_f64() * 1e3;
        let m = self.map.read().expect("map lock poisoned");
        let mut state = self.state.lock().expect("loop closing lock poisoned");
        let LoopState {
            recognition,
            closer,
        } = &mut *state;
        recognition.milliseconds += elapsed;
        recognition.process_with_words(&m, key, words);
        if let Some(ready) = &self.ready {
            let start = std::time::Instant::now();
            if closer.screen(&m, recognition) {
                ready.store(true, Ordering::Release);
            }
            closer.during_tracking_ms += start.elapsed().as_secs_f64() * 1e3;
        }
    }
}

/// The keyframe detector. On a thread it detects only the newest waiting keyframe
/// (the older ones come back skipped) and answers no sooner than `latency` (a simulated
/// detector time for instant sources such as the synthetic oracle).
pub struct Detection {
    /// The detector.
    pub detector: Box<dyn Detector>,
    /// Its simulated latency.
    pub latency: Duration,
}

impl Stage for Detection {
    type Job = Job;
    type Output = Outcome;
    const NAME: &'static str = "detection";
    const NICE: i32 = 10;

    fn process(&mut self, job: Job, outputs: &mut Vec<Outcome>) {
        let outcome = run(self.detector.as_mut(), job);
        let elapsed = Duration::from_secs_f64(outcome.milliseconds / 1e3);
        if let Some(rest) = self.latency.checked_sub(elapsed) {
            std::thread::sleep(rest);
        }
        outputs.push(outcome);
    }

    fn skip(&self, job: &Job) -> Option<Outcome> {
        Some(skipped(job))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::detect::DetectError;
    use crate::detect::Detection as Found;
    use crate::system::worker::{Execution, Worker};
    use image::RgbImage;
    use std::time::Instant;

    /// Finds one "person" whose box is the image's size, slowly.
    struct Slow;

    impl Detector for Slow {
        fn detect(&mut self, timestamp: f64, image: &RgbImage) -> Result<Vec<Found>, DetectError> {
            std::thread::sleep(std::time::Duration::from_millis(20));
            if timestamp < 0.0 {
                return Err(DetectError::Runtime("negative time".into()));
            }
            Ok(vec![Found {
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
            let stage = Detection {
                detector: Box::new(Slow),
                latency: Duration::ZERO,
            };
            let mut worker = Worker::start(stage, Execution::of(deterministic));
            let mut outcomes = Vec::new();
            for id in 0..4 {
                worker.submit(job(id));
                // One at a time, so that none is skipped.
                while outcomes.len() <= id {
                    outcomes.extend(worker.poll());
                    std::thread::yield_now();
                }
            }
            outcomes.extend(worker.finish().1);
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
    fn a_busy_thread_detects_only_the_newest_waiting_keyframe() {
        let stage = Detection {
            detector: Box::new(Slow),
            latency: Duration::from_millis(50),
        };
        let mut worker = Worker::start(stage, Execution::Threads);
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
        let outcomes = worker.finish().1;
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
