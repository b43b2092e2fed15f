//! Depth registration: a depth image in the depth camera's own geometry (RealSense and
//! Azure Kinect record it so) re-sampled into the colour camera, as `rs2::align` does.
//!
//! Each depth pixel \((u, v)\) with depth \(z\) covers the square between its corners
//! \((u \pm \tfrac12, v \pm \tfrac12)\). Both corners are undistorted with the depth
//! camera's Brown-Conrady model, lifted to depth \(z\), moved into the colour camera by
//! \(T_{cd}\) (`colour_from_depth`), projected and distorted with the colour camera's
//! model; the colour pixels whose centres lie between the two images of the corners (a
//! half-open box, so that neighbouring footprints, which share corners, cover each centre
//! once) get the depth of the pixel centre's point in the colour camera,
//! \(z_c = (T_{cd}\, z\, \bar x)_z\). (`rs2::align` rounds the corners instead, which
//! gives a centre the nearest of up to four footprints' depths: on a slanted surface, a
//! bias of up to one pixel's depth step.) Where
//! several depth pixels land on one colour pixel the nearest wins (a z-buffer), so a
//! foreground edge hides the background behind it.

use nalgebra::{Isometry3, Point3, Vector2, Vector3};

use crate::geometry::camera::PinholeCamera;
use crate::io::image_files::DepthImage;

/// A depth camera's image resampled into a colour camera.
#[derive(Debug, Clone)]
pub struct Registration {
    colour: PinholeCamera,
    /// Whether the colour camera has a lens model to apply.
    colour_distorted: bool,
    /// \(t_{cd}\), the translation of `colour_from_depth`.
    translation: Vector3<f64>,
    depth_size: (u32, u32),
    /// The depth pixels' corners as rays turned into the colour camera,
    /// \(R_{cd}\,(x, y, 1)^\top\) with \((x, y)\) undistorted and normalised, row-major
    /// over \((w + 1) \times (h + 1)\): the corner at depth \(z\) is \(z\, R_{cd}\bar x +
    /// t_{cd}\) in the colour camera.
    corners: Vec<Vector3<f64>>,
    /// The depth (z) component of the same for the pixels' centres, row-major over
    /// \(w \times h\): a centre at depth \(z\) lies at depth \(z\,(R_{cd}\bar x)_z +
    /// t_{cd,z}\) in the colour camera.
    centre_z: Vec<f64>,
}

/// \(\lceil x \rceil\) without a call into libm (which `f64::ceil` is on a baseline
/// x86-64 build: a third of the registration's time). Truncation is the ceiling for
/// negative values; NaN gives 0 and infinities saturate, as `as` does.
fn ceil(x: f64) -> i64 {
    let truncated = x as i64;
    truncated + i64::from((truncated as f64) < x)
}

/// The normalised ideal coordinates \((x, y)\) of a (distorted) pixel of `camera`.
fn normalised(camera: &PinholeCamera, pixel: Vector2<f64>) -> Vector2<f64> {
    let ideal = camera.undistort(&pixel);
    Vector2::new(
        (ideal.x - camera.cx) / camera.fx,
        (ideal.y - camera.cy) / camera.fy,
    )
}

impl Registration {
    /// Precomputes the depth camera's rays, turned into the colour camera.
    pub fn new(
        depth: &PinholeCamera,
        colour: &PinholeCamera,
        colour_from_depth: Isometry3<f64>,
    ) -> Self {
        let (w, h) = (depth.width, depth.height);
        let turned = |p: Vector2<f64>| {
            let ray = normalised(depth, p);
            colour_from_depth.rotation * Vector3::new(ray.x, ray.y, 1.0)
        };
        let corners = (0..=h)
            .flat_map(|v| (0..=w).map(move |u| Vector2::new(u as f64 - 0.5, v as f64 - 0.5)))
            .map(turned)
            .collect();
        let centre_z = (0..h)
            .flat_map(|v| (0..w).map(move |u| Vector2::new(u as f64, v as f64)))
            .map(|p| turned(p).z)
            .collect();
        Self {
            colour: *colour,
            colour_distorted: !colour.is_undistorted(),
            translation: colour_from_depth.translation.vector,
            depth_size: (w, h),
            corners,
            centre_z,
        }
    }

    /// The point in the colour camera of a turned ray at depth `z`.
    fn to_colour(&self, turned: &Vector3<f64>, z: f64) -> Point3<f64> {
        Point3::from(turned * z + self.translation)
    }

    /// The (distorted) colour pixel of a point in the colour camera.
    fn pixel(&self, p: &Point3<f64>) -> Vector2<f64> {
        let ideal = self.colour.project(&p.coords);
        if self.colour_distorted {
            self.colour.distort(&ideal)
        } else {
            ideal
        }
    }

