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

/// The most values a [`MedianSample`] keeps.
pub const MEDIAN_SAMPLE_CAP: usize = 1 << 18;

/// Values kept for a median: every value up to [`MEDIAN_SAMPLE_CAP`], then an evenly spaced
/// subsample (every second value dropped each time it fills), so that the median of
/// any number of frames' values takes bounded memory and is exact below the cap.
#[derive(Debug)]
pub struct MedianSample {
    values: Vec<f64>,
    stride: usize,
    seen: usize,
}

impl Default for MedianSample {
    fn default() -> Self {
        Self {
            values: Vec::new(),
            stride: 1,
            seen: 0,
        }
    }
}

impl MedianSample {
    /// Adds a value.
    pub fn push(&mut self, value: f64) {
        if self.seen.is_multiple_of(self.stride) {
            self.values.push(value);
            if self.values.len() == MEDIAN_SAMPLE_CAP {
                let mut i = 0;
                self.values.retain(|_| {
                    i += 1;
                    i % 2 == 1
                });
                self.stride *= 2;
            }
        }
        self.seen += 1;
    }

    /// The median of the values kept (0 without any).
    pub fn median(mut self) -> f64 {
        median(&mut self.values)
    }
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

    #[test]
    fn a_sample_keeps_every_value_below_its_cap_and_an_even_subsample_above() {
        let mut below = MedianSample::default();
        (0..1001).rev().for_each(|v| below.push(v as f64));
        assert_eq!(below.median(), 500.0);
        let mut above = MedianSample::default();
        let n = 3 * MEDIAN_SAMPLE_CAP + 7;
        (0..n).for_each(|v| above.push(v as f64));
        assert!(
            above.values.len() <= MEDIAN_SAMPLE_CAP && above.values.len() > MEDIAN_SAMPLE_CAP / 2
        );
        let middle = above.median() / n as f64;
        assert!((middle - 0.5).abs() < 1e-3, "{middle}");
    }
}
