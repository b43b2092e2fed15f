//! The global pass (after tracking): loop closure over the keyframes in the order they
//! were made ([`loop_closing`]) on the candidates that place recognition
//! ([`crate::bow`]) found beside the tracking pass (`system::stages::Recognition`, in
//! its own thread), essential graph optimisation ([`essential_graph`]) after each loop, then a
//! full bundle adjustment over every keyframe and every static map point, then every
//! tracked frame estimated again on the final map ([`frame_refinement`]) and smoothed
//! with a motion prior ([`trajectory_smoothing`]). Frames follow
//! their reference keyframes when the trajectory is written.
//!
//! Entry point: [`run`] on the map the tracking pass left.

pub mod candidates;
pub mod disparity_offset;
pub mod essential_graph;
pub mod frame_refinement;
pub mod loop_closing;
pub mod loop_confirmation;
pub mod place_recognition;
pub mod rigid_motion;
pub mod trajectory_smoothing;
pub mod word_matching;

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::bow::Vocabulary;
use crate::features::ScalePyramid;
use crate::geometry::stereo_camera::StereoCamera;
use crate::io::IoError;
use crate::map::record::{FrameRecords, RECORD_CHUNK};
use crate::map::Map;
use crate::mapping::window_ba::Window;
use candidates::Candidate;
use loop_closing::{ClosedLoop, LoopState};
use place_recognition::LoopConfig;

/// The `[global]` section of a config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GlobalConfig {
    /// Run the global pass after tracking (`dopslam run --no-global` skips it).
    pub enabled: bool,
    /// The place-recognition vocabulary (`dopslam vocab train`); relative paths are
    /// taken from the working directory. Unset: `vocabulary.dbow` in the runtime data
    /// directory ([`crate::io::data_dir`]).
    pub vocabulary: Option<PathBuf>,
    /// `[global.loops]`: loop detection and closing.
    pub loops: LoopConfig,
    /// Full bundle adjustment at the end: iterations with the Huber kernel, then
    /// without it on the inliers.
    pub full_ba: bool,
    /// Stereo: after full BA, estimate the rig's disparity offset from the map, take
    /// it out of every disparity and run full BA again ([`disparity_offset`]; needs
    /// `full_ba`).
    pub disparity_offset: bool,
    /// The smallest first estimate (pixels) that is taken out: the estimate reads
    /// about 0.3 px on a real rig whose disparities want none (KITTI 06), so smaller
    /// ones are not told apart from its own error (`docs/design.md`).
    pub disparity_offset_min_px: f64,
    /// Full BA iterations with the Huber kernel.
    pub full_ba_robust_iterations: usize,
    /// Full BA iterations without it, on the inliers.
    pub full_ba_inlier_iterations: usize,
    /// After full BA, estimate every tracked frame's pose again against the final
    /// static map points it saw ([`frame_refinement`]).
    pub refine_frames: bool,
    /// Then smooth every frame's pose with a motion prior ([`trajectory_smoothing`]).
    pub smoothing: trajectory_smoothing::SmoothingConfig,
}

impl Default for GlobalConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            vocabulary: None,
            loops: LoopConfig::default(),
            full_ba: true,
            disparity_offset: true,
            disparity_offset_min_px: 0.75,
            full_ba_robust_iterations: 10,
            full_ba_inlier_iterations: 5,
            refine_frames: true,
            smoothing: trajectory_smoothing::SmoothingConfig::default(),
        }
    }
}

/// What the full bundle adjustment did.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct FullBaReport {
    /// Keyframes in the full BA.
    pub keyframes: usize,
    /// Keyframes held (the oldest of each map segment, and those with too few static
    /// observations).
    pub held: usize,
    /// Map points in it.
    pub points: usize,
    /// Observations in it.
    pub observations: usize,
    /// \(\chi^2\) before.
    pub initial_cost: f64,
    /// \(\chi^2\) after.
    pub final_cost: f64,
    /// Observations dropped as outliers.
    pub outliers_removed: usize,
    /// The full BA's time.
    pub milliseconds: f64,
}

