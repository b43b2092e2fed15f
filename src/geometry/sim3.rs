//! Sim(3): similarity transforms \(x \mapsto sRx + t\), used for scale-correcting
//! alignment of trajectories and (later) monocular loop closure.
//!
//! The tangent vector is \(\zeta = (\rho, \phi, \sigma)\) with \(s = e^\sigma\):
//!
//! \[ \exp(\zeta) = (e^\sigma,\ \exp(\hat\phi),\ W(\phi, \sigma)\rho),\qquad
//!    W = C I + A\hat\phi + B\hat\phi^2 \]
//!
//! where, with \(\theta = \|\phi\|\), \(a = e^\sigma\sin\theta\), \(b = e^\sigma\cos\theta\),
//! \(c = \theta^2 + \sigma^2\):
//! \(C = (e^\sigma - 1)/\sigma\), \(A = (a\sigma + (1-b)\theta)/(\theta c)\),
//! \(B = (C - ((b-1)\sigma + a\theta)/c)/\theta^2\), with their limits as
//! \(\sigma \to 0\) or \(\theta \to 0\).

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::se3::{self, Se3};
use super::so3;

const SMALL: f64 = 1e-9;

/// A similarity transform `a_from_b`: \(p_a = s R p_b + t\).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    /// \(R\).
    pub rotation: Rotation3<f64>,
    /// \(t\).
    pub translation: Vector3<f64>,
    /// \(s > 0\).
    pub scale: f64,
}

/// A Sim(3) tangent vector: translation part, rotation part, log of the scale.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3Tangent {
    /// \(\rho\): the translation part.
    pub rho: Vector3<f64>,
    /// \(\phi\): the rotation part (axis times angle).
    pub phi: Vector3<f64>,
    /// \(\sigma = \ln s\).
    pub sigma: f64,
}

impl Sim3 {
    /// The identity (\(s = 1\)).
    pub fn identity() -> Self {
        Self {
            rotation: Rotation3::identity(),
            translation: Vector3::zeros(),
            scale: 1.0,
        }
    }

    /// \(p_a = s R p_b + t\).
    pub fn new(rotation: Rotation3<f64>, translation: Vector3<f64>, scale: f64) -> Self {
        Self {
            rotation,
            translation,
            scale,
        }
    }

    /// The similarity with unit scale equal to a rigid transform.
    pub fn from_se3(pose: &Se3) -> Self {
        Self::new(pose.rotation, pose.translation.vector, 1.0)
    }

    /// \(s R p + t\).
    pub fn transform_point(&self, p: &Vector3<f64>) -> Vector3<f64> {
        self.scale * (self.rotation * p) + self.translation
    }

    /// \((s_1, R_1, t_1)(s_2, R_2, t_2) = (s_1 s_2,\ R_1 R_2,\ s_1 R_1 t_2 + t_1)\).
    pub fn compose(&self, other: &Sim3) -> Sim3 {
        Sim3::new(
            self.rotation * other.rotation,
            self.transform_point(&other.translation),
            self.scale * other.scale,
        )
    }

    /// \((s, R, t)^{-1} = (1/s,\ R^\top,\ -R^\top t / s)\).
    pub fn inverse(&self) -> Sim3 {
        let r_inv = self.rotation.inverse();
        Sim3::new(
            r_inv,
            -(r_inv * self.translation) / self.scale,
            1.0 / self.scale,
        )
    }

    /// Applies the similarity to a camera pose `world_from_camera`, as evo's
    /// `scale` followed by `transform` does: the position is mapped by \(sRp + t\) and the
    /// orientation is rotated by \(R\). The result is again a rigid pose.
    pub fn apply_to_pose(&self, pose: &Se3) -> Se3 {
        se3::from_parts(
            self.transform_point(&pose.translation.vector),
            self.rotation.matrix() * pose.rotation.matrix(),
        )
    }

    /// \(\exp: \mathfrak{sim}(3) \to Sim(3)\).
    pub fn exp(zeta: &Sim3Tangent) -> Sim3 {
        let w = w_matrix(&zeta.phi, zeta.sigma);
        Sim3::new(so3::exp(&zeta.phi), w * zeta.rho, zeta.sigma.exp())
    }

    /// \(\log: Sim(3) \to \mathfrak{sim}(3)\), for rotation angles below \(\pi\).
    pub fn log(&self) -> Sim3Tangent {
        let phi = so3::log(&self.rotation);
        let sigma = self.scale.ln();
        let w = w_matrix(&phi, sigma);
        let rho = w
            .lu()
            .solve(&self.translation)
            .expect("W(phi, sigma) is invertible for angles below pi");
        Sim3Tangent { rho, phi, sigma }
    }
}

