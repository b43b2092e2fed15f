//! Closed-form alignment of two point sets: Umeyama (1991) and Horn (1987).
//!
//! Given source points \(x_i\) (an estimate) and target points \(y_i\) (ground truth),
//! Umeyama finds \(s, R, t\) minimising \(\frac1n\sum_i \|y_i - (sRx_i + t)\|^2\):
//!
//! \[ \Sigma_{xy} = \frac1n \sum_i (y_i-\mu_y)(x_i-\mu_x)^\top = U D V^\top,\quad
//!    S = \operatorname{diag}(1, 1, \det U \det V < 0\ ?\ -1 : 1) \]
//! \[ R = U S V^\top,\quad s = \frac{\operatorname{tr}(DS)}{\sigma_x^2},\quad t = \mu_y - sR\mu_x \]
//!
//! with \(\sigma_x^2 = \frac1n\sum_i\|x_i-\mu_x\|^2\). This is exactly evo's
//! `umeyama_alignment`. Horn's method finds the same rotation as the eigenvector of a
//! symmetric 4x4 matrix built from the same covariance.

use nalgebra::{Matrix3, Matrix4, Rotation3, UnitQuaternion, Vector3};
use thiserror::Error;

use super::sim3::Sim3;

/// Why an alignment could not be computed.
#[derive(Debug, Error, PartialEq)]
pub enum AlignmentError {
    #[error("alignment needs at least {needed} point pairs, got {got}")]
    /// Fewer point pairs than the alignment's unknowns need.
    TooFewPoints {
        /// Pairs needed.
        needed: usize,
        /// Pairs given.
        got: usize,
    },
    #[error(
        "alignment needs as many source points ({source_len}) as target points ({target_len})"
    )]
    /// The two point lists have different lengths.
    LengthMismatch {
        /// Points in the source list.
        source_len: usize,
        /// Points in the target list.
        target_len: usize,
    },
    #[error("the source points are all at one place: the scale cannot be estimated")]
    /// All source points coincide.
    Degenerate,
}

/// Which transform an alignment may use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AlignmentKind {
    /// Rotation and translation.
    Se3,
    /// Rotation, translation and scale.
    Sim3,
    /// Scale only (evo's `--correct_scale` without `--align`).
    ScaleOnly,
}

fn centroid(points: &[Vector3<f64>]) -> Vector3<f64> {
    points.iter().sum::<Vector3<f64>>() / points.len() as f64
}

fn check_lengths(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    needed: usize,
) -> Result<(), AlignmentError> {
    if source.len() != target.len() {
        return Err(AlignmentError::LengthMismatch {
            source_len: source.len(),
            target_len: target.len(),
        });
    }
    if source.len() < needed {
        return Err(AlignmentError::TooFewPoints {
            needed,
            got: source.len(),
        });
    }
    Ok(())
}

/// Umeyama's least-squares similarity (or rigid transform when `kind` is
/// [`AlignmentKind::Se3`]) mapping `source` onto `target`.
pub fn umeyama(
    source: &[Vector3<f64>],
    target: &[Vector3<f64>],
    kind: AlignmentKind,
) -> Result<Sim3, AlignmentError> {
    check_lengths(
        source,
        target,
        if kind == AlignmentKind::ScaleOnly {
            1
        } else {
            2
        },
    )?;
    let n = source.len() as f64;
    let mean_x = centroid(source);
    let mean_y = centroid(target);
    let sigma_x = source
        .iter()
        .map(|x| (x - mean_x).norm_squared())
        .sum::<f64>()
        / n;
    let mut cov = Matrix3::zeros();
    for (x, y) in source.iter().zip(target) {
        cov += (y - mean_y) * (x - mean_x).transpose();
    }
    cov /= n;
    let svd = cov.svd(true, true);
    let (u, v_t) = (svd.u.expect("u requested"), svd.v_t.expect("v_t requested"));
    let mut s = Matrix3::identity();
    if u.determinant() * v_t.determinant() < 0.0 {
        s[(2, 2)] = -1.0;
    }
    let rotation = u * s * v_t;
    let scale = match kind {
        AlignmentKind::Se3 => 1.0,
        AlignmentKind::Sim3 | AlignmentKind::ScaleOnly => {
            if sigma_x <= f64::EPSILON * mean_x.norm_squared().max(1.0) {
                return Err(AlignmentError::Degenerate);
            }
            (Matrix3::from_diagonal(&svd.singular_values) * s).trace() / sigma_x
        }
    };
    if kind == AlignmentKind::ScaleOnly {
        return Ok(Sim3::new(Rotation3::identity(), Vector3::zeros(), scale));
    }
    let translation = mean_y - scale * (rotation * mean_x);
    Ok(Sim3::new(
        Rotation3::from_matrix_unchecked(rotation),
        translation,
        scale,
    ))
}