/// What the global pass did (in `report.json`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct GlobalReport {
    /// The loops closed.
    pub loops: Vec<ClosedLoop>,
    /// Every loop candidate that reached consistency checking, with its outcome.
    pub candidates: Vec<Candidate>,
    /// The full BA, when it ran (the last one, after the disparity offset's rounds).
    pub full_ba: Option<FullBaReport>,
    /// Stereo: the rig's disparity offset, when it was estimated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub disparity_offset: Option<disparity_offset::OffsetReport>,
    /// The frames estimated again on the final map.
    pub frames: Option<frame_refinement::RefinementReport>,
    /// The frames' poses smoothed with a motion prior.
    pub smoothing: Option<trajectory_smoothing::SmoothingReport>,
    /// Place recognition beside the tracking pass (its thread's time), and loop
    /// verification and correction in the global pass, milliseconds.
    pub loop_detection_ms: f64,
    /// Loop verification and correction in the global pass, milliseconds.
    pub loop_closing_ms: f64,
    /// Loop verification and correction during the tracking pass (`[global.loops]
    /// during_tracking`), milliseconds: part of the tracking pass's time.
    #[serde(default)]
    pub loop_closing_during_tracking_ms: f64,
    /// The global pass itself (loop closing and full BA).
    pub total_ms: f64,
    /// Why loop detection did not run, when it did not.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// The peak resident memory of each part of the pass.
    #[serde(default)]
    pub memory: GlobalMemory,
}

/// Loops closed after tracking, with none during it, from which a run's summary
/// suggests closing them during tracking ([`GlobalReport::revisit_hint`]).
pub const REVISIT_HINT_LOOPS: usize = 10;

impl GlobalReport {
    /// For a run whose tracking pass came back to places it had mapped many times (at
    /// least [`REVISIT_HINT_LOOPS`] loops, all closed after tracking): that it mapped
    /// them as new ground, and what `[global.loops] during_tracking` changes.
    pub fn revisit_hint(&self) -> Option<String> {
        let after = self.loops.iter().filter(|l| !l.during_tracking).count();
        (after >= REVISIT_HINT_LOOPS && after == self.loops.len()).then(|| {
            format!(
                "hint: {after} loops were closed after tracking, so the tracking pass mapped the places it came back to as new ground; `[global.loops] during_tracking = true` tracks them in the earlier visit's map: fewer keyframes, and memory that stays flat on a route driven again, but tracking stops while each loop is corrected, and a street's trajectory spreads more between runs (docs/configuration.md)"
            )
        })
    }
}

/// The peak resident memory (MiB, sampled; the process's, so each includes the map)
/// of each part of the global pass, where the system reports it.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct GlobalMemory {
    /// Loop verification and correction.
    pub loops_mib: Option<f64>,
    /// Full BA, with the disparity offset's rounds.
    pub full_ba_mib: Option<f64>,
    /// The frames estimated again and smoothed.
    pub frames_mib: Option<f64>,
    /// What the map held when the pass began (MiB): its keyframes (features, depth,
    /// grid, observations) and its points.
    #[serde(default)]
    pub keyframes_held_mib: f64,
    /// The map points' part of it.
    #[serde(default)]
    pub points_held_mib: f64,
    /// The tracked frames' records (the map points each saw, for their estimate
    /// on the final map).
    #[serde(default)]
    pub frame_records_held_mib: f64,
}

impl GlobalMemory {
    /// Records what the map and the frames' records hold.
    fn hold(&mut self, map: &Map, records: &FrameRecords) {
        const MIB: f64 = 1024.0 * 1024.0;
        let held = map.footprint();
        self.keyframes_held_mib = held.keyframes as f64 / MIB;
        self.points_held_mib = held.points as f64 / MIB;
        self.frame_records_held_mib = records.heap_bytes() as f64 / MIB;
    }
}

/// What the pass needs of the system.
pub struct GlobalInputs<'a> {
    /// The camera and its baseline.
    pub camera: &'a StereoCamera,
    /// The scale pyramid.
    pub pyramid: &'a ScalePyramid,
    /// A stereo sequence (its disparities may carry the rig's offset).
    pub stereo: bool,
    /// The image size, pixels.
    pub size: (f32, f32),
    /// Points above this moving probability are dynamic and take no part.
    pub removal_threshold: f32,
    /// The frames' refinement starts from the points its initial pose explains when
    /// they are this share of all (`[tracking] prediction_gate_share`; 0: off).
    pub prediction_gate_share: f64,
}

/// What loop closing needs of the run, owned: the closer lives in the online system
/// when loops are closed during tracking ([`loop_closing::LoopCloser`]).
#[derive(Debug, Clone)]
pub struct LoopInputs {
    /// The camera and its baseline.
    pub camera: StereoCamera,
    /// The scale pyramid.
    pub pyramid: ScalePyramid,
    /// The image size, pixels.
    pub size: (f32, f32),
    /// Points above this moving probability are dynamic and take no part.
    pub removal_threshold: f32,
}

