//! Bundle adjustment over a window of keyframes and the points they see (ORB-SLAM2's
//! local BA, §III-D): minimise \(\sum \rho(e^\top \Omega e)\),
//! \(e_{ij} = z_{ij} - \pi(T_i X_j)\), over the free poses \(T_i\) (camera-from-world,
//! left perturbations) and all points \(X_j\), with fixed poses holding the gauge.
//!
//! Levenberg-Marquardt on the normal equations with the points eliminated by the Schur
//! complement: with \(U\) the pose blocks, \(V\) the (block-diagonal) point blocks and
//! \(W\) the coupling, \((U - W V^{-1} W^\top)\,\delta_T = b_T - W V^{-1} b_X\), then
//! \(\delta_X = V^{-1}(b_X - W^\top \delta_T)\). The reduced camera system of a local
//! window is block-sparse (poses couple only through shared points) and is solved by
//! `faer`'s sparse Cholesky on a pattern fixed once per solve ([`BlockPattern`]: ordering and
//! symbolic factorisation once, numeric factorisation per step); the Schur complement is
//! accumulated over points in parallel. The full BA of the global pass is the same solver. As in ORB-SLAM2, a first pass
//! with the Huber kernel is followed by a second without it after removing the
//! observations above the chi-square gate.

use nalgebra::{DVector, Matrix3, Matrix3x6, Matrix6, Matrix6x3, Vector3, Vector6};
use rayon::prelude::*;

use super::block_sparse::{BlockPattern, Slot};
use super::robust::{huber_weight, CHI2_MONO, CHI2_STEREO};
use super::stereo_projection::point_jacobian_wrt_pose;
use crate::geometry::se3::{self, Se3};
use crate::geometry::stereo_camera::StereoCamera;

/// One observation of point `point` by camera `camera`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaObservation {
    /// Index into `poses`.
    pub camera: usize,
    /// Index into `points`.
    pub point: usize,
    /// \((u, v, u_R)\); `u_R` unused when not `stereo`.
    pub measurement: Vector3<f64>,
    /// Whether `measurement` holds a right coordinate.
    pub stereo: bool,
    /// \(\sigma^{-2}\) of the keypoint's level.
    pub information: f64,
}

/// A bundle adjustment problem; `poses` are `camera_from_world`.
#[derive(Debug, Clone, PartialEq)]
pub struct BaProblem {
    /// \(T_{cw}\) per camera.
    pub poses: Vec<Se3>,
    /// Per camera: held fixed (the gauge and the outer keyframes).
    pub fixed: Vec<bool>,
    /// World positions.
    pub points: Vec<Vector3<f64>>,
    /// Every observation.
    pub observations: Vec<BaObservation>,
}

/// What a run did.
#[derive(Debug, Clone, PartialEq)]
pub struct BaReport {
    /// Per observation: inside the chi-square gate at the end.
    pub inliers: Vec<bool>,
    /// \(\chi^2\) over the inliers before the first iteration.
    pub initial_cost: f64,
    /// \(\chi^2\) over the inliers at the end.
    pub final_cost: f64,
}

fn gate(stereo: bool) -> f64 {
    if stereo {
        CHI2_STEREO
    } else {
        CHI2_MONO
    }
}

/// Chunks of points whose Schur complements are summed separately: a fixed count, not
/// one per thread (see the reduced camera system). Each chunk holds a copy of the whole
/// reduced system (14 MB for 225 keyframes), so more chunks cost more than they give:
/// 8 took the 225-keyframe full BA from 1.7 s to 2.9 s on 2 cores.
const SCHUR_CHUNKS: usize = 2;

/// The residual and the camera-frame point, or `None` behind the camera.
fn residual(
    camera: &StereoCamera,
    pose: &Se3,
    point: &Vector3<f64>,
    o: &BaObservation,
) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let p = pose * nalgebra::Point3::from(*point);
    (p.z > 1e-6).then(|| (o.measurement - camera.project(&p.coords), p.coords))
}

