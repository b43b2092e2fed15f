//! Pinhole camera intrinsics with Brown-Conrady distortion, and the stereo
//! baseline used by RGB-D (virtual stereo) and stereo rigs.

use nalgebra::{Vector2, Vector3};
use serde::{Deserialize, Serialize};

use crate::checks::{positive, BadValue};

/// An image's size in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageSize {
    /// Columns.
    pub width: u32,
    /// Rows.
    pub height: u32,
}

impl From<(u32, u32)> for ImageSize {
    /// From `(width, height)`, as `image`'s `dimensions()` gives them.
    fn from(dimensions: (u32, u32)) -> Self {
        Self {
            width: dimensions.0,
            height: dimensions.1,
        }
    }
}

/// Intrinsics of a pinhole camera, in pixels; distortion as OpenCV's
/// `(k1, k2, p1, p2, k3)`, with the rational model's `(k4, k5, k6)` beside it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinholeCamera {
    /// Focal length along x, in pixels.
    pub fx: f64,
    /// Focal length along y, in pixels.
    pub fy: f64,
    /// Principal point, x.
    pub cx: f64,
    /// Principal point, y.
    pub cy: f64,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Brown-Conrady \((k_1, k_2, p_1, p_2, k_3)\), OpenCV's order; zeros: none.
    #[serde(default)]
    pub distortion: [f64; 5],
    /// The rational model's denominator \((k_4, k_5, k_6)\) (OpenCV's
    /// `CALIB_RATIONAL_MODEL`, ROS's `rational_polynomial`, the Azure Kinect's lenses);
    /// zeros: the plain Brown-Conrady model.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub rational: [f64; 3],
}

fn is_zero(k: &[f64; 3]) -> bool {
    k.iter().all(|&v| v == 0.0)
}

impl PinholeCamera {
    /// TUM RGB-D freiburg3 (Kinect) intrinsics, already undistorted.
    pub fn tum_fr3() -> Self {
        Self {
            fx: 535.4,
            fy: 539.2,
            cx: 320.1,
            cy: 247.6,
            width: 640,
            height: 480,
            distortion: [0.0; 5],
            rational: [0.0; 3],
        }
    }

    /// \(u = f_x x/z + c_x,\ v = f_y y/z + c_y\) for a point in the camera frame.
    pub fn project(&self, p_camera: &Vector3<f64>) -> Vector2<f64> {
        Vector2::new(
            self.fx * p_camera.x / p_camera.z + self.cx,
            self.fy * p_camera.y / p_camera.z + self.cy,
        )
    }

    /// The camera-frame point at depth `z` (metres) seen at pixel `(u, v)`.
    pub fn unproject(&self, pixel: &Vector2<f64>, z: f64) -> Vector3<f64> {
        Vector3::new(
            (pixel.x - self.cx) * z / self.fx,
            (pixel.y - self.cy) * z / self.fy,
            z,
        )
    }

    /// Whether all distortion coefficients are zero.
    pub fn is_undistorted(&self) -> bool {
        self.distortion.iter().all(|&k| k == 0.0) && is_zero(&self.rational)
    }

