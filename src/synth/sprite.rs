//! Cut-outs of real people (RGBA images) shown as camera-facing billboards: a vertical
//! rectangle standing on the floor, turned towards the camera of the frame being
//! rendered, textured by the cut-out; transparent pixels let rays through.
//!
//! A ray \(o + t d\) meets the billboard's plane (point \(b\), normal \(n\)) at
//! \(t = (b - o)\cdot n / (d \cdot n)\); the hit's offsets along the billboard's right and
//! up axes, divided by its width and height, give the cut-out's texture coordinates.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use nalgebra::Vector3;

use crate::io::image_files::read_rgba;
use crate::io::IoError;

/// An RGBA cut-out.
#[derive(Debug, Clone, PartialEq)]
pub struct Sprite {
    /// The cut-out's file.
    pub path: PathBuf,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    rgba: Vec<[u8; 4]>,
}

impl Sprite {
    /// Loads a cut-out; the file must have an alpha channel.
    pub fn load(path: &Path) -> Result<Arc<Self>, IoError> {
        let image = read_rgba(path, "person cut-out (sprite) named by the synth config")?;
        let opaque = image.pixels().filter(|p| p[3] > 127).count();
        if opaque == 0 {
            return Err(IoError::invalid(path, "the cut-out is fully transparent"));
        }
        Ok(Arc::new(Self {
            path: path.to_path_buf(),
            width: image.width(),
            height: image.height(),
            rgba: image.pixels().map(|p| p.0).collect(),
        }))
    }

    /// Width over height.
    pub fn aspect(&self) -> f64 {
        self.width as f64 / self.height as f64
    }

    /// The colour (0..1) at texture coordinates `s` (left to right) and `r` (bottom to
    /// top), both in [0, 1); `None` where the cut-out is transparent.
    pub fn sample(&self, s: f64, r: f64) -> Option<[f64; 3]> {
        if !(0.0..1.0).contains(&s) || !(0.0..1.0).contains(&r) {
            return None;
        }
        let x = ((s * self.width as f64) as u32).min(self.width - 1);
        let y = (((1.0 - r) * self.height as f64) as u32).min(self.height - 1);
        let p = self.rgba[(y * self.width + x) as usize];
        (p[3] > 127).then(|| [p[0], p[1], p[2]].map(|c| c as f64 / 255.0))
    }
}

/// A cut-out standing at `base` (the middle of its bottom edge), facing a camera.
#[derive(Debug, Clone, PartialEq)]
pub struct Billboard {
    /// The middle of the bottom edge.
    pub base: Vector3<f64>,
    /// Unit vectors: world up, the billboard's right (as the camera sees it), and its
    /// normal (towards the camera).
    pub up: Vector3<f64>,
    /// The right vector.
    pub right: Vector3<f64>,
    /// The normal vector.
    pub normal: Vector3<f64>,
    /// Height, metres.
    pub height: f64,
    /// Width, metres.
    pub width: f64,
    /// The cut-out.
    pub sprite: Arc<Sprite>,
    /// The walking pose: legs opened by this fraction of the width at the feet, and
    /// the cut-out mirrored (walking the other way).
    pub gait: Gait,
}

/// A walking pose of a cut-out: below the hips (`HIP` of the height) the left half
/// moves left and the right half right by \(a (h - r) / h\) of the width at height
/// \(r\), so the legs open and close with the stride phase.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Gait {
    /// Legs opened by this fraction of the width at the feet.
    pub open: f64,
    /// Mirrored (walking the other way).
    pub mirrored: bool,
}

/// Where the legs start, as a fraction of the height.
const HIP: f64 = 0.47;

impl Gait {
    /// The cut-out's texture coordinate seen at `(s, r)`: `None` where the opened legs
    /// leave a gap.
    fn source(&self, s: f64, r: f64) -> Option<f64> {
        let s = if self.mirrored { 1.0 - s } else { s };
        if r >= HIP || self.open == 0.0 {
            return Some(s);
        }
        let shift = self.open * (HIP - r) / HIP;
        if s < 0.5 {
            let source = s + shift;
            (source < 0.5).then_some(source)
        } else {
            let source = s - shift;
            (source >= 0.5).then_some(source)
        }
    }
}

