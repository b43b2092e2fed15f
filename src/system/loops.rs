//! Place recognition beside the tracking pass, and loop closing during it (ORB-SLAM2's
//! loop closing thread): place recognition's worker verifies each keyframe it found
//! once its confirmations are in ([`LoopCloser::screen`], under the map's read lock);
//! when a loop verifies, the tracking thread lets local mapping finish its queue, takes
//! the map's write lock between two frames, and verifies, corrects and fuses the loop
//! ([`LoopCloser::close_ready`]). The frames after it are then tracked in the map the
//! loop joined (`[global.loops] during_tracking`, off by default: `docs/design.md`,
//! "Loops closed during tracking").

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use super::stages::{LocalMapping, Recognition};
use super::worker::{Execution, Worker};
use crate::bow::Vocabulary;
use crate::global::loop_closing::{LoopCloser, LoopState};
use crate::global::place_recognition::PlaceRecognition;
use crate::global::LoopInputs;
use crate::map::record::FrameRecord;
use crate::map::SharedMap;
use crate::tracking::Tracker;

/// Place recognition's worker and loop closing's state (shared with the worker).
pub struct Loops {
    worker: Worker<Recognition>,
    state: Arc<Mutex<LoopState>>,
    /// Raised by the worker when a loop it verified waits (never without
    /// `during_tracking`); lowered here once it is closed.
    ready: Arc<AtomicBool>,
}

/// What [`Loops::start`] is built from.
pub struct LoopsSetup {
    /// Place recognition, seeded with a loaded map's keyframes.
    pub recognition: PlaceRecognition,
    /// The vocabulary.
    pub vocabulary: Arc<Vocabulary>,
    /// What the closer needs of the run.
    pub inputs: LoopInputs,
    /// Inline (deterministic) or threads (real time).
    pub execution: Execution,
}

impl Loops {
    /// Starts place recognition's worker on `map`.
    pub fn start(setup: LoopsSetup, map: &SharedMap) -> Self {
        let config = setup.recognition.config().clone();
        let ready = Arc::new(AtomicBool::new(false));
        let stage = Recognition {
            ready: config.during_tracking.then(|| ready.clone()),
            state: Arc::new(Mutex::new(LoopState {
                recognition: setup.recognition,
                closer: LoopCloser::new(setup.inputs, config),
            })),
            vocabulary: setup.vocabulary,
            map: map.clone(),
        };
        Self {
            state: stage.state.clone(),
            worker: Worker::start(stage, setup.execution),
            ready,
        }
    }

    /// The worker, for local mapping's hand-over.
    pub fn worker(&self) -> &Worker<Recognition> {
        &self.worker
    }

    /// Closes the loop place recognition verified, when one waits: local mapping first
    /// finishes its queue, then the loop is verified again and the map corrected under
    /// its write lock, and the tracker's last frame (`record`) follows its reference
    /// keyframe. Returns how many loops were closed.
    pub fn close_ready(
        &mut self,
        map: &SharedMap,
        mapping: &Worker<LocalMapping>,
        tracker: &mut Tracker,
        record: &FrameRecord,
    ) -> usize {
        // Read every frame: the worker may hold loop closing's lock for a while.
        if !self.ready.load(Ordering::Acquire) {
            return 0;
        }
        let start = Instant::now();
        mapping.wait_idle();
        // The map's lock before loop closing's, as the worker takes them.
        let mut map = map.write().expect("map lock poisoned");
        let mut state = self.state.lock().expect("loop closing lock poisoned");
        let LoopState {
            recognition,
            closer,
        } = &mut *state;
        let closed = closer.close_ready(&mut map, recognition);
        // Lowered under the lock: the worker raises it again only after this.
        self.ready.store(closer.is_ready(), Ordering::Release);
        if closed > 0 {
            let placed = record
                .camera_from_world_on(|key| map.keyframes().get(key).map(|k| k.camera_from_world));
            // The tracker takes its reference keyframe's segment on the next frame.
            tracker.adjust_last(placed, |_| {});
        }
        closer.during_tracking_ms += start.elapsed().as_secs_f64() * 1e3;
        closed
    }

    /// Waits for place recognition to finish its queue (local mapping has finished
    /// and dropped its hand-over), then hands the state over for the global pass.
    pub fn finish(self) -> LoopState {
        drop(self.worker.finish());
        let Ok(state) = Arc::try_unwrap(self.state) else {
            unreachable!("place recognition's worker has finished")
        };
        state.into_inner().expect("loop closing lock poisoned")
    }
}
