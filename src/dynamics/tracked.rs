//! The DOP model on each tracked frame (paper §III-C, D). The tracker finds the pose;
//! between its search and its keyframe decision the system makes one call here,
//! [`after_pose`]: the geometric check's verdicts on the final matches (within the
//! pose's gate, and the rigidity test) update the map points' probabilities, then the
//! frame takes its own (propagation from its map points, else from the last frame's
//! keypoints, else \(P_{init}\); expansion; the followed objects' boxes). After a
//! detection the last frame is refreshed ([`refresh_last`]); before the next
//! extraction the keypoint budget makes up for the keypoints movers take
//! ([`feature_budget`]).

use std::time::Instant;

use nalgebra::Vector3;

use super::frames::{geometric_check, propagate_and_expand, Participation};
use crate::dop::consistency::Judgement;
use crate::dop::rigidity::{agreement, Matched};
use crate::dop::DopConfig;
use crate::features::{hamming, ScalePyramid, TH_LOW};
use crate::frame::{Area, Frame};
use crate::geometry::depth_noise::DepthNoise;
use crate::geometry::se3::Se3;
use crate::geometry::stereo_camera::StereoCamera;
use crate::map::{Map, MapPoint, MapPointKey};
use crate::optim::pose_only::{error_within, gated_error, PoseObservation};

/// Matches with depth a point is compared with before the rigidity test gives a
/// verdict on it (see `crate::dop::rigidity`).
pub const RIGIDITY_MIN_PARTNERS: usize = 20;

/// Radius (pixels, level 0) of the search for a keypoint's match in the last frame
/// when its probability propagates from there.
const PROPAGATION_RADIUS: f32 = 20.0;

/// What the DOP model needs of the sensor: the camera, the scale pyramid (the
/// observations' information) and the depth noise (the rigidity test).
#[derive(Debug, Clone, Copy)]
pub struct Sensor<'a> {
    /// The camera and its baseline.
    pub camera: &'a StereoCamera,
    /// The scale pyramid (the keypoints' level variances).
    pub pyramid: &'a ScalePyramid,
    /// The depth noise of the sensor.
    pub depth_noise: DepthNoise,
}

impl Sensor<'_> {
    /// Keypoint `i` of `frame` seeing `point`, as the pose optimisation weighs it.
    pub fn observation(&self, frame: &Frame, i: usize, point: &MapPoint) -> PoseObservation {
        let k = &frame.keypoints[i];
        PoseObservation::of_keypoint(
            point.position,
            (k.x, k.y, frame.right_u[i]),
            self.pyramid.inverse_sigma2[k.level as usize],
        )
    }

    /// Keypoint `i` of `frame` back-projected with its depth, in the camera:
    /// \(p = z\,((u - c_x)/f_x, (v - c_y)/f_y, 1)\).
    pub fn back_project(&self, frame: &Frame, i: usize) -> Vector3<f64> {
        let k = &frame.keypoints[i];
        let z = frame.depth[i] as f64;
        Vector3::new(
            (k.x as f64 - self.camera.cx) * z / self.camera.fx,
            (k.y as f64 - self.camera.cy) * z / self.camera.fy,
            z,
        )
    }
}

/// The tracker's pose of a frame: the pose, each keypoint's candidate map point of the
/// last search (before the pose's gate) and the matches kept as inliers.
#[derive(Debug, Clone, Copy)]
pub struct TrackedPose<'a> {
    /// The frame's pose, \(T_{cw}\).
    pub camera_from_world: &'a Se3,
    /// Per keypoint: the map point it was matched to before the pose.
    pub candidates: &'a [Option<MapPointKey>],
    /// Per keypoint: the map point it is an inlier of after the pose.
    pub matches: &'a [Option<MapPointKey>],
}

/// What [`after_pose`] did, for the frame's report line.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct DopFigures {
    /// Map points whose probability the geometric check raised and lowered.
    pub geometric_raised: usize,
    /// Map points whose probability the geometric check lowered.
    pub geometric_lowered: usize,
    /// Matches the rigidity test found moved.
    pub rigidity_outliers: usize,
    /// The frame's keypoints in a removed (dynamic) state.
    pub dynamic_keypoints: usize,
    /// Milliseconds of the frame's probabilities (propagation and expansion).
    pub dop_ms: f64,
}

