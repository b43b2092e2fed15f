//! Loop detection beside the tracking pass: place recognition
//! ([`PlaceRecognition`]: words, database, candidates consistent over consecutive
//! keyframes) runs on each keyframe as local mapping finishes it, in its own thread at
//! a lower priority, as ORB-SLAM2's loop closing does; `--deterministic` runs it inline
//! instead. Verification and correction wait for the global pass
//! ([`super::loop_closing::LoopCloser::close_found`]), which then finds the candidates
//! ready.
//!
//! The thread reads a keyframe's descriptors under the map's read lock, computes its
//! words without the lock, then takes the read lock again for the database query and
//! the consistency check, which need the covisibility graph.

use std::sync::mpsc::{channel, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use super::loop_closing::{LoopConfig, PlaceRecognition};
use crate::bow::Vocabulary;
use crate::map::{KeyFrameKey, SharedMap};

/// Place recognition beside tracking.
pub enum LoopDetection {
    Inline {
        /// Taken out by [`LoopDetection::finish`] (the hand-over may still hold the
        /// `Arc`).
        recognition: Arc<Mutex<Option<PlaceRecognition>>>,
        vocabulary: Arc<Vocabulary>,
        map: SharedMap,
    },
    Thread {
        sender: Sender<KeyFrameKey>,
        handle: JoinHandle<PlaceRecognition>,
    },
}

impl LoopDetection {
    /// Starts place recognition on `map`; `deterministic` runs it inline.
    pub fn start(
        vocabulary: Arc<Vocabulary>,
        config: LoopConfig,
        map: SharedMap,
        deterministic: bool,
    ) -> Self {
        let recognition = PlaceRecognition::new(&vocabulary, config.clone());
        if deterministic {
            return Self::Inline {
                recognition: Arc::new(Mutex::new(Some(recognition))),
                vocabulary,
                map,
            };
        }
        let (sender, receiver) = channel::<KeyFrameKey>();
        let handle = std::thread::Builder::new()
            .name("loop-detection".into())
            .spawn(move || {
                crate::threads::lower_priority(5);
                let mut recognition = recognition;
                for key in receiver {
                    let descriptors = {
                        let m = map.read().expect("map lock poisoned");
                        match m.keyframes.get(key) {
                            Some(kf) => kf.frame.descriptors.clone(),
                            None => continue,
                        }
                    };
                    let start = std::time::Instant::now();
                    let words = vocabulary.transform(&descriptors);
                    recognition.milliseconds += start.elapsed().as_secs_f64() * 1e3;
                    let m = map.read().expect("map lock poisoned");
                    recognition.process_with_words(&m, key, words);
                }
                recognition
            })
            .expect("spawn the loop detection thread");
        Self::Thread { sender, handle }
    }

    /// The hand-over for local mapping ([`crate::mapping::LocalMapper::then`]): each
    /// processed keyframe goes to place recognition.
    pub fn hand_over(&self) -> Box<dyn FnMut(KeyFrameKey) + Send> {
        match self {
            Self::Inline {
                recognition,
                vocabulary,
                map,
                ..
            } => {
                let (recognition, vocabulary, map) =
                    (recognition.clone(), vocabulary.clone(), map.clone());
                Box::new(move |key| {
                    let m = map.read().expect("map lock poisoned");
                    let mut guard = recognition.lock().expect("place recognition lock poisoned");
                    if let Some(r) = guard.as_mut() {
                        r.process(&vocabulary, &m, key);
                    }
                })
            }
            Self::Thread { sender, .. } => {
                let sender = sender.clone();
                // The thread ends only when every sender is gone, so a send fails only
                // if it panicked, which `finish` reports.
                Box::new(move |key| {
                    let _ = sender.send(key);
                })
            }
        }
    }

    /// Waits for the keyframes handed over (after local mapping has finished, which
    /// drops its hand-over) and returns what place recognition found.
    pub fn finish(self) -> PlaceRecognition {
        match self {
            Self::Inline { recognition, .. } => recognition
                .lock()
                .expect("place recognition lock poisoned")
                .take()
                .expect("place recognition is taken once, by finish"),
            Self::Thread { sender, handle } => {
                drop(sender);
                handle.join().expect("loop detection thread panicked")
            }
        }
    }
}
