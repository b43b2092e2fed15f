//! Pose-only optimisation (ORB-SLAM2's motion-only bundle adjustment, §III-C): the
//! camera pose \(T_{cw}\) minimising
//! \(\sum_i \rho\big(e_i^\top \Omega_i e_i\big)\), \(e_i = z_i - \pi(T_{cw} X_i)\), with map
//! points \(X_i\) fixed, \(\Omega_i = \sigma_{l_i}^{-2} I\) from the keypoint's pyramid
//! level, \(\rho\) Huber. Four rounds of Levenberg-Marquardt; after each, observations
//! with \(e^\top \Omega e\) above the \(\chi^2_{0.95}\) gate (2 or 3 degrees of freedom)
//! are outliers for the next round (and may come back); the last two rounds drop the
//! robust kernel.
//!
//! With a *prediction gate* (tracking with the DOP model), the rounds start from the
//! observations that the predicted pose \(\hat T_{cw}\) (the motion model's, or the
//! previous search's pose) already explains within a tighter gate,
//! \(e^\top \Omega e \le f \chi^2_{0.95}\) with \(f\) = [`PREDICTION_GATE_FACTOR`],
//! when those are at least a share \(s\) of all. The others take no part in any round
//! and are classified only against the final pose. A mover that starts to move in
//! front of a scene that hardly constrains one direction of the camera's motion (a
//! box carried before a flat wall: a sideways step and a turn look alike there) pulls
//! the pose along that direction by its own motion, and in ORB-SLAM2's rounds its
//! points come back once the pose has followed them a little; here they cannot. When
//! the camera itself moved unlike the prediction, fewer than \(s\) agree and the rounds
//! start from all observations, as ORB-SLAM2's do.

use nalgebra::{Matrix6, Vector3, Vector6};

use super::robust::{huber_weight, CHI2_MONO, CHI2_STEREO};
use super::stereo_projection::point_jacobian_wrt_pose;
use crate::geometry::se3::{self, Se3};
use crate::geometry::stereo_camera::StereoCamera;

/// One map point seen in the frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseObservation {
    /// The point's world position.
    pub point_world: Vector3<f64>,
    /// \((u, v, u_R)\); `u_R` is ignored when `stereo` is false.
    pub measurement: Vector3<f64>,
    /// Whether `measurement` holds a right coordinate.
    pub stereo: bool,
    /// \(\sigma^{-2}\) of the keypoint's level.
    pub information: f64,
}

impl PoseObservation {
    /// A keypoint at level-0 pixel `(u, v)` with virtual right coordinate `u_R`
    /// (negative without depth, then monocular) seeing `point_world`, weighted by its
    /// level's \(\sigma^{-2}\).
    pub fn of_keypoint(
        point_world: Vector3<f64>,
        (u, v, u_r): (f32, f32, f32),
        information: f64,
    ) -> Self {
        Self {
            point_world,
            measurement: Vector3::new(u as f64, v as f64, u_r as f64),
            stereo: u_r > 0.0,
            information,
        }
    }
}

/// The optimised pose and which observations are inliers.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseEstimate {
    /// \(T_{cw}\).
    pub camera_from_world: Se3,
    /// Per observation: inside the \(\chi^2\) gate at the end.
    pub inliers: Vec<bool>,
}

impl PoseEstimate {
    /// The number of inliers.
    pub fn inlier_count(&self) -> usize {
        self.inliers.iter().filter(|&&i| i).count()
    }
}

const ROUNDS: usize = 4;
const ITERATIONS: usize = 10;

/// The prediction gate's share of the \(\chi^2_{0.95}\) gate (see the module's notes).
/// Measured on `unknown_movers_close` (`--deterministic`, seeds 1 and 2): the full gate
/// let the box's slowest points in (ATE 12.1 and 14.6 mm), a half kept them out (2.0
/// and 1.7 mm), a quarter was worse again (11.6 and 8.3 mm).
pub const PREDICTION_GATE_FACTOR: f64 = 0.5;
/// Fewest observations the prediction gate starts from.
const PREDICTION_GATE_MIN: usize = 10;

/// The whitened squared error and, when asked, its Jacobian rows.
fn error(
    camera: &StereoCamera,
    pose: &Se3,
    observation: &PoseObservation,
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let p = pose * nalgebra::Point3::from(observation.point_world);
    if p.z <= 1e-6 {
        return None;
    }
    Some((
        observation.measurement - camera.project(&p.coords),
        p.coords,
    ))
}

fn squared(e: &Vector3<f64>, stereo: bool, information: f64) -> f64 {
    let s = e.x * e.x + e.y * e.y + if stereo { e.z * e.z } else { 0.0 };
    s * information
}