impl GlobalConfig {
    /// The vocabulary file this config uses.
    pub fn vocabulary_file(&self) -> PathBuf {
        crate::io::data_dir::resolve(self.vocabulary.as_deref(), crate::io::data_dir::VOCABULARY)
    }
}

/// Why the global pass runs without loop closing (in `report.json` as its sentence,
/// `global.note`).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NoLoops {
    /// The config or `--no-loops` turned it off.
    #[error("loop closing is off ([global.loops] enabled = false, --no-loops)")]
    TurnedOff,
    /// The vocabulary at `path` cannot be read (`problem`); `fix` says how to get one.
    #[error("loop closing needs the vocabulary {}: {problem}; {fix}; or run with --no-loops", path.display())]
    NoVocabulary {
        /// The vocabulary file.
        path: PathBuf,
        /// Why it cannot be read.
        problem: String,
        /// How to get one.
        fix: &'static str,
    },
}

/// The place-recognition vocabulary of `config`, or why loop detection cannot run:
/// the error names the file and the ways out.
pub fn load_vocabulary(config: &GlobalConfig) -> Result<Arc<Vocabulary>, NoLoops> {
    let path = config.vocabulary_file();
    Vocabulary::read(&path)
        .map(Arc::new)
        .map_err(|e| NoLoops::NoVocabulary {
            fix: if path.exists() {
                "train one with `dopslam vocab train` or set [global] vocabulary"
            } else {
                crate::io::data_dir::INSTALL_HINT
            },
            problem: e.to_string(),
            path,
        })
}

/// Runs the global pass on `map` in place: loops verified and corrected from what
/// place recognition found beside tracking (`Err`: why it could not run), then full BA,
/// then the tracked frames' `records` estimated again on the final map and smoothed
/// (`Err`: their observations could not be read or written).
pub fn run(
    map: &mut Map,
    inputs: &GlobalInputs,
    config: &GlobalConfig,
    recognised: Result<LoopState, NoLoops>,
    records: &mut FrameRecords,
) -> Result<GlobalReport, IoError> {
    let start = Instant::now();
    let mut report = GlobalReport::default();
    let gauge = Gauge::of(map);
    crate::memory::part_peak_mib();
    match recognised {
        Ok(LoopState {
            mut recognition,
            mut closer,
        }) => {
            report.loop_closing_during_tracking_ms = closer.during_tracking_ms;
            closer.close_found(map, &mut recognition);
            (report.loops, report.candidates, report.loop_detection_ms) =
                closer.finish(recognition);
        }
        Err(why) => report.note = Some(why.to_string()),
    }
    report.loop_closing_ms = start.elapsed().as_secs_f64() * 1e3;
    report.memory.loops_mib = crate::memory::part_peak_mib();
    // Place recognition's words and database are gone: their pages go back before
    // full BA builds its arrays (and after it, before the frames).
    crate::memory::release_freed_memory();
    report.memory.hold(map, records);
    if config.full_ba {
        report.full_ba = full_bundle_adjustment(map, inputs, config);
        if config.disparity_offset && inputs.stereo && report.full_ba.is_some() {
            report.disparity_offset = take_out_disparity_offset(
                map,
                inputs,
                config,
                disparity_offset::OffsetTest::First(config.disparity_offset_min_px),
                &mut report.full_ba,
                records,
            )?;
        }
    }
    report.memory.full_ba_mib = crate::memory::part_peak_mib();
    crate::memory::release_freed_memory();
    if let Some(gauge) = gauge {
        gauge.restore(map, records)?;
    }
    if config.refine_frames {
        report.frames = Some(frame_refinement::refine_frames(map, inputs, records)?);
    }
    if config.smoothing.enabled {
        let smoothed = trajectory_smoothing::smooth_records(map, &config.smoothing, records)?;
        report.smoothing = Some(smoothed);
    }
    report.memory.frames_mib = crate::memory::part_peak_mib();
    report.total_ms = start.elapsed().as_secs_f64() * 1e3;
    Ok(report)
}

/// The world frame the tracking pass left: its oldest keyframe's pose (the first
/// keyframe of the run, or of the loaded map). Loop corrections may move that
/// keyframe too (tracking matches old points on a revisit, so the loop keyframe's
/// neighbourhood can hold it), so the pass ends by moving the whole map back rigidly
/// onto it: the trajectory stays in the frame ORB-SLAM2 gives it, and in the loaded
/// map's frame (`dopslam run --map`).
struct Gauge {
    key: crate::map::KeyFrameKey,
    camera_from_world: crate::geometry::se3::Se3,
}

