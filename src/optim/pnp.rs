//! Camera pose from 2-D/3-D correspondences: EPnP (Lepetit, Moreno-Noguer and Fua,
//! IJCV 2009) inside RANSAC, as ORB-SLAM's relocalisation uses it.
//!
//! EPnP writes each world point as a barycentric combination of four control points,
//! \(X_i = \sum_j \alpha_{ij} c_j\) (the centroid and the principal axes). In the
//! camera frame the same \(\alpha_{ij}\) hold, and each normalised observation
//! \((x_i, y_i)\) gives two linear equations in the 12 camera-frame control
//! coordinates: \(\sum_j \alpha_{ij} (c^c_{j,x} - x_i c^c_{j,z}) = 0\) and likewise for
//! \(y\). The solution lies in the null space of that \(2n \times 12\) matrix \(M\):
//! \(x = \sum_{k=1}^{N} \beta_k v_k\) with \(v_k\) the eigenvectors of \(M^\top M\) of
//! smallest eigenvalue; the \(\beta_k\) follow from keeping the six distances between
//! control points. Cases \(N = 1, 2, 3\) are solved and the pose (by absolute
//! orientation between \(X_i\) and their camera-frame positions) with the smallest
//! reprojection error is kept.

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, SymmetricEigen, Vector2, Vector3};

use super::ransac::{ransac, Estimator, Redraw, Rounds};
use crate::geometry::alignment::{umeyama, AlignmentKind};
use crate::geometry::se3::{self, Se3};
use crate::random::Rng;

/// One correspondence: a world point and its normalised image coordinates
/// \(((u - c_x)/f_x, (v - c_y)/f_y)\).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    /// The point in the world frame.
    pub world: Vector3<f64>,
    /// Its observation in normalised coordinates.
    pub normalised: Vector2<f64>,
}

/// The six control point pairs whose distances fix the \(\beta\)s.
const PAIRS: [(usize, usize); 6] = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)];

/// EPnP on at least 4 correspondences (not all on a line); `None` when degenerate.
pub fn epnp(points: &[Correspondence]) -> Option<Se3> {
    let n = points.len();
    if n < 4 {
        return None;
    }
    // Control points: centroid and principal axes scaled by their spread.
    let centroid = points.iter().map(|p| p.world).sum::<Vector3<f64>>() / n as f64;
    let mut covariance = Matrix3::zeros();
    for p in points {
        let d = p.world - centroid;
        covariance += d * d.transpose();
    }
    let eigen = SymmetricEigen::new(covariance / n as f64);
    let mut control = [centroid; 4];
    for k in 0..3 {
        let spread = eigen.eigenvalues[k].max(0.0).sqrt();
        if spread < 1e-9 {
            return None;
        }
        control[k + 1] = centroid + eigen.eigenvectors.column(k) * spread;
    }
    let basis = Matrix3::from_columns(&[
        control[1] - centroid,
        control[2] - centroid,
        control[3] - centroid,
    ]);
    let basis_inv = basis.try_inverse()?;
    let alphas: Vec<[f64; 4]> = points
        .iter()
        .map(|p| {
            let a = basis_inv * (p.world - centroid);
            [1.0 - a.x - a.y - a.z, a.x, a.y, a.z]
        })
        .collect();
    let mut m = DMatrix::<f64>::zeros(2 * n, 12);
    for (i, (p, a)) in points.iter().zip(&alphas).enumerate() {
        for j in 0..4 {
            m[(2 * i, 3 * j)] = a[j];
            m[(2 * i, 3 * j + 2)] = -a[j] * p.normalised.x;
            m[(2 * i + 1, 3 * j + 1)] = a[j];
            m[(2 * i + 1, 3 * j + 2)] = -a[j] * p.normalised.y;
        }
    }
    let mtm: SMatrix<f64, 12, 12> = SMatrix::from_iterator((m.transpose() * &m).iter().copied());
    let eigen = SymmetricEigen::new(mtm);
    let mut order: Vec<usize> = (0..12).collect();
    order.sort_by(|&a, &b| eigen.eigenvalues[a].total_cmp(&eigen.eigenvalues[b]));
    let v: Vec<DVector<f64>> = order[..3]
        .iter()
        .map(|&k| DVector::from_iterator(12, eigen.eigenvectors.column(k).iter().copied()))
        .collect();
    let world_distance2: Vec<f64> = PAIRS
        .iter()
        .map(|&(a, b)| (control[a] - control[b]).norm_squared())
        .collect();
    let mut best: Option<(f64, Se3)> = None;
    for dims in 1..=3 {
        let Some(betas) = solve_betas(&v[..dims], &world_distance2) else {
            continue;
        };
        let mut x = DVector::<f64>::zeros(12);
        for (beta, vk) in betas.iter().zip(&v) {
            x += vk * *beta;
        }
        let Some(pose) = pose_from_control(points, &alphas, &x) else {
            continue;
        };
        let error = reprojection_error(points, &pose);
        if best.as_ref().is_none_or(|(e, _)| error < *e) {
            best = Some((error, pose));
        }
    }
    best.map(|(_, pose)| pose)
}