/// Whether `observation` reprojects within the \(\chi^2_{0.95}\) gate from `pose`
/// (the test that makes an inlier).
pub fn within_gate(camera: &StereoCamera, pose: &Se3, observation: &PoseObservation) -> bool {
    within_share_of_gate(camera, pose, observation, 1.0)
}

/// Whether `observation` reprojects within `share` of its gate from `pose`.
fn within_share_of_gate(
    camera: &StereoCamera,
    pose: &Se3,
    observation: &PoseObservation,
    share: f64,
) -> bool {
    error_within(gated_error(camera, pose, observation), share)
}

/// Whether a [`gated_error`] lies within `share` of its gate (behind the camera: no).
pub fn error_within(error: Option<(f64, f64)>, share: f64) -> bool {
    error.is_some_and(|(e, g)| e <= share * g)
}

/// The error \(e^\top \Omega e\) of `observation` from `pose` and its gate
/// \(\chi^2_{0.95}\), so that one projection answers several shares of the gate;
/// `None` where the point is behind the camera.
pub fn gated_error(
    camera: &StereoCamera,
    pose: &Se3,
    observation: &PoseObservation,
) -> Option<(f64, f64)> {
    error(camera, pose, observation).map(|(e, _)| {
        (
            squared(&e, observation.stereo, observation.information),
            gate(observation),
        )
    })
}

/// Optimises `initial` (`camera_from_world`) against the observations.
pub fn optimise_pose(
    camera: &StereoCamera,
    initial: &Se3,
    observations: &[PoseObservation],
) -> PoseEstimate {
    optimise_pose_predicted(camera, initial, observations, 0.0)
}

/// [`optimise_pose`] from the predicted pose `predicted` with the prediction gate: when
/// at least `share` of the observations lie within [`PREDICTION_GATE_FACTOR`] of the
/// gate there, only those take part in the rounds; all are classified against the
/// final pose. `share` 0 is [`optimise_pose`].
pub fn optimise_pose_predicted(
    camera: &StereoCamera,
    predicted: &Se3,
    observations: &[PoseObservation],
    share: f64,
) -> PoseEstimate {
    let mut pose = se3::normalised(predicted);
    let taking_part = prediction_gate(camera, &pose, observations, share);
    let mut inliers = taking_part.clone();
    for round in 0..ROUNDS {
        let robust = round < 2;
        pose = levenberg_marquardt(camera, pose, observations, &inliers, robust);
        // Classify every observation that takes part (outliers may come back).
        for ((o, inlier), &part) in observations
            .iter()
            .zip(inliers.iter_mut())
            .zip(&taking_part)
        {
            *inlier = part && within_gate(camera, &pose, o);
        }
        if inliers.iter().filter(|&&i| i).count() < 10 {
            break;
        }
    }
    let pose = se3::normalised(&pose);
    // Those left out by the prediction gate are judged by the final pose alone.
    for ((o, inlier), &part) in observations
        .iter()
        .zip(inliers.iter_mut())
        .zip(&taking_part)
    {
        if !part {
            *inlier = within_gate(camera, &pose, o);
        }
    }
    PoseEstimate {
        camera_from_world: pose,
        inliers,
    }
}