    /// The radial factor \(\frac{1 + k_1 r^2 + k_2 r^4 + k_3 r^6}{1 + k_4 r^2 + k_5 r^4 + k_6 r^6}\)
    /// at \(r^2\) (the denominator is exactly 1 without the rational terms).
    fn radial(&self, r2: f64) -> f64 {
        let [k1, k2, _, _, k3] = self.distortion;
        let [k4, k5, k6] = self.rational;
        (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    }

    /// The distorted pixel of an ideal (undistorted) one: with normalised
    /// \((x, y)\), \(r^2 = x^2 + y^2\),
    /// \(x_d = x\, \rho(r^2) + 2 p_1 x y + p_2 (r^2 + 2 x^2)\) and
    /// \(y_d = y\, \rho(r^2) + p_1 (r^2 + 2 y^2) + 2 p_2 x y\), with the radial factor
    /// \(\rho = \frac{1 + k_1 r^2 + k_2 r^4 + k_3 r^6}{1 + k_4 r^2 + k_5 r^4 + k_6 r^6}\)
    /// (OpenCV's model; the Azure Kinect SDK's Brown-Conrady model is the same).
    pub fn distort(&self, pixel: &Vector2<f64>) -> Vector2<f64> {
        let [_, _, p1, p2, _] = self.distortion;
        let (x, y) = ((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy);
        let r2 = x * x + y * y;
        let radial = self.radial(r2);
        let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
        let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
        Vector2::new(self.fx * xd + self.cx, self.fy * yd + self.cy)
    }

    /// The ideal pixel of a distorted one (inverse of [`PinholeCamera::distort`], by
    /// fixed-point iteration as OpenCV's `undistortPoints`); unchanged without distortion.
    pub fn undistort(&self, pixel: &Vector2<f64>) -> Vector2<f64> {
        if self.is_undistorted() {
            return *pixel;
        }
        let [_, _, p1, p2, _] = self.distortion;
        let (xd, yd) = ((pixel.x - self.cx) / self.fx, (pixel.y - self.cy) / self.fy);
        let (mut x, mut y) = (xd, yd);
        for _ in 0..20 {
            let r2 = x * x + y * y;
            let radial = self.radial(r2);
            let dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
            let dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
            x = (xd - dx) / radial;
            y = (yd - dy) / radial;
        }
        Vector2::new(self.fx * x + self.cx, self.fy * y + self.cy)
    }

    /// Checks that the intrinsics are usable, naming the first bad value.
    pub fn validate(&self) -> Result<(), BadValue> {
        positive("camera.fx", self.fx)?;
        positive("camera.fy", self.fy)?;
        for (key, value) in [("camera.cx", self.cx), ("camera.cy", self.cy)] {
            if !value.is_finite() {
                return Err(BadValue::new(key, format!("must be finite, got {value}")));
            }
        }
        if self.width == 0 || self.height == 0 {
            return Err(BadValue::new(
                "camera.width",
                format!(
                    "and height must be positive, got {}x{}",
                    self.width, self.height
                ),
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn unproject_inverts_project(x in -2.0..2.0f64, y in -2.0..2.0f64, z in 0.1..10.0f64) {
            let camera = PinholeCamera::tum_fr3();
            let p = Vector3::new(x, y, z);
            let back = camera.unproject(&camera.project(&p), z);
            prop_assert!((back - p).norm() < 1e-12);
        }
    }

    proptest! {
        #[test]
        fn undistort_inverts_distort(u in 0.0..640.0f64, v in 0.0..480.0f64) {
            // TUM fr1's published distortion.
            let mut camera = PinholeCamera::tum_fr3();
            camera.distortion = [0.2624, -0.9531, -0.0054, 0.0026, 1.1633];
            let ideal = Vector2::new(u, v);
            let back = camera.undistort(&camera.distort(&ideal));
            prop_assert!((back - ideal).norm() < 1e-3, "{back} vs {ideal}");
        }

        #[test]
        fn undistort_inverts_the_rational_model(u in 0.0..640.0f64, v in 0.0..576.0f64) {
            // An Azure Kinect depth camera's lens in NFOV unbinned mode (its calibration's
            // k1-k6, p1, p2 as the SDK's mode-specific intrinsics give them).
            let camera = PinholeCamera {
                fx: 504.2, fy: 504.3, cx: 321.4, cy: 329.2, width: 640, height: 576,
                distortion: [5.7, 3.6, 0.00005, -0.00004, 0.17],
                rational: [6.03, 5.5, 0.9],
            };
            let ideal = camera.undistort(&Vector2::new(u, v));
            let back = camera.distort(&ideal);
            prop_assert!((back - Vector2::new(u, v)).norm() < 1e-3, "{back} vs ({u}, {v})");
        }
    }

    #[test]
    fn validation_names_the_bad_value() {
        let mut camera = PinholeCamera::tum_fr3();
        camera.fy = -1.0;
        assert!(camera.validate().unwrap_err().key == "camera.fy");
    }
}
