//! SO(3): the exponential and logarithm maps and the left Jacobian.
//!
//! With \(\theta = \|\omega\|\) and \(\hat\omega\) the skew-symmetric matrix of \(\omega\):
//!
//! \[ \exp(\hat\omega) = I + \frac{\sin\theta}{\theta}\hat\omega + \frac{1-\cos\theta}{\theta^2}\hat\omega^2 \]
//!
//! \[ J_l(\omega) = I + \frac{1-\cos\theta}{\theta^2}\hat\omega + \frac{\theta-\sin\theta}{\theta^3}\hat\omega^2 \]
//!
//! so that \(\exp(\omega + \delta) \approx \exp(J_l(\omega)\,\delta)\exp(\omega)\).

use nalgebra::{Matrix3, Rotation3, Vector3};

/// Below this angle the series expansions replace the closed forms.
const SMALL_ANGLE: f64 = 1e-8;

/// The skew-symmetric matrix \(\hat v\) with \(\hat v\, u = v \times u\).
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The inverse of [`hat`]: reads \(v\) back from a skew-symmetric matrix.
pub fn vee(m: &Matrix3<f64>) -> Vector3<f64> {
    Vector3::new(m[(2, 1)], m[(0, 2)], m[(1, 0)])
}

/// \(\exp: \mathfrak{so}(3) \to SO(3)\), Rodrigues' formula.
pub fn exp(omega: &Vector3<f64>) -> Rotation3<f64> {
    Rotation3::new(*omega)
}

/// \(\log: SO(3) \to \mathfrak{so}(3)\), the rotation vector with angle in \([0, \pi]\).
///
/// Computed through the unit quaternion \(q = (w, v)\), \(w \ge 0\):
/// \(\log R = 2\,\mathrm{atan2}(\|v\|, w)\, v / \|v\|\), which keeps full precision for
/// small angles (the `acos` of the trace, as nalgebra's `scaled_axis` uses, loses half
/// the digits there).
pub fn log(rotation: &Rotation3<f64>) -> Vector3<f64> {
    let q = nalgebra::UnitQuaternion::from_rotation_matrix(rotation);
    let (w, v) = if q.w < 0.0 {
        (-q.w, -q.imag())
    } else {
        (q.w, q.imag())
    };
    let sin_half = v.norm();
    if sin_half < 1e-300 {
        return Vector3::zeros();
    }
    let theta = 2.0 * sin_half.atan2(w);
    // theta / sin(theta / 2) -> 2 as theta -> 0
    let factor = if sin_half < 1e-8 {
        2.0 / w
    } else {
        theta / sin_half
    };
    v * factor
}

/// The rotation angle \(\theta \in [0, \pi]\) of a rotation matrix: the norm of its
/// rotation vector, computed through a unit quaternion \(q = (w, v)\) as
/// \(2\,\mathrm{atan2}(\|v\|, |w|)\), accurate near 0 and \(\pi\) (as scipy's
/// `as_rotvec`, which evo uses; `acos((tr R - 1)/2)` loses digits near 0).
pub fn angle(rotation: &Matrix3<f64>) -> f64 {
    let q = nalgebra::UnitQuaternion::from_matrix(rotation);
    2.0 * q.imag().norm().atan2(q.w.abs())
}

/// The left Jacobian \(J_l(\omega)\) of SO(3).
pub fn left_jacobian(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = omega.norm_squared();
    let w = hat(omega);
    if theta2 < SMALL_ANGLE * SMALL_ANGLE {
        return Matrix3::identity() + 0.5 * w + (1.0 / 6.0) * w * w;
    }
    let theta = theta2.sqrt();
    Matrix3::identity()
        + ((1.0 - theta.cos()) / theta2) * w
        + ((theta - theta.sin()) / (theta2 * theta)) * w * w
}

/// The inverse left Jacobian
/// \(J_l^{-1}(\omega) = I - \tfrac12\hat\omega + \left(\frac{1}{\theta^2} - \frac{1+\cos\theta}{2\theta\sin\theta}\right)\hat\omega^2\).
pub fn left_jacobian_inverse(omega: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = omega.norm_squared();
    let w = hat(omega);
    if theta2 < SMALL_ANGLE * SMALL_ANGLE {
        return Matrix3::identity() - 0.5 * w + (1.0 / 12.0) * w * w;
    }
    let theta = theta2.sqrt();
    let coefficient = 1.0 / theta2 - (1.0 + theta.cos()) / (2.0 * theta * theta.sin());
    Matrix3::identity() - 0.5 * w + coefficient * w * w
}

/// The right Jacobian \(J_r(\omega) = J_l(-\omega)\).
pub fn right_jacobian(omega: &Vector3<f64>) -> Matrix3<f64> {
    left_jacobian(&(-omega))
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn small_vector(bound: f64) -> impl Strategy<Value = Vector3<f64>> {
        (-bound..bound, -bound..bound, -bound..bound).prop_map(|(x, y, z)| Vector3::new(x, y, z))
    }

    proptest! {
        #[test]
        fn hat_vee_roundtrip(v in small_vector(10.0)) {
            prop_assert!((vee(&hat(&v)) - v).norm() < 1e-15);
        }

        #[test]
        fn log_inverts_exp(v in small_vector(1.7)) {
            // |v| < sqrt(3) * 1.7 may exceed pi only along diagonals; restrict to the ball.
            prop_assume!(v.norm() < 3.0);
            prop_assert!((log(&exp(&v)) - v).norm() < 1e-9);
        }

        #[test]
        fn left_jacobian_matches_finite_differences(v in small_vector(1.5), d in small_vector(1.0)) {
            prop_assume!(v.norm() < 2.8);
            let eps = 1e-6;
            let delta = d * eps;
            // exp(v + delta) exp(v)^-1 = exp(J_l(v) delta) to first order
            let lhs = log(&(exp(&(v + delta)) * exp(&v).inverse()));
            let rhs = left_jacobian(&v) * delta;
            prop_assert!((lhs - rhs).norm() < 1e-4 * delta.norm() + 1e-14, "{} vs {}", lhs, rhs);
        }

        #[test]
        fn left_jacobian_inverse_is_inverse(v in small_vector(1.5)) {
            prop_assume!(v.norm() < 2.8);
            let product = left_jacobian(&v) * left_jacobian_inverse(&v);
            prop_assert!((product - Matrix3::identity()).norm() < 1e-9);
        }

        #[test]
        fn angle_equals_log_norm(v in small_vector(1.7)) {
            prop_assume!(v.norm() < 3.0);
            prop_assert!((angle(exp(&v).matrix()) - v.norm()).abs() < 1e-7);
        }
    }

    #[test]
    fn small_angle_branches_are_continuous() {
        let v = Vector3::new(1e-9, -2e-9, 3e-9);
        let v_big = v * 1e3;
        assert!((left_jacobian(&v) - Matrix3::identity()).norm() < 1e-8);
        assert!((left_jacobian(&v_big) - left_jacobian(&(v_big * 0.999_999))).norm() < 1e-9);
        assert!(
            (left_jacobian_inverse(&v) * left_jacobian(&v) - Matrix3::identity()).norm() < 1e-12
        );
    }
}