/// One round's Levenberg-Marquardt iterations from `pose` over the `inliers` (Huber
/// weights when `robust`): with \(H = J^\top W J\), the damped normal equations
/// \((H + \lambda\,(\mathrm{diag}\,H + \epsilon))\,\delta = J^\top W e\), a step
/// \(T \leftarrow \exp(\delta)\,T\) kept when it lowers the cost. Returns the last
/// pose kept.
fn levenberg_marquardt(
    camera: &StereoCamera,
    mut pose: Se3,
    observations: &[PoseObservation],
    inliers: &[bool],
    robust: bool,
) -> Se3 {
    let mut lambda = 1e-5;
    let mut current = cost(camera, &pose, observations, inliers, robust);
    for _ in 0..ITERATIONS {
        let mut h = Matrix6::<f64>::zeros();
        let mut b = Vector6::<f64>::zeros();
        for (o, _) in observations.iter().zip(inliers).filter(|(_, &i)| i) {
            let Some((e, p)) = error(camera, &pose, o) else {
                continue;
            };
            let s = squared(&e, o.stereo, o.information);
            let w = o.information
                * if robust {
                    huber_weight(s, gate(o).sqrt())
                } else {
                    1.0
                };
            // e = z - π(p(δ)): ∂e/∂δ = -J_π J_p.
            let j = camera.jacobian(&p) * point_jacobian_wrt_pose(&p);
            let rows = if o.stereo { 3 } else { 2 };
            for r in 0..rows {
                let row = j.row(r);
                h += w * row.transpose() * row;
                b += w * row.transpose() * e[r];
            }
        }
        // Normal equations with ∂e/∂δ = -J: (JᵀWJ) δ = JᵀWe.
        let mut accepted = false;
        for _ in 0..6 {
            let mut damped = h;
            for k in 0..6 {
                damped[(k, k)] += lambda * (h[(k, k)] + 1e-9);
            }
            let Some(delta) = damped.cholesky().map(|c| c.solve(&b)) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = se3::exp(&delta) * pose;
            let candidate_cost = cost(camera, &candidate, observations, inliers, robust);
            if candidate_cost <= current {
                pose = candidate;
                let improvement = current - candidate_cost;
                current = candidate_cost;
                lambda = (lambda * 0.3).max(1e-9);
                accepted = delta.norm() > 1e-10 && improvement > 1e-12 * current.max(1.0);
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            break;
        }
    }
    pose
}

/// The cost of `pose` over the `inliers`: the squared errors, Huber-robustified with
/// each observation's gate as the threshold when `robust`; \(10^6\) for a point
/// behind the camera.
fn cost(
    camera: &StereoCamera,
    pose: &Se3,
    observations: &[PoseObservation],
    inliers: &[bool],
    robust: bool,
) -> f64 {
    observations
        .iter()
        .zip(inliers)
        .filter(|(_, &inlier)| inlier)
        .map(|(o, _)| match error(camera, pose, o) {
            Some((e, _)) => {
                let s = squared(&e, o.stereo, o.information);
                if robust {
                    let delta = gate(o).sqrt();
                    let r = s.sqrt();
                    if r <= delta {
                        s
                    } else {
                        2.0 * delta * r - delta * delta
                    }
                } else {
                    s
                }
            }
            None => 1e6,
        })
        .sum()
}

/// Which observations take part in the rounds: those within [`PREDICTION_GATE_FACTOR`]
/// of the gate at `predicted` when they are at least `share` of all (and at least
/// [`PREDICTION_GATE_MIN`]), else all.
fn prediction_gate(
    camera: &StereoCamera,
    predicted: &Se3,
    observations: &[PoseObservation],
    share: f64,
) -> Vec<bool> {
    let all = vec![true; observations.len()];
    if share <= 0.0 {
        return all;
    }
    let agree: Vec<bool> = observations
        .iter()
        .map(|o| within_share_of_gate(camera, predicted, o, PREDICTION_GATE_FACTOR))
        .collect();
    let n = agree.iter().filter(|&&a| a).count();
    if n >= PREDICTION_GATE_MIN && n as f64 >= share * observations.len() as f64 {
        agree
    } else {
        all
    }
}

/// The \(\chi^2_{0.95}\) gate of an observation (2 or 3 degrees of freedom).
fn gate(observation: &PoseObservation) -> f64 {
    if observation.stereo {
        CHI2_STEREO
    } else {
        CHI2_MONO
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3::tests::tangent;
    use crate::random::Rng;
    use proptest::prelude::*;

    /// TUM fr3 intrinsics with ORB-SLAM2's virtual RGB-D baseline.
    fn camera() -> StereoCamera {
        StereoCamera::new(&crate::geometry::camera::PinholeCamera::tum_fr3(), 40.0)
    }

    /// Points in front of a camera at `truth`, observed with 0.5 px noise; a fraction are
    /// gross outliers (random pixels).
    fn problem(truth: &Se3, n: usize, outliers: f64, seed: u64) -> Vec<PoseObservation> {
        let mut rng = Rng::new(seed);
        let world_from_camera = truth.inverse();
        (0..n)
            .map(|i| {
                let p_camera = Vector3::new(
                    rng.range(-1.5, 1.5),
                    rng.range(-1.0, 1.0),
                    rng.range(0.8, 4.0),
                );
                let point_world = (world_from_camera * nalgebra::Point3::from(p_camera)).coords;
                let mut measurement = camera().project(&p_camera)
                    + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.5;
                if (i as f64) < outliers * n as f64 {
                    measurement = Vector3::new(rng.range(0.0, 640.0), rng.range(0.0, 480.0), 0.0);
                    measurement.z = measurement.x - rng.range(5.0, 50.0);
                }
                PoseObservation {
                    point_world,
                    measurement,
                    stereo: i % 3 != 0,
                    information: 1.0,
                }
            })
            .collect()
    }

    /// A flat wall 3.4-3.8 m away and a box 1.3 m away that moved `box_shift` metres
    /// sideways since the map saw it (its points: the first `movers`), observed from
    /// `truth` with 0.5 px noise: the near-degenerate view of `unknown_movers_close`,
    /// where a sideways step and a turn look alike.
    fn wall_and_box(truth: &Se3, movers: usize, box_shift: f64, seed: u64) -> Vec<PoseObservation> {
        let mut rng = Rng::new(seed);
        let world_from_camera = truth.inverse();
        (0..400)
            .map(|i| {
                let on_box = i < movers;
                let p_camera = if on_box {
                    Vector3::new(
                        rng.range(0.2, 0.9),
                        rng.range(-0.2, 0.5),
                        rng.range(1.25, 1.35),
                    )
                } else {
                    Vector3::new(
                        rng.range(-1.8, 1.8),
                        rng.range(-1.3, 1.3),
                        rng.range(3.4, 3.8),
                    )
                };
                let mut point_world = (world_from_camera * nalgebra::Point3::from(p_camera)).coords;
                if on_box {
                    // The map saw the box before it moved.
                    point_world.x -= box_shift;
                }
                let noise = Vector3::new(rng.normal(), rng.normal(), 0.0) * 0.5;
                let mut measurement = camera().project(&p_camera) + noise;
                measurement.z += noise.x;
                PoseObservation {
                    point_world,
                    measurement,
                    stereo: true,
                    information: 1.0,
                }
            })
            .collect()
    }

    #[test]
    fn the_prediction_gate_keeps_a_moving_box_from_dragging_the_pose() {
        let truth = se3::exp(&Vector6::new(0.05, -0.02, 0.1, 0.01, -0.02, 0.005));
        // The motion model predicted within a millimetre and a few hundredths of a degree.
        let predicted =
            se3::exp(&Vector6::new(0.001, -0.0005, 0.0005, 0.0003, -0.0002, 0.0)) * truth;
        let observations = wall_and_box(&truth, 40, 0.012, 7);
        let apart = |a: &Se3, b: &Se3| se3::log(&(a * b.inverse())).fixed_rows::<3>(0).norm();
        let free = optimise_pose(&camera(), &predicted, &observations);
        let gated = optimise_pose_predicted(&camera(), &predicted, &observations, 0.7);
        // The best the wall alone can do (its noise leaves millimetres along the
        // sideways-step-and-turn direction).
        let wall = optimise_pose(&camera(), &predicted, &observations[40..]).camera_from_world;
        let dragged = apart(&free.camera_from_world, &wall);
        assert!(
            dragged > 0.01,
            "without the gate the box drags the pose {dragged} m"
        );
        let off = apart(&gated.camera_from_world, &wall);
        assert!(
            off < 0.001,
            "with the gate the pose is {off} m from the wall's own"
        );
        let box_inliers = gated.inliers[..40].iter().filter(|&&i| i).count();
        assert!(
            box_inliers <= 8,
            "{box_inliers} of the box's 40 points are inliers"
        );
        assert!(gated.inliers[40..].iter().filter(|&&i| i).count() >= 340);
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(32))]
        #[test]
        fn recovers_a_perturbed_pose_despite_outliers(
            truth in tangent(1.0, 1.0),
            perturbation in tangent(0.08, 0.08),
            seed in 0u64..1000,
        ) {
            let truth = se3::exp(&truth);
            let observations = problem(&truth, 300, 0.3, seed);
            let start = se3::exp(&perturbation) * truth;
            let estimate = optimise_pose(&camera(), &start, &observations);
            let error = se3::log(&(estimate.camera_from_world * truth.inverse()));
            prop_assert!(error.fixed_rows::<3>(0).norm() < 0.01, "translation {}", error);
            prop_assert!(error.fixed_rows::<3>(3).norm() < 0.002, "rotation {}", error);
            // The gross outliers (the first 30 %) are found; nearly all good ones kept.
            let flagged = estimate.inliers[..90].iter().filter(|&&i| !i).count();
            let kept = estimate.inliers[90..].iter().filter(|&&i| i).count();
            prop_assert!(flagged >= 85, "{flagged} of 90 outliers flagged");
            prop_assert!(kept >= 190, "{kept} of 210 inliers kept");
        }

        /// When the camera moved unlike the prediction, too few observations agree
        /// with it and the gate starts from all of them, as without it.
        #[test]
        fn a_wrong_prediction_falls_back_to_every_observation(
            truth in tangent(1.0, 1.0),
            perturbation in tangent(0.05, 0.05),
            seed in 0u64..1000,
        ) {
            // A turn of more than a degree moves nearly every point out of the gate.
            prop_assume!(perturbation.fixed_rows::<3>(3).norm() > 0.02);
            let truth = se3::exp(&truth);
            let observations = problem(&truth, 300, 0.1, seed);
            let start = se3::exp(&perturbation) * truth;
            let gated = optimise_pose_predicted(&camera(), &start, &observations, 0.7);
            let free = optimise_pose(&camera(), &start, &observations);
            prop_assert_eq!(gated, free);
        }
    }
}
