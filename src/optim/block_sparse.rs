//! A symmetric positive-definite system \(A x = b\) assembled from dense square blocks
//! (one block row per pose) and solved by `faer`'s sparse Cholesky
//! \(A = L L^\top\). Bundle adjustment's reduced camera system and the pose graph of
//! the global pass both have this shape: a block \((i, j)\) exists only where poses
//! \(i\) and \(j\) share points (or an edge), so a long window stays sparse.

use faer::linalg::solvers::Solve;
use faer::Side;
use nalgebra::DVector;
/// Where a block goes in the values ([`BlockPattern::slot`]): its slot, and whether
/// it goes there transposed (a block below the diagonal stored above it).
#[derive(Debug, Clone, Copy)]
pub struct Slot {
    /// The slot's index.
    pub index: usize,
    /// Whether the block is stored transposed.
    pub transposed: bool,
}

/// A block sparsity pattern fixed once (the edges of a pose graph, the covisibility of
/// a bundle adjustment), with its compressed-column layout and its symbolic Cholesky
/// (fill-reducing ordering and elimination tree) computed once: each solve then fills
/// the values in place and runs only the numeric factorisation
/// \(A = L L^\top\) and two triangular solves.
#[derive(Debug, Clone)]
pub struct BlockPattern {
    block: usize,
    n: usize,
    /// Lower blocks \((i, j)\), \(i \ge j\), to their slot.
    slots: std::collections::HashMap<(usize, usize), usize>,
    /// Per slot and block column \(c\), the value index of its first stored entry: row
    /// 0 of an off-diagonal block, row \(c\) of a diagonal one (only its lower half is
    /// stored); the column's stored rows follow contiguously.
    entries: Vec<u32>,
    /// Per slot: a diagonal block.
    diagonal: Vec<bool>,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    symbolic: faer::sparse::linalg::solvers::SymbolicLlt<usize>,
}

impl BlockPattern {
    /// The pattern of an `n`-block-row matrix with blocks of size `block` at the
    /// diagonal and at each pair of `off_diagonal` (either order; repeats allowed).
    pub fn new(
        n: usize,
        block: usize,
        off_diagonal: impl IntoIterator<Item = (usize, usize)>,
    ) -> Option<Self> {
        let mut columns: Vec<Vec<usize>> = (0..n).map(|j| vec![j]).collect();
        for (a, b) in off_diagonal {
            let (i, j) = if a >= b { (a, b) } else { (b, a) };
            if i != j && i < n {
                columns[j].push(i);
            }
        }
        let mut slots = std::collections::HashMap::new();
        let mut col_ptr = vec![0usize];
        let mut row_idx = Vec::new();
        // Value index of the first entry of block row `i` in scalar column `j*block+c`.
        let mut starts: Vec<(usize, usize, usize, usize)> = Vec::new();
        for (j, rows) in columns.iter_mut().enumerate() {
            rows.sort_unstable();
            rows.dedup();
            for c in 0..block {
                for &i in rows.iter() {
                    let first_row = if i == j { c } else { 0 };
                    starts.push((i, j, c, row_idx.len()));
                    for r in first_row..block {
                        row_idx.push(i * block + r);
                    }
                }
                col_ptr.push(row_idx.len());
            }
        }
        let mut entries = Vec::new();
        let mut diagonal = Vec::new();
        for (i, j, c, start) in starts {
            let slot = *slots.entry((i, j)).or_insert_with(|| {
                entries.extend(std::iter::repeat_n(0u32, block));
                diagonal.push(i == j);
                diagonal.len() - 1
            });
            entries[slot * block + c] = start as u32;
        }
        let size = n * block;
        let structure = faer::sparse::SymbolicSparseColMatRef::new_checked(
            size, size, &col_ptr, None, &row_idx,
        );
        let symbolic =
            faer::sparse::linalg::solvers::SymbolicLlt::try_new(structure, Side::Lower).ok()?;
        Some(Self {
            block,
            n,
            slots,
            entries,
            diagonal,
            col_ptr,
            row_idx,
            symbolic,
        })
    }

    /// Zeroed values for [`BlockPattern::add`].
    pub fn zeros(&self) -> Vec<f64> {
        vec![0.0; self.row_idx.len()]
    }

    /// Adds the column-major `block`x`block` matrix `m` to block \((i, j)\) (and its
    /// transpose to \((j, i)\)); `false` when the block is not in the pattern.
    pub fn add(&self, values: &mut [f64], i: usize, j: usize, m: &[f64]) -> bool {
        match self.slot(i, j) {
            Some(slot) => {
                self.add_at(values, slot, m);
                true
            }
            None => false,
        }
    }

    /// The slot of block \((i, j)\) and whether `m` must be transposed to go there.
    pub fn slot(&self, i: usize, j: usize) -> Option<Slot> {
        let (key, transposed) = if i >= j {
            ((i, j), false)
        } else {
            ((j, i), true)
        };
        self.slots
            .get(&key)
            .map(|&index| Slot { index, transposed })
    }