impl Gauge {
    fn of(map: &Map) -> Option<Self> {
        let key = *map.keyframe_order().first()?;
        Some(Self {
            key,
            camera_from_world: map.keyframes()[key].camera_from_world,
        })
    }

    /// The map and the frames' tracked poses moved rigidly so that the keyframe is
    /// where it was (nothing when it is gone).
    fn restore(&self, map: &mut Map, frames: &mut FrameRecords) -> Result<(), IoError> {
        let Some(now) = map.keyframes().get(self.key).map(|k| k.camera_from_world) else {
            return Ok(());
        };
        // T_cw' = T_cw S^-1 = T_before  =>  S = T_before^-1 T_cw.
        let change = self.camera_from_world.inverse() * now;
        map.transform_world(&change);
        let inverse = change.inverse();
        frames.update(RECORD_CHUNK, |frames, _| {
            for frame in frames.iter_mut() {
                if let Some(pose) = frame.camera_from_world.as_mut() {
                    *pose *= inverse;
                }
            }
            Ok(())
        })
    }
}

/// At most this many rounds of estimate, correction and full BA.
const OFFSET_ROUNDS: usize = 3;
/// After a first correction, an estimate below this (pixels) ends the rounds.
const MIN_OFFSET_PX: f64 = 0.05;

/// Rounds of [`disparity_offset::estimate`], [`disparity_offset::correct`] and full BA:
/// nothing is taken out unless the first estimate passes the confidence test
/// ([`disparity_offset::Estimate::verdict`] as `test` says), and
/// the rounds end when one falls below [`MIN_OFFSET_PX`]; `full_ba` becomes the last
/// BA's report. `None` when the map has too few points with parallax for an estimate;
/// `Err` when the `records`' observations could not be corrected.
pub fn take_out_disparity_offset(
    map: &mut Map,
    inputs: &GlobalInputs,
    config: &GlobalConfig,
    test: disparity_offset::OffsetTest,
    full_ba: &mut Option<FullBaReport>,
    records: &mut FrameRecords,
) -> Result<Option<disparity_offset::OffsetReport>, IoError> {
    let Some(first) = disparity_offset::estimate(map, inputs.camera, inputs.removal_threshold)
    else {
        return Ok(None);
    };
    let test = match test {
        disparity_offset::OffsetTest::First(min_px) => {
            disparity_offset::OffsetTest::First(min_px.max(MIN_OFFSET_PX))
        }
        residual => residual,
    };
    let verdict = first.verdict(test);
    let mut offset = disparity_offset::OffsetReport::first(&first, &verdict);
    if verdict != disparity_offset::Verdict::Apply {
        return Ok(Some(offset));
    }
    let mut found = first.offset_px;
    for round in 0..OFFSET_ROUNDS {
        if round > 0 {
            let Some(next) =
                disparity_offset::estimate(map, inputs.camera, inputs.removal_threshold)
            else {
                break;
            };
            offset.rounds.push(next.offset_px);
            offset.pairs = next.pairs;
            offset.scale = next.scale;
            if next.offset_px.abs() < MIN_OFFSET_PX {
                break;
            }
            found = next.offset_px;
        }
        disparity_offset::correct(map, records, inputs.camera.bf, found)?;
        offset.offset_px += found;
        *full_ba = full_bundle_adjustment(map, inputs, config);
    }
    Ok(Some(offset))
}

/// Keyframes with fewer static observations are held in full BA.
pub const MIN_FULL_BA_OBSERVATIONS: usize = 50;

/// Bundle adjustment over every keyframe and static point; outlier observations removed.
pub fn full_bundle_adjustment(
    map: &mut Map,
    inputs: &GlobalInputs,
    config: &GlobalConfig,
) -> Option<FullBaReport> {
    let start = Instant::now();
    let mut window = Window::whole_map(map, inputs.pyramid, inputs.removal_threshold)?;
    // A keyframe with few static observations (the DOP model called most of its points
    // dynamic) is held: BA would fit its pose to a handful of points, where tracking
    // had hundreds.
    let mut seen = vec![0usize; window.problem.poses.len()];
    for o in &window.problem.observations {
        seen[o.camera] += 1;
    }
    for (fixed, &count) in window.problem.fixed.iter_mut().zip(&seen) {
        *fixed |= count < MIN_FULL_BA_OBSERVATIONS;
    }
    let ba = window.solve_with(
        inputs.camera,
        config.full_ba_robust_iterations,
        config.full_ba_inlier_iterations,
    );
    let removed = window.apply(map, &ba, &inputs.pyramid.factors);
    if removed > 0 {
        // Removed observations change what keyframes share.
        let keyframes = map.keyframe_order().to_vec();
        for k in keyframes {
            map.update_connections(k);
        }
    }
    Some(FullBaReport {
        keyframes: window.problem.poses.len(),
        held: window.problem.fixed.iter().filter(|f| **f).count(),
        points: window.problem.points.len(),
        observations: window.problem.observations.len(),
        initial_cost: ba.initial_cost,
        final_cost: ba.final_cost,
        outliers_removed: removed,
        milliseconds: start.elapsed().as_secs_f64() * 1e3,
    })
}