fn whitened(e: &Vector3<f64>, o: &BaObservation) -> f64 {
    (e.x * e.x + e.y * e.y + if o.stereo { e.z * e.z } else { 0.0 }) * o.information
}

/// Observations per chunk of the cost: chunks of a fixed size are summed in parallel,
/// then in order, so the cost does not depend on the thread count.
const COST_CHUNK: usize = 8192;

/// Chunks of points of the linearisation: a fixed count (see [`COST_CHUNK`]), as each
/// holds its own copy of the pose blocks (1592 keyframes: 0.5 MB a chunk).
const LINEARISE_CHUNKS: usize = 16;

fn cost(problem: &BaProblem, camera: &StereoCamera, active: &[bool], robust: bool) -> f64 {
    let partial: Vec<f64> = problem
        .observations
        .par_chunks(COST_CHUNK)
        .zip(active.par_chunks(COST_CHUNK))
        .map(|(observations, active)| {
            observation_cost(problem, camera, observations, active, robust)
        })
        .collect();
    partial.iter().sum()
}

fn observation_cost(
    problem: &BaProblem,
    camera: &StereoCamera,
    observations: &[BaObservation],
    active: &[bool],
    robust: bool,
) -> f64 {
    observations
        .iter()
        .zip(active)
        .filter(|(_, &a)| a)
        .map(|(o, _)| {
            match residual(
                camera,
                &problem.poses[o.camera],
                &problem.points[o.point],
                o,
            ) {
                Some((e, _)) => {
                    let s = whitened(&e, o);
                    let delta = gate(o.stereo).sqrt();
                    if robust && s.sqrt() > delta {
                        2.0 * delta * s.sqrt() - delta * delta
                    } else {
                        s
                    }
                }
                None => 1e6,
            }
        })
        .sum()
}

/// The blocks of the normal equations (see the module notes).
struct NormalBlocks {
    u: Vec<Matrix6<f64>>,
    b_pose: Vec<Vector6<f64>>,
    v: Vec<Matrix3<f64>>,
    b_point: Vec<Vector3<f64>>,
    /// Per point: (free pose index, \(W\) block), one per observation of a free pose.
    coupling: Vec<Vec<(usize, Matrix6x3<f64>)>>,
}

/// One point's \(V\), \(b_X\) and coupling blocks (free pose index, \(W\)).
type PointBlocks = (Matrix3<f64>, Vector3<f64>, Vec<(usize, Matrix6x3<f64>)>);

/// The normal equations' blocks, from the active observations (the layout's
/// `observations_of`, per point): per free pose \(U\) and \(b_T\), per point \(V\) and \(b_X\), and per
/// point its coupling blocks \(W\) with the free poses (index in the reduced system).
/// Points are linearised in parallel in a fixed number of chunks; the pose blocks are
/// summed over the chunks in order, so the result does not depend on the thread count.
fn linearise(
    problem: &BaProblem,
    camera: &StereoCamera,
    layout: &SchurLayout,
    robust: bool,
) -> NormalBlocks {
    let (observations_of, free_index, free) =
        (&layout.observations_of, &layout.free_index, layout.free);
    type ChunkBlocks = (Vec<Matrix6<f64>>, Vec<Vector6<f64>>, Vec<PointBlocks>);
    let chunks: Vec<ChunkBlocks> = observations_of
        .par_chunks(observations_of.len().div_ceil(LINEARISE_CHUNKS).max(1))
        .map(|points| {
            let mut u = vec![Matrix6::<f64>::zeros(); free];
            let mut b_pose = vec![Vector6::<f64>::zeros(); free];
            let blocks = points
                .iter()
                .map(|indices| {
                    let pose_blocks = PoseBlocks {
                        u: &mut u,
                        b_pose: &mut b_pose,
                    };
                    point_blocks(problem, camera, free_index, robust, indices, pose_blocks)
                })
                .collect();
            (u, b_pose, blocks)
        })
        .collect();
    let mut u = vec![Matrix6::<f64>::zeros(); free];
    let mut b_pose = vec![Vector6::<f64>::zeros(); free];
    let n_points = observations_of.len();
    let (mut v, mut b_point, mut coupling) = (
        Vec::with_capacity(n_points),
        Vec::with_capacity(n_points),
        Vec::with_capacity(n_points),
    );
    for (chunk_u, chunk_b, blocks) in chunks {
        for c in 0..free {
            u[c] += chunk_u[c];
            b_pose[c] += chunk_b[c];
        }
        for (vj, bj, wj) in blocks {
            v.push(vj);
            b_point.push(bj);
            coupling.push(wj);
        }
    }
    NormalBlocks {
        u,
        b_pose,
        v,
        b_point,
        coupling,
    }
}

