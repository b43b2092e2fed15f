//! Error statistics as evo reports them (numpy's definitions).

use serde::{Deserialize, Serialize};

/// rmse, mean, median, std, min, max and sse of a list of errors.
///
/// \( \mathrm{rmse} = \sqrt{\tfrac1n\sum e_i^2} \), \( \mathrm{sse} = \sum e_i^2 \),
/// std is the population standard deviation (numpy's `np.std`, ddof 0), the median of
/// an even count is the mean of the two middle values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Statistics {
    /// Root mean square.
    pub rmse: f64,
    /// Mean.
    pub mean: f64,
    /// Median.
    pub median: f64,
    /// Standard deviation (population).
    pub std: f64,
    /// Smallest.
    pub min: f64,
    /// Largest.
    pub max: f64,
    /// Sum of squares.
    pub sse: f64,
    /// How many.
    pub count: usize,
}

impl Statistics {
    /// Statistics of a non-empty list; `None` for an empty one.
    pub fn of(errors: &[f64]) -> Option<Self> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / n;
        let variance = errors.iter().map(|e| (e - mean) * (e - mean)).sum::<f64>() / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let middle = sorted.len() / 2;
        let median = if sorted.len().is_multiple_of(2) {
            0.5 * (sorted[middle - 1] + sorted[middle])
        } else {
            sorted[middle]
        };
        Some(Self {
            rmse: (sse / n).sqrt(),
            mean,
            median,
            std: variance.sqrt(),
            min: sorted[0],
            max: sorted[sorted.len() - 1],
            sse,
            count: errors.len(),
        })
    }

    /// The statistics as (name, value) rows in evo's order.
    pub fn rows(&self) -> [(&'static str, f64); 7] {
        [
            ("max", self.max),
            ("mean", self.mean),
            ("median", self.median),
            ("min", self.min),
            ("rmse", self.rmse),
            ("sse", self.sse),
            ("std", self.std),
        ]
    }

    /// Every statistic divided by `factor` (sse by its square), e.g. to report a rate.
    pub fn scaled(&self, factor: f64) -> Self {
        Self {
            rmse: self.rmse / factor,
            mean: self.mean / factor,
            median: self.median / factor,
            std: self.std / factor,
            min: self.min / factor,
            max: self.max / factor,
            sse: self.sse / (factor * factor),
            count: self.count,
        }
    }
}

/// numpy's median of a sorted, non-empty slice (the mean of the two middle values
/// for an even count).
pub fn median_of_sorted(sorted: &[f64]) -> f64 {
    let middle = sorted.len() / 2;
    if sorted.len().is_multiple_of(2) {
        0.5 * (sorted[middle - 1] + sorted[middle])
    } else {
        sorted[middle]
    }
}

/// The median of `values` (sorted in place); 0 when empty.
pub fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return 0.0;
    }
    values.sort_by(f64::total_cmp);
    median_of_sorted(values)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hand_computed_values() {
        let s = Statistics::of(&[1.0, 2.0, 3.0, 6.0]).unwrap();
        assert_eq!(s.sse, 50.0);
        assert_eq!(s.mean, 3.0);
        assert_eq!(s.median, 2.5);
        assert!((s.rmse - 12.5f64.sqrt()).abs() < 1e-15);
        assert!((s.std - 3.5f64.sqrt()).abs() < 1e-15);
        assert_eq!((s.min, s.max, s.count), (1.0, 6.0, 4));
        assert_eq!(Statistics::of(&[4.0, 1.0, 2.0]).unwrap().median, 2.0);
        assert!(Statistics::of(&[]).is_none());
    }
}
