//! One RANSAC loop for every robust fit of the system (EPnP in relocalisation, Horn's
//! closed form in loop closing), split as kornia-3d's `ransac` is: an [`Estimator`]
//! (the minimal fit and its consensus), a [`Sampler`] (which correspondences a
//! hypothesis is fitted to) and [`ransac`], the loop with its refits.
//!
//! For `iterations` rounds, a minimal sample \(S\) of the \(n\) correspondences gives
//! a model \(M_S\) and its consensus set \(C(M_S) = \{i : e_i(M_S) < \tau_i\}\); the model
//! with the largest consensus (the first one on a tie) wins. Then, `refits` times at
//! most, the model is fitted again to its whole consensus set, kept while its new
//! consensus is no smaller.

use crate::random::Rng;

/// A model that RANSAC fits to samples of `n` correspondences.
pub trait Estimator {
    /// The fitted model (a pose).
    type Model;
    /// The correspondences' count.
    fn count(&self) -> usize;
    /// The size of a minimal sample.
    fn sample_size(&self) -> usize;
    /// The model fitted to the correspondences `indices` (a minimal sample or a
    /// consensus set), or `None` when they are degenerate.
    fn fit(&self, indices: &[usize]) -> Option<Self::Model>;
    /// The consensus set of `model`: the indices of the correspondences it explains,
    /// ascending.
    fn inliers(&self, model: &Self::Model) -> Vec<usize>;
}

/// Draws the minimal samples.
pub trait Sampler {
    /// Fills `sample` with `size` indices below `n`; `false` when this round has no
    /// sample (it is skipped).
    fn draw(&mut self, n: usize, size: usize, sample: &mut Vec<usize>) -> bool;
}

/// Draws `size` distinct indices, drawing again on a repeat (\(\lfloor u n \rfloor\)
/// for a uniform \(u \in [0, 1)\)).
pub struct Redraw<'a>(pub &'a mut Rng);

impl Sampler for Redraw<'_> {
    fn draw(&mut self, n: usize, size: usize, sample: &mut Vec<usize>) -> bool {
        sample.clear();
        while sample.len() < size {
            let i = (self.0.uniform() * n as f64) as usize % n;
            if !sample.contains(&i) {
                sample.push(i);
            }
        }
        true
    }
}

/// Draws `size` indices (a 64-bit draw modulo \(n\)) and skips the round when two are
/// the same.
pub struct SkipRepeats<'a>(pub &'a mut Rng);

impl Sampler for SkipRepeats<'_> {
    fn draw(&mut self, n: usize, size: usize, sample: &mut Vec<usize>) -> bool {
        sample.clear();
        sample.extend((0..size).map(|_| (self.0.next_u64() % n as u64) as usize));
        (1..size).all(|i| !sample[..i].contains(&sample[i]))
    }
}

/// How long [`ransac`] runs.
#[derive(Debug, Clone, Copy)]
pub struct Rounds {
    /// Hypotheses drawn.
    pub iterations: usize,
    /// The fewest inliers the best hypothesis needs (checked before the refits).
    pub min_inliers: usize,
    /// Refits on the consensus set at most.
    pub refits: usize,
}