/// The free poses' blocks one point's observations add to: \(U\) and \(b_T\).
struct PoseBlocks<'a> {
    u: &'a mut [Matrix6<f64>],
    b_pose: &'a mut [Vector6<f64>],
}

/// One point's blocks from its active observations (`indices`): \(V\), \(b_X\) and its
/// coupling blocks \(W\) with the free poses; each observation of a free pose adds to
/// that pose's \(U\) and \(b_T\) in `poses`.
fn point_blocks(
    problem: &BaProblem,
    camera: &StereoCamera,
    free_index: &[usize],
    robust: bool,
    indices: &[usize],
    poses: PoseBlocks,
) -> PointBlocks {
    let PoseBlocks { u, b_pose } = poses;
    let mut v = Matrix3::<f64>::zeros();
    let mut b_point = Vector3::<f64>::zeros();
    let mut coupling = Vec::with_capacity(indices.len());
    for &i in indices {
        let o = &problem.observations[i];
        let pose = &problem.poses[o.camera];
        let c = free_index[o.camera];
        let Some((e, p)) = residual(camera, pose, &problem.points[o.point], o) else {
            // Behind the camera: no terms, but the block keeps its place.
            if c != usize::MAX {
                coupling.push((c, Matrix6x3::zeros()));
            }
            continue;
        };
        let s = whitened(&e, o);
        let w = o.information
            * if robust {
                huber_weight(s, gate(o.stereo).sqrt())
            } else {
                1.0
            };
        let projection = camera.jacobian(&p);
        let a_pose: Matrix3x6<f64> = projection * point_jacobian_wrt_pose(&p);
        let a_point: Matrix3<f64> = projection * pose.rotation.matrix();
        let rows = if o.stereo { 3 } else { 2 };
        let (mut upose, mut bp, mut wcp) = (
            Matrix6::<f64>::zeros(),
            Vector6::<f64>::zeros(),
            Matrix6x3::<f64>::zeros(),
        );
        for r in 0..rows {
            let jp = a_pose.row(r).transpose();
            let jx = a_point.row(r).transpose();
            v += w * jx * jx.transpose();
            b_point += w * jx * e[r];
            if c != usize::MAX {
                upose += w * jp * jp.transpose();
                bp += w * jp * e[r];
                wcp += w * jp * jx.transpose();
            }
        }
        if c != usize::MAX {
            u[c] += upose;
            b_pose[c] += bp;
            coupling.push((c, wcp));
        }
    }
    (v, b_point, coupling)
}

/// Runs LM iterations with the given active observations; returns the final cost.
fn levenberg_marquardt(
    problem: &mut BaProblem,
    camera: &StereoCamera,
    active: &[bool],
    robust: bool,
    iterations: usize,
) -> f64 {
    let Some(layout) = SchurLayout::new(problem, active) else {
        return cost(problem, camera, active, robust);
    };
    let mut current = cost(problem, camera, active, robust);
    let mut lambda = 1e-4;
    for _ in 0..iterations {
        let blocks = linearise(problem, camera, &layout, robust);
        let mut accepted = false;
        for _ in 0..8 {
            let damped_v = damped_point_inverses(&blocks.v, lambda);
            let Some(delta_pose) = solve_poses(&layout, &blocks, &damped_v, lambda) else {
                lambda *= 10.0;
                continue;
            };
            // Only poses and points change: the observations stay where they are.
            let mut candidate = BaProblem {
                poses: problem.poses.clone(),
                fixed: Vec::new(),
                points: problem.points.clone(),
                observations: std::mem::take(&mut problem.observations),
            };
            apply_step(&mut candidate, &layout, &blocks, &damped_v, &delta_pose);
            let candidate_cost = cost(&candidate, camera, active, robust);
            problem.observations = std::mem::take(&mut candidate.observations);
            if candidate_cost < current {
                let improvement = current - candidate_cost;
                problem.poses = candidate.poses;
                problem.points = candidate.points;
                current = candidate_cost;
                lambda = (lambda * 0.3).max(1e-9);
                accepted = improvement > 1e-9 * current.max(1e-9);
                break;
            }
            lambda *= 10.0;
        }
        if !accepted {
            break;
        }
    }
    current
}