/// The DOP model's step on a frame tracked at `pose` (see the module doc); nothing
/// without the model. `last` is the last tracked frame, with its probabilities.
pub fn after_pose(
    gate: &Participation,
    map: &mut Map,
    frame: &mut Frame,
    pose: TrackedPose,
    sensor: &Sensor,
    last: Option<&Frame>,
) -> DopFigures {
    let Some(dop) = gate.dop else {
        return DopFigures::default();
    };
    let mut figures = DopFigures::default();
    if dop.geometric {
        let (checks, moved) = judge_matches(gate, map, frame, dop, &pose, sensor);
        figures.rigidity_outliers = moved;
        (figures.geometric_raised, figures.geometric_lowered) =
            geometric_check(dop, map, &checks, frame.timestamp);
    }
    let start = Instant::now();
    frame.moving = moving_probabilities(gate, dop, map, frame, &pose, last);
    figures.dynamic_keypoints = frame.moving.iter().filter(|p| dop.removed(**p)).count();
    figures.dop_ms = start.elapsed().as_secs_f64() * 1e3;
    figures
}

/// One final match as the geometric check sees it.
struct Judged {
    keypoint: usize,
    key: MapPointKey,
    /// The map point's position (world).
    position: Vector3<f64>,
    /// Within the pose's gate, just outside it, or far outside.
    judgement: Judgement,
    /// Left out of the pose as dynamic.
    excluded: bool,
}

/// The geometric check's verdicts on the frame's final matches: the optimisation's
/// inliers are consistent; points that took no part (dynamic, waiting) are tested
/// against the final pose with the same gate. A point outside the gate is unclear
/// within `geometric_gate` times it, else inconsistent. A point the rigidity test
/// finds moved ([`moved`]) is inconsistent whatever the pose says. Also returns how
/// many the rigidity test found moved.
fn judge_matches(
    gate: &Participation,
    map: &Map,
    frame: &Frame,
    dop: &DopConfig,
    pose: &TrackedPose,
    sensor: &Sensor,
) -> (Vec<(MapPointKey, Judgement)>, usize) {
    let judged: Vec<Judged> = pose
        .candidates
        .iter()
        .zip(pose.matches)
        .enumerate()
        .filter_map(|(i, (candidate, inlier))| {
            let key = (*candidate)?;
            let point = map.points().get(key)?;
            let excluded = gate.excluded(point);
            // Projected only where needed (most matches are the pose's inliers), and
            // at most once: the error against the gate answers both the gate and the band.
            let projected = std::cell::OnceCell::new();
            let error = || {
                *projected.get_or_init(|| {
                    let observation = sensor.observation(frame, i, point);
                    gated_error(sensor.camera, pose.camera_from_world, &observation)
                })
            };
            let consistent = if excluded || gate.awaiting(map, point) {
                error_within(error(), 1.0)
            } else {
                inlier.is_some()
            };
            // A gate of 1 has no band: the check as before, with no second projection.
            let judgement = if consistent {
                Judgement::Consistent
            } else if dop.geometric_gate > 1.0
                && error_within(error(), f64::from(dop.geometric_gate))
            {
                Judgement::Unclear
            } else {
                Judgement::Inconsistent
            };
            Some(Judged {
                keypoint: i,
                key,
                position: point.position,
                judgement,
                excluded,
            })
        })
        .collect();
    let moved = moved(frame, dop, sensor, &judged);
    let checks = judged
        .iter()
        .zip(&moved)
        .map(|(j, moved)| {
            (
                j.key,
                if *moved {
                    Judgement::Inconsistent
                } else {
                    j.judgement
                },
            )
        })
        .collect();
    (checks, moved.iter().filter(|m| **m).count())
}

/// The rigidity test ([`crate::dop::rigidity`]) on the judged matches with depth:
/// which keep their distances to fewer than `rigidity_agreement` of the matches not
/// left out as dynamic, within `rigidity_sigmas` standard deviations of the
/// sensor's depth noise. Needs no pose, so it sees a mover that the pose follows.
fn moved(frame: &Frame, dop: &DopConfig, sensor: &Sensor, judged: &[Judged]) -> Vec<bool> {
    let mut moved = vec![false; judged.len()];
    if dop.rigidity_sigmas <= 0.0 {
        return moved;
    }
    let with_depth: Vec<usize> = (0..judged.len())
        .filter(|&n| frame.depth[judged[n].keypoint] > 0.0)
        .collect();
    let matched: Vec<Matched> = with_depth
        .iter()
        .map(|&n| {
            let camera = sensor.back_project(frame, judged[n].keypoint);
            Matched {
                world: judged[n].position,
                camera,
                sigma: sensor.depth_noise.sigma(camera.z),
            }
        })
        .collect();
    let reference: Vec<usize> = (0..with_depth.len())
        .filter(|&m| !judged[with_depth[m]].excluded)
        .collect();
    let shares = agreement(
        &matched,
        &reference,
        f64::from(dop.rigidity_sigmas),
        RIGIDITY_MIN_PARTNERS,
    );
    for (&n, share) in with_depth.iter().zip(shares) {
        moved[n] = share.is_some_and(|s| s < dop.rigidity_agreement);
    }
    moved
}

