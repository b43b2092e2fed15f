//! Where a map point should appear from a pose (ORB-SLAM's visibility test): in front of
//! the camera and inside the image, within its scale-invariance distances
//! \([0.8\,d_{min}, 1.2\,d_{max}]\), seen less than 60° away from its mean viewing
//! direction, and on the pyramid level \(\lceil \log_s (d_{max} / d) \rceil\) at which
//! a point created at \(d_{max}\) on the finest level would appear at distance \(d\).

use nalgebra::Point3;

use super::MapPoint;
use crate::features::ScalePyramid;
use crate::geometry::se3::Se3;
use crate::geometry::stereo_camera::StereoCamera;

/// A predicted view of a map point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct View {
    /// Predicted column (level-0 pixels).
    pub u: f32,
    /// Predicted row.
    pub v: f32,
    /// Predicted right-image coordinate \(u - bf / z\).
    pub right_u: f32,
    /// The pyramid level the point's distance predicts.
    pub level: u8,
    /// Cosine between the viewing ray and the point's mean viewing direction.
    pub view_cos: f64,
}

/// The view of `point` from `camera_from_world` in a `width` x `height` image, if the
/// point passes the visibility test.
pub fn predict_view(
    point: &MapPoint,
    camera_from_world: &Se3,
    camera: &StereoCamera,
    width: f32,
    height: f32,
    pyramid: &ScalePyramid,
) -> Option<View> {
    let p = camera_from_world * Point3::from(point.position);
    if p.z <= 0.0 {
        return None;
    }
    let uvr = camera.project(&p.coords);
    let (u, v) = (uvr.x as f32, uvr.y as f32);
    if !(u >= 0.0 && v >= 0.0 && u < width && v < height) {
        return None;
    }
    // The point less the camera centre, \(X - C = R^T (R X + t)\): no inverse pose.
    let offset = camera_from_world
        .rotation
        .inverse_transform_vector(&p.coords);
    let distance = offset.norm();
    if distance < 0.8 * point.min_distance || distance > 1.2 * point.max_distance {
        return None;
    }
    let view_cos = offset.dot(&point.normal) / distance;
    if view_cos < 0.5 {
        return None;
    }
    let level = ((point.max_distance / distance).ln() / pyramid.scale_factor.ln())
        .ceil()
        .clamp(0.0, pyramid.levels() as f64 - 1.0) as u8;
    Some(View {
        u,
        v,
        right_u: uvr.z as f32,
        level,
        view_cos,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::camera::PinholeCamera;
    use nalgebra::Vector3;

    #[test]
    fn predicts_coarser_levels_for_nearer_points_and_rejects_the_rest() {
        let camera = StereoCamera::new(&PinholeCamera::tum_fr3(), 40.0);
        let pyramid = ScalePyramid::new(8, 1.2);
        let size = (640.0, 480.0);
        // Made at 2 m on level 0: d_max = 2 m, d_min = 2 / 1.2^7.
        let point = MapPoint::new(
            Vector3::new(0.0, 0.0, 2.0),
            [0; 4],
            Vector3::z(),
            (2.0 / 1.2f64.powi(7), 2.0),
            0,
        );
        let at = |z: f64| Se3::translation(0.0, 0.0, z - 2.0);
        assert_eq!(
            predict_view(&point, &at(2.0), &camera, size.0, size.1, &pyramid)
                .unwrap()
                .level,
            0
        );
        // 2 / 1.44 m away: two levels up (1.2^2 = 1.44).
        let near = predict_view(
            &point,
            &at(2.0 / 1.44 + 1e-9),
            &camera,
            size.0,
            size.1,
            &pyramid,
        )
        .unwrap();
        assert_eq!(near.level, 2);
        assert!((near.u - camera.cx as f32).abs() < 1e-3);
        // Beyond 1.2 d_max, behind the camera, or outside the image: not visible.
        assert!(predict_view(&point, &at(2.5), &camera, size.0, size.1, &pyramid).is_none());
        assert!(predict_view(&point, &at(-1.0), &camera, size.0, size.1, &pyramid).is_none());
        let aside = Se3::translation(-3.0, 0.0, 0.0);
        assert!(predict_view(&point, &aside, &camera, size.0, size.1, &pyramid).is_none());
    }
}