    /// `depth` (in the depth camera, of the size given to [`Registration::new`])
    /// resampled into the colour camera; `None` when its size is another.
    pub fn apply(&self, depth: &DepthImage) -> Option<DepthImage> {
        let (w, h) = (self.depth_size.0 as usize, self.depth_size.1 as usize);
        if (depth.width as usize, depth.height as usize) != (w, h) {
            return None;
        }
        let (cw, ch) = (self.colour.width as usize, self.colour.height as usize);
        let mut out = vec![f32::INFINITY; cw * ch];
        let stride = w + 1;
        for v in 0..h {
            let row = &depth.metres[v * w..(v + 1) * w];
            let centre_z = &self.centre_z[v * w..(v + 1) * w];
            let top = &self.corners[v * stride..(v + 1) * stride];
            let bottom = &self.corners[(v + 1) * stride..(v + 2) * stride];
            for u in 0..w {
                let z = row[u] as f64;
                if z.is_nan() || z <= 0.0 {
                    continue;
                }
                let zc = z * centre_z[u] + self.translation.z;
                if zc <= 0.0 {
                    continue;
                }
                let a = self.pixel(&self.to_colour(&top[u], z));
                let b = self.pixel(&self.to_colour(&bottom[u + 1], z));
                fill(&mut out, (cw, ch), (a, b), zc as f32);
            }
        }
        let metres = out
            .into_iter()
            .map(|z| if z.is_finite() { z } else { 0.0 })
            .collect();
        Some(DepthImage {
            width: cw as u32,
            height: ch as u32,
            metres,
        })
    }
}

/// Gives the colour pixels whose centres lie in `[min, max)` of the corners' images
/// `a`, `b` the depth `z` where it is nearer than theirs (footprints that share corners
/// tile the image, so each centre is covered once).
fn fill(out: &mut [f32], (cw, ch): (usize, usize), (a, b): (Vector2<f64>, Vector2<f64>), z: f32) {
    let (cw, ch) = (cw as i64, ch as i64);
    let (x0, x1) = (
        ceil(a.x.min(b.x)).max(0),
        (ceil(a.x.max(b.x)) - 1).min(cw - 1),
    );
    let (y0, y1) = (
        ceil(a.y.min(b.y)).max(0),
        (ceil(a.y.max(b.y)) - 1).min(ch - 1),
    );
    if x0 > x1 {
        return;
    }
    for y in y0..=y1 {
        let row = (y * cw) as usize;
        for cell in &mut out[row + x0 as usize..=row + x1 as usize] {
            *cell = cell.min(z);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Translation3, UnitQuaternion, Vector3};

    fn camera(f: f64, w: u32, h: u32, distortion: [f64; 5]) -> PinholeCamera {
        PinholeCamera {
            fx: f,
            fy: f,
            cx: w as f64 / 2.0 - 0.5,
            cy: h as f64 / 2.0 - 0.5,
            width: w,
            height: h,
            distortion,
            rational: [0.0; 3],
        }
    }

    /// A wall at 2 m seen by a distorted depth camera 25 mm beside the colour camera
    /// lands at 2 m in the colour camera, filling it but for the side the depth camera
    /// does not see.
    #[test]
    fn the_ceiling_without_libm_is_the_ceiling() {
        for x in [-3.5, -3.0, -0.2, 0.0, 0.2, 1.0, 1.0000001, 639.5, f64::NAN] {
            let expected = if x.is_nan() { 0 } else { x.ceil() as i64 };
            assert_eq!(ceil(x), expected, "{x}");
        }
    }

    #[test]
    fn a_wall_seen_from_the_side_lands_at_its_depth() {
        let depth_camera = camera(300.0, 160, 120, [0.05, -0.02, 0.0, 0.0, 0.0]);
        let colour = camera(320.0, 160, 120, [0.0; 5]);
        let colour_from_depth = Isometry3::from_parts(
            Translation3::new(0.025, 0.0, 0.0),
            UnitQuaternion::identity(),
        );
        let registration = Registration::new(&depth_camera, &colour, colour_from_depth);
        let mut wall = DepthImage::new(160, 120);
        wall.metres.iter_mut().for_each(|z| *z = 2.0);
        let out = registration.apply(&wall).unwrap();
        let valid: Vec<f32> = out.metres.iter().copied().filter(|&z| z > 0.0).collect();
        assert!(valid.iter().all(|z| (z - 2.0).abs() < 1e-4));
        assert!(
            valid.len() as f64 > 0.9 * out.metres.len() as f64,
            "{} of {}",
            valid.len(),
            out.metres.len()
        );
        // A closer box in front: the z-buffer keeps the box where both land.
        for v in 50..70 {
            for u in 70..90 {
                wall.metres[v * 160 + u] = 1.0;
            }
        }
        let out = registration.apply(&wall).unwrap();
        let near = out
            .metres
            .iter()
            .filter(|&&z| (z - 1.0).abs() < 1e-4)
            .count();
        assert!(
            (300..600).contains(&near),
            "{near} colour pixels on the box"
        );
        // A rotation turns depth: the centre pixel of a 2 m wall, the camera turned 10°.
        let turned = Isometry3::from_parts(
            Translation3::identity(),
            UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 0.17),
        );
        let registration = Registration::new(&depth_camera, &colour, turned);
        assert!(
            registration.apply(&DepthImage::new(10, 10)).is_none(),
            "another size"
        );
        let out = registration.apply(&wall).unwrap();
        assert!(out
            .metres
            .iter()
            .any(|&z| z > 0.0 && (z - 2.0).abs() > 0.01));
    }
}