/// The best model and its consensus set (see the module doc); `None` without a model
/// or with fewer than `rounds.min_inliers` inliers.
pub fn ransac<E: Estimator>(
    estimator: &E,
    sampler: &mut impl Sampler,
    rounds: Rounds,
) -> Option<(E::Model, Vec<usize>)> {
    let (n, size) = (estimator.count(), estimator.sample_size());
    if n < size.max(1) {
        return None;
    }
    let mut best: Option<(E::Model, Vec<usize>)> = None;
    let mut sample = Vec::with_capacity(size);
    for _ in 0..rounds.iterations {
        if !sampler.draw(n, size, &mut sample) {
            continue;
        }
        let Some(model) = estimator.fit(&sample) else {
            continue;
        };
        let inliers = estimator.inliers(&model);
        if best.as_ref().is_none_or(|(_, b)| inliers.len() > b.len()) {
            best = Some((model, inliers));
        }
    }
    let (mut model, mut inliers) = best?;
    if inliers.len() < rounds.min_inliers {
        return None;
    }
    for _ in 0..rounds.refits {
        if inliers.len() < size {
            break;
        }
        let Some(refit) = estimator.fit(&inliers) else {
            break;
        };
        let again = estimator.inliers(&refit);
        if again.len() < inliers.len() {
            break;
        }
        (model, inliers) = (refit, again);
    }
    Some((model, inliers))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::{any, prop_assert, prop_assert_eq, proptest};

    /// A line \(y = a x + b\) through points, 1e-9 the inlier gate.
    struct Line<'a>(&'a [(f64, f64)]);

    impl Estimator for Line<'_> {
        type Model = (f64, f64);
        fn count(&self) -> usize {
            self.0.len()
        }
        fn sample_size(&self) -> usize {
            2
        }
        fn fit(&self, indices: &[usize]) -> Option<(f64, f64)> {
            // Least squares over the indices.
            let m = indices.len() as f64;
            let (sx, sy) = indices
                .iter()
                .fold((0.0, 0.0), |(x, y), &i| (x + self.0[i].0, y + self.0[i].1));
            let (mx, my) = (sx / m, sy / m);
            let sxx: f64 = indices.iter().map(|&i| (self.0[i].0 - mx).powi(2)).sum();
            let sxy: f64 = indices
                .iter()
                .map(|&i| (self.0[i].0 - mx) * (self.0[i].1 - my))
                .sum();
            (sxx > 1e-12).then(|| (sxy / sxx, my - sxy / sxx * mx))
        }
        fn inliers(&self, (a, b): &(f64, f64)) -> Vec<usize> {
            (0..self.0.len())
                .filter(|&i| (a * self.0[i].0 + b - self.0[i].1).abs() < 1e-9)
                .collect()
        }
    }

    fn points(seed: u64, outliers: usize) -> Vec<(f64, f64)> {
        let mut rng = Rng::new(seed);
        (0..20)
            .map(|i| {
                let x = i as f64;
                if i < outliers {
                    (x, rng.range(-50.0, 50.0))
                } else {
                    (x, 0.5 * x - 2.0)
                }
            })
            .collect()
    }

    proptest! {
        #[test]
        fn both_samplers_find_the_line_among_forty_percent_outliers(seed in 0u64..500) {
            let points = points(seed, 8);
            let rounds = Rounds { iterations: 60, min_inliers: 10, refits: 2 };
            for skip in [false, true] {
                let mut rng = Rng::new(seed);
                let found = if skip {
                    ransac(&Line(&points), &mut SkipRepeats(&mut rng), rounds)
                } else {
                    ransac(&Line(&points), &mut Redraw(&mut rng), rounds)
                };
                let ((a, b), inliers) = found.expect("a line");
                prop_assert!((a - 0.5).abs() < 1e-9 && (b + 2.0).abs() < 1e-9);
                prop_assert_eq!(inliers, (8..20).collect::<Vec<_>>());
            }
        }

        #[test]
        fn a_redrawn_sample_has_distinct_indices_and_a_skipped_one_has_a_repeat(seed in any::<u64>()) {
            let mut rng = Rng::new(seed);
            let mut sample = Vec::new();
            Redraw(&mut rng).draw(4, 3, &mut sample);
            prop_assert!(sample.iter().all(|&i| i < 4) && sample[0] != sample[1] && sample[1] != sample[2] && sample[0] != sample[2]);
            let kept = SkipRepeats(&mut rng).draw(4, 3, &mut sample);
            let distinct = sample[0] != sample[1] && sample[1] != sample[2] && sample[0] != sample[2];
            prop_assert_eq!(kept, distinct);
        }
    }

    #[test]
    fn too_few_inliers_or_points_give_no_model() {
        let points = points(3, 15);
        let rounds = Rounds {
            iterations: 60,
            min_inliers: 10,
            refits: 2,
        };
        assert!(ransac(&Line(&points), &mut Redraw(&mut Rng::new(3)), rounds).is_none());
        assert!(ransac(&Line(&points[..1]), &mut Redraw(&mut Rng::new(3)), rounds).is_none());
    }
}
