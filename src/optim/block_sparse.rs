//! A symmetric positive-definite system \(A x = b\) assembled from dense square blocks
//! (one block row per pose) and solved by `faer`'s sparse Cholesky
//! \(A = L L^\top\). Bundle adjustment's reduced camera system and the pose graph of
//! the global pass both have this shape: a block \((i, j)\) exists only where poses
//! \(i\) and \(j\) share points (or an edge), so a long window stays sparse.

use std::collections::BTreeMap;

use faer::linalg::solvers::Solve;
use faer::sparse::{SparseColMat, Triplet};
use faer::Side;
use nalgebra::{DMatrix, DVector};

/// Blocks of size `block` of a symmetric matrix with `n` block rows; only the lower
/// triangle (`row >= col`) is stored.
#[derive(Debug, Clone)]
pub struct BlockSystem {
    block: usize,
    n: usize,
    blocks: BTreeMap<(usize, usize), DMatrix<f64>>,
    pub rhs: DVector<f64>,
}

impl BlockSystem {
    pub fn new(n: usize, block: usize) -> Self {
        Self {
            block,
            n,
            blocks: BTreeMap::new(),
            rhs: DVector::zeros(n * block),
        }
    }

    /// Adds `m` to block \((i, j)\) (and, implicitly, its transpose to \((j, i)\)).
    pub fn add(&mut self, i: usize, j: usize, m: &DMatrix<f64>) {
        let (key, value) = if i >= j {
            ((i, j), m.clone())
        } else {
            ((j, i), m.transpose())
        };
        let entry = self
            .blocks
            .entry(key)
            .or_insert_with(|| DMatrix::zeros(self.block, self.block));
        *entry += value;
    }

    /// Solves the system; `None` when the matrix is not positive definite.
    pub fn solve(&self) -> Option<DVector<f64>> {
        let size = self.n * self.block;
        if size == 0 {
            return Some(DVector::zeros(0));
        }
        let mut triplets = Vec::new();
        for (&(bi, bj), m) in &self.blocks {
            for r in 0..self.block {
                for c in 0..self.block {
                    let (row, col) = (bi * self.block + r, bj * self.block + c);
                    if row >= col && m[(r, c)] != 0.0 {
                        triplets.push(Triplet::new(row, col, m[(r, c)]));
                    }
                }
            }
        }
        let matrix =
            SparseColMat::<usize, f64>::try_new_from_triplets(size, size, &triplets).ok()?;
        let llt = matrix.sp_cholesky(Side::Lower).ok()?;
        let mut x = faer::Mat::<f64>::from_fn(size, 1, |i, _| self.rhs[i]);
        llt.solve_in_place(x.as_mut());
        let solution = DVector::from_fn(size, |i, _| x[(i, 0)]);
        solution.iter().all(|v| v.is_finite()).then_some(solution)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn solves_a_block_tridiagonal_system_like_a_dense_solver() {
        let (n, b) = (5, 3);
        let mut system = BlockSystem::new(n, b);
        let mut dense = DMatrix::<f64>::zeros(n * b, n * b);
        for i in 0..n {
            let d = DMatrix::from_fn(b, b, |r, c| if r == c { 4.0 + i as f64 } else { 0.5 });
            system.add(i, i, &d);
            dense.view_mut((i * b, i * b), (b, b)).copy_from(&d);
            if i + 1 < n {
                let o = DMatrix::from_fn(b, b, |r, c| 0.1 * (r + 2 * c) as f64 - 0.3);
                system.add(i, i + 1, &o);
                dense.view_mut((i * b, (i + 1) * b), (b, b)).copy_from(&o);
                dense
                    .view_mut(((i + 1) * b, i * b), (b, b))
                    .copy_from(&o.transpose());
            }
        }
        system.rhs = DVector::from_fn(n * b, |i, _| (i as f64).sin());
        let sparse = system.solve().expect("positive definite");
        let reference = dense.cholesky().unwrap().solve(&system.rhs);
        assert!((sparse - reference).norm() < 1e-10);
    }

    #[test]
    fn refuses_an_indefinite_matrix() {
        let mut system = BlockSystem::new(1, 2);
        system.add(0, 0, &DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]));
        system.rhs = DVector::from_vec(vec![1.0, 1.0]);
        assert!(system.solve().is_none());
    }
}
