//! New map points by triangulation between a new keyframe and a covisible one (ORB-SLAM
//! §VI-C, ORB-SLAM2 §III-D): keypoints that see no map point yet are matched by
//! descriptor under the epipolar constraint, then placed by linear triangulation where
//! the rays' parallax beats the depth sensor's (else from the better depth), and kept
//! only with positive depth, a small reprojection error in both views and consistent
//! scales.
//!
//! Epipolar constraint: with \(T_{12} = T_{1w} T_{2w}^{-1}\) (rotation \(R_{12}\),
//! translation \(t_{12}\)), \(F_{12} = K^{-\top} [t_{12}]_\times R_{12} K^{-1}\) and a
//! match \((x_1, x_2)\) satisfies \(x_1^\top F_{12} x_2 = 0\): \(x_2\) lies on the line
//! \(l_2 = F_{12}^\top x_1\), within \(\sqrt{3.84}\,\sigma\) of it.

use nalgebra::{Matrix3, Matrix3x4, Matrix4, Point3, Vector2, Vector3};

use crate::features::TH_LOW;
use crate::features::{hamming, ScalePyramid};
use crate::geometry::stereo_camera::StereoCamera;
use crate::map::KeyFrame;
use crate::optim::robust::{CHI2_MONO, CHI2_STEREO};

/// Linear (DLT) triangulation of one point from two views: \(P_1, P_2\) map world
/// points to normalised image coordinates \(x_1, x_2\); the point is the null vector of
/// \(\begin{bmatrix} x_1 P_1^3 - P_1^1 \\ y_1 P_1^3 - P_1^2 \\ x_2 P_2^3 - P_2^1 \\
/// y_2 P_2^3 - P_2^2 \end{bmatrix}\).
pub fn triangulate(
    p1: &Matrix3x4<f64>,
    p2: &Matrix3x4<f64>,
    x1: &Vector2<f64>,
    x2: &Vector2<f64>,
) -> Option<Vector3<f64>> {
    let mut a = Matrix4::zeros();
    a.set_row(0, &(x1.x * p1.row(2) - p1.row(0)));
    a.set_row(1, &(x1.y * p1.row(2) - p1.row(1)));
    a.set_row(2, &(x2.x * p2.row(2) - p2.row(0)));
    a.set_row(3, &(x2.y * p2.row(2) - p2.row(1)));
    let svd = a.svd(false, true);
    let v_t = svd.v_t?;
    let (smallest, _) = svd
        .singular_values
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))?;
    let h = v_t.row(smallest);
    (h[3].abs() > 1e-12).then(|| Vector3::new(h[0] / h[3], h[1] / h[3], h[2] / h[3]))
}

/// A new point: its position and the keypoint index in each of the two keyframes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewPoint {
    /// The point in the world frame.
    pub position: Vector3<f64>,
    /// Its keypoint in the first keyframe.
    pub index1: usize,
    /// Its keypoint in the second keyframe.
    pub index2: usize,
}

fn skew(t: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -t.z, t.y, t.z, 0.0, -t.x, -t.y, t.x, 0.0)
}

fn intrinsics(camera: &StereoCamera) -> Matrix3<f64> {
    Matrix3::new(
        camera.fx, 0.0, camera.cx, 0.0, camera.fy, camera.cy, 0.0, 0.0, 1.0,
    )
}

/// The fundamental matrix \(F_{12} = K^{-\top} [t_{12}]_\times R_{12} K^{-1}\) of the
/// pair and the epipole in image 2 (camera 1's centre seen from camera 2; `None`
/// behind it).
fn epipolar(
    kf1: &KeyFrame,
    kf2: &KeyFrame,
    camera: &StereoCamera,
) -> (Matrix3<f64>, Option<Vector2<f64>>) {
    let t12 = kf1.camera_from_world * kf2.world_from_camera();
    let k = intrinsics(camera);
    let k_inv = k.try_inverse().expect("invertible intrinsics");
    let f12 = k_inv.transpose() * skew(&t12.translation.vector) * t12.rotation.matrix() * k_inv;
    let e2 = kf2.camera_from_world * Point3::from(kf1.centre());
    let epipole2 = (e2.z > 0.0).then(|| {
        Vector2::new(
            camera.fx * e2.x / e2.z + camera.cx,
            camera.fy * e2.y / e2.z + camera.cy,
        )
    });
    (f12, epipole2)
}

