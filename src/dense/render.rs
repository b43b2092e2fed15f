//! Pictures of a dense map: a perspective view from a camera pose and a top view (a
//! floor plan: what lies above the cameras is cut away), points splatted with a depth
//! buffer; two maps side by side with their ghosts in red.

use image::{Rgb, RgbImage};
use nalgebra::{Matrix3, Point3, Vector3};

use super::mask_layers::MaskLayer;
use crate::geometry::camera::PinholeCamera;
use crate::geometry::mesh::Mesh;
use crate::geometry::se3::{self, Se3};

/// Where the views look from.
#[derive(Debug, Clone, Copy)]
pub struct Viewpoint {
    /// A camera pose to render the perspective view from (`camera_from_world`).
    pub camera_from_world: Se3,
    /// The world's up direction (unit).
    pub up: Vector3<f64>,
    /// Points higher than this along `up` are left out of the top view.
    pub cut_height: f64,
}

impl Viewpoint {
    /// From camera poses (`world_from_camera`): up is the mean of the cameras' \(-y\)
    /// axes (image up), the perspective camera is the first pose pulled back 1 m and
    /// raised 0.5 m, looking at the same point; the cut is 0.3 m above the highest camera.
    pub fn from_cameras(world_from_cameras: &[Se3]) -> Option<Self> {
        let read = |each: &mut dyn FnMut(&Se3)| {
            world_from_cameras.iter().for_each(each);
            Ok::<_, std::convert::Infallible>(())
        };
        match Self::from_camera_reads(read) {
            Ok(view) => view,
            Err(never) => match never {},
        }
    }

    /// [`Viewpoint::from_cameras`] from cameras read twice, not held: `read(each)`
    /// hands every `world_from_camera` to `each`, in the same order each time.
    pub fn from_camera_reads<E>(
        mut read: impl FnMut(&mut dyn FnMut(&Se3)) -> Result<(), E>,
    ) -> Result<Option<Self>, E> {
        let (mut first, mut up) = (None, Vector3::zeros());
        read(&mut |p: &Se3| {
            first.get_or_insert(*p);
            up += -p.rotation.matrix().column(1).into_owned();
        })?;
        let (Some(first), Some(up)) = (first, up.try_normalize(1e-9)) else {
            return Ok(None);
        };
        let mut highest = f64::NEG_INFINITY;
        read(&mut |p: &Se3| highest = highest.max(p.translation.vector.dot(&up)))?;
        let forward = first.rotation.matrix().column(2).into_owned();
        let target = first.translation.vector + forward * 2.0;
        let eye = first.translation.vector - forward * 1.0 + up * 0.5;
        Ok(look_at(&eye, &target, &up).map(|camera_from_world| Self {
            camera_from_world,
            up,
            cut_height: highest + 0.3,
        }))
    }

    /// Without poses: up is the axis of least extent of the points, the camera stands
    /// outside the bounding box on a diagonal, looking at its centre.
    pub fn from_points(points: &[[f32; 3]]) -> Option<Self> {
        let (min, max) = bounds(points)?;
        let extent = max - min;
        let axis = extent.imin();
        let mut up = Vector3::zeros();
        up[axis] = 1.0;
        let centre = (min + max) / 2.0;
        let side = (extent - extent.component_mul(&up)).norm().max(0.1);
        let horizontal = (Vector3::repeat(1.0) - up).normalize();
        let eye = centre - horizontal * side + up * side * 0.6;
        Some(Self {
            camera_from_world: look_at(&eye, &centre, &up)?,
            up,
            cut_height: centre.dot(&up) + 0.25 * extent[axis],
        })
    }
}

fn bounds(points: &[[f32; 3]]) -> Option<(Vector3<f64>, Vector3<f64>)> {
    let first = Vector3::from(points.first()?.map(f64::from));
    Some(points.iter().fold((first, first), |(lo, hi), p| {
        let p = Vector3::from(p.map(f64::from));
        (lo.inf(&p), hi.sup(&p))
    }))
}

