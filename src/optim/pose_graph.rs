//! Pose-graph optimisation on SE(3): the essential graph of the global pass and the
//! standard g2o benchmark graphs.
//!
//! Poses are \(T_i\) = `world_from_node`; an edge \((i, j)\) measures
//! \(Z_{ij} \approx T_i^{-1} T_j\) with information \(\Omega_{ij}\) in the tangent
//! order \((\rho, \phi)\) (translation, then rotation). The cost is
//! \(\chi^2 = \sum e_{ij}^\top \Omega_{ij} e_{ij}\) with
//! \(e_{ij} = \log(Z_{ij}^{-1} T_i^{-1} T_j)\). Updates are right perturbations
//! \(T_i \leftarrow T_i \exp(\delta_i)\), so
//! \(\partial e / \partial \delta_j = J_r^{-1}(e)\) and
//! \(\partial e / \partial \delta_i = -J_r^{-1}(e)\,\mathrm{Ad}(T_j^{-1} T_i)\), with
//! \(J_r^{-1}(e) \approx I + \tfrac12 \mathrm{ad}(e)\),
//! \(\mathrm{ad}(\rho, \phi) = \begin{pmatrix} \hat\phi & \hat\rho \\ 0 & \hat\phi \end{pmatrix}\).
//!
//! Levenberg-Marquardt on \((H + \lambda\,\mathrm{diag} H)\,\delta = -b\): the
//! block pattern of \(H\) is the graph's, so its ordering and symbolic Cholesky are
//! computed once ([`BlockPattern`]) and each iteration only refactorises numerically.

use nalgebra::{DVector, Matrix6, Vector6};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::block_sparse::BlockPattern;
use crate::geometry::se3::{self, Se3};
use crate::geometry::so3::hat;
use crate::io::g2o::{G2oEdge, G2oGraph};

/// One relative-pose constraint.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseEdge {
    /// Index of the first pose.
    pub from: usize,
    /// Index of the second pose.
    pub to: usize,
    /// \(Z = T_{from}^{-1} T_{to}\) as measured.
    pub measurement: Se3,
    /// Information in \((\rho, \phi)\) order.
    pub information: Matrix6<f64>,
}

/// A pose graph; `fixed` poses hold the gauge (the first pose when none is).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PoseGraph {
    /// \(T_{wc}\) or \(T_{cw}\) per node, as the edges measure them.
    pub poses: Vec<Se3>,
    /// Per pose: held fixed.
    pub fixed: Vec<bool>,
    /// The constraints.
    pub edges: Vec<PoseEdge>,
}

/// Stopping rules.
#[derive(Debug, Clone, Copy)]
pub struct GraphOptions {
    /// Gauss-Newton iterations at most.
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub relative_tolerance: f64,
}

impl Default for GraphOptions {
    fn default() -> Self {
        Self {
            max_iterations: 50,
            relative_tolerance: 1e-7,
        }
    }
}

/// What an optimisation did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct GraphReport {
    /// Iterations done.
    pub iterations: usize,
    /// \(\chi^2\) before and after (GTSAM's graph error is half of it).
    pub initial_cost: f64,
    /// \(\chi^2\) at the end.
    pub final_cost: f64,
    /// Whether the relative tolerance was reached.
    pub converged: bool,
}

impl PoseGraph {
    /// From a g2o file's graph (vertex ids become indices in file order). g2o's
    /// information is in (translation, rotation) order like ours; its rotation error
    /// is the quaternion's vector part, read here as the rotation vector, as GTSAM's
    /// `readG2o` does. Returns the graph and the ids of its poses.
    pub fn from_g2o(graph: &G2oGraph) -> (Self, Vec<u64>) {
        let index: std::collections::HashMap<u64, usize> = graph
            .vertices
            .iter()
            .enumerate()
            .map(|(i, (id, _))| (*id, i))
            .collect();
        let mut fixed = vec![false; graph.vertices.len()];
        for id in &graph.fixed {
            if let Some(&i) = index.get(id) {
                fixed[i] = true;
            }
        }
        let edges = graph
            .edges
            .iter()
            .map(|e| PoseEdge {
                from: index[&e.from],
                to: index[&e.to],
                measurement: e.measurement,
                information: e.information,
            })
            .collect();
        let ids = graph.vertices.iter().map(|(id, _)| *id).collect();
        (
            Self {
                poses: graph.vertices.iter().map(|(_, p)| *p).collect(),
                fixed,
                edges,
            },
            ids,
        )
    }

    /// The graph in g2o's terms, with the given vertex ids.
    pub fn to_g2o(&self, ids: &[u64]) -> G2oGraph {
        G2oGraph {
            vertices: ids
                .iter()
                .copied()
                .zip(self.poses.iter().copied())
                .collect(),
            edges: self
                .edges
                .iter()
                .map(|e| G2oEdge {
                    from: ids[e.from],
                    to: ids[e.to],
                    measurement: e.measurement,
                    information: e.information,
                })
                .collect(),
            fixed: self
                .fixed
                .iter()
                .zip(ids)
                .filter(|(f, _)| **f)
                .map(|(_, id)| *id)
                .collect(),
        }
    }

