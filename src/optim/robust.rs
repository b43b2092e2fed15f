//! Robust kernels and the chi-square gates ORB-SLAM2 uses to call a residual an
//! outlier: 95 % quantiles for 2 (mono) and 3 (stereo) degrees of freedom.

/// \(\chi^2_{0.95}\) with 2 degrees of freedom.
pub const CHI2_MONO: f64 = 5.991;
/// \(\chi^2_{0.95}\) with 3 degrees of freedom.
pub const CHI2_STEREO: f64 = 7.815;

/// The Huber weight for a squared (whitened) error \(e^2\) with threshold \(\delta^2\):
/// 1 inside, \(\delta / |e|\) outside, so that the cost grows linearly.
pub fn huber_weight(squared_error: f64, delta: f64) -> f64 {
    let e = squared_error.sqrt();
    if e <= delta {
        1.0
    } else {
        delta / e
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huber_is_quadratic_inside_and_linear_outside() {
        assert_eq!(huber_weight(4.0, 3.0), 1.0);
        // |e| = 6, delta = 3: weight 0.5, so the weighted square 0.5 * 36 = 2 delta |e|.
        assert!((huber_weight(36.0, 3.0) - 0.5).abs() < 1e-15);
    }
}