/// `camera_from_world` of a camera at `eye` looking at `target` (image up along `up`).
fn look_at(eye: &Vector3<f64>, target: &Vector3<f64>, up: &Vector3<f64>) -> Option<Se3> {
    let z = (target - eye).try_normalize(1e-9)?;
    let x = (-up).cross(&z).try_normalize(1e-9)?;
    let y = z.cross(&x);
    let world_from_camera = se3::from_parts(*eye, Matrix3::from_columns(&[x, y, z]));
    Some(world_from_camera.inverse())
}

/// Splats `points` into an image of `camera` from `camera_from_world` (nearest wins,
/// 2x2 pixels a point), on a dark background.
pub fn perspective(
    points: &[[f32; 3]],
    colours: &[[u8; 3]],
    camera_from_world: &Se3,
    camera: &PinholeCamera,
) -> RgbImage {
    let (w, h) = (camera.width, camera.height);
    let mut image = RgbImage::from_pixel(w, h, Rgb([24, 24, 28]));
    let mut depth = vec![f64::INFINITY; (w * h) as usize];
    for (p, c) in points.iter().zip(colours) {
        let q = camera_from_world * Point3::from(p.map(f64::from));
        if q.z <= 0.05 {
            continue;
        }
        let uv = camera.project(&q.coords);
        splat(&mut image, &mut depth, uv.x, uv.y, q.z, *c);
    }
    image
}

fn splat(image: &mut RgbImage, depth: &mut [f64], u: f64, v: f64, z: f64, c: [u8; 3]) {
    let (w, h) = (image.width() as i64, image.height() as i64);
    let (u0, v0) = (u.floor() as i64, v.floor() as i64);
    for dv in 0..2 {
        for du in 0..2 {
            let (x, y) = (u0 + du, v0 + dv);
            if x < 0 || y < 0 || x >= w || y >= h {
                continue;
            }
            let i = (y * w + x) as usize;
            if z < depth[i] {
                depth[i] = z;
                image.put_pixel(x as u32, y as u32, Rgb(c));
            }
        }
    }
}

/// The top view: points below the cut, seen from above along `up`, `size` pixels on
/// the longer side.
pub fn top(points: &[[f32; 3]], colours: &[[u8; 3]], view: &Viewpoint, size: u32) -> RgbImage {
    let up = view.up;
    let a = if up.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = (a - up * a.dot(&up)).normalize();
    let e2 = up.cross(&e1);
    let kept: Vec<(f64, f64, f64, [u8; 3])> = points
        .iter()
        .zip(colours)
        .map(|(p, c)| {
            let p = Vector3::from(p.map(f64::from));
            (p.dot(&e1), p.dot(&e2), p.dot(&up), *c)
        })
        .filter(|&(_, _, h, _)| h <= view.cut_height)
        .collect();
    let fold = |f: fn(f64, f64) -> f64, init: f64, k: usize| {
        kept.iter()
            .map(|p| if k == 0 { p.0 } else { p.1 })
            .fold(init, f)
    };
    let (x0, x1) = (
        fold(f64::min, f64::INFINITY, 0),
        fold(f64::max, f64::NEG_INFINITY, 0),
    );
    let (y0, y1) = (
        fold(f64::min, f64::INFINITY, 1),
        fold(f64::max, f64::NEG_INFINITY, 1),
    );
    let span = (x1 - x0).max(y1 - y0).max(1e-3);
    let scale = (size as f64 - 8.0) / span;
    let (w, h) = (
        ((x1 - x0) * scale) as u32 + 8,
        ((y1 - y0) * scale) as u32 + 8,
    );
    let mut image = RgbImage::from_pixel(w.max(8), h.max(8), Rgb([24, 24, 28]));
    let mut depth = vec![f64::INFINITY; (image.width() * image.height()) as usize];
    for &(x, y, height, c) in &kept {
        let u = (x - x0) * scale + 4.0;
        let v = (y1 - y) * scale + 4.0;
        splat(&mut image, &mut depth, u, v, -height, c);
    }
    image
}

