//! Every tracked frame estimated again on the final map (beyond ORB-SLAM2, which keeps
//! each frame where tracking put it relative to its reference keyframe).
//!
//! Tracking placed a frame on map points that one or two keyframes' depths had just
//! made, and the set of those points changes from frame to frame, so the points' noise
//! shows as one-frame jitter (most where movers hide much of the image and fewer
//! points remain). After the loops and full BA the static points are fitted to every
//! keyframe that sees them. Each frame's pose is then optimised again, from its
//! corrected pose \(T_{cr} T_{rw}\), against the final positions of the static map points
//! it had as inliers, with the same robust pose optimisation as tracking:
//! \(\min_T \sum_i \rho\left(\lVert z_i - \pi(T X_i) \rVert^2_{\Sigma_i}\right)\).
//! Its pose relative to the reference keyframe is replaced, so the trajectory and the
//! dense pass take the refined pose. A frame keeps its pose when fewer than
//! [`MIN_POINTS`] of its points remain static, or when fewer than half of them are
//! inliers of the new pose.

use std::time::Instant;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::GlobalInputs;
use crate::eval::stats::MedianSample;
use crate::geometry::se3::Se3;
use crate::io::IoError;
use crate::map::record::{
    FrameObservation, FrameRecord, FrameRecords, ObservationReader, RECORD_CHUNK,
};
use crate::map::Map;
use crate::optim::pose_only::{optimise_pose_predicted, PoseObservation};

/// Fewest static points a frame needs to be estimated again.
pub const MIN_POINTS: usize = 30;

/// What the refinement did (in `report.json`, under `global`).
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct RefinementReport {
    /// Tracked frames that are not keyframes (keyframes have their BA poses).
    pub frames: usize,
    /// Frames given a new pose.
    pub refined: usize,
    /// Kept their poses: too few static points left, or too few inliers.
    pub kept: usize,
    /// How far the refined frames moved from their corrected poses, millimetres.
    pub median_shift_mm: f64,
    /// The largest shift, millimetres.
    pub max_shift_mm: f64,
    /// The refinement's time.
    pub milliseconds: f64,
}

/// Estimates every tracked frame of `records` again on `map` (see the module doc);
/// `Err` when their observations cannot be read.
pub fn refine_frames(
    map: &Map,
    inputs: &GlobalInputs,
    records: &mut FrameRecords,
) -> Result<RefinementReport, IoError> {
    let start = Instant::now();
    let (mut tried, mut refined, mut moved, mut max_shift_mm) =
        (0, 0, MedianSample::default(), 0.0f64);
    records.update(RECORD_CHUNK, |records, reader| {
        let mut frames: Vec<&mut FrameRecord> = records
            .iter_mut()
            .filter(|f| !f.is_keyframe() && f.reference.is_some() && f.observation_count() > 0)
            .collect();
        let shifts: Vec<Option<f64>> = frames
            .par_iter_mut()
            .map(|frame| refine(map, inputs, reader, frame))
            .collect::<Result<_, IoError>>()?;
        tried += frames.len();
        for shift_mm in shifts.iter().flatten().map(|s| s * 1e3) {
            refined += 1;
            max_shift_mm = max_shift_mm.max(shift_mm);
            moved.push(shift_mm);
        }
        Ok::<(), IoError>(())
    })?;
    Ok(RefinementReport {
        frames: tried,
        refined,
        kept: tried - refined,
        median_shift_mm: moved.median(),
        max_shift_mm,
        milliseconds: start.elapsed().as_secs_f64() * 1e3,
    })
}

/// One frame: its new pose relative to its reference keyframe, and how far it moved
/// (metres); `None` where it keeps its pose.
fn refine(
    map: &Map,
    inputs: &GlobalInputs,
    reader: ObservationReader,
    frame: &mut FrameRecord,
) -> Result<Option<f64>, IoError> {
    let Some((key, camera_from_reference)) = frame.reference else {
        return Ok(None);
    };
    let Some(reference_from_world) = map.keyframe_pose(key) else {
        return Ok(None);
    };
    let initial = camera_from_reference * reference_from_world;
    let observations = reader.observations(frame)?;
    let Some(pose) = refined_pose(map, inputs, &initial, &observations) else {
        return Ok(None);
    };
    frame.reference = Some((key, pose * reference_from_world.inverse()));
    frame.camera_from_world = Some(pose);
    let centre = |p: &Se3| p.inverse().translation.vector;
    Ok(Some((centre(&pose) - centre(&initial)).norm()))
}

