//! The tracker (ORB-SLAM2 §III-B/C, for RGB-D and stereo): the state machine
//! NOT_INITIALISED / OK / LOST over a map it is handed. Initialisation from the first
//! frame with enough depth; a constant-velocity motion model with a projection search
//! against the last frame, else brute-force matching against the reference keyframe;
//! local-map tracking; pose-only optimisation after each search ([`search`], [`pose`]);
//! the keyframe decision and new map points from depth ([`keyframes`]); relocalisation
//! by EPnP RANSAC after a loss ([`relocalise`]); when relocalisation keeps failing, a
//! new map segment (ORB-SLAM3's Atlas: a new map, merged when a loop connects it). The
//! DOP model's per-frame part runs between [`Tracker::locate`] and [`Tracker::settle`]
//! ([`crate::dynamics::tracked`]).
//!
//! The map is shared with local mapping, which may run in its own thread: searches and
//! pose optimisation hold the map's read lock; only the counters and a new keyframe
//! take the write lock. Feature extraction happens before, without it.

pub mod keyframes;
mod pose;
mod projection;
mod relocalise;
mod revisit;
mod search;
#[cfg(test)]
mod tests;

use crate::dynamics::frames::Participation;
use crate::dynamics::tracked::{DopFigures, LastTracked, Sensor, TrackedPose};
use crate::features::ScalePyramid;
use crate::frame::Frame;
use crate::geometry::depth_noise::DepthNoise;
use crate::geometry::se3::{self, Se3};
use crate::geometry::stereo_camera::StereoCamera;
use crate::map::record::FrameObservation;
use crate::map::{KeyFrameKey, Map, MapPointKey, SharedMap};
use crate::tracking::params::TrackerConfig;
use crate::tracking::report::{PoseEstimate, Reject, TrackedFrame, TrackingState};
use projection::Projector;
use search::LocalSearch;

/// The tracker's reference keyframe and segment on `map` as it is now: a keyframe that
/// local mapping culled gives way to its segment's newest, and a segment that a loop
/// merged into an older one (during tracking) gives way to that one.
fn reference_now(
    map: &Map,
    reference: Option<KeyFrameKey>,
    segment: usize,
) -> (Option<KeyFrameKey>, usize) {
    match reference.and_then(|k| map.keyframes().get(k).map(|kf| (k, kf.segment))) {
        Some((key, segment)) => (Some(key), segment),
        None => (map.newest_of_segment(segment), segment),
    }
}

/// What the keyframe decision needs beside the frame: whether local mapping has caught
/// up, whether the frame is tracked on a revisit, and the tracker's newest keyframe,
/// from which the points it is weighed against follow ([`revisit`]).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Settling {
    pub mapping_idle: bool,
    pub revisiting: bool,
    pub newest: Option<usize>,
}

impl Settling {
    /// The state of a frame tracked with `matches`, for a tracker whose newest
    /// keyframe is `newest`.
    fn of(
        map: &Map,
        mapping_idle: bool,
        newest: Option<usize>,
        matches: &[Option<MapPointKey>],
    ) -> Self {
        Self {
            mapping_idle,
            revisiting: revisit::is_revisit(map, newest, matches),
            newest,
        }
    }

    /// The points the keyframe decision weighs a frame matched to `matches` against:
    /// on a revisit the revisited keyframe's ([`revisit::revisited_points`]), else
    /// the reference keyframe's `reference`.
    pub fn weighed<'a>(
        &self,
        map: &Map,
        matches: &[Option<MapPointKey>],
        reference: &'a [Option<MapPointKey>],
    ) -> std::borrow::Cow<'a, [Option<MapPointKey>]> {
        let revisited = match self.revisiting {
            true => revisit::revisited_points(map, self.newest, matches),
            false => None,
        };
        revisited.map_or(std::borrow::Cow::Borrowed(reference), Into::into)
    }
}

/// The last tracked frame, kept for the motion model.
struct LastFrame {
    frame: Frame,
    camera_from_world: Se3,
    points: Vec<Option<MapPointKey>>,
}