/// Two pictures side by side on one canvas (tops aligned, 8 px apart).
pub fn side_by_side(left: &RgbImage, right: &RgbImage) -> RgbImage {
    let w = left.width() + 8 + right.width();
    let h = left.height().max(right.height());
    let mut canvas = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    image::imageops::replace(&mut canvas, left, 0, 0);
    image::imageops::replace(&mut canvas, right, (left.width() + 8) as i64, 0);
    canvas
}

/// Writes `text` on a dark band along the top of `picture`; without a font (see
/// [`crate::eval::plot::ensure_font`]) the picture stays unlabelled.
pub fn label(picture: &mut RgbImage, text: &str) {
    use plotters::prelude::*;
    if crate::eval::plot::ensure_font().is_err() {
        return;
    }
    let (w, h) = picture.dimensions();
    let root = BitMapBackend::with_buffer(picture.as_mut(), (w, h)).into_drawing_area();
    let band = Rectangle::new([(0, 0), (w as i32, 30)], RGBColor(40, 40, 40).filled());
    let font = ("sans-serif", 19).into_font().color(&WHITE);
    // Drawing on an in-memory buffer fails only on a size mismatch, which cannot happen.
    let _ = root.draw(&band);
    let _ = root.draw(&Text::new(text.to_string(), (10, 6), font));
    let _ = root.present();
}

/// A fused frame's mask beside the frame. Against the ground-truth instance ids of a
/// synthetic frame (0: static): green where a mover is masked, red where the static
/// scene is masked, yellow where a mover is fused, black elsewhere. Without the truth,
/// each masked pixel in its first source's colour ([`MaskLayer::colour`]; white
/// without `sources`) and a pixel the static map released in dark green.
pub fn mask_picture(picture: MaskPicture) -> RgbImage {
    let MaskPicture {
        colour,
        mask,
        truth,
        sources,
    } = picture;
    let (w, h) = colour.dimensions();
    let masked = |i: usize| mask.is_some_and(|m| m[i]);
    let source = |i: usize| sources.and_then(|s| MaskLayer::first_of(s[i]));
    let picture = RgbImage::from_fn(w, h, |u, v| {
        let i = (v * w + u) as usize;
        match (masked(i), truth.map(|t| t[i] != 0)) {
            (true, Some(true)) => Rgb([0, 200, 0]),
            (true, Some(false)) => Rgb([220, 0, 0]),
            (false, Some(true)) => Rgb([255, 230, 0]),
            (true, None) => Rgb(source(i).map_or([255, 255, 255], MaskLayer::colour)),
            (false, None) if source(i) == Some(MaskLayer::MapAgrees) => {
                Rgb(MaskLayer::MapAgrees.colour())
            }
            (false, _) => Rgb([0, 0, 0]),
        }
    });
    side_by_side(colour, &picture)
}

/// What [`mask_picture`] draws: the frame, its mask, and optionally the truth's
/// instance ids and the mask's sources ([`MaskLayer::bit`]s), a value per pixel.
pub struct MaskPicture<'a> {
    /// The frame.
    pub colour: &'a RgbImage,
    /// Its mask (true: masked).
    pub mask: Option<&'a [bool]>,
    /// A synthetic frame's instance ids (0: static).
    pub truth: Option<&'a [u16]>,
    /// Each pixel's [`MaskLayer::bit`]s.
    pub sources: Option<&'a [u8]>,
}

