//! The one reprojection model for RGB-D and stereo (ORB-SLAM2 §III-A): a point
//! \(p = (x, y, z)\) in the camera frame is seen at
//! \(u = f_x x / z + c_x\), \(v = f_y y / z + c_y\), and in the (virtual) right image at
//! \(u_R = u - b f / z\).

use nalgebra::{Matrix2x3, Matrix3, Vector3};

use super::camera::PinholeCamera;

/// Pinhole intrinsics plus the (virtual) stereo baseline times fx.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoCamera {
    /// Focal length along x, in pixels.
    pub fx: f64,
    /// Focal length along y, in pixels.
    pub fy: f64,
    /// Principal point, x.
    pub cx: f64,
    /// Principal point, y.
    pub cy: f64,
    /// Baseline times \(f_x\) (pixels times metres): \(u_R = u - bf / z\).
    pub bf: f64,
}

impl StereoCamera {
    /// The undistorted pinhole `camera` with baseline times fx `bf`.
    pub fn new(camera: &PinholeCamera, bf: f64) -> Self {
        Self {
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
            bf,
        }
    }

    /// \((u, v, u_R)\) of a camera-frame point.
    pub fn project(&self, p: &Vector3<f64>) -> Vector3<f64> {
        let inv_z = 1.0 / p.z;
        let u = self.fx * p.x * inv_z + self.cx;
        Vector3::new(u, self.fy * p.y * inv_z + self.cy, u - self.bf * inv_z)
    }

    /// \(\partial (u, v, u_R) / \partial p\).
    pub fn jacobian(&self, p: &Vector3<f64>) -> Matrix3<f64> {
        let inv_z = 1.0 / p.z;
        let inv_z2 = inv_z * inv_z;
        Matrix3::new(
            self.fx * inv_z,
            0.0,
            -self.fx * p.x * inv_z2,
            0.0,
            self.fy * inv_z,
            -self.fy * p.y * inv_z2,
            self.fx * inv_z,
            0.0,
            -self.fx * p.x * inv_z2 + self.bf * inv_z2,
        )
    }

    /// \(\partial (u, v) / \partial p\).
    pub fn jacobian_mono(&self, p: &Vector3<f64>) -> Matrix2x3<f64> {
        self.jacobian(p).fixed_rows::<2>(0).into_owned()
    }
}