/// What stays fixed over one solve: the free poses' indices in the reduced system
/// (`usize::MAX` for a fixed pose), the reduced camera system's block pattern (free
/// poses that share an active point), each point's active observations in observation
/// order, and each point's pair slots in the order the Schur loop visits them (all
/// points' in one array, packed: a whole map's full BA has 2-3 pairs an observation).
struct SchurLayout {
    free_index: Vec<usize>,
    free: usize,
    pattern: BlockPattern,
    observations_of: Vec<Vec<usize>>,
    /// Per point, where its pairs begin in `slots` (one entry more than points).
    slot_start: Vec<usize>,
    /// Every point's pair slots, [`pack`]ed.
    slots: Vec<u32>,
}

/// Points a chunk when the pair slots are found in parallel.
const SLOT_CHUNK: usize = 4096;

/// A slot in 4 bytes: its index (below \(2^{31}\): the pattern numbers its values in
/// `u32`, 36 to a block) and whether it goes transposed.
fn pack(slot: Slot) -> u32 {
    ((slot.index as u32) << 1) | slot.transposed as u32
}

/// [`pack`] undone.
fn unpack(packed: u32) -> Slot {
    Slot {
        index: (packed >> 1) as usize,
        transposed: packed & 1 == 1,
    }
}

impl SchurLayout {
    /// `None` when no free pose shares a point (nothing to solve).
    fn new(problem: &BaProblem, active: &[bool]) -> Option<SchurLayout> {
        let mut free_index = vec![usize::MAX; problem.poses.len()];
        let mut free = 0;
        for (i, fixed) in problem.fixed.iter().enumerate() {
            if !fixed {
                free_index[i] = free;
                free += 1;
            }
        }
        let n_points = problem.points.len();
        let mut cameras_of: Vec<Vec<usize>> = vec![Vec::new(); n_points];
        for (o, _) in problem.observations.iter().zip(active).filter(|(_, &a)| a) {
            let c = free_index[o.camera];
            if c != usize::MAX {
                cameras_of[o.point].push(c);
            }
        }
        let pairs = cameras_of.iter().flat_map(|cams| {
            cams.iter()
                .enumerate()
                .flat_map(move |(a, &c1)| cams[..a].iter().map(move |&c2| (c1, c2)))
        });
        let pattern = BlockPattern::new(free, 6, pairs)?;
        let mut slot_start = Vec::with_capacity(n_points + 1);
        slot_start.push(0);
        for cams in &cameras_of {
            let k = cams.len();
            slot_start.push(slot_start[slot_start.len() - 1] + k * (k + 1) / 2);
        }
        drop(cameras_of);
        let mut observations_of: Vec<Vec<usize>> = vec![Vec::new(); n_points];
        for (i, _) in active.iter().enumerate().filter(|(_, &a)| a) {
            observations_of[problem.observations[i].point].push(i);
        }
        // The coupling blocks of a point follow its observations of free poses, one each.
        let chunks: Vec<Vec<u32>> = observations_of
            .par_chunks(SLOT_CHUNK)
            .map(|points| {
                let mut s = Vec::new();
                for indices in points {
                    let cameras: Vec<usize> = indices
                        .iter()
                        .map(|&i| free_index[problem.observations[i].camera])
                        .filter(|&c| c != usize::MAX)
                        .collect();
                    for (a, &c1) in cameras.iter().enumerate() {
                        for &c2 in &cameras[..=a] {
                            s.push(pack(pattern.slot(c1, c2).expect("pair in the pattern")));
                        }
                    }
                }
                s
            })
            .collect();
        let mut slots = Vec::with_capacity(slot_start[n_points]);
        for chunk in chunks {
            slots.extend_from_slice(&chunk);
        }
        Some(SchurLayout {
            free_index,
            free,
            pattern,
            observations_of,
            slot_start,
            slots,
        })
    }
}

