//! The online SLAM system (ORB-SLAM2's `System`): it creates and owns the map, the
//! tracker, the helpers beside it (local mapping, place recognition fed by local
//! mapping, the keyframe detector: each a [`worker::Worker`], inline or on its thread)
//! and the DOP state of the run ([`crate::dynamics::Dynamics`]). Per frame
//! ([`System::track`], then [`System::receive_detections`]):
//! 1. the tracker tracks the frame against the map;
//! 2. a new keyframe goes to the dynamics (it may wait for its detection), to local
//!    mapping and to the detector;
//! 3. detections that came back are applied to their keyframes, and the tracker's last
//!    frame takes the new probabilities.
//!
//! [`System::finish`] joins the helpers and hands the map over owned and unlocked
//! ([`Tracked`]), for the global pass.

pub mod loops;
pub mod stages;
pub mod worker;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::Vector3;

use crate::bow::Vocabulary;
use crate::config::Config;
use crate::detect::job::{Job, Outcome};
use crate::detect::Detector;
use crate::dop::{DopConfig, Mode};
use crate::dynamics::tracked::{after_pose, feature_budget, refresh_last, DopFigures};
use crate::dynamics::{Applied, DetectionTotals, Dynamics, DynamicsConfig};
use crate::features::ScalePyramid;
use crate::frame::Frame;
use crate::geometry::camera::PinholeCamera;
use crate::geometry::depth_noise::DepthNoise;
use crate::geometry::stereo_camera::StereoCamera;
use crate::global::loop_closing::LoopState;
use crate::global::place_recognition::PlaceRecognition;
use crate::global::{LoopInputs, NoLoops};
use crate::map::{Map, SharedMap};
use crate::mapping::{LocalMapper, MappingStats};
use crate::tracking::input::Picture;
use crate::tracking::tracker::Located;
use crate::tracking::{TrackedFrame, Tracker, TrackingState};
use loops::{Loops, LoopsSetup};
use stages::{Detection, LocalMapping};
use worker::{Execution, Worker};

/// How long real-time mode waits for the first keyframe's detection.
const FIRST_DETECTION_WAIT: Duration = Duration::from_secs(5);

/// What the system is built from (the run's set-up, resolved once).
pub struct SystemSetup<'a> {
    /// The config for the sequence's sensor.
    pub config: &'a Config,
    /// The camera and its baseline.
    pub camera: StereoCamera,
    /// The undistorted pinhole camera.
    pub pinhole: PinholeCamera,
    /// The scale pyramid.
    pub pyramid: ScalePyramid,
    /// DOP, mask boxes or none.
    pub mode: Mode,
    /// The sensor's weight of a detection.
    pub alpha: f32,
    /// RGB-D close/far limit in metres (`ThDepth` baselines).
    pub close_depth: f32,
    /// The sensor's depth noise (the geometric check's rigidity test).
    pub depth_noise: DepthNoise,
    /// Inline (deterministic) or threads (real time).
    pub execution: Execution,
    /// Where each keyframe's detections are written.
    pub detection_cache: PathBuf,
}

/// The helpers' inputs that may be missing: the vocabulary of place recognition
/// (`None`: no global pass; `Some(Err(why))`: the global pass runs without loops) and
/// the keyframe detector with its simulated latency.
pub struct Helpers {
    /// The vocabulary, or why loops cannot run (`None`: no global pass).
    pub vocabulary: Option<Result<Arc<Vocabulary>, NoLoops>>,
    /// The detector and its simulated latency (`None`: no detection).
    pub detector: Option<(Box<dyn Detector>, Duration)>,
}

/// What the tracking pass leaves for the global pass: the map owned and unlocked.
pub struct Tracked {
    /// The map.
    pub map: Map,
    /// Place recognition's findings and the loops closed during tracking (`None`
    /// without a global pass).
    pub recognised: Option<Result<LoopState, NoLoops>>,
    /// What local mapping did.
    pub mapping: MappingStats,
    /// What detection did.
    pub detection: DetectionTotals,
    /// What the detections did that the last [`System::take_applied`] left.
    pub applied: Vec<Applied>,
}

