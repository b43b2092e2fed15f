//! The one reprojection model for RGB-D and stereo (ORB-SLAM2 §III-A): a point
//! \(p = (x, y, z)\) in the camera frame is seen at
//! \(u = f_x x / z + c_x\), \(v = f_y y / z + c_y\), and in the (virtual) right image at
//! \(u_R = u - b f / z\).
//!
//! Pose perturbations act on the left, \(T_{cw} \leftarrow \exp(\delta) T_{cw}\) with
//! \(\delta = (\rho, \phi)\), so \(\partial p / \partial \delta = [I \;\; -[p]_\times]\).

use nalgebra::{Matrix3, Matrix3x6, Vector3};

use crate::geometry::so3::hat;

/// \(\partial p / \partial \delta = [I \;\; -[p]_\times]\) for a left perturbation.
pub fn point_jacobian_wrt_pose(p: &Vector3<f64>) -> Matrix3x6<f64> {
    let mut j = Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&Matrix3::identity());
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-hat(p)));
    j
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3;
    use crate::geometry::stereo_camera::StereoCamera;
    use nalgebra::Vector6;
    use proptest::prelude::*;

    proptest! {
        #[test]
        fn jacobians_equal_finite_differences(
            x in -2.0..2.0f64, y in -1.5..1.5f64, z in 0.5..6.0f64,
            xi in se3::tests::tangent(0.3, 0.3),
        ) {
            let camera = StereoCamera { fx: 535.4, fy: 539.2, cx: 320.1, cy: 247.6, bf: 40.0 };
            let pose = se3::exp(&xi);
            let p_world = Vector3::new(x, y, z);
            let p = pose * nalgebra::Point3::from(p_world);
            prop_assume!(p.z > 0.3);
            let analytic = camera.jacobian(&p.coords) * point_jacobian_wrt_pose(&p.coords);
            let h = 1e-6;
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = h;
                let plus = camera.project(&(se3::exp(&d) * pose * nalgebra::Point3::from(p_world)).coords);
                let minus = camera.project(&(se3::exp(&-d) * pose * nalgebra::Point3::from(p_world)).coords);
                let numeric = (plus - minus) / (2.0 * h);
                let column = analytic.column(k);
                prop_assert!((numeric - column).norm() < 1e-4 * (1.0 + column.norm()),
                    "column {k}: {numeric} vs {column}");
            }
        }
    }
}
