//! The DOP model applied over a run: the one owner of its state between frames and
//! keyframes ([`crate::dop`] stays the pure model). [`Dynamics`] keeps which keyframe
//! each detection job belongs to, which keyframes wait for their detection
//! ([`Waiting`]), the objects followed across keyframes ([`keyframes::DynamicObjects`])
//! and the totals of the report; it applies each detection that comes back to its
//! keyframe's map points ([`keyframes`]).
//!
//! Each frame the tracker receives from here which points take part in its pose
//! ([`frames::Participation`]: the model, the followed objects, the newest keyframe's
//! probation); after the pose, the model's step on the frame is [`tracked`].

pub mod frames;
pub mod keyframes;
pub mod tracked;

use std::collections::{BTreeMap, HashMap};
use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::detect::job::Outcome;
use crate::detect::{write_cache, FrameDetections};
use crate::dop::boxes::in_dynamic_box;
use crate::dop::tracks::FollowedObjects;
use crate::dop::{DopConfig, Mode};
use crate::eval::truth::{Classification, Recall};
use crate::geometry::camera::PinholeCamera;
use crate::map::{KeyFrameKey, Map};
use frames::{Participation, Probation, NEAR_BOX_PX, NEAR_BOX_SHARE};
use keyframes::{apply_detections, object_boxes, DynamicObjects};

/// What the keyframe detector did over a run.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct DetectionTotals {
    /// Keyframes handed to the detector, those whose detections came back, and those
    /// skipped because a newer keyframe was waiting (real-time mode).
    pub submitted: usize,
    /// Keyframes whose detections came back.
    pub detected: usize,
    /// Keyframes skipped (a newer one was waiting).
    pub skipped: usize,
    /// Boxes predicted for followed people the detector missed, and keyframes that a
    /// late detection reached after they were made.
    pub predicted_boxes: usize,
    /// Later keyframes a late detection reached.
    pub later_keyframes_reached: usize,
    /// Person recall on detected keyframes against the ground-truth masks of a
    /// synthetic sequence: people covering at least 1 % of the image, found by a
    /// dynamic box used there (detected or predicted) with IoU >= 0.5 (filled by the
    /// run's scorer from [`Applied`]).
    pub person_recall: Option<Recall>,
    /// Detections per class name over all keyframes.
    pub per_class: BTreeMap<String, usize>,
    /// Detector time per keyframe (in its own thread), milliseconds.
    pub median_ms: f64,
    /// Each model's median time per keyframe, when several run (a pool).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub per_model_median_ms: BTreeMap<String, f64>,
    /// Map points whose moving probability a keyframe's detections updated, and those
    /// removed as dynamic (by the DOP model or, with --mask-boxes, inside a box).
    pub map_points_updated: usize,
    /// Map points removed as dynamic.
    pub map_points_removed: usize,
    /// Updates where a point on a detected dynamic object counted as static because
    /// the geometric check had verified it (`[dop] static_check`).
    pub map_points_verified_static: usize,
    /// Detected boxes of a dynamic class whose points the geometric check found
    /// standing still: static on their keyframe (`[dop] standing_boxes`).
    pub standing_boxes: usize,
    /// Keypoints called dynamic against the synthetic ground-truth masks (`masks/` of
    /// a `dopslam synth` sequence): every tracked frame with --dop, the detected
    /// keyframes with --mask-boxes (filled by the run's scorer).
    pub classification: Option<Classification>,
    /// Detector errors, each once.
    pub errors: Vec<String>,
}

/// What one detection did on its keyframe, for scoring against ground truth.
#[derive(Debug, Clone, PartialEq)]
pub enum Applied {
    /// DOP: the dynamic boxes used on the keyframe (detected, then predicted).
    Boxes {
        /// The keyframe's time, seconds.
        timestamp: f64,
        /// The boxes, `[x1, y1, x2, y2]` in pixels.
        boxes: Vec<[f32; 4]>,
    },
    /// Every mode: what the detector found on the keyframe of frame `frame` (for the
    /// run's Rerun recording).
    Detected {
        /// The keyframe's frame index.
        frame: usize,
        /// The detector's boxes.
        detections: Vec<crate::detect::Detection>,
    },
    /// Mask boxes: the keyframe's keypoints and which of them lie in a dynamic box.
    Keypoints {
        /// The keyframe's time, seconds.
        timestamp: f64,
        /// The keypoints' positions, pixels.
        positions: Vec<(f32, f32)>,
        /// Per keypoint: inside a dynamic box.
        in_box: Vec<bool>,
    },
}