/// The tracker of `setup`, placing frames in `map` when it was loaded (`placing`).
fn tracker_of(setup: &SystemSetup, map: &Map, placing: Option<&Placing>) -> Tracker {
    let tracker = Tracker::new(
        setup.config.tracking.clone(),
        setup.camera,
        setup.pyramid.clone(),
        setup.pinhole.width,
        setup.pinhole.height,
    )
    .with_depth_noise(setup.depth_noise);
    match placing {
        Some(placing) => tracker.placing_in(map.segments_used(), placing.frozen),
        None => tracker,
    }
}

/// What loop closing needs of the run (as [`crate::run`] gives the global pass).
fn loop_inputs(setup: &SystemSetup) -> LoopInputs {
    LoopInputs {
        camera: setup.camera,
        pyramid: setup.pyramid.clone(),
        size: (setup.pinhole.width as f32, setup.pinhole.height as f32),
        removal_threshold: setup.mode.removal_threshold(&setup.config.dop),
    }
}

/// The recent keyframes' map points ([`System::recent_map_points`]).
#[derive(Debug, Clone, Default)]
pub struct RecentMap {
    /// Points the DOP model keeps.
    pub fixed: Vec<Vector3<f64>>,
    /// Points the DOP model removes (moving probability above its threshold).
    pub moving: Vec<Vector3<f64>>,
}

/// The online system (see the module doc).
pub struct System {
    map: SharedMap,
    tracker: Tracker,
    mapping: Worker<LocalMapping>,
    recognition: Option<Result<Loops, NoLoops>>,
    detection: Option<Worker<Detection>>,
    dynamics: Dynamics,
    execution: Execution,
}

/// A map loaded for the run to track in (`dopslam run --map`).
pub struct Placing {
    /// Localisation only: the tracker adds no keyframe.
    pub frozen: bool,
}

impl System {
    /// Creates the map and starts the helpers.
    pub fn start(setup: &SystemSetup, helpers: Helpers) -> Self {
        Self::start_in(setup, helpers, Map::default(), None)
    }

    /// Starts the helpers on `map` (empty, or loaded with `placing`: the frames then
    /// wait until relocalisation places one in it, and place recognition knows its
    /// keyframes).
    pub fn start_in(
        setup: &SystemSetup,
        helpers: Helpers,
        map: Map,
        placing: Option<Placing>,
    ) -> Self {
        let config = setup.config;
        let size = (setup.pinhole.width, setup.pinhole.height);
        let tracker = tracker_of(setup, &map, placing.as_ref());
        let mut mapper = LocalMapper::new(
            config.mapping.clone(),
            setup.camera,
            setup.pyramid.clone(),
            size,
            setup.close_depth,
        );
        mapper.removal_threshold = setup.mode.removal_threshold(&config.dop);
        let map = SharedMap::new(std::sync::RwLock::new(map));
        let recognition = helpers.vocabulary.map(|vocabulary| {
            vocabulary.map(|vocabulary| {
                let mut recognition =
                    PlaceRecognition::new(&vocabulary, config.global.loops.clone());
                // A loaded map's keyframes can be found again.
                recognition.seed(&vocabulary, &map.read().expect("map lock poisoned"));
                let setup = LoopsSetup {
                    recognition,
                    vocabulary,
                    inputs: loop_inputs(setup),
                    execution: setup.execution,
                };
                Loops::start(setup, &map)
            })
        });
        if let Some(Ok(recognition)) = &recognition {
            let mut submitter = recognition.worker().submitter();
            mapper.then = Some(Box::new(move |key| submitter.submit(key)));
        }
        let mapping = Worker::start(
            LocalMapping {
                mapper,
                map: map.clone(),
            },
            setup.execution,
        );
        let detection = helpers.detector.map(|(detector, latency)| {
            let latency = match setup.execution {
                Execution::Inline => Duration::ZERO,
                Execution::Threads => latency,
            };
            Worker::start(Detection { detector, latency }, setup.execution)
        });
        let dynamics = Dynamics::new(
            DynamicsConfig {
                mode: setup.mode,
                dop: config.dop.clone(),
                alpha: setup.alpha,
                dynamic_classes: config.detector.dynamic_classes.clone(),
                cache: setup.detection_cache.clone(),
                probation_frames: config.tracking.probation_frames,
                wait_near_boxes_only: config.tracking.wait_near_boxes_only,
            },
            setup.pinhole,
        );
        Self {
            map,
            tracker,
            mapping,
            recognition,
            detection,
            dynamics,
            execution: setup.execution,
        }
    }

