//! Pose-only estimation from matched points (ORB-SLAM2's `PoseOptimization` after each
//! search): which matches take part (dynamic points never, points that wait for their
//! keyframe's detection or out their probation only when too few others remain), the
//! optimisation with its robust gate, and the geometric check's verdicts on the final
//! matches.

use std::time::Instant;

use nalgebra::Vector3;

use super::{Timing, Tracker};
use crate::dop::rigidity::{agreement, Matched};
use crate::dop::DopConfig;
use crate::dynamics::frames::Participation;
use crate::frame::Frame;
use crate::geometry::se3::Se3;
use crate::map::{Map, MapPoint, MapPointKey};
use crate::optim::pose_only::{optimise_pose_predicted, within_gate, PoseObservation};
use crate::tracking::params::{MIN_POSE_OBSERVATIONS, MIN_TRUSTED_POINTS, RIGIDITY_MIN_PARTNERS};
use crate::tracking::report::PoseEstimate;

/// One final match as the geometric check sees it.
struct Judged {
    keypoint: usize,
    key: MapPointKey,
    /// The map point's position (world).
    position: Vector3<f64>,
    /// Within the pose's gate.
    consistent: bool,
    /// Left out of the pose as dynamic.
    excluded: bool,
}

impl Tracker {
    /// Optimises a pose from matched `points`, starting at `initial`. Dynamic points
    /// take no part but keep their match (their keypoint inherits the point's
    /// probability); so do waiting points while `held_out_min_points` others remain.
    /// With fewer than [`MIN_POSE_OBSERVATIONS`] observations the pose stays `initial`
    /// with no inliers.
    pub(super) fn optimise(
        &self,
        (map, frame, gate): (&Map, &Frame, &Participation),
        initial: &Se3,
        points: &[Option<MapPointKey>],
        timing: &mut Timing,
    ) -> PoseEstimate {
        let start = Instant::now();
        let mut indices = Vec::new();
        let mut observations = Vec::new();
        let mut kept = vec![None; points.len()];
        let mut awaiting = Vec::new();
        for (i, key) in points.iter().enumerate() {
            let Some(point) = key.and_then(|k| map.points.get(k)) else {
                continue;
            };
            if gate.excluded(point) {
                kept[i] = points[i];
                continue;
            }
            if gate.awaiting(map, point) {
                awaiting.push((i, point));
                continue;
            }
            observations.push(self.observation(frame, i, point));
            indices.push(i);
        }
        if observations.len() >= self.config.held_out_min_points {
            // Kept like dynamic matches until the detection says what they are.
            for (i, _) in awaiting {
                kept[i] = points[i];
            }
        } else {
            self.admit_waiting(
                frame,
                (initial, self.prediction_gate_share(gate)),
                awaiting,
                (&mut observations, &mut indices),
                (points, &mut kept),
            );
        }
        if observations.len() < MIN_POSE_OBSERVATIONS {
            timing.optimisation += start.elapsed().as_secs_f64() * 1e3;
            return PoseEstimate {
                camera_from_world: *initial,
                matches: kept,
                inliers: 0,
            };
        }
        let estimate = optimise_pose_predicted(
            &self.camera,
            initial,
            &observations,
            self.prediction_gate_share(gate),
        );
        let mut inliers = 0;
        for (n, &i) in indices.iter().enumerate() {
            if estimate.inliers[n] {
                kept[i] = points[i];
                inliers += 1;
            }
        }
        timing.optimisation += start.elapsed().as_secs_f64() * 1e3;
        PoseEstimate {
            camera_from_world: estimate.camera_from_world,
            matches: kept,
            inliers,
        }
    }