/// Matches the unmatched keypoints of `kf1` and `kf2` under the epipolar constraint and
/// triangulates them. `close_depth` is the RGB-D close/far limit in metres; keypoints
/// with a moving probability above `removal_threshold` are left out.
pub fn triangulate_pair(
    kf1: &KeyFrame,
    kf2: &KeyFrame,
    camera: &StereoCamera,
    pyramid: &ScalePyramid,
    close_depth: f32,
    removal_threshold: f32,
) -> Vec<NewPoint> {
    let baseline = camera.bf / camera.fx;
    let (c1, c2) = (kf1.centre(), kf2.centre());
    if (c2 - c1).norm() < baseline {
        return Vec::new();
    }
    let (f12, epipole2) = epipolar(kf1, kf2, camera);
    let (f1, f2) = (&kf1.frame, &kf2.frame);
    // Keypoints the DOP model calls dynamic make no new points.
    let free2: Vec<usize> = (0..f2.len())
        .filter(|&j| kf2.map_points[j].is_none() && f2.moving[j] <= removal_threshold)
        .collect();
    let mut taken2 = vec![false; f2.len()];
    let mut found = Vec::new();
    let (p1, p2) = (projection(kf1), projection(kf2));
    for i in 0..f1.len() {
        if kf1.map_points[i].is_some() || f1.moving[i] > removal_threshold {
            continue;
        }
        // Close points with depth were already made from depth at insertion.
        let stereo1 = f1.depth[i] > 0.0;
        if stereo1 && f1.depth[i] <= close_depth {
            continue;
        }
        let kp1 = &f1.keypoints[i];
        let line = f12.transpose() * Vector3::new(kp1.x as f64, kp1.y as f64, 1.0);
        let norm = (line.x * line.x + line.y * line.y).sqrt();
        if norm < 1e-12 {
            continue;
        }
        let mut best = (TH_LOW + 1, usize::MAX);
        for &j in &free2 {
            if taken2[j] {
                continue;
            }
            let kp2 = &f2.keypoints[j];
            let distance = (line.x * kp2.x as f64 + line.y * kp2.y as f64 + line.z) / norm;
            if distance * distance >= 3.84 * pyramid.sigma2[kp2.level as usize] {
                continue;
            }
            if !stereo1 {
                if let Some(e) = epipole2 {
                    let (dx, dy) = (e.x - kp2.x as f64, e.y - kp2.y as f64);
                    if dx * dx + dy * dy < 100.0 * pyramid.factors[kp2.level as usize] {
                        continue;
                    }
                }
            }
            let d = hamming(&f1.descriptors[i], &f2.descriptors[j]);
            if d < best.0 {
                best = (d, j);
            }
        }
        let j = best.1;
        if j == usize::MAX {
            continue;
        }
        if let Some(position) = place(kf1, kf2, i, j, [&p1, &p2], camera, pyramid) {
            taken2[j] = true;
            found.push(NewPoint {
                position,
                index1: i,
                index2: j,
            });
        }
    }
    found
}

/// The keyframe's \([R \mid t]\) (camera from world) as a 3x4 matrix.
fn projection(kf: &KeyFrame) -> Matrix3x4<f64> {
    kf.camera_from_world
        .to_homogeneous()
        .fixed_view::<3, 4>(0, 0)
        .into_owned()
}