/// `camera_from_world` optimised from `initial` against the static map points of
/// `observations`; `None` when too few remain or too few are inliers.
fn refined_pose(
    map: &Map,
    inputs: &GlobalInputs,
    initial: &Se3,
    observations: &[FrameObservation],
) -> Option<Se3> {
    let observations: Vec<PoseObservation> = observations
        .iter()
        .filter_map(|o| {
            let point = map.points().get(o.point)?;
            (point.moving <= inputs.removal_threshold).then(|| {
                PoseObservation::of_keypoint(
                    point.position,
                    (o.x, o.y, o.right_u),
                    inputs.pyramid.inverse_sigma2[o.level as usize],
                )
            })
        })
        .collect();
    if observations.len() < MIN_POINTS {
        return None;
    }
    let estimate = optimise_pose_predicted(
        inputs.camera,
        initial,
        &observations,
        inputs.prediction_gate_share,
    );
    (estimate.inlier_count() * 2 >= observations.len()).then_some(estimate.camera_from_world)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::ScalePyramid;
    use crate::geometry::camera::PinholeCamera;
    use crate::geometry::stereo_camera::StereoCamera;
    use crate::map::MapPoint;
    use crate::random::Rng;
    use nalgebra::{Rotation3, Translation3, Vector3};

    /// A map of 100 points 1.5-4 m ahead, the last 20 of them dynamic; a frame that
    /// saw every point from `truth`, pixel-exact; the same frame's observations.
    fn scene(truth: &Se3, camera: &StereoCamera) -> (Map, Vec<FrameObservation>) {
        let mut rng = Rng::new(7);
        let mut map = Map::default();
        let mut observations = Vec::new();
        for i in 0..100 {
            let z = 1.5 + 2.5 * rng.uniform();
            let (x, y) = ((rng.uniform() - 0.5) * z, (rng.uniform() - 0.5) * 0.75 * z);
            let world = truth.inverse() * nalgebra::Point3::new(x, y, z);
            let mut point = MapPoint::new(world.coords, [0; 4], Vector3::z(), (0.1, 10.0), 0);
            if i >= 80 {
                // A mover: where the map holds it is not where the frame saw it.
                point.moving = 0.9;
                point.position += Vector3::new(0.3, 0.0, 0.0);
            }
            let key = map.insert_point(point);
            let seen = camera.project(&Vector3::new(x, y, z));
            observations.push(FrameObservation {
                point: key,
                keypoint: i,
                x: seen.x as f32,
                y: seen.y as f32,
                right_u: seen.z as f32,
                level: 0,
            });
        }
        (map, observations)
    }

    #[test]
    fn a_frame_off_by_centimetres_returns_to_where_it_saw_the_static_points() {
        let camera = StereoCamera::new(&PinholeCamera::tum_fr3(), 40.0);
        let pyramid = ScalePyramid::new(8, 1.2);
        let inputs = GlobalInputs {
            camera: &camera,
            pyramid: &pyramid,
            stereo: false,
            size: (640.0, 480.0),
            removal_threshold: 0.6,
            prediction_gate_share: 0.7,
        };
        let truth = Se3::from_parts(
            Translation3::new(0.1, -0.05, 0.2),
            Rotation3::from_scaled_axis(Vector3::new(0.05, -0.1, 0.02)),
        );
        let (map, observations) = scene(&truth, &camera);
        let off = Se3::from_parts(
            Translation3::new(0.02, 0.01, -0.03),
            Rotation3::from_scaled_axis(Vector3::new(0.01, 0.0, -0.01)),
        ) * truth;
        let pose = refined_pose(&map, &inputs, &off, &observations).expect("refined");
        let error = pose * truth.inverse();
        assert!(error.translation.vector.norm() < 1e-6, "{error:?}");
        assert!(error.rotation.angle() < 1e-6);
        // Too few static points left: the frame keeps its pose.
        assert!(refined_pose(&map, &inputs, &off, &observations[60..]).is_none());
    }
}