#[cfg(test)]
mod gauge_tests {
    use super::*;
    use crate::frame::Frame;
    use crate::geometry::se3;
    use crate::map::{KeyFrame, MapPoint};
    use nalgebra::Vector3;

    #[test]
    fn the_pass_ends_in_the_world_frame_of_the_oldest_keyframe() {
        let mut map = Map::default();
        let pose = |x: f64, yaw: f64| {
            se3::from_parts(
                Vector3::new(x, 0.1, 0.0),
                *nalgebra::Rotation3::from_euler_angles(0.0, yaw, 0.02).matrix(),
            )
        };
        let first = map.add_keyframe(KeyFrame::new(Frame::blank(1, (640, 480)), pose(0.0, 0.1)));
        let second = map.add_keyframe(KeyFrame::new(Frame::blank(1, (640, 480)), pose(1.0, 0.3)));
        let point = map.insert_point(MapPoint::new(
            Vector3::new(0.5, 0.2, 3.0),
            [0; 4],
            Vector3::z(),
            (0.1, 10.0),
            0,
        ));
        map.add_observation(point, second, 0);
        let relative = |m: &Map| {
            let (a, b) = (&m.keyframes()[first], &m.keyframes()[second]);
            let seen = b.camera_from_world * nalgebra::Point3::from(m.points()[point].position);
            (a.camera_from_world * b.world_from_camera(), seen)
        };
        let before = (map.keyframes()[first].camera_from_world, relative(&map));
        let gauge = Gauge::of(&map).unwrap();
        // A correction that moved everything, the oldest keyframe too.
        map.transform_world(&pose(0.4, -0.5));
        let mut records = FrameRecords::default();
        let record = crate::map::record::FrameRecord {
            camera_from_world: Some(map.keyframes()[second].camera_from_world),
            ..Default::default()
        };
        records.push(record).unwrap();
        gauge.restore(&mut map, &mut records).unwrap();
        let record = records.last().unwrap();
        let close = |a: &crate::geometry::se3::Se3, b: &crate::geometry::se3::Se3| {
            (a.to_homogeneous() - b.to_homogeneous()).norm() < 1e-9
        };
        assert!(close(&map.keyframes()[first].camera_from_world, &before.0));
        let (pose_after, seen_after) = relative(&map);
        assert!(close(&pose_after, &before.1 .0));
        assert!((seen_after - before.1 .1).norm() < 1e-9);
        assert!(close(
            &record.camera_from_world.unwrap(),
            &map.keyframes()[second].camera_from_world
        ));
    }
}

#[cfg(test)]
mod hint_tests {
    use super::*;
    use crate::global::candidates::LoopPair;

    fn closed(during_tracking: bool) -> ClosedLoop {
        ClosedLoop {
            pair: LoopPair {
                keyframe: 300,
                matched: 10,
                keyframe_time: 30.0,
                matched_time: 1.0,
            },
            inliers: 40,
            guided_matches: 200,
            correction_m: 0.5,
            correction_deg: 1.0,
            fused_points: 500,
            essential_graph: Default::default(),
            merged: None,
            during_tracking,
        }
    }

    fn with_loops(after: usize, during: usize) -> GlobalReport {
        let loops = (0..after).map(|_| closed(false));
        GlobalReport {
            loops: loops.chain((0..during).map(|_| closed(true))).collect(),
            ..Default::default()
        }
    }

    #[test]
    fn many_loops_closed_after_tracking_bring_the_hint_to_close_them_during_it() {
        let hint = with_loops(REVISIT_HINT_LOOPS, 0).revisit_hint().unwrap();
        assert!(
            hint.contains(&format!("{REVISIT_HINT_LOOPS} loops")),
            "{hint}"
        );
        assert!(hint.contains("during_tracking = true"), "{hint}");
        assert_eq!(with_loops(REVISIT_HINT_LOOPS - 1, 0).revisit_hint(), None);
        // Closed during tracking already: the option is on.
        assert_eq!(with_loops(REVISIT_HINT_LOOPS, 1).revisit_hint(), None);
    }
}