    /// Too few others to go without them: the waiting points join the pose, but when
    /// the others can give a pose of their own, only those that agree with it (a person
    /// the detector has not reported yet moved away from it, and would outnumber the
    /// room's few points); the others keep their match only.
    fn admit_waiting(
        &self,
        frame: &Frame,
        (initial, share): (&Se3, f64),
        awaiting: Vec<(usize, &MapPoint)>,
        (observations, indices): (&mut Vec<PoseObservation>, &mut Vec<usize>),
        (points, kept): (&[Option<MapPointKey>], &mut [Option<MapPointKey>]),
    ) {
        let trusted = (observations.len() >= MIN_TRUSTED_POINTS)
            .then(|| optimise_pose_predicted(&self.camera, initial, observations, share))
            .filter(|estimate| {
                estimate.inliers.iter().filter(|i| **i).count() >= MIN_TRUSTED_POINTS
            });
        for (i, point) in awaiting {
            let observation = self.observation(frame, i, point);
            let agrees = trusted.as_ref().is_none_or(|estimate| {
                within_gate(&self.camera, &estimate.camera_from_world, &observation)
            });
            if agrees {
                observations.push(observation);
                indices.push(i);
            } else {
                kept[i] = points[i];
            }
        }
    }

    /// The prediction gate's share (`[tracking] prediction_gate_share`) with the DOP
    /// model; 0 (ORB-SLAM2's rounds) without it.
    fn prediction_gate_share(&self, gate: &Participation) -> f64 {
        if gate.dop.is_some() {
            self.config.prediction_gate_share
        } else {
            0.0
        }
    }

    /// Keypoint `i` of `frame` seeing `point`, for the pose optimisation.
    pub(super) fn observation(&self, frame: &Frame, i: usize, point: &MapPoint) -> PoseObservation {
        let k = &frame.keypoints[i];
        PoseObservation::of_keypoint(
            point.position,
            (k.x, k.y, frame.right_u[i]),
            self.pyramid.inverse_sigma2[k.level as usize],
        )
    }

    /// The geometric check's verdicts on the frame's final matches: the optimisation's
    /// inliers are consistent; points that took no part (dynamic, waiting) are tested
    /// against the final pose with the same gate. A point the rigidity test finds moved
    /// ([`Tracker::moved`]) is inconsistent whatever the pose says. Also returns how
    /// many the rigidity test found moved.
    pub(super) fn consistency(
        &self,
        (map, frame, gate): (&Map, &Frame, &Participation),
        (dop, pose): (&DopConfig, &Se3),
        candidates: &[Option<MapPointKey>],
        inliers: &[Option<MapPointKey>],
    ) -> (Vec<(MapPointKey, bool)>, usize) {
        let judged: Vec<Judged> = candidates
            .iter()
            .zip(inliers)
            .enumerate()
            .filter_map(|(i, (candidate, inlier))| {
                let key = (*candidate)?;
                let point = map.points.get(key)?;
                let excluded = gate.excluded(point);
                let consistent = if excluded || gate.awaiting(map, point) {
                    within_gate(&self.camera, pose, &self.observation(frame, i, point))
                } else {
                    inlier.is_some()
                };
                Some(Judged {
                    keypoint: i,
                    key,
                    position: point.position,
                    consistent,
                    excluded,
                })
            })
            .collect();
        let moved = self.moved(frame, dop, &judged);
        let checks = judged
            .iter()
            .zip(&moved)
            .map(|(j, moved)| (j.key, j.consistent && !moved))
            .collect();
        (checks, moved.iter().filter(|m| **m).count())
    }

    /// The rigidity test ([`crate::dop::rigidity`]) on the judged matches with depth:
    /// which keep their distances to fewer than `rigidity_agreement` of the matches not
    /// left out as dynamic, within `rigidity_sigmas` standard deviations of the
    /// sensor's depth noise. Needs no pose, so it sees a mover that the pose follows.
    fn moved(&self, frame: &Frame, dop: &DopConfig, judged: &[Judged]) -> Vec<bool> {
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
                let camera = self.back_project(frame, judged[n].keypoint);
                Matched {
                    world: judged[n].position,
                    camera,
                    sigma: self.depth_noise.sigma(camera.z),
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
}