/// \((V_j + \lambda\,\mathrm{diag}(V_j))^{-1}\) per point (`None` where singular).
fn damped_point_inverses(v: &[Matrix3<f64>], lambda: f64) -> Vec<Option<Matrix3<f64>>> {
    v.iter()
        .map(|m| {
            let mut d = *m;
            for k in 0..3 {
                d[(k, k)] += lambda * m[(k, k)] + 1e-12;
            }
            d.try_inverse()
        })
        .collect()
}

/// The pose step \(\delta_T\) of the damped reduced camera system
/// \((U + \lambda\,\mathrm{diag}(U) - W V_\lambda^{-1} W^\top)\,\delta_T = b_T - W V_\lambda^{-1} b_X\);
/// `None` when the factorisation fails.
fn solve_poses(
    layout: &SchurLayout,
    blocks: &NormalBlocks,
    damped_v: &[Option<Matrix3<f64>>],
    lambda: f64,
) -> Option<DVector<f64>> {
    let (mut values, schur_rhs) = schur_complement(layout, blocks, damped_v);
    let mut rhs = DVector::<f64>::zeros(6 * layout.free);
    for c in 0..layout.free {
        let mut rows = rhs.fixed_rows_mut::<6>(6 * c);
        rows += blocks.b_pose[c];
        // Damp the pose diagonal with the undamped U only.
        let mut d = blocks.u[c];
        for k in 0..6 {
            d[(k, k)] += lambda * blocks.u[c][(k, k)] + 1e-12;
        }
        layout.pattern.add(&mut values, c, c, d.as_slice());
    }
    rhs -= schur_rhs;
    layout.pattern.solve(&values, &rhs)
}

/// \(-W V_\lambda^{-1} W^\top\) in the pattern's values and \(W V_\lambda^{-1} b_X\),
/// accumulated per point over a fixed number of chunks in parallel (each its own copy
/// of the values), then summed in chunk order: the sum does not depend on the thread
/// count, so deterministic runs repeat exactly on any machine.
fn schur_complement(
    layout: &SchurLayout,
    blocks: &NormalBlocks,
    damped_v: &[Option<Matrix3<f64>>],
) -> (Vec<f64>, DVector<f64>) {
    let n_points = damped_v.len();
    let pattern = &layout.pattern;
    let chunk = n_points.div_ceil(SCHUR_CHUNKS).max(1);
    let partials: Vec<(Vec<f64>, DVector<f64>)> = (0..n_points.div_ceil(chunk))
        .into_par_iter()
        .map(|c| {
            let mut values = pattern.zeros();
            let mut rhs = DVector::<f64>::zeros(6 * layout.free);
            let end = ((c + 1) * chunk).min(n_points);
            for (j, v_inv) in damped_v.iter().enumerate().take(end).skip(c * chunk) {
                let Some(v_inv) = *v_inv else {
                    continue;
                };
                let coupling = &blocks.coupling[j];
                let mut pair = layout.slots[layout.slot_start[j]..layout.slot_start[j + 1]]
                    .iter()
                    .map(|&p| unpack(p));
                for (a, &(c1, w1)) in coupling.iter().enumerate() {
                    let w1_vinv = w1 * v_inv;
                    let mut rows = rhs.fixed_rows_mut::<6>(6 * c1);
                    rows += w1_vinv * blocks.b_point[j];
                    for &(_, w2) in &coupling[..=a] {
                        let slot = pair.next().expect("one slot per pair");
                        let m: Matrix6<f64> = -(w1_vinv * w2.transpose());
                        pattern.add_at(&mut values, slot, m.as_slice());
                    }
                }
            }
            (values, rhs)
        })
        .collect();
    let mut reduced = (pattern.zeros(), DVector::<f64>::zeros(6 * layout.free));
    for (values, rhs) in partials {
        for (x, y) in reduced.0.iter_mut().zip(&values) {
            *x += y;
        }
        reduced.1 += rhs;
    }
    reduced
}

