//! Depth sensors' noise: how far a measured depth may lie from the truth. The
//! synthetic renderer draws its Kinect-type noise from here, and the geometric check's
//! rigidity test (`crate::dop::rigidity`) bounds what a static point may change by it.

/// Which depth noise model a sensor follows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DepthNoise {
    /// A structured-light or time-of-flight RGB-D camera ([`kinect_depth_sigma`]).
    Rgbd,
    /// A stereo pair with baseline `bf` (pixels times metres) and a disparity noise of
    /// [`STEREO_DISPARITY_SIGMA`] pixels ([`stereo_depth_sigma`]).
    Stereo {
        /// Baseline times \(f_x\).
        bf: f64,
    },
}

/// The disparity noise assumed for stereo matches, in pixels (ORB-SLAM2 refines
/// disparities to a tenth of a pixel; a pixel leaves room for matches off by one).
pub const STEREO_DISPARITY_SIGMA: f64 = 1.0;

impl DepthNoise {
    /// The depth noise (standard deviation, metres) at depth `z` (RGB-D: never below
    /// its value at the sensor's near limit, 0.4 m).
    pub fn sigma(&self, z: f64) -> f64 {
        match *self {
            DepthNoise::Rgbd => kinect_depth_sigma(z.max(0.4)),
            DepthNoise::Stereo { bf } => stereo_depth_sigma(z, bf, STEREO_DISPARITY_SIGMA),
        }
    }
}

/// The standard deviation of Kinect depth noise at depth `z` metres (Nguyen, Izadi
/// and Lovell 2012): \(\sigma_z = 0.0012 + 0.0019 (z - 0.4)^2\).
pub fn kinect_depth_sigma(z: f64) -> f64 {
    0.0012 + 0.0019 * (z - 0.4) * (z - 0.4)
}

/// The depth noise of a stereo pair with baseline `bf` (pixels times metres) at depth
/// `z`, for a disparity noise of `disparity_sigma` pixels: \(\sigma_z = z^2 \sigma_d / bf\).
pub fn stereo_depth_sigma(z: f64, bf: f64, disparity_sigma: f64) -> f64 {
    z * z * disparity_sigma / bf
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stereo_noise_grows_with_the_square_of_depth() {
        let near = stereo_depth_sigma(1.0, 40.0, 0.5);
        assert!((stereo_depth_sigma(2.0, 40.0, 0.5) - 4.0 * near).abs() < 1e-12);
        assert!(kinect_depth_sigma(0.4) == 0.0012);
    }
}