    /// [`BlockPattern::add`] at a slot found once by [`BlockPattern::slot`].
    pub fn add_at(&self, values: &mut [f64], slot: Slot, m: &[f64]) {
        let Slot {
            index: slot,
            transposed,
        } = slot;
        let b = self.block;
        let diagonal = self.diagonal[slot];
        for (c, &start) in self.entries[slot * b..(slot + 1) * b].iter().enumerate() {
            let first = if diagonal { c } else { 0 };
            let column = &mut values[start as usize..start as usize + b - first];
            if transposed {
                for (k, v) in column.iter_mut().enumerate() {
                    *v += m[(first + k) * b + c];
                }
            } else {
                for (v, x) in column.iter_mut().zip(&m[c * b + first..(c + 1) * b]) {
                    *v += x;
                }
            }
        }
    }

    /// The value index of the diagonal entry of scalar row `row` (for damping).
    pub fn diagonal_index(&self, row: usize) -> usize {
        let (i, r) = (row / self.block, row % self.block);
        let slot = self.slots[&(i, i)];
        self.entries[slot * self.block + r] as usize
    }

    /// Solves \(A x = b\) for the values filled in; `None` when \(A\) is not
    /// positive definite.
    pub fn solve(&self, values: &[f64], rhs: &DVector<f64>) -> Option<DVector<f64>> {
        let size = self.n * self.block;
        if size == 0 {
            return Some(DVector::zeros(0));
        }
        let matrix = faer::sparse::SparseColMatRef::new(
            faer::sparse::SymbolicSparseColMatRef::new_checked(
                size,
                size,
                &self.col_ptr,
                None,
                &self.row_idx,
            ),
            values,
        );
        let llt = faer::sparse::linalg::solvers::Llt::try_new_with_symbolic(
            self.symbolic.clone(),
            matrix,
            Side::Lower,
        )
        .ok()?;
        let mut x = faer::Mat::<f64>::from_fn(size, 1, |i, _| rhs[i]);
        llt.solve_in_place(x.as_mut());
        let solution = DVector::from_fn(size, |i, _| x[(i, 0)]);
        solution.iter().all(|v| v.is_finite()).then_some(solution)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::DMatrix;

    /// Adds block `m` at \((i, j)\) (and its transpose at \((j, i)\)) to both the
    /// pattern's values and a dense matrix.
    fn add_both(
        pattern: &BlockPattern,
        values: &mut [f64],
        dense: &mut DMatrix<f64>,
        (i, j): (usize, usize),
        m: &DMatrix<f64>,
    ) -> bool {
        let b = m.nrows();
        if i == j {
            let mut view = dense.view_mut((i * b, i * b), (b, b));
            view += m;
        } else {
            let mut view = dense.view_mut((i * b, j * b), (b, b));
            view += m;
            let mut view = dense.view_mut((j * b, i * b), (b, b));
            view += m.transpose();
        }
        pattern.add(values, i, j, m.as_slice())
    }

    #[test]
    fn solves_a_block_tridiagonal_system_like_a_dense_solver() {
        let (n, b) = (5, 3);
        let pattern = BlockPattern::new(n, b, (0..n - 1).map(|i| (i, i + 1))).expect("pattern");
        let mut values = pattern.zeros();
        let mut dense = DMatrix::<f64>::zeros(n * b, n * b);
        for i in 0..n {
            let d = DMatrix::from_fn(b, b, |r, c| if r == c { 4.0 + i as f64 } else { 0.5 });
            add_both(&pattern, &mut values, &mut dense, (i, i), &d);
            if i + 1 < n {
                let o = DMatrix::from_fn(b, b, |r, c| 0.1 * (r + 2 * c) as f64 - 0.3);
                add_both(&pattern, &mut values, &mut dense, (i, i + 1), &o);
            }
        }
        let rhs = DVector::from_fn(n * b, |i, _| (i as f64).sin());
        let sparse = pattern.solve(&values, &rhs).expect("positive definite");
        let reference = dense.cholesky().unwrap().solve(&rhs);
        assert!((sparse - reference).norm() < 1e-10);
    }

    #[test]
    fn refuses_an_indefinite_matrix() {
        let pattern = BlockPattern::new(1, 2, std::iter::empty()).expect("pattern");
        let mut values = pattern.zeros();
        pattern.add(&mut values, 0, 0, &[1.0, 2.0, 2.0, 1.0]);
        assert!(pattern
            .solve(&values, &DVector::from_vec(vec![1.0, 1.0]))
            .is_none());
    }

    #[test]
    fn a_fixed_pattern_solves_like_the_assembled_system() {
        let (n, b) = (6, 3);
        let pairs = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0), (2, 0)];
        let pattern = BlockPattern::new(n, b, pairs).expect("pattern");
        let mut values = pattern.zeros();
        let mut dense = DMatrix::<f64>::zeros(n * b, n * b);
        for i in 0..n {
            let d = DMatrix::from_fn(b, b, |r, c| if r == c { 6.0 + i as f64 } else { 0.3 });
            assert!(add_both(&pattern, &mut values, &mut dense, (i, i), &d));
        }
        for (k, &(i, j)) in pairs.iter().enumerate() {
            let o = DMatrix::from_fn(b, b, |r, c| 0.1 * (r + 2 * c + k) as f64 - 0.4);
            assert!(add_both(&pattern, &mut values, &mut dense, (i, j), &o));
        }
        assert!(!pattern.add(&mut values, 1, 4, DMatrix::<f64>::zeros(b, b).as_slice()));
        let rhs = DVector::from_fn(n * b, |i, _| (i as f64).cos());
        let expected = dense.cholesky().expect("positive definite").solve(&rhs);
        let got = pattern.solve(&values, &rhs).expect("positive definite");
        assert!((expected - got).norm() < 1e-10);
    }
}