/// How detections act on the map over a run.
#[derive(Debug, Clone)]
pub struct DynamicsConfig {
    /// DOP, mask boxes or none (ORB-SLAM2).
    pub mode: Mode,
    /// The DOP model's settings.
    pub dop: DopConfig,
    /// The sensor's weight of a detection (the paper: 0.3 RGB-D, 0.5 stereo).
    pub alpha: f32,
    /// The COCO classes that move.
    pub dynamic_classes: Vec<String>,
    /// Where each keyframe's detections are written (the run's detection cache,
    /// readable back with `source = "cache"`).
    pub cache: PathBuf,
    /// Frames a keyframe's new points stay out of the pose (`[tracking]
    /// probation_frames`; DOP mode only).
    pub probation_frames: usize,
    /// Only new points near the latest detection's dynamic boxes wait (`[tracking]
    /// wait_near_boxes_only`; DOP mode only).
    pub wait_near_boxes_only: bool,
}

/// The DOP state of a run (see the module doc).
pub struct Dynamics {
    config: DynamicsConfig,
    keyframe_of_job: HashMap<usize, KeyFrameKey>,
    totals: DetectionTotals,
    milliseconds: Vec<f64>,
    model_milliseconds: BTreeMap<String, Vec<f64>>,
    /// The followed objects (DOP mode only).
    objects: Option<DynamicObjects>,
    /// Keyframe ids of submitted jobs whose detection has not come back.
    awaited: Waiting,
    applied: Vec<Applied>,
    /// The followed objects as of the latest detection (DOP mode).
    followed: Option<FollowedObjects>,
}

impl Dynamics {
    /// The DOP state of a run that starts with `config`, boxes predicted in `camera`.
    pub fn new(config: DynamicsConfig, camera: PinholeCamera) -> Self {
        Self {
            objects: (config.mode == Mode::Dop).then(|| DynamicObjects::new(camera)),
            config,
            keyframe_of_job: HashMap::new(),
            totals: DetectionTotals::default(),
            milliseconds: Vec::new(),
            model_milliseconds: BTreeMap::new(),
            awaited: Waiting::default(),
            applied: Vec::new(),
            followed: None,
        }
    }

    /// The DOP model, when on.
    pub fn dop(&self) -> Option<&DopConfig> {
        (self.config.mode == Mode::Dop).then_some(&self.config.dop)
    }