    /// \(e_{ij} = \log(Z_{ij}^{-1} T_i^{-1} T_j)\).
    pub fn residual(&self, edge: &PoseEdge) -> Vector6<f64> {
        se3::log(
            &(edge.measurement.inverse() * self.poses[edge.from].inverse() * self.poses[edge.to]),
        )
    }

    /// The residual and its Jacobians with respect to the `from` and `to` poses' right
    /// perturbations (first-order \(J_r^{-1}\), see the module's doc).
    pub fn linearised(&self, edge: &PoseEdge) -> (Vector6<f64>, Matrix6<f64>, Matrix6<f64>) {
        let r = self.residual(edge);
        let (phi_hat, rho_hat) = (
            hat(&r.fixed_rows::<3>(3).into_owned()),
            hat(&r.fixed_rows::<3>(0).into_owned()),
        );
        let mut ad = Matrix6::zeros();
        ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&phi_hat);
        ad.fixed_view_mut::<3, 3>(0, 3).copy_from(&rho_hat);
        ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&phi_hat);
        let jr_inv = Matrix6::identity() + 0.5 * ad;
        let j_from =
            -jr_inv * se3::adjoint(&(self.poses[edge.to].inverse() * self.poses[edge.from]));
        (r, j_from, jr_inv)
    }

    /// \(\chi^2 = \sum e^\top \Omega e\).
    pub fn cost(&self) -> f64 {
        // Terms in parallel, summed in edge order (a parallel sum's order would follow
        // the thread count).
        let terms: Vec<f64> = self
            .edges
            .par_iter()
            .map(|e| {
                let r = self.residual(e);
                (r.transpose() * e.information * r)[0]
            })
            .collect();
        terms.iter().sum()
    }

    /// Each pose's index among the free ones (`usize::MAX`: fixed), and how many are
    /// free. With none fixed, the first pose is.
    fn free_indices(&self) -> (Vec<usize>, usize) {
        let n = self.poses.len();
        let mut fixed = self.fixed.clone();
        fixed.resize(n, false);
        if n > 0 && !fixed.iter().any(|f| *f) {
            fixed[0] = true;
        }
        let mut free_index = vec![usize::MAX; n];
        let mut free = 0;
        for i in 0..n {
            if !fixed[i] {
                free_index[i] = free;
                free += 1;
            }
        }
        (free_index, free)
    }

    /// Moves each free pose by its part of `delta`: \(T \leftarrow T \exp(-\delta)\).
    fn step(&mut self, delta: &nalgebra::DVector<f64>, free_index: &[usize]) {
        for (i, pose) in self.poses.iter_mut().enumerate() {
            let c = free_index[i];
            if c != usize::MAX {
                let d: Vector6<f64> = -delta.fixed_rows::<6>(6 * c).into_owned();
                *pose = se3::normalised(&(*pose * se3::exp(&d)));
            }
        }
    }

    /// Optimises the free poses in place.
    pub fn optimise(&mut self, options: &GraphOptions) -> GraphReport {
        let (free_index, free) = self.free_indices();
        let initial_cost = self.cost();
        let mut report = GraphReport {
            initial_cost,
            final_cost: initial_cost,
            ..GraphReport::default()
        };
        if free == 0 || self.edges.is_empty() {
            report.converged = true;
            return report;
        }
        let pairs = self.edges.iter().filter_map(|e| {
            let (a, b) = (free_index[e.from], free_index[e.to]);
            (a != usize::MAX && b != usize::MAX).then_some((a, b))
        });
        let Some(pattern) = BlockPattern::new(free, 6, pairs) else {
            return report;
        };
        let mut current = initial_cost;
        let mut lambda = 1e-5;
        for _ in 0..options.max_iterations {
            report.iterations += 1;
            let (values, rhs) = self.normal_equations(&pattern, &free_index, free);
            let diagonal: Vec<(usize, f64)> = (0..6 * free)
                .map(|row| {
                    let at = pattern.diagonal_index(row);
                    (at, values[at])
                })
                .collect();
            let mut accepted = false;
            for _ in 0..10 {
                let mut damped = values.clone();
                for &(at, d) in &diagonal {
                    damped[at] += lambda * d.max(1e-9) + 1e-12;
                }
                let Some(delta) = pattern.solve(&damped, &rhs) else {
                    lambda *= 10.0;
                    continue;
                };
                let previous = self.poses.clone();
                self.step(&delta, &free_index);
                let candidate = self.cost();
                if candidate < current {
                    let gain = (current - candidate) / current.max(1e-300);
                    current = candidate;
                    lambda = (lambda / 3.0).max(1e-12);
                    accepted = true;
                    if gain < options.relative_tolerance {
                        report.converged = true;
                    }
                    break;
                }
                self.poses = previous;
                lambda *= 10.0;
            }
            if !accepted {
                // No step lowers the cost: a minimum to the solver's precision.
                report.converged = true;
            }
            if report.converged {
                break;
            }
        }
        report.final_cost = current;
        report
    }

    /// \(H\) (values in `pattern`'s layout) and \(b = \sum J^\top \Omega e\).
    fn normal_equations(
        &self,
        pattern: &BlockPattern,
        free_index: &[usize],
        free: usize,
    ) -> (Vec<f64>, DVector<f64>) {
        let blocks: Vec<_> = self
            .edges
            .par_iter()
            .map(|e| {
                let (r, j_from, j_to) = self.linearised(e);
                let omega = e.information;
                (
                    j_from.transpose() * omega * j_from,
                    j_from.transpose() * omega * j_to,
                    j_to.transpose() * omega * j_to,
                    j_from.transpose() * omega * r,
                    j_to.transpose() * omega * r,
                )
            })
            .collect();
        let mut values = pattern.zeros();
        let mut rhs = DVector::zeros(6 * free);
        for (e, (h_ff, h_ft, h_tt, b_f, b_t)) in self.edges.iter().zip(&blocks) {
            let (a, b) = (free_index[e.from], free_index[e.to]);
            if a != usize::MAX {
                pattern.add(&mut values, a, a, h_ff.as_slice());
                let mut rows = rhs.fixed_rows_mut::<6>(6 * a);
                rows += b_f;
            }
            if b != usize::MAX {
                pattern.add(&mut values, b, b, h_tt.as_slice());
                let mut rows = rhs.fixed_rows_mut::<6>(6 * b);
                rows += b_t;
            }
            if a != usize::MAX && b != usize::MAX && a != b {
                pattern.add(&mut values, a, b, h_ft.as_slice());
            }
        }
        (values, rhs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;

    /// A ring of `n` poses with odometry and a loop edge; noisy odometry chained as the
    /// initial guess (drift), exact edges: the optimum is the truth.
    fn ring(n: usize, seed: u64) -> (PoseGraph, Vec<Se3>) {
        let mut rng = Rng::new(seed);
        let truth: Vec<Se3> = (0..n)
            .map(|i| {
                let a = std::f64::consts::TAU * i as f64 / n as f64;
                se3::exp(&Vector6::new(
                    3.0 * a.cos(),
                    3.0 * a.sin(),
                    0.1 * (3.0 * a).sin(),
                    0.0,
                    0.0,
                    a,
                ))
            })
            .collect();
        let mut edges = Vec::new();
        for i in 0..n {
            for step in [1, 2] {
                let j = (i + step) % n;
                edges.push(PoseEdge {
                    from: i,
                    to: j,
                    measurement: truth[i].inverse() * truth[j],
                    information: Matrix6::identity() * 100.0,
                });
            }
        }
        let mut poses = vec![truth[0]];
        for i in 1..n {
            let z = truth[i - 1].inverse() * truth[i] * se3::gaussian(&mut rng, 0.05, 0.03);
            poses.push(poses[i - 1] * z);
        }
        (
            PoseGraph {
                poses,
                fixed: (0..n).map(|i| i == 0).collect(),
                edges,
            },
            truth,
        )
    }

    #[test]
    fn a_drifted_ring_converges_to_the_truth() {
        for seed in [1, 2, 3] {
            let (mut graph, truth) = ring(60, seed);
            let before = graph.cost();
            let report = graph.optimise(&GraphOptions::default());
            assert!(
                report.converged && report.final_cost < 1e-8 * before.max(1.0),
                "{report:?}"
            );
            let worst = graph
                .poses
                .iter()
                .zip(&truth)
                .map(|(a, b)| se3::log(&(a.inverse() * b)).norm())
                .fold(0.0, f64::max);
            assert!(worst < 1e-5, "seed {seed}: {worst}");
        }
    }

    #[test]
    fn jacobians_equal_finite_differences() {
        let (graph, _) = ring(5, 4);
        let e = &graph.edges[3];
        let i = e.from;
        let (r, j_from, _) = graph.linearised(e);
        for k in 0..6 {
            let mut d = Vector6::zeros();
            d[k] = 1e-6;
            let mut plus = graph.clone();
            plus.poses[i] = graph.poses[i] * se3::exp(&d);
            let mut minus = graph.clone();
            minus.poses[i] = graph.poses[i] * se3::exp(&-d);
            let numeric = (plus.residual(e) - minus.residual(e)) / 2e-6;
            // First-order J_r^{-1}: exact up to O(|e|^2).
            assert!(
                (numeric - j_from.column(k)).norm() < 5e-2 * (1.0 + r.norm()),
                "{k}"
            );
        }
    }

    #[test]
    fn g2o_round_trip_keeps_the_graph() {
        let (graph, _) = ring(8, 5);
        let ids: Vec<u64> = (0..8).map(|i| 100 + i).collect();
        let (back, back_ids) = PoseGraph::from_g2o(&graph.to_g2o(&ids));
        assert_eq!(back_ids, ids);
        assert_eq!(back, graph);
    }
}