    /// The tracking state after the last frame.
    pub fn state(&self) -> TrackingState {
        self.tracker.state()
    }

    /// The keypoint budget for the next frame ([`feature_budget`]).
    pub fn feature_budget(&self, n_features: usize) -> usize {
        feature_budget(n_features, self.dynamics.dop(), self.tracker.last_frame())
    }

    /// The DOP model, when on.
    pub fn dop(&self) -> Option<&DopConfig> {
        self.dynamics.dop()
    }

    /// Frame `index` as tracked (with its moving probabilities), if tracking kept it.
    pub fn tracked_frame(&self, index: usize) -> Option<&Frame> {
        self.tracker.last_frame().filter(|f| f.index == index)
    }

    /// The points of the last `keyframes` keyframes, split into static ones and ones
    /// the DOP model removes (for the run's Rerun recording).
    pub fn recent_map_points(&self, keyframes: usize) -> RecentMap {
        let map = self.map.read().expect("map lock poisoned");
        let dop = self.dynamics.dop();
        let mut seen = std::collections::HashSet::new();
        let (mut fixed, mut moving) = (Vec::new(), Vec::new());
        for key in map.keyframe_order().iter().rev().take(keyframes) {
            let Some(keyframe) = map.keyframes().get(*key) else {
                continue;
            };
            for point_key in keyframe.map_points.iter().flatten() {
                let Some(point) = map
                    .points()
                    .get(*point_key)
                    .filter(|_| seen.insert(*point_key))
                else {
                    continue;
                };
                if dop.is_some_and(|d| d.removed(point.moving)) {
                    moving.push(point.position);
                } else {
                    fixed.push(point.position);
                }
            }
        }
        RecentMap { fixed, moving }
    }

    /// Tracks one frame (`picture` is what the detector sees of it) and hands a new
    /// keyframe to the dynamics, local mapping and the detector. Returns the report
    /// and the time from `started` (before feature extraction) to the tracked pose,
    /// in milliseconds.
    pub fn track(
        &mut self,
        frame: Frame,
        picture: Picture,
        started: Instant,
    ) -> (TrackedFrame, f64) {
        let (index, timestamp) = (frame.index, frame.timestamp);
        let gate = self.dynamics.participation(self.tracker.keyframe_clock());
        // Whether local mapping has caught up, as the frame arrives.
        let mapping_idle = self.mapping.is_idle();
        let report = match self.tracker.locate(&self.map, frame, &gate) {
            Located::Started(report) => *report,
            Located::Searched(mut search) => {
                let mut map = self.map.write().expect("map lock poisoned");
                // The DOP model's step between the pose and the keyframe decision.
                let sensor = self.tracker.sensor();
                let (frame, pose) = search.parts();
                let dop = pose.map_or_else(DopFigures::default, |pose| {
                    after_pose(
                        &gate,
                        &mut map,
                        frame,
                        pose,
                        &sensor,
                        self.tracker.last_frame(),
                    )
                });
                self.tracker
                    .settle(&mut map, &gate, *search, dop, mapping_idle)
            }
        };
        let tracking_ms = started.elapsed().as_secs_f64() * 1e3;
        if let Some(key) = report.record.keyframe {
            // Marked before local mapping sees the keyframe, whose BA leaves its points
            // out while they wait.
            let awaits = self.detection.is_some()
                && self.execution == Execution::Threads
                && self.dynamics.dop().is_some();
            if self.detection.is_some() {
                let mut map = self.map.write().expect("map lock poisoned");
                self.dynamics.on_keyframe(&mut map, index, key, awaits);
            }
            self.mapping.submit(key);
            if let Some(worker) = self.detection.as_mut() {
                worker.submit(Job {
                    id: index,
                    timestamp,
                    image: picture.into_colour(),
                });
                if awaits && self.dynamics.submitted() == 1 {
                    // The first map waits for its detection: nothing older can carry
                    // the pose while its points wait.
                    let outcomes = worker.wait(FIRST_DETECTION_WAIT);
                    self.receive(outcomes);
                }
            }
        }
        if let Some(Ok(loops)) = self.recognition.as_mut() {
            loops.close_ready(&self.map, &self.mapping, &mut self.tracker, &report.record);
        }
        (report, tracking_ms)
    }