    /// Which points take part in the next frame's pose; `clock` is the tracker's
    /// newest keyframe and the frames tracked since it
    /// ([`crate::tracking::Tracker::keyframe_clock`]).
    pub fn participation(&self, clock: Option<(usize, usize)>) -> Participation<'_> {
        let dop = self.dop();
        Participation {
            dop,
            followed: self.followed.as_ref(),
            probation: clock
                .filter(|_| dop.is_some())
                .map(|(keyframe_id, frames_since)| Probation {
                    keyframe_id,
                    frames_since,
                    frames: self.config.probation_frames,
                }),
        }
    }

    /// Keyframe `key` was submitted to the detector as job `job`; with `awaits` its new
    /// points wait for the detection (they stay out of the pose and of local BA
    /// meanwhile, see [`crate::map::Map::awaiting_detection`]). Call before local
    /// mapping sees the keyframe.
    pub fn on_keyframe(&mut self, map: &mut Map, job: usize, key: KeyFrameKey, awaits: bool) {
        if awaits {
            if let Some(id) = map.keyframes().get(key).map(|kf| kf.id) {
                self.awaited.insert(job, id);
                map.await_detection(id);
            }
        }
        self.keyframe_of_job.insert(job, key);
        self.totals.submitted += 1;
    }

    /// How many keyframes went to the detector.
    pub fn submitted(&self) -> usize {
        self.totals.submitted
    }

    /// What the detections applied since the last call did, for scoring.
    pub fn take_applied(&mut self) -> Vec<Applied> {
        std::mem::take(&mut self.applied)
    }

    /// The totals, with the detector's median time.
    pub fn finish(mut self) -> DetectionTotals {
        self.totals.median_ms = crate::eval::stats::median(&mut self.milliseconds);
        if self.model_milliseconds.len() > 1 {
            for (model, times) in &mut self.model_milliseconds {
                let median = crate::eval::stats::median(times);
                self.totals
                    .per_model_median_ms
                    .insert(model.clone(), median);
            }
        }
        self.totals
    }

    /// Attaches detections that came back to their keyframes (which local mapping may
    /// have culled meanwhile), applies them to the map points, and writes them to the
    /// run's detection cache.
    pub fn receive(&mut self, map: &mut Map, outcomes: Vec<Outcome>) {
        for outcome in outcomes {
            for id in self.awaited.release(&outcome) {
                map.detection_came_back(id);
            }
            if outcome.skipped {
                self.totals.skipped += 1;
                continue;
            }
            match outcome.detections {
                Ok(detections) => {
                    let frame = FrameDetections {
                        timestamp: outcome.timestamp,
                        detections,
                    };
                    for (model, ms) in outcome.model_milliseconds {
                        self.model_milliseconds.entry(model).or_default().push(ms);
                    }
                    self.apply(map, outcome.id, outcome.milliseconds, frame);
                }
                Err(e) => self
                    .totals
                    .errors
                    .push(format!("frame {}: {e}", outcome.id)),
            }
        }
        // Every frame from now on sees the followed objects.
        if let Some(objects) = &self.objects {
            self.followed = Some(objects.followed(self.config.alpha));
        }
    }

    /// One job's detections.
    fn apply(&mut self, map: &mut Map, job: usize, milliseconds: f64, frame: FrameDetections) {
        let totals = &mut self.totals;
        let config = &self.config;
        totals.detected += 1;
        self.milliseconds.push(milliseconds);
        for d in &frame.detections {
            *totals.per_class.entry(d.class.clone()).or_default() += 1;
        }
        self.applied.push(Applied::Detected {
            frame: job,
            detections: frame.detections.clone(),
        });
        if let Err(e) = write_cache(&config.cache, &frame) {
            totals.errors.push(e.to_string());
        }
        let Some(&key) = self.keyframe_of_job.get(&job) else {
            return;
        };
        if config.mode == Mode::MaskBoxes {
            if let Some(kf) = map.keyframes().get(key) {
                let boxes = object_boxes(&frame.detections, &config.dynamic_classes);
                let positions: Vec<(f32, f32)> =
                    kf.frame.keypoints.iter().map(|k| (k.x, k.y)).collect();
                let in_box = positions
                    .iter()
                    .map(|&(x, y)| in_dynamic_box(&boxes, x, y))
                    .collect();
                self.applied.push(Applied::Keypoints {
                    timestamp: frame.timestamp,
                    positions,
                    in_box,
                });
            }
        }
        if let Some(objects) = self.objects.as_mut() {
            let done = objects.receive(
                map,
                key,
                &frame.detections,
                &config.dynamic_classes,
                &config.dop,
                config.alpha,
            );
            totals.map_points_updated += done.effect.updated;
            totals.map_points_removed += done.effect.removed;
            totals.map_points_verified_static += done.effect.verified_static;
            totals.standing_boxes += done.effect.standing_boxes;
            if config.wait_near_boxes_only {
                let widened = done
                    .zones
                    .iter()
                    .map(|b| b.widened(NEAR_BOX_SHARE, NEAR_BOX_PX));
                map.set_wait_zones(Some(widened.collect()));
            }
            totals.predicted_boxes += done.predicted_boxes;
            totals.later_keyframes_reached += done.later_keyframes;
            self.applied.push(Applied::Boxes {
                timestamp: frame.timestamp,
                boxes: done.boxes,
            });
        } else if config.mode != Mode::Off {
            let done = apply_detections(
                map,
                key,
                &frame.detections,
                &config.dynamic_classes,
                &DopConfig {
                    mode: config.mode,
                    ..config.dop.clone()
                },
                config.alpha,
            );
            totals.map_points_updated += done.updated;
            totals.map_points_removed += done.removed;
            totals.map_points_verified_static += done.verified_static;
            totals.standing_boxes += done.standing_boxes;
        }
        map.set_detections(key, frame.detections);
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

#[cfg(test)]
mod tests {
    use super::*;

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
            model_milliseconds: Vec::new(),
            skipped,
        };
        assert!(waiting.release(&outcome(10, true)).is_empty());
        assert!(waiting.release(&outcome(11, true)).is_empty());
        assert_eq!(waiting.release(&outcome(12, false)), vec![5, 3, 4]);
        // An unknown job releases nothing; a detected one with no waiter nothing more.
        assert!(waiting.release(&outcome(13, false)).is_empty());
    }

    fn dynamics(mode: Mode) -> Dynamics {
        let config = DynamicsConfig {
            mode,
            dop: DopConfig::default(),
            alpha: 0.3,
            dynamic_classes: vec!["person".into()],
            cache: PathBuf::from("unused"),
            probation_frames: 2,
            wait_near_boxes_only: false,
        };
        Dynamics::new(config, PinholeCamera::tum_fr3())
    }

    #[test]
    fn the_newest_keyframe_is_on_probation_with_the_model_only() {
        let d = dynamics(Mode::Dop);
        assert_eq!(d.participation(None).probation, None);
        let probation = d.participation(Some((4, 1))).probation.unwrap();
        assert_eq!((probation.keyframe_id, probation.frames_since), (4, 1));
        assert_eq!(probation.frames, 2);
        // Without the model there is no probation and no gate.
        let off = dynamics(Mode::Off);
        let gate = off.participation(Some((4, 1)));
        assert!(gate.probation.is_none() && gate.dop.is_none());
    }
}