/// The matrix \(W(\phi, \sigma)\) that maps \(\rho\) to the translation in [`Sim3::exp`].
fn w_matrix(phi: &Vector3<f64>, sigma: f64) -> Matrix3<f64> {
    let theta = phi.norm();
    let w = so3::hat(phi);
    let w2 = w * w;
    let s = sigma.exp();
    let (a_coef, b_coef, c_coef);
    if sigma.abs() < SMALL {
        c_coef = 1.0;
        if theta < SMALL {
            a_coef = 0.5;
            b_coef = 1.0 / 6.0;
        } else {
            let theta2 = theta * theta;
            a_coef = (1.0 - theta.cos()) / theta2;
            b_coef = (theta - theta.sin()) / (theta2 * theta);
        }
    } else {
        c_coef = (s - 1.0) / sigma;
        if theta < SMALL {
            let sigma2 = sigma * sigma;
            a_coef = ((sigma - 1.0) * s + 1.0) / sigma2;
            b_coef = ((0.5 * sigma2 - sigma + 1.0) * s - 1.0) / (sigma2 * sigma);
        } else {
            let a = s * theta.sin();
            let b = s * theta.cos();
            let theta2 = theta * theta;
            let c = theta2 + sigma * sigma;
            a_coef = (a * sigma + (1.0 - b) * theta) / (theta * c);
            b_coef = (c_coef - ((b - 1.0) * sigma + a * theta) / c) / theta2;
        }
    }
    c_coef * Matrix3::identity() + a_coef * w + b_coef * w2
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn tangent() -> impl Strategy<Value = Sim3Tangent> {
        (
            (-3.0..3.0, -3.0..3.0, -3.0..3.0),
            (-1.5..1.5, -1.5..1.5, -1.5..1.5),
            -1.0..1.0f64,
        )
            .prop_map(|((a, b, c), (d, e, f), sigma)| Sim3Tangent {
                rho: Vector3::new(a, b, c),
                phi: Vector3::new(d, e, f),
                sigma,
            })
    }

    fn close(a: &Sim3, b: &Sim3, tol: f64) -> bool {
        (a.rotation.matrix() - b.rotation.matrix()).norm() < tol
            && (a.translation - b.translation).norm() < tol
            && (a.scale - b.scale).abs() < tol
    }

    proptest! {
        #[test]
        fn log_inverts_exp(z in tangent()) {
            let back = Sim3::exp(&z).log();
            prop_assert!((back.rho - z.rho).norm() < 1e-8);
            prop_assert!((back.phi - z.phi).norm() < 1e-8);
            prop_assert!((back.sigma - z.sigma).abs() < 1e-12);
        }

        #[test]
        fn inverse_and_identity(z in tangent()) {
            let t = Sim3::exp(&z);
            prop_assert!(close(&t.compose(&t.inverse()), &Sim3::identity(), 1e-12));
            prop_assert!(close(&t.compose(&Sim3::identity()), &t, 1e-14));
        }

        #[test]
        fn associativity(a in tangent(), b in tangent(), c in tangent()) {
            let (ta, tb, tc) = (Sim3::exp(&a), Sim3::exp(&b), Sim3::exp(&c));
            prop_assert!(close(&ta.compose(&tb).compose(&tc), &ta.compose(&tb.compose(&tc)), 1e-10));
        }

        #[test]
        fn compose_acts_on_points(a in tangent(), b in tangent()) {
            let (ta, tb) = (Sim3::exp(&a), Sim3::exp(&b));
            let p = Vector3::new(0.3, -1.2, 2.0);
            let lhs = ta.compose(&tb).transform_point(&p);
            let rhs = ta.transform_point(&tb.transform_point(&p));
            prop_assert!((lhs - rhs).norm() < 1e-10);
        }
    }

    #[test]
    fn w_matrix_is_continuous_at_the_limits() {
        let phi = Vector3::new(0.3, -0.2, 0.1);
        let near = w_matrix(&phi, 2e-9);
        let at = w_matrix(&phi, 0.0);
        assert!((near - at).norm() < 1e-7);
        let tiny = Vector3::new(1e-10, 0.0, 0.0);
        assert!((w_matrix(&tiny, 0.4) - w_matrix(&(tiny * 1e6), 0.4)).norm() < 1e-4);
    }

    #[test]
    fn unit_scale_matches_se3() {
        let xi = nalgebra::Vector6::new(0.5, -1.0, 2.0, 0.3, 0.2, -0.4);
        let rigid = se3::exp(&xi);
        let sim = Sim3::exp(&Sim3Tangent {
            rho: xi.fixed_rows::<3>(0).into_owned(),
            phi: xi.fixed_rows::<3>(3).into_owned(),
            sigma: 0.0,
        });
        assert!(close(&sim, &Sim3::from_se3(&rigid), 1e-12));
    }
}