impl Billboard {
    /// A billboard of the given height (width from the cut-out's aspect) turned to face
    /// `camera` about the up axis.
    pub fn facing(
        base: Vector3<f64>,
        up: Vector3<f64>,
        height: f64,
        camera: &Vector3<f64>,
        sprite: Arc<Sprite>,
    ) -> Self {
        let to_camera = camera - base;
        let horizontal = to_camera - up * up.dot(&to_camera);
        let normal = horizontal.try_normalize(1e-9).unwrap_or_else(|| {
            // Camera straight above: any horizontal normal will do.
            let side = if up.x.abs() < 0.9 {
                Vector3::x()
            } else {
                Vector3::y()
            };
            (side - up * up.dot(&side)).normalize()
        });
        // Seen from the camera, looking along -normal with `up` up, image x points
        // along up × normal.
        let right = up.cross(&normal);
        Self {
            base,
            up,
            right,
            normal,
            width: height * sprite.aspect(),
            height,
            sprite,
            gait: Gait::default(),
        }
    }

    /// The ray parameter and colour where the ray meets an opaque pixel, if it does.
    pub fn intersect(
        &self,
        origin: &Vector3<f64>,
        direction: &Vector3<f64>,
    ) -> Option<(f64, [f64; 3])> {
        let denominator = direction.dot(&self.normal);
        if denominator.abs() < 1e-12 {
            return None;
        }
        let t = (self.base - origin).dot(&self.normal) / denominator;
        if t <= 1e-6 {
            return None;
        }
        let offset = origin + direction * t - self.base;
        let s = offset.dot(&self.right) / self.width + 0.5;
        let r = offset.dot(&self.up) / self.height;
        let s = self.gait.source(s, r)?;
        self.sprite.sample(s, r).map(|colour| (t, colour))
    }

    /// The distance of a point from the billboard's plane.
    pub fn plane_distance(&self, p: &Vector3<f64>) -> f64 {
        (p - self.base).dot(&self.normal).abs()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_by_two() -> Arc<Sprite> {
        // Top row opaque red and transparent, bottom row opaque green and blue.
        Arc::new(Sprite {
            path: PathBuf::from("test"),
            width: 2,
            height: 2,
            rgba: vec![
                [255, 0, 0, 255],
                [0, 0, 0, 0],
                [0, 255, 0, 255],
                [0, 0, 255, 255],
            ],
        })
    }

    #[test]
    fn rays_see_the_cut_out_the_right_way_up() {
        // Camera at the origin looking along +z, world up is -y; billboard 2 m ahead.
        let up = Vector3::new(0.0, -1.0, 0.0);
        let board = Billboard::facing(
            Vector3::new(0.0, 1.0, 2.0),
            up,
            2.0,
            &Vector3::zeros(),
            two_by_two(),
        );
        assert!((board.width - 2.0).abs() < 1e-12);
        assert!((board.normal - Vector3::new(0.0, 0.0, -1.0)).norm() < 1e-12);
        // Image x grows to the right: the top-left quarter is red.
        let (t, colour) = board
            .intersect(&Vector3::zeros(), &Vector3::new(-0.25, -0.25, 1.0))
            .unwrap();
        assert!((t - 2.0).abs() < 1e-12 && colour == [1.0, 0.0, 0.0]);
        assert!(board
            .intersect(&Vector3::zeros(), &Vector3::new(0.25, -0.25, 1.0))
            .is_none());
        let (_, colour) = board
            .intersect(&Vector3::zeros(), &Vector3::new(0.25, 0.25, 1.0))
            .unwrap();
        assert_eq!(colour, [0.0, 0.0, 1.0]);
        assert!(board
            .intersect(&Vector3::zeros(), &Vector3::new(0.0, 0.0, -1.0))
            .is_none());
    }

    #[test]
    fn gait_mirrors_and_opens_the_legs() {
        let mirrored = Gait {
            open: 0.0,
            mirrored: true,
        };
        assert_eq!(mirrored.source(0.2, 0.8), Some(0.8));
        let open = Gait {
            open: 0.2,
            mirrored: false,
        };
        // Above the hips nothing moves; at the feet the left leg comes from 0.2 further
        // right, and the middle opens into a gap.
        assert_eq!(open.source(0.3, 0.6), Some(0.3));
        assert!((open.source(0.1, 0.0).unwrap() - 0.3).abs() < 1e-12);
        assert!((open.source(0.9, 0.0).unwrap() - 0.7).abs() < 1e-12);
        assert_eq!(open.source(0.45, 0.0), None);
        assert_eq!(open.source(0.55, 0.0), None);
    }
}
