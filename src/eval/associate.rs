//! Pairing the poses of two trajectories.
//!
//! - [`AssociationRule::Evo`]: evo 1.38's `associate_trajectories`: starting from the
//!   trajectory with fewer poses, each of its stamps takes the nearest stamp of the other
//!   when \(|\Delta t| \le\) `max_diff` (on a tie the earlier one). A pose of the longer
//!   trajectory may be taken more than once, exactly as in evo.
//! - [`AssociationRule::TumGreedy`]: TUM's `associate.py`: globally greedy by smallest
//!   \(|\Delta t| <\) `max_diff`, each stamp used once.
//! - [`AssociationRule::ByIndex`]: pose \(i\) with pose \(i\) (KITTI files without times).

use serde::Serialize;

use crate::io::file_list::associate_greedy;
use crate::io::Trajectory;

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "kebab-case")]
/// How estimated and reference poses are paired.
pub enum AssociationRule {
    /// evo's nearest-timestamp rule (default tolerance 0.01 s).
    Evo,
    /// TUM associate.py's greedy rule (default tolerance 0.02 s).
    TumGreedy,
    /// Pose i with pose i; both trajectories must have the same length.
    ByIndex,
}

impl AssociationRule {
    /// The tolerance each rule's own tool uses by default.
    pub fn default_max_diff(self) -> f64 {
        match self {
            Self::Evo => 0.01,
            Self::TumGreedy => 0.02,
            Self::ByIndex => 0.0,
        }
    }
}

/// Index pairs `(reference, estimate)` and the pose count the coverage is judged against.
#[derive(Debug, Clone, PartialEq)]
pub struct Association {
    /// `(reference index, estimate index)` per pair, in time order.
    pub pairs: Vec<(usize, usize)>,
    /// The number of poses of the shorter trajectory (evo's `max_pairs`).
    pub max_pairs: usize,
}

/// evo's `matching_time_indices`: for each stamp of `first`, the index of the nearest
/// stamp of `second + offset` within `max_diff`. Binary search when `second` is sorted,
/// else evo's linear fallback (first minimum).
pub fn matching_time_indices(
    first: &[f64],
    second: &[f64],
    max_diff: f64,
    offset: f64,
) -> Vec<(usize, usize)> {
    let shifted: Vec<f64> = second.iter().map(|t| t + offset).collect();
    let mut matches = Vec::new();
    if shifted.is_empty() {
        return matches;
    }
    if shifted.windows(2).any(|w| w[1] < w[0]) {
        return nearest_linear(first, &shifted, max_diff);
    }
    let last = shifted.len() - 1;
    for (i, &t) in first.iter().enumerate() {
        if t < shifted[0] - max_diff || t > shifted[last] + max_diff {
            continue;
        }
        let upper = shifted.partition_point(|&s| s <= t).min(last);
        let diff_upper = shifted[upper] - t;
        let diff_lower = if upper > 0 {
            t - shifted[upper - 1]
        } else {
            f64::INFINITY
        };
        if diff_upper <= max_diff && diff_upper < diff_lower {
            matches.push((i, upper));
        } else if diff_lower <= max_diff && diff_lower <= diff_upper {
            matches.push((i, upper - 1));
        }
    }
    matches
}

/// evo's linear fallback for unsorted stamps: the first stamp of `second` with the
/// smallest \(|\Delta t|\), kept when within `max_diff`.
fn nearest_linear(first: &[f64], second: &[f64], max_diff: f64) -> Vec<(usize, usize)> {
    let mut matches = Vec::new();
    for (i, &t) in first.iter().enumerate() {
        let (best, diff) = second
            .iter()
            .enumerate()
            .map(|(j, s)| (j, (s - t).abs()))
            .fold(
                (0, f64::INFINITY),
                |acc, x| if x.1 < acc.1 { x } else { acc },
            );
        if diff <= max_diff {
            matches.push((i, best));
        }
    }
    matches
}

/// Pairs the poses of `reference` and `estimate` by the given rule.
/// `offset` is added to the estimate's timestamps.
pub fn associate(
    reference: &Trajectory,
    estimate: &Trajectory,
    rule: AssociationRule,
    max_diff: f64,
    offset: f64,
) -> Association {
    let max_pairs = reference.len().min(estimate.len());
    let pairs = match rule {
        AssociationRule::ByIndex => (0..max_pairs).map(|i| (i, i)).collect(),
        AssociationRule::TumGreedy => associate_greedy(
            &reference.timestamps,
            &estimate.timestamps,
            offset,
            max_diff,
        ),
        AssociationRule::Evo => {
            if estimate.len() > reference.len() {
                matching_time_indices(
                    &reference.timestamps,
                    &estimate.timestamps,
                    max_diff,
                    offset,
                )
            } else {
                matching_time_indices(
                    &estimate.timestamps,
                    &reference.timestamps,
                    max_diff,
                    -offset,
                )
                .into_iter()
                .map(|(e, r)| (r, e))
                .collect()
            }
        }
    };
    Association { pairs, max_pairs }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn binary_search_equals_linear_rule(
            first in prop::collection::vec(0u32..300, 0..50),
            mut second in prop::collection::vec(0u32..300, 1..50),
        ) {
            // Times on a 0.01 s grid produce ties, the case where the two rules could differ.
            // evo's sorted branch takes the later of two equal stamps; keep them distinct.
            second.sort();
            second.dedup();
            let a: Vec<f64> = first.iter().map(|&v| v as f64 * 0.01).collect();
            let b: Vec<f64> = second.iter().map(|&v| v as f64 * 0.01).collect();
            // The linear rule is evo's definition; the binary search must reproduce it.
            prop_assert_eq!(matching_time_indices(&a, &b, 0.015, 0.0), nearest_linear(&a, &b, 0.015));
        }
    }

    #[test]
    fn starts_from_the_shorter_trajectory() {
        let mut reference = Trajectory::default();
        for i in 0..10 {
            reference.push(i as f64 * 0.1, Default::default());
        }
        let mut estimate = Trajectory::default();
        for t in [0.201, 0.5, 0.7999, 5.0] {
            estimate.push(t, Default::default());
        }
        let a = associate(&reference, &estimate, AssociationRule::Evo, 0.01, 0.0);
        assert_eq!(a.pairs, vec![(2, 0), (5, 1), (8, 2)]);
        assert_eq!(a.max_pairs, 4);
    }
}
