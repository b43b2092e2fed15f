//! Pose-only estimation from matched points (ORB-SLAM2's `PoseOptimization` after each
//! search): which matches take part (dynamic points never, points that wait for their
//! keyframe's detection or out their probation only when too few others remain) and
//! the optimisation with its robust gate. The geometric check's verdicts on the final
//! matches are the DOP model's ([`crate::dynamics::tracked`]).

use std::time::Instant;

use super::{Timing, TrackInput, Tracker};
use crate::dynamics::frames::Participation;
use crate::dynamics::tracked::Sensor;
use crate::frame::Frame;
use crate::geometry::se3::Se3;
use crate::map::{MapPoint, MapPointKey};
use crate::optim::pose_only::{optimise_pose_predicted, within_gate, PoseObservation};
use crate::tracking::params::{MIN_POSE_OBSERVATIONS, MIN_TRUSTED_POINTS};
use crate::tracking::report::PoseEstimate;

impl Tracker {
    /// Optimises a pose from matched `points`, starting at `initial`. Dynamic points
    /// take no part but keep their match (their keypoint inherits the point's
    /// probability); so do waiting points while `held_out_min_points` others remain.
    /// With fewer than [`MIN_POSE_OBSERVATIONS`] observations the pose stays `initial`
    /// with no inliers.
    pub(super) fn optimise(
        &self,
        input: TrackInput,
        initial: &Se3,
        points: &[Option<MapPointKey>],
        timing: &mut Timing,
    ) -> PoseEstimate {
        let TrackInput { map, frame, gate } = input;
        let (start, sensor) = (Instant::now(), self.sensor());
        let mut taken = Taken {
            observations: Vec::new(),
            indices: Vec::new(),
            kept: vec![None; points.len()],
        };
        let mut awaiting = Vec::new();
        for (i, key) in points.iter().enumerate() {
            let Some(point) = key.and_then(|k| map.points().get(k)) else {
                continue;
            };
            if gate.excluded(point) {
                taken.kept[i] = points[i];
                continue;
            }
            if gate.awaiting(map, point) {
                awaiting.push((i, point));
                continue;
            }
            taken.observations.push(sensor.observation(frame, i, point));
            taken.indices.push(i);
        }
        if taken.observations.len() >= self.config.held_out_min_points {
            // Kept like dynamic matches until the detection says what they are.
            for (i, _) in awaiting {
                taken.kept[i] = points[i];
            }
        } else {
            let share = self.prediction_gate_share(gate);
            admit_waiting(&sensor, frame, initial, share, awaiting, points, &mut taken);
        }
        let Taken {
            observations,
            indices,
            mut kept,
        } = taken;
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

    /// The prediction gate's share (`[tracking] prediction_gate_share`) with the DOP
    /// model; 0 (ORB-SLAM2's rounds) without it.
    fn prediction_gate_share(&self, gate: &Participation) -> f64 {
        if gate.dop.is_some() {
            self.config.prediction_gate_share
        } else {
            0.0
        }
    }
}

/// The observations a pose is optimised from, the keypoint index of each, and the
/// matches kept beside them (dynamic and waiting points keep their match).
struct Taken {
    observations: Vec<PoseObservation>,
    indices: Vec<usize>,
    kept: Vec<Option<MapPointKey>>,
}

/// Too few others to go without them: the waiting points join the pose, but when
/// the others can give a pose of their own, only those that agree with it (a person
/// the detector has not reported yet moved away from it, and would outnumber the
/// room's few points); the others keep their match only.
fn admit_waiting(
    sensor: &Sensor,
    frame: &Frame,
    initial: &Se3,
    share: f64,
    awaiting: Vec<(usize, &MapPoint)>,
    points: &[Option<MapPointKey>],
    taken: &mut Taken,
) {
    let Taken {
        observations,
        indices,
        kept,
    } = taken;
    let trusted = (observations.len() >= MIN_TRUSTED_POINTS)
        .then(|| optimise_pose_predicted(sensor.camera, initial, observations, share))
        .filter(|estimate| estimate.inliers.iter().filter(|i| **i).count() >= MIN_TRUSTED_POINTS);
    for (i, point) in awaiting {
        let observation = sensor.observation(frame, i, point);
        let agrees = trusted.as_ref().is_none_or(|estimate| {
            within_gate(sensor.camera, &estimate.camera_from_world, &observation)
        });
        if agrees {
            observations.push(observation);
            indices.push(i);
        } else {
            kept[i] = points[i];
        }
    }
}