/// The DOP model's probabilities for a frame tracked at `camera_from_world` with
/// `points` matched: propagation from its map points, else from the last frame's
/// keypoints (the best descriptor match within [`PROPAGATION_RADIUS`] and one pyramid
/// level), else \(P_{init}\); then expansion and the followed objects' boxes.
fn moving_probabilities(
    gate: &Participation,
    dop: &DopConfig,
    map: &Map,
    frame: &Frame,
    pose: &TrackedPose,
    last: Option<&Frame>,
) -> Vec<f32> {
    let from_map: Vec<Option<f32>> = pose
        .matches
        .iter()
        .map(|k| k.and_then(|k| map.points().get(k)).map(|p| p.moving))
        .collect();
    let from_last: Vec<Option<f32>> = match (last, dop.propagation) {
        (Some(last), true) => (0..frame.len())
            .map(|i| {
                if from_map[i].is_some() {
                    return None;
                }
                let k = &frame.keypoints[i];
                let area = Area {
                    x: k.x,
                    y: k.y,
                    radius: PROPAGATION_RADIUS,
                    min_level: k.level.saturating_sub(1),
                    max_level: k.level + 1,
                };
                // The nearest descriptor within TH_LOW (the lowest index of equals).
                let mut best: Option<(u32, usize)> = None;
                last.for_features_in_area(area, |j| {
                    let candidate = (hamming(&frame.descriptors[i], &last.descriptors[j]), j);
                    if candidate.0 <= TH_LOW && best.is_none_or(|b| candidate < b) {
                        best = Some(candidate);
                    }
                });
                best.map(|(_, j)| last.moving[j])
            })
            .collect(),
        _ => vec![None; frame.len()],
    };
    let followed = gate.followed.map(|f| (f, pose.camera_from_world));
    propagate_and_expand(dop, frame, &from_map, &from_last, followed)
}

/// The last tracked frame, as [`refresh_last`] updates it: the frame, its map points
/// and its pose.
pub struct LastTracked<'a> {
    /// The frame.
    pub frame: &'a mut Frame,
    /// Per keypoint: the map point it observes.
    pub points: &'a [Option<MapPointKey>],
    /// Its pose, \(T_{cw}\).
    pub camera_from_world: &'a Se3,
}

/// After detections updated the map: the last frame's keypoints take their map
/// points' probabilities (the others keep theirs), then expansion runs again, so the
/// next frame propagates what the detections said.
pub fn refresh_last(gate: &Participation, map: &Map, last: LastTracked) {
    let Some(dop) = gate.dop else {
        return;
    };
    let from_map: Vec<Option<f32>> = last
        .points
        .iter()
        .map(|k| k.and_then(|k| map.points().get(k)).map(|p| p.moving))
        .collect();
    let kept: Vec<Option<f32>> = last
        .frame
        .moving
        .iter()
        .zip(&from_map)
        .map(|(p, m)| (m.is_none() && *p != dop.p_init).then_some(*p))
        .collect();
    let followed = gate.followed.map(|f| (f, last.camera_from_world));
    last.frame.moving = propagate_and_expand(dop, last.frame, &from_map, &kept, followed);
}

/// The keypoint budget for the next frame: `n_features` over the static share
/// \(\phi\) of the last frame's keypoints (those the DOP model did not remove), so
/// that movers taking keypoints do not leave the pose fewer static ones
/// ([`crate::features::orb::OrbExtractor::with_budget`] clamps it).
pub fn feature_budget(n_features: usize, dop: Option<&DopConfig>, last: Option<&Frame>) -> usize {
    let (Some(last), Some(dop)) = (last, dop) else {
        return n_features;
    };
    let total = last.moving.len();
    let dynamic = last.moving.iter().filter(|p| dop.removed(**p)).count();
    let share = (total - dynamic) as f64 / total.max(1) as f64;
    (n_features as f64 / share.max(0.01)).round() as usize
}