/// The difference of control points `a` and `b` in a 12-vector.
fn difference(v: &DVector<f64>, a: usize, b: usize) -> Vector3<f64> {
    Vector3::new(
        v[3 * a] - v[3 * b],
        v[3 * a + 1] - v[3 * b + 1],
        v[3 * a + 2] - v[3 * b + 2],
    )
}

/// The \(\beta\)s for a null space of dimension `v.len()` from the six distances,
/// linearised in the products \(\beta_k \beta_l\).
fn solve_betas(v: &[DVector<f64>], world_distance2: &[f64]) -> Option<Vec<f64>> {
    let dims = v.len();
    let products: Vec<(usize, usize)> = (0..dims)
        .flat_map(|k| (k..dims).map(move |l| (k, l)))
        .collect();
    let mut l = DMatrix::<f64>::zeros(6, products.len());
    let rho = DVector::from_column_slice(world_distance2);
    for (row, &(a, b)) in PAIRS.iter().enumerate() {
        let d: Vec<Vector3<f64>> = v.iter().map(|vk| difference(vk, a, b)).collect();
        for (col, &(k, m)) in products.iter().enumerate() {
            l[(row, col)] = if k == m {
                d[k].norm_squared()
            } else {
                2.0 * d[k].dot(&d[m])
            };
        }
    }
    let svd = l.clone().svd(true, true);
    let products_solution = svd.solve(&rho, 1e-12).ok()?;
    // beta_k from the squares on the diagonal, signs from the cross products with beta_0.
    let square = |k: usize| {
        products
            .iter()
            .position(|&p| p == (k, k))
            .map(|i| products_solution[i])
    };
    let b00 = square(0)?;
    let mut betas = vec![b00.abs().sqrt(); dims];
    let sign0 = if b00 < 0.0 { -1.0 } else { 1.0 };
    for (k, beta) in betas.iter_mut().enumerate().skip(1) {
        let cross = products.iter().position(|&p| p == (0, k))?;
        let bkk = square(k)?.abs().sqrt();
        *beta = if products_solution[cross] * sign0 < 0.0 {
            -bkk
        } else {
            bkk
        };
    }
    if sign0 < 0.0 {
        betas.iter_mut().for_each(|b| *b = -*b);
    }
    Some(betas)
}

/// The pose from camera-frame control points `x` (sign fixed so points are in front).
fn pose_from_control(
    points: &[Correspondence],
    alphas: &[[f64; 4]],
    x: &DVector<f64>,
) -> Option<Se3> {
    let camera_point = |a: &[f64; 4], sign: f64| -> Vector3<f64> {
        (0..4)
            .map(|j| Vector3::new(x[3 * j], x[3 * j + 1], x[3 * j + 2]) * a[j] * sign)
            .sum()
    };
    let in_front = alphas
        .iter()
        .filter(|a| camera_point(a, 1.0).z > 0.0)
        .count();
    let sign = if 2 * in_front >= alphas.len() {
        1.0
    } else {
        -1.0
    };
    let source: Vec<Vector3<f64>> = points.iter().map(|p| p.world).collect();
    let target: Vec<Vector3<f64>> = alphas.iter().map(|a| camera_point(a, sign)).collect();
    let transform = umeyama(&source, &target, AlignmentKind::Se3).ok()?;
    Some(se3::from_parts(
        transform.translation,
        *transform.rotation.matrix(),
    ))
}

/// Mean squared reprojection error in normalised coordinates.
fn reprojection_error(points: &[Correspondence], camera_from_world: &Se3) -> f64 {
    points
        .iter()
        .map(|p| {
            let c = camera_from_world * nalgebra::Point3::from(p.world);
            if c.z <= 0.0 {
                return 1e3;
            }
            (Vector2::new(c.x / c.z, c.y / c.z) - p.normalised).norm_squared()
        })
        .sum::<f64>()
        / points.len() as f64
}

/// RANSAC settings: `thresholds[i]` is correspondence i's largest squared error in
/// normalised coordinates (the chi-square gate times \(\sigma^2 / f^2\)).
#[derive(Debug, Clone)]
pub struct Ransac {
    /// Hypotheses drawn.
    pub iterations: usize,
    /// Correspondences per hypothesis (EPnP needs 4 or more).
    pub sample: usize,
    /// The fewest inliers a pose needs.
    pub min_inliers: usize,
    /// The seed of the samples (the same samples in every run).
    pub seed: u64,
}