/// Horn's closed-form absolute orientation with unit quaternions (rigid, no scale):
/// the rotation is the eigenvector of the largest eigenvalue of the symmetric matrix
/// \(N(M)\) built from \(M = \sum_i (x_i-\mu_x)(y_i-\mu_y)^\top\).
pub fn horn(source: &[Vector3<f64>], target: &[Vector3<f64>]) -> Result<Sim3, AlignmentError> {
    check_lengths(source, target, 2)?;
    let mean_x = centroid(source);
    let mean_y = centroid(target);
    let mut m = Matrix3::zeros();
    for (x, y) in source.iter().zip(target) {
        m += (x - mean_x) * (y - mean_y).transpose();
    }
    let (sxx, sxy, sxz) = (m[(0, 0)], m[(0, 1)], m[(0, 2)]);
    let (syx, syy, syz) = (m[(1, 0)], m[(1, 1)], m[(1, 2)]);
    let (szx, szy, szz) = (m[(2, 0)], m[(2, 1)], m[(2, 2)]);
    let n = Matrix4::new(
        sxx + syy + szz,
        syz - szy,
        szx - sxz,
        sxy - syx,
        syz - szy,
        sxx - syy - szz,
        sxy + syx,
        szx + sxz,
        szx - sxz,
        sxy + syx,
        -sxx + syy - szz,
        syz + szy,
        sxy - syx,
        szx + sxz,
        syz + szy,
        -sxx - syy + szz,
    );
    let eigen = n.symmetric_eigen();
    let best = eigen.eigenvalues.imax();
    let q = eigen.eigenvectors.column(best);
    let rotation =
        UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q[0], q[1], q[2], q[3]))
            .to_rotation_matrix();
    let translation = mean_y - rotation * mean_x;
    Ok(Sim3::new(rotation, translation, 1.0))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::sim3::Sim3Tangent;
    use proptest::prelude::*;

    fn cloud(seed_points: &[(f64, f64, f64)]) -> Vec<Vector3<f64>> {
        seed_points
            .iter()
            .map(|&(x, y, z)| Vector3::new(x, y, z))
            .collect()
    }

    fn points() -> impl Strategy<Value = Vec<(f64, f64, f64)>> {
        prop::collection::vec((-5.0..5.0, -5.0..5.0, -5.0..5.0), 4..40)
    }

    fn transform() -> impl Strategy<Value = Sim3> {
        (
            (-3.0..3.0, -3.0..3.0, -3.0..3.0),
            (-1.5..1.5, -1.5..1.5, -1.5..1.5),
            -1.0..1.0f64,
        )
            .prop_map(|((a, b, c), (d, e, f), sigma)| {
                Sim3::exp(&Sim3Tangent {
                    rho: Vector3::new(a, b, c),
                    phi: Vector3::new(d, e, f),
                    sigma,
                })
            })
    }

    /// Points spread in all three directions, so that the alignment is unique.
    fn well_spread(points: &[Vector3<f64>]) -> bool {
        let mean = centroid(points);
        let mut cov = Matrix3::zeros();
        for p in points {
            cov += (p - mean) * (p - mean).transpose();
        }
        cov.symmetric_eigenvalues().min() > 0.5
    }

    proptest! {
        #[test]
        fn umeyama_recovers_a_similarity(raw in points(), truth in transform()) {
            let source = cloud(&raw);
            prop_assume!(well_spread(&source));
            let target: Vec<_> = source.iter().map(|p| truth.transform_point(p)).collect();
            let found = umeyama(&source, &target, AlignmentKind::Sim3).unwrap();
            prop_assert!((found.scale - truth.scale).abs() < 1e-9);
            prop_assert!((found.rotation.matrix() - truth.rotation.matrix()).norm() < 1e-9);
            prop_assert!((found.translation - truth.translation).norm() < 1e-8);
        }

        #[test]
        fn horn_equals_umeyama_rigid(raw in points(), truth in transform(), noise in -0.1..0.1f64) {
            let source = cloud(&raw);
            prop_assume!(well_spread(&source));
            let target: Vec<_> = source.iter().enumerate()
                .map(|(i, p)| truth.transform_point(p) + Vector3::repeat(noise * ((i % 3) as f64 - 1.0)))
                .collect();
            let a = umeyama(&source, &target, AlignmentKind::Se3).unwrap();
            let b = horn(&source, &target).unwrap();
            prop_assert!((a.rotation.matrix() - b.rotation.matrix()).norm() < 1e-8);
            prop_assert!((a.translation - b.translation).norm() < 1e-7);
        }
    }

    #[test]
    fn errors_on_bad_input() {
        let one = vec![Vector3::zeros()];
        assert_eq!(
            umeyama(&one, &one, AlignmentKind::Se3),
            Err(AlignmentError::TooFewPoints { needed: 2, got: 1 })
        );
        let two = vec![Vector3::zeros(), Vector3::x()];
        assert!(matches!(
            umeyama(&one, &two, AlignmentKind::Se3),
            Err(AlignmentError::LengthMismatch { .. })
        ));
        let same = vec![Vector3::new(1.0, 2.0, 3.0); 5];
        assert_eq!(
            umeyama(&same, &same, AlignmentKind::Sim3),
            Err(AlignmentError::Degenerate)
        );
    }

    #[test]
    fn reflection_is_not_returned() {
        // A mirrored target: the best proper rotation must still have det +1.
        let source = cloud(&[
            (1.0, 0.0, 0.0),
            (0.0, 1.0, 0.0),
            (0.0, 0.0, 1.0),
            (1.0, 1.0, 1.0),
        ]);
        let target: Vec<_> = source
            .iter()
            .map(|p| Vector3::new(-p.x, p.y, p.z))
            .collect();
        let found = umeyama(&source, &target, AlignmentKind::Se3).unwrap();
        assert!((found.rotation.matrix().determinant() - 1.0).abs() < 1e-12);
    }
}