/// A map's colours with the flagged points (ghosts) in red.
pub fn with_ghosts(mesh: &Mesh, ghost: &[bool]) -> Vec<[u8; 3]> {
    (0..mesh.len())
        .map(|i| {
            if ghost.get(i).copied().unwrap_or(false) {
                [255, 0, 0]
            } else {
                mesh.colours.get(i).copied().unwrap_or([180, 180, 180])
            }
        })
        .collect()
}

/// The camera of the pictures: 640x480 with a wide field of view.
pub fn picture_camera() -> PinholeCamera {
    PinholeCamera {
        fx: 380.0,
        fy: 380.0,
        cx: 320.0,
        cy: 240.0,
        width: 640,
        height: 480,
        distortion: [0.0; 5],
        rational: [0.0; 3],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_mask_picture_colours_each_pixel_against_the_truth() {
        let colour = RgbImage::from_pixel(2, 2, Rgb([9, 9, 9]));
        let mask = [true, true, false, false];
        let truth = [3u16, 0, 3, 0];
        let picture = mask_picture(MaskPicture {
            colour: &colour,
            mask: Some(&mask),
            truth: Some(&truth),
            sources: None,
        });
        assert_eq!(picture.dimensions(), (2 + 8 + 2, 2));
        let at = |u: u32, v: u32| picture.get_pixel(10 + u, v).0;
        assert_eq!(at(0, 0), [0, 200, 0], "mover masked");
        assert_eq!(at(1, 0), [220, 0, 0], "static masked");
        assert_eq!(at(0, 1), [255, 230, 0], "mover fused");
        assert_eq!(at(1, 1), [0, 0, 0], "static fused");
        assert_eq!(
            picture.get_pixel(0, 0).0,
            [9, 9, 9],
            "the frame on the left"
        );
        let plain = mask_picture(MaskPicture {
            colour: &colour,
            mask: Some(&mask),
            truth: None,
            sources: None,
        });
        assert_eq!(plain.get_pixel(10, 0).0, [255, 255, 255]);
        let (discs, band) = (MaskLayer::Discs.bit(), MaskLayer::ObjectBand.bit());
        let map = MaskLayer::MapAgrees.bit();
        let by_source = mask_picture(MaskPicture {
            colour: &colour,
            mask: Some(&mask),
            truth: None,
            sources: Some(&[discs | band, 0, map, 0]),
        });
        let at = |u: u32, v: u32| by_source.get_pixel(10 + u, v).0;
        assert_eq!(at(0, 0), MaskLayer::ObjectBand.colour(), "the first source");
        assert_eq!(at(1, 0), [255, 255, 255], "masked, no source known");
        assert_eq!(at(0, 1), MaskLayer::MapAgrees.colour(), "released");
        assert_eq!(at(1, 1), [0, 0, 0], "fused");
    }

    #[test]
    fn a_point_in_front_of_the_view_is_drawn_and_one_behind_is_not() {
        let poses = [Se3::identity()];
        let view = Viewpoint::from_cameras(&poses).unwrap();
        // Camera y points down in the image: up is -y.
        assert!((view.up - Vector3::new(0.0, -1.0, 0.0)).norm() < 1e-9);
        let camera = picture_camera();
        let red = [[255, 0, 0]];
        let seen = perspective(&[[0.0, 0.0, 2.0]], &red, &view.camera_from_world, &camera);
        assert!(seen.pixels().any(|p| p.0 == [255, 0, 0]));
        let behind = perspective(&[[0.0, 0.0, -3.0]], &red, &view.camera_from_world, &camera);
        assert!(!behind.pixels().any(|p| p.0 == [255, 0, 0]));
        // The top view drops points above the cut (0.3 m above the camera).
        let top_view = top(
            &[[0.0, -1.0, 1.0], [1.0, 0.5, 1.0]],
            &[[9, 9, 9], [255, 0, 0]],
            &view,
            100,
        );
        assert!(!top_view.pixels().any(|p| p.0 == [9, 9, 9]));
        assert!(top_view.pixels().any(|p| p.0 == [255, 0, 0]));
    }
}