impl Default for Ransac {
    fn default() -> Self {
        Self {
            iterations: 300,
            sample: 5,
            min_inliers: 15,
            seed: 1,
        }
    }
}

/// EPnP on the correspondences, a correspondence an inlier when it reprojects within
/// its threshold in normalised coordinates.
struct EpnpEstimator<'a> {
    points: &'a [Correspondence],
    thresholds: &'a [f64],
    sample: usize,
}

impl Estimator for EpnpEstimator<'_> {
    type Model = Se3;

    fn count(&self) -> usize {
        self.points.len()
    }

    fn sample_size(&self) -> usize {
        self.sample
    }

    fn fit(&self, indices: &[usize]) -> Option<Se3> {
        let subset: Vec<Correspondence> = indices.iter().map(|&i| self.points[i]).collect();
        epnp(&subset)
    }

    fn inliers(&self, pose: &Se3) -> Vec<usize> {
        (0..self.points.len())
            .filter(|&i| {
                let (p, t) = (&self.points[i], self.thresholds[i]);
                let c = pose * nalgebra::Point3::from(p.world);
                c.z > 0.0 && (Vector2::new(c.x / c.z, c.y / c.z) - p.normalised).norm_squared() < t
            })
            .collect()
    }
}

/// EPnP in RANSAC ([`crate::optim::ransac`]), the best hypothesis refitted once on its
/// inliers; returns the pose and the inlier flags, or `None` with fewer than
/// `min_inliers` inliers.
pub fn epnp_ransac(
    points: &[Correspondence],
    thresholds: &[f64],
    settings: &Ransac,
) -> Option<(Se3, Vec<bool>)> {
    if points.len() < settings.min_inliers.max(settings.sample) {
        return None;
    }
    let estimator = EpnpEstimator {
        points,
        thresholds,
        sample: settings.sample,
    };
    let rounds = Rounds {
        iterations: settings.iterations,
        min_inliers: settings.min_inliers,
        refits: 1,
    };
    let mut rng = Rng::new(settings.seed);
    let (pose, inliers) = ransac(&estimator, &mut Redraw(&mut rng), rounds)?;
    let mut flags = vec![false; points.len()];
    inliers.iter().for_each(|&i| flags[i] = true);
    Some((pose, flags))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Vector6};
    use proptest::prelude::{prop_assert, proptest};

    fn correspondences(pose: &Se3, rng: &mut Rng, n: usize) -> Vec<Correspondence> {
        (0..n)
            .map(|_| {
                let camera = Vector3::new(
                    rng.range(-1.0, 1.0),
                    rng.range(-0.8, 0.8),
                    rng.range(1.0, 4.0),
                );
                let world = (pose.inverse() * Point3::from(camera)).coords;
                Correspondence {
                    world,
                    normalised: Vector2::new(camera.x / camera.z, camera.y / camera.z),
                }
            })
            .collect()
    }

    fn pose_error(a: &Se3, b: &Se3) -> f64 {
        se3::log(&(a * b.inverse())).norm()
    }

    proptest! {
        /// Exact correspondences give back the pose.
        #[test]
        fn epnp_recovers_the_pose(xi in se3::tests::tangent(2.0, 3.0), seed in 0u64..1000) {
            let pose = se3::exp(&xi);
            let mut rng = Rng::new(seed);
            let points = correspondences(&pose, &mut rng, 8);
            let found = epnp(&points).unwrap();
            prop_assert!(pose_error(&found, &pose) < 1e-6, "{}", pose_error(&found, &pose));
        }
    }

    #[test]
    fn ransac_finds_the_pose_among_forty_percent_outliers() {
        let pose = se3::exp(&Vector6::new(0.3, -0.2, 0.5, 0.2, -0.4, 0.1));
        for seed in 1..6 {
            let mut rng = Rng::new(seed);
            let mut points = correspondences(&pose, &mut rng, 100);
            let noise = 0.5 / 535.0; // half a pixel
            for (i, p) in points.iter_mut().enumerate() {
                p.normalised += Vector2::new(rng.normal(), rng.normal()) * noise;
                if i % 5 < 2 {
                    p.normalised += Vector2::new(rng.range(-0.3, 0.3), rng.range(-0.3, 0.3));
                }
            }
            let thresholds = vec![5.991 / (535.0 * 535.0); points.len()];
            let (found, inliers) = epnp_ransac(
                &points,
                &thresholds,
                &Ransac {
                    seed,
                    ..Ransac::default()
                },
            )
            .unwrap();
            let count = inliers.iter().filter(|&&b| b).count();
            assert!((55..=62).contains(&count), "seed {seed}: {count} inliers");
            let error = pose_error(&found, &pose);
            assert!(error < 0.01, "seed {seed}: pose error {error}");
        }
    }
}