/// Tracking against a growing map (see the module doc).
pub struct Tracker {
    config: TrackerConfig,
    camera: StereoCamera,
    pyramid: ScalePyramid,
    state: TrackingState,
    last: Option<LastFrame>,
    velocity: Option<Se3>,
    reference: Option<KeyFrameKey>,
    frames_since_keyframe: usize,
    /// The id of the keyframe this tracker made last.
    newest_keyframe_id: Option<usize>,
    /// Whether the last frame was tracked on a revisit ([`revisit`]): the next
    /// frame's local map then reaches further.
    revisiting: bool,
    /// The active map segment, the number of segments started, and since when
    /// (timestamp) tracking is lost.
    segment: usize,
    segments: usize,
    lost_since: Option<f64>,
    width: f32,
    height: f32,
    /// The sensor's depth noise, for the rigidity test.
    depth_noise: DepthNoise,
    /// Localisation only: no keyframe is made and no segment started.
    frozen: bool,
    /// A frozen map's local map, kept while its keyframes stay the same.
    frozen_local: Option<std::cell::RefCell<projection::FrozenLocalMap>>,
}

/// What the tracker's searches look at: the map (read), the frame, and which points
/// take part.
#[derive(Clone, Copy)]
pub(super) struct TrackInput<'a> {
    pub map: &'a Map,
    pub frame: &'a Frame,
    pub gate: &'a Participation<'a>,
}

/// The first half of tracking a frame ([`Tracker::locate`]).
pub enum Located {
    /// The frame started a map segment: tracked.
    Started(Box<TrackedFrame>),
    /// The frame was searched: for the DOP model, then [`Tracker::settle`].
    Searched(Box<Search>),
}

/// A frame searched against the map: the pose found (or why none was) and what the
/// local search saw.
pub struct Search {
    frame: Frame,
    tracked: Result<PoseEstimate, Reject>,
    seen: LocalSearch,
    report: TrackedFrame,
}

impl Search {
    /// The frame (its probabilities are the DOP model's to set) and, when a pose was
    /// found, the pose with the search's candidates and the inliers kept.
    pub fn parts(&mut self) -> (&mut Frame, Option<TrackedPose<'_>>) {
        let pose = self.tracked.as_ref().ok().map(|estimate| TrackedPose {
            camera_from_world: &estimate.camera_from_world,
            candidates: &self.seen.candidates,
            matches: &estimate.matches,
        });
        (&mut self.frame, pose)
    }
}

/// Timers of one frame.
#[derive(Default)]
struct Timing {
    matching: f64,
    optimisation: f64,
}

impl Tracker {
    /// A tracker for `config` with `camera`, `pyramid` and `extractor` settings.
    pub fn new(
        config: TrackerConfig,
        camera: StereoCamera,
        pyramid: ScalePyramid,
        width: u32,
        height: u32,
    ) -> Self {
        Self {
            config,
            camera,
            pyramid,
            state: TrackingState::NotInitialised,
            last: None,
            velocity: None,
            reference: None,
            frames_since_keyframe: 0,
            newest_keyframe_id: None,
            revisiting: false,
            segment: 0,
            segments: 0,
            lost_since: None,
            width: width as f32,
            height: height as f32,
            depth_noise: DepthNoise::Rgbd,
            frozen: false,
            frozen_local: None,
        }
    }

    /// Lost in a loaded map of `segments` segments until placed; `frozen`: adds nothing.
    pub fn placing_in(mut self, segments: usize, frozen: bool) -> Self {
        (self.state, self.segments, self.frozen) = (TrackingState::Lost, segments, frozen);
        self.frozen_local = frozen.then(Default::default);
        self
    }

    /// The tracker with `depth_noise` as its sensor's (RGB-D by default).
    pub fn with_depth_noise(self, depth_noise: DepthNoise) -> Self {
        Self {
            depth_noise,
            ..self
        }
    }

    /// The tracking state.
    pub fn state(&self) -> TrackingState {
        self.state
    }

    /// The keyframe this tracker made last (its id) and the frames tracked since: the
    /// DOP model keeps that keyframe's new points on probation.
    pub fn keyframe_clock(&self) -> Option<(usize, usize)> {
        self.newest_keyframe_id
            .map(|id| (id, self.frames_since_keyframe))
    }

    /// The last tracked frame (with its moving probabilities).
    pub fn last_frame(&self) -> Option<&Frame> {
        self.last.as_ref().map(|l| &l.frame)
    }

    /// The last tracked frame after the map under it changed (the rig's disparity
    /// offset taken out): `adjust` corrects the frame, and it takes `camera_from_world`
    /// (its pose on its reference keyframe's new pose) when there is one.
    pub fn adjust_last(&mut self, camera_from_world: Option<Se3>, adjust: impl FnOnce(&mut Frame)) {
        if let Some(last) = self.last.as_mut() {
            adjust(&mut last.frame);
            if let Some(pose) = camera_from_world {
                last.camera_from_world = pose;
            }
        }
    }