    /// `f` on the map as it stands (under its read lock).
    pub fn with_map<R>(&self, f: impl FnOnce(&Map) -> R) -> R {
        f(&self.map.read().expect("map lock poisoned"))
    }

    /// Waits until local mapping has processed every keyframe handed to it, then lets
    /// `f` change the map (under its write lock: the rig's disparity offset taken out
    /// of it, [`crate::run`]). The tracker's last frame follows what `f` did:
    /// `adjust_last` corrects it, and it is placed on the pose its `record`'s
    /// reference keyframe has after `f`.
    pub fn edit_map<R>(
        &mut self,
        f: impl FnOnce(&mut Map) -> R,
        record: &crate::map::record::FrameRecord,
        adjust_last: impl FnOnce(&R, &mut Frame),
    ) -> R {
        self.mapping.wait_idle();
        let mut map = self.map.write().expect("map lock poisoned");
        let out = f(&mut map);
        let placed = record
            .camera_from_world_on(|key| map.keyframes().get(key).map(|k| k.camera_from_world));
        self.tracker
            .adjust_last(placed, |frame| adjust_last(&out, frame));
        out
    }

    /// Applies the detections that came back since the last call.
    pub fn receive_detections(&mut self) {
        if let Some(worker) = self.detection.as_mut() {
            let outcomes = worker.poll();
            self.receive(outcomes);
        }
    }

    /// What the detections applied since the last call did (for scoring).
    pub fn take_applied(&mut self) -> Vec<Applied> {
        self.dynamics.take_applied()
    }

    /// Detections applied to the map; the tracker's last frame takes the new
    /// probabilities and the followed objects, so that the next frame propagates what
    /// the detections said.
    fn receive(&mut self, outcomes: Vec<Outcome>) {
        if outcomes.is_empty() {
            return;
        }
        let mut map = self.map.write().expect("map lock poisoned");
        self.dynamics.receive(&mut map, outcomes);
        let gate = self.dynamics.participation(self.tracker.keyframe_clock());
        if let Some(last) = self.tracker.last_tracked() {
            refresh_last(&gate, &map, last);
        }
    }

    /// Waits for the helpers (the detector's last outcomes are applied), then hands the
    /// map over.
    pub fn finish(mut self) -> Tracked {
        if let Some(worker) = self.detection.take() {
            let (_, outcomes) = worker.finish();
            self.receive(outcomes);
        }
        // Local mapping drops its hand-over to place recognition here, which then
        // finishes its queue.
        let mapping = {
            let (stage, _) = self.mapping.finish();
            stage.mapper.stats
        };
        let recognised = self.recognition.map(|r| r.map(Loops::finish));
        let applied = self.dynamics.take_applied();
        drop(self.tracker);
        let Ok(lock) = Arc::try_unwrap(self.map) else {
            unreachable!("the helpers that shared the map have finished")
        };
        let map = lock.into_inner().expect("map lock poisoned");
        Tracked {
            map,
            recognised,
            mapping,
            detection: self.dynamics.finish(),
            applied,
        }
    }
}