/// Applies \(\delta_T\) to the free poses (left perturbation) and the back-substituted
/// \(\delta_X = V_\lambda^{-1}(b_X - W^\top \delta_T)\) to the points of `candidate`.
fn apply_step(
    candidate: &mut BaProblem,
    layout: &SchurLayout,
    blocks: &NormalBlocks,
    damped_v: &[Option<Matrix3<f64>>],
    delta_pose: &DVector<f64>,
) {
    for (i, pose) in candidate.poses.iter_mut().enumerate() {
        let c = layout.free_index[i];
        if c != usize::MAX {
            let d: Vector6<f64> = delta_pose.fixed_rows::<6>(6 * c).into_owned();
            *pose = se3::normalised(&(se3::exp(&d) * *pose));
        }
    }
    for (j, v_inv) in damped_v.iter().enumerate() {
        let Some(v_inv) = v_inv else { continue };
        let mut r = blocks.b_point[j];
        for &(c, w) in &blocks.coupling[j] {
            let d: Vector6<f64> = delta_pose.fixed_rows::<6>(6 * c).into_owned();
            r -= w.transpose() * d;
        }
        candidate.points[j] += v_inv * r;
    }
}

/// Runs ORB-SLAM2's two passes: `first` iterations with the Huber kernel, then, without
/// the observations above the gate, `second` iterations without it.
pub fn bundle_adjust(
    problem: &mut BaProblem,
    camera: &StereoCamera,
    first: usize,
    second: usize,
) -> BaReport {
    let all = vec![true; problem.observations.len()];
    let initial_cost = cost(problem, camera, &all, false);
    levenberg_marquardt(problem, camera, &all, true, first);
    let classify = |problem: &BaProblem| -> Vec<bool> {
        problem
            .observations
            .iter()
            .map(|o| {
                residual(
                    camera,
                    &problem.poses[o.camera],
                    &problem.points[o.point],
                    o,
                )
                .is_some_and(|(e, _)| whitened(&e, o) <= gate(o.stereo))
            })
            .collect()
    };
    let active = classify(problem);
    levenberg_marquardt(problem, camera, &active, false, second);
    let inliers = classify(problem);
    let final_cost = cost(problem, camera, &inliers, false);
    BaReport {
        inliers,
        initial_cost,
        final_cost,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    /// TUM fr3 intrinsics with ORB-SLAM2's virtual RGB-D baseline.
    fn camera() -> StereoCamera {
        StereoCamera::new(&crate::geometry::camera::PinholeCamera::tum_fr3(), 40.0)
    }

    /// Six cameras along a line looking at 300 points 2-4 m away; observations with
    /// 0.5 px noise and 5 % gross outliers; the first two poses fixed.
    fn problem(seed: u64) -> (BaProblem, Vec<Se3>, Vec<Vector3<f64>>) {
        let mut rng = Rng::new(seed);
        let truth_poses: Vec<Se3> = (0..6)
            .map(|i| {
                let world_from_camera = se3::exp(&Vector6::new(
                    0.1 * i as f64,
                    0.02 * rng.normal(),
                    0.05 * i as f64,
                    0.02 * rng.normal(),
                    0.03 * rng.normal(),
                    0.01 * rng.normal(),
                ));
                world_from_camera.inverse()
            })
            .collect();
        let truth_points: Vec<Vector3<f64>> = (0..300)
            .map(|_| {
                Vector3::new(
                    rng.range(-1.5, 2.0),
                    rng.range(-1.0, 1.0),
                    rng.range(2.0, 4.0),
                )
            })
            .collect();
        let mut observations = Vec::new();
        for (c, pose) in truth_poses.iter().enumerate() {
            for (j, x) in truth_points.iter().enumerate() {
                let p = pose * nalgebra::Point3::from(*x);
                let mut z = camera().project(&p.coords)
                    + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.5;
                if rng.uniform() < 0.05 {
                    z += Vector3::new(rng.range(20.0, 60.0), rng.range(-60.0, 60.0), 0.0);
                }
                observations.push(BaObservation {
                    camera: c,
                    point: j,
                    measurement: z,
                    stereo: j % 2 == 0,
                    information: 1.0,
                });
            }
        }
        let poses = truth_poses
            .iter()
            .enumerate()
            .map(|(i, t)| {
                if i < 2 {
                    *t
                } else {
                    se3::exp(&Vector6::new(
                        0.02 * rng.normal(),
                        0.02 * rng.normal(),
                        0.02 * rng.normal(),
                        0.01 * rng.normal(),
                        0.01 * rng.normal(),
                        0.01 * rng.normal(),
                    )) * t
                }
            })
            .collect();
        let points = truth_points
            .iter()
            .map(|x| x + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.03)
            .collect();
        let problem = BaProblem {
            poses,
            fixed: (0..6).map(|i| i < 2).collect(),
            points,
            observations,
        };
        (problem, truth_poses, truth_points)
    }

    fn errors(problem: &BaProblem, poses: &[Se3], points: &[Vector3<f64>]) -> (f64, f64) {
        let pose_error = problem
            .poses
            .iter()
            .zip(poses)
            .map(|(a, b)| (a.inverse().translation.vector - b.inverse().translation.vector).norm())
            .fold(0.0, f64::max);
        let point_rms = (problem
            .points
            .iter()
            .zip(points)
            .map(|(a, b)| (a - b).norm_squared())
            .sum::<f64>()
            / points.len() as f64)
            .sqrt();
        (pose_error, point_rms)
    }

    #[test]
    fn recovers_poses_and_points_despite_outliers() {
        for seed in [1, 2, 3] {
            let (mut problem, poses, points) = problem(seed);
            let (pose_before, point_before) = errors(&problem, &poses, &points);
            let report = bundle_adjust(&mut problem, &camera(), 5, 10);
            let (pose_after, _) = errors(&problem, &poses, &points);
            let mut point_errors: Vec<f64> = problem
                .points
                .iter()
                .zip(&points)
                .map(|(a, b)| (a - b).norm())
                .collect();
            point_errors.sort_by(f64::total_cmp);
            assert!(report.final_cost < report.initial_cost);
            assert!(pose_before > 0.01 && point_before > 0.03);
            assert!(pose_after < 0.003, "seed {seed}: pose error {pose_after} m");
            // The noise limits depth to about 1-2 cm at 3 m (half a pixel over a 0.5 m
            // baseline): the median point lands there, from 5 cm before.
            let median = point_errors[point_errors.len() / 2];
            assert!(median < 0.02, "seed {seed}: median point error {median} m");
            let flagged = report.inliers.iter().filter(|&&i| !i).count();
            let total = report.inliers.len();
            assert!(
                flagged * 100 > total * 4 && flagged * 100 < total * 7,
                "{flagged} / {total}"
            );
        }
    }

    #[test]
    fn point_jacobian_equals_finite_differences() {
        let pose = se3::exp(&Vector6::new(0.1, -0.2, 0.3, 0.1, 0.2, -0.1));
        let x = Vector3::new(0.3, -0.2, 2.5);
        let p = (pose * nalgebra::Point3::from(x)).coords;
        let analytic = camera().jacobian(&p) * pose.rotation.matrix();
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = 1e-6;
            let plus = camera().project(&(pose * nalgebra::Point3::from(x + d)).coords);
            let minus = camera().project(&(pose * nalgebra::Point3::from(x - d)).coords);
            let numeric = (plus - minus) / 2e-6;
            assert!((numeric - analytic.column(k)).norm() < 1e-4);
        }
    }
}