    /// The last tracked frame with its map points and pose, for the DOP model's
    /// refresh after a detection ([`crate::dynamics::tracked::refresh_last`]).
    pub fn last_tracked(&mut self) -> Option<LastTracked<'_>> {
        self.last.as_mut().map(|l| LastTracked {
            frame: &mut l.frame,
            points: &l.points,
            camera_from_world: &l.camera_from_world,
        })
    }

    /// The first half of tracking a frame against `shared` (under its read lock): the
    /// pose search (motion model, else reference keyframe; relocalisation when lost)
    /// and the local map. `gate` says which points take part (the DOP model's state,
    /// from [`crate::dynamics`]). The first frame of a map segment is done here
    /// ([`Located::Started`]); otherwise the search goes to the DOP model
    /// ([`crate::dynamics::tracked::after_pose`]) and then to [`Tracker::settle`].
    pub fn locate(&mut self, shared: &SharedMap, frame: Frame, gate: &Participation) -> Located {
        let mut timing = Timing::default();
        let mut report = TrackedFrame::start(&frame, self.state, self.segment);
        if self.state == TrackingState::NotInitialised {
            let mut map = shared.write().expect("map lock poisoned");
            self.start_segment(&mut map, gate, frame, Se3::identity(), &mut report);
            return Located::Started(Box::new(report));
        }
        let map = shared.read().expect("map lock poisoned");
        (self.reference, self.segment) = reference_now(&map, self.reference, self.segment);
        let input = TrackInput {
            map: &map,
            frame: &frame,
            gate,
        };
        let found = if self.state == TrackingState::Ok {
            self.track_motion_model(input, &mut timing)
                .or_else(|_| self.track_reference_keyframe(input, &mut timing))
        } else {
            self.relocalise(input, &mut timing)
        };
        let mut seen = LocalSearch::default();
        let tracked =
            found.and_then(|found| self.track_local_map(input, found, &mut seen, &mut timing));
        report.stats.matching_ms = timing.matching;
        report.stats.optimisation_ms = timing.optimisation;
        Located::Searched(Box::new(Search {
            frame,
            tracked,
            seen,
            report,
        }))
    }

    /// The second half of tracking a frame (under the map's write lock), after the DOP
    /// model's step (`dop`, with the frame's probabilities set): culling's counters,
    /// then OK or LOST, the keyframe decision and the frame as the last frame.
    /// `mapping_idle` says whether local mapping has caught up (always in
    /// deterministic mode); while it has not, a keyframe is only made when tracking
    /// gets weak. A new keyframe is in the record, for local mapping.
    pub fn settle(
        &mut self,
        map: &mut Map,
        gate: &Participation,
        search: Search,
        dop: DopFigures,
        mapping_idle: bool,
    ) -> TrackedFrame {
        let Search {
            frame,
            tracked,
            seen,
            mut report,
        } = search;
        let found = tracked.as_ref().map_or(&[][..], |e| &e.matches[..]);
        map.count_visibility(&seen.visible, found);
        let stats = &mut report.stats;
        (stats.geometric_raised, stats.geometric_lowered) =
            (dop.geometric_raised, dop.geometric_lowered);
        (stats.rigidity_outliers, stats.dynamic_keypoints) =
            (dop.rigidity_outliers, dop.dynamic_keypoints);
        stats.dop_ms = dop.dop_ms;
        match tracked {
            Err(reject) => self.lose(map, gate, frame, reject, &mut report),
            Ok(estimate) => {
                report.stats.dynamic_map_points = seen.dynamic;
                let newest = self.newest_keyframe_id;
                let state = Settling::of(map, mapping_idle, newest, &estimate.matches);
                (self.revisiting, report.stats.revisiting) = (state.revisiting, state.revisiting);
                self.accept(map, gate, frame, estimate, state, &mut report);
            }
        }
        report
    }

    /// What a projection of map points needs.
    fn projector(&self) -> Projector<'_> {
        Projector {
            camera: &self.camera,
            pyramid: &self.pyramid,
            size: (self.width, self.height),
        }
    }

    /// What the DOP model needs of the sensor.
    pub fn sensor(&self) -> Sensor<'_> {
        Sensor {
            camera: &self.camera,
            pyramid: &self.pyramid,
            depth_noise: self.depth_noise,
        }
    }

    /// The frame was not tracked: LOST; after `new_map_after_seconds` of it, a new map
    /// segment starts at the last tracked pose.
    fn lose(
        &mut self,
        map: &mut Map,
        gate: &Participation,
        frame: Frame,
        reject: Reject,
        report: &mut TrackedFrame,
    ) {
        self.state = TrackingState::Lost;
        self.velocity = None;
        report.stats.state = TrackingState::Lost;
        report.stats.lost = Some(reject);
        let since = *self.lost_since.get_or_insert(frame.timestamp);
        if !self.frozen && frame.timestamp - since >= self.config.new_map_after_seconds {
            if let Some(last) = self.last.as_ref().map(|l| l.camera_from_world) {
                self.start_segment(map, gate, frame, last, report);
            }
        }
    }

    /// The frame was tracked at `estimate`: OK, the report's pose observations, the
    /// motion model, the keyframe decision; the frame becomes the last frame.
    fn accept(
        &mut self,
        map: &mut Map,
        gate: &Participation,
        frame: Frame,
        estimate: PoseEstimate,
        state: Settling,
        report: &mut TrackedFrame,
    ) {
        let PoseEstimate {
            camera_from_world: pose,
            matches: points,
            inliers,
        } = estimate;
        self.lost_since = None;
        self.state = TrackingState::Ok;
        report.stats.state = TrackingState::Ok;
        report.in_segment(self.segment);
        report.stats.inliers = inliers;
        report.stats.matches = points.iter().filter(|p| p.is_some()).count();
        report.record.observations = observations(map, gate, &frame, &points);
        if let Some(last) = &self.last {
            self.velocity = Some(se3::normalised(&(pose * last.camera_from_world.inverse())));
        }
        self.frames_since_keyframe += 1;
        // The keyframe decision looks at the frame as counted.
        let counted = gate.counting_this_frame();
        let input = TrackInput {
            map,
            frame: &frame,
            gate: &counted,
        };
        let need = !self.frozen && self.need_keyframe(input, &pose, &points, inliers, state);
        let (pose, points) = if need {
            self.insert_keyframe(map, &frame, gate, pose, points, false);
            let key = self.reference.expect("just inserted");
            report.made_keyframe(Some(key));
            let keyframe = &map.keyframes()[key];
            (keyframe.camera_from_world, keyframe.map_points.clone())
        } else {
            (pose, points)
        };
        report.record.camera_from_world = Some(pose);
        report.record.reference = self.reference.and_then(|k| {
            let keyframe = map.keyframes().get(k)?;
            Some((k, pose * keyframe.world_from_camera()))
        });
        self.last = Some(LastFrame {
            frame,
            camera_from_world: pose,
            points,
        });
    }

    /// Starts a map segment (the first, or a new one after tracking stayed lost) with
    /// `frame` as its first keyframe at `camera_from_world`, when the frame has enough
    /// keypoints with depth.
    fn start_segment(
        &mut self,
        map: &mut Map,
        gate: &Participation,
        frame: Frame,
        camera_from_world: Se3,
        report: &mut TrackedFrame,
    ) {
        let with_depth = frame.depth.iter().filter(|&&z| z > 0.0).count();
        if with_depth < self.config.min_initial_points {
            return;
        }
        self.segment = self.segments;
        self.segments += 1;
        self.insert_keyframe(
            map,
            &frame,
            gate,
            camera_from_world,
            vec![None; frame.len()],
            true,
        );
        report.started_segment(self.segment, self.reference, camera_from_world, with_depth);
        self.state = TrackingState::Ok;
        self.velocity = None;
        self.lost_since = None;
        let points = self
            .reference
            .and_then(|k| map.keyframes().get(k))
            .map_or_else(Vec::new, |kf| kf.map_points.clone());
        self.last = Some(LastFrame {
            frame,
            camera_from_world,
            points,
        });
    }
}

/// The frame's matches to points that take part (`gate`), as the report records them.
fn observations(
    map: &Map,
    gate: &Participation,
    frame: &Frame,
    points: &[Option<MapPointKey>],
) -> Vec<FrameObservation> {
    points
        .iter()
        .enumerate()
        .filter_map(|(i, k)| {
            let key = k.filter(|&k| map.points().get(k).is_some_and(|p| !gate.excluded(p)))?;
            let keypoint = &frame.keypoints[i];
            Some(FrameObservation {
                point: key,
                keypoint: i as u32,
                x: keypoint.x,
                y: keypoint.y,
                right_u: frame.right_u[i],
                level: keypoint.level,
            })
        })
        .collect()
}