/// Places the point of match `(i, j)` and checks it in both views.
fn place(
    kf1: &KeyFrame,
    kf2: &KeyFrame,
    i: usize,
    j: usize,
    projections: [&Matrix3x4<f64>; 2],
    camera: &StereoCamera,
    pyramid: &ScalePyramid,
) -> Option<Vector3<f64>> {
    let [p1, p2] = projections;
    let (f1, f2) = (&kf1.frame, &kf2.frame);
    let (kp1, kp2) = (&f1.keypoints[i], &f2.keypoints[j]);
    let normalised = |x: f32, y: f32| {
        Vector2::new(
            (x as f64 - camera.cx) / camera.fx,
            (y as f64 - camera.cy) / camera.fy,
        )
    };
    let (x1, x2) = (normalised(kp1.x, kp1.y), normalised(kp2.x, kp2.y));
    let ray1 = kf1.world_from_camera().rotation * Vector3::new(x1.x, x1.y, 1.0);
    let ray2 = kf2.world_from_camera().rotation * Vector3::new(x2.x, x2.y, 1.0);
    let cos_rays = ray1.dot(&ray2) / (ray1.norm() * ray2.norm());
    let baseline = camera.bf / camera.fx;
    let stereo_cos = |z: f32| {
        if z > 0.0 {
            (2.0 * (baseline / 2.0).atan2(z as f64)).cos()
        } else {
            2.0
        }
    };
    let (cos1, cos2) = (stereo_cos(f1.depth[i]), stereo_cos(f2.depth[j]));
    let (stereo1, stereo2) = (f1.depth[i] > 0.0, f2.depth[j] > 0.0);
    let position: Vector3<f64> =
        if cos_rays < cos1.min(cos2) && cos_rays > 0.0 && (stereo1 || stereo2 || cos_rays < 0.9998)
        {
            triangulate(p1, p2, &x1, &x2)?
        } else if stereo1 && cos1 < cos2 {
            let z = f1.depth[i] as f64;
            (kf1.world_from_camera() * Point3::new(x1.x * z, x1.y * z, z)).coords
        } else if stereo2 && cos2 < cos1 {
            let z = f2.depth[j] as f64;
            (kf2.world_from_camera() * Point3::new(x2.x * z, x2.y * z, z)).coords
        } else {
            return None;
        };
    if misses(kf1, i, &position, camera, pyramid) || misses(kf2, j, &position, camera, pyramid) {
        return None;
    }
    // Scale consistency: the distance ratio must agree with the level ratio.
    let (d1, d2) = (
        (position - kf1.centre()).norm(),
        (position - kf2.centre()).norm(),
    );
    if d1 == 0.0 || d2 == 0.0 {
        return None;
    }
    let ratio_distance = d2 / d1;
    let ratio_octave = pyramid.factors[kp1.level as usize] / pyramid.factors[kp2.level as usize];
    let factor = 1.5 * pyramid.scale_factor;
    if ratio_distance * factor < ratio_octave || ratio_distance > ratio_octave * factor {
        return None;
    }
    Some(position)
}

/// Whether `position` lies behind `kf` or reprojects off its keypoint `index`, beyond
/// the \(\chi^2\) gate (stereo with a right column, else mono).
fn misses(
    kf: &KeyFrame,
    index: usize,
    position: &Vector3<f64>,
    camera: &StereoCamera,
    pyramid: &ScalePyramid,
) -> bool {
    let p = kf.camera_from_world * Point3::from(*position);
    if p.z <= 0.0 {
        return true;
    }
    let kp = &kf.frame.keypoints[index];
    let predicted = camera.project(&p.coords);
    let right = kf.frame.right_u[index];
    let (ex, ey) = (predicted.x - kp.x as f64, predicted.y - kp.y as f64);
    let information = pyramid.inverse_sigma2[kp.level as usize];
    if right > 0.0 {
        let er = predicted.z - right as f64;
        (ex * ex + ey * ey + er * er) * information > CHI2_STEREO
    } else {
        (ex * ex + ey * ey) * information > CHI2_MONO
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::se3::{self, Se3};
    use nalgebra::Vector6;
    use proptest::prelude::*;

    fn projection(pose: &Se3) -> Matrix3x4<f64> {
        pose.to_homogeneous().fixed_view::<3, 4>(0, 0).into_owned()
    }

    fn normalised(pose: &Se3, x: &Vector3<f64>) -> Vector2<f64> {
        let p = pose * Point3::from(*x);
        Vector2::new(p.x / p.z, p.y / p.z)
    }

    proptest! {
        /// Exact observations from two poses with a real baseline give back the point.
        #[test]
        fn triangulation_recovers_the_point(
            xi in se3::tests::tangent(0.5, 0.3),
            x in -1.0f64..1.0, y in -1.0f64..1.0, z in 1.5f64..5.0,
        ) {
            let point = Vector3::new(x, y, z);
            let pose1 = Se3::identity();
            let pose2 = se3::exp(&(xi + Vector6::new(0.3, 0.0, 0.0, 0.0, 0.0, 0.0)));
            prop_assume!((pose2 * Point3::from(point)).z > 0.5);
            prop_assume!(pose2.inverse().translation.vector.norm() > 0.1);
            let found = triangulate(
                &projection(&pose1),
                &projection(&pose2),
                &normalised(&pose1, &point),
                &normalised(&pose2, &point),
            )
            .unwrap();
            prop_assert!((found - point).norm() < 1e-6, "{found} vs {point}");
        }
    }
}
