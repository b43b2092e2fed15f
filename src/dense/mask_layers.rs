//! A frame's dense mask with where each masked pixel's mask came from: the detected
//! objects, the discs around dynamic keypoints, the pixels the frames around saw
//! through, the depth segments, the dilation's ring; and the pixels a mask source
//! marked that the static map built so far explained ([`MaskLayer::MapAgrees`]), which
//! are fused.
//!
//! `dense.json`'s `truth.sources` counts each source's pixels against a synthetic
//! sequence's truth masks (its precision), so a source that masks much of the static
//! scene shows by name.

use rayon::prelude::*;

use super::free_space::{Evidence, PosedDepth};
use super::tsdf::TsdfVolume;
use crate::geometry::camera::{ImageSize, PinholeCamera};

/// One source of a dense mask, a bit of [`MaskLayers::sources`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MaskLayer {
    /// A detected (or followed) object's box, the pixels within `delta_z` of its
    /// depth (its body) and those without depth.
    Objects,
    /// The same box's pixels behind its body, up to `mask_depth_behind` (the far leg,
    /// the feet; and whatever static lies there).
    ObjectBand,
    /// A disc around a dynamic keypoint.
    Discs,
    /// A pixel the frames around saw through.
    FreeSpace,
    /// A depth segment grown from a dynamic keypoint, a moving pixel or a followed
    /// segment.
    Segments,
    /// The ring the dilation added.
    Dilation,
    /// Marked by a source, but its depth lies on the static map fused so far: fused
    /// (not part of the mask).
    MapAgrees,
}

impl MaskLayer {
    /// Every source, in the order `dense.json` lists them.
    pub const ALL: [MaskLayer; 7] = [
        MaskLayer::Objects,
        MaskLayer::ObjectBand,
        MaskLayer::Discs,
        MaskLayer::FreeSpace,
        MaskLayer::Segments,
        MaskLayer::Dilation,
        MaskLayer::MapAgrees,
    ];

    /// Its bit in [`MaskLayers::sources`].
    pub fn bit(self) -> u8 {
        match self {
            MaskLayer::Objects => 1,
            MaskLayer::Discs => 2,
            MaskLayer::FreeSpace => 4,
            MaskLayer::Segments => 8,
            MaskLayer::Dilation => 16,
            MaskLayer::MapAgrees => 32,
            MaskLayer::ObjectBand => 64,
        }
    }

    /// Its colour in a mask picture without truth ([`super::render::mask_picture`]).
    pub fn colour(self) -> [u8; 3] {
        match self {
            MaskLayer::Objects => [255, 255, 255],
            MaskLayer::ObjectBand => [120, 170, 255],
            MaskLayer::Discs => [230, 60, 230],
            MaskLayer::FreeSpace => [0, 220, 220],
            MaskLayer::Segments => [255, 150, 0],
            MaskLayer::Dilation => [130, 130, 130],
            MaskLayer::MapAgrees => [40, 90, 40],
        }
    }

    /// The first source (in [`MaskLayer::ALL`]'s order) among a pixel's `bits`.
    pub fn first_of(bits: u8) -> Option<MaskLayer> {
        MaskLayer::ALL.into_iter().find(|l| bits & l.bit() != 0)
    }

    /// Its name in `dense.json`.
    pub fn name(self) -> &'static str {
        match self {
            MaskLayer::Objects => "objects",
            MaskLayer::ObjectBand => "object_band",
            MaskLayer::Discs => "discs",
            MaskLayer::FreeSpace => "free_space",
            MaskLayer::Segments => "segments",
            MaskLayer::Dilation => "dilation",
            MaskLayer::MapAgrees => "map_agrees",
        }
    }
}

/// Which masked pixels the static map releases ([`MaskLayers::release_on_map`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapRelease<'a> {
    /// The map's weight (frames) a pixel's depth must meet on its surface.
    pub min_weight: f32,
    /// Per pixel, whether the frames around saw it still ([`Evidence::still`]): a
    /// detected object's body pixels seen still are released too (the floor at a
    /// walker's feet, a desk beside them at the same depth). `None`: no body pixel.
    pub bodies_still: Option<&'a [bool]>,
    /// How far in front of the map's surface (metres) a pixel's depth may lie (at most
    /// the truncation).
    pub band: f32,
}

/// A frame's mask and the sources of its pixels.
#[derive(Debug, Clone)]
pub struct MaskLayers {
    /// Per pixel: dynamic (not fused).
    pub dynamic: Vec<bool>,
    /// Per pixel: the [`MaskLayer`] bits that marked it (a pixel with
    /// [`MaskLayer::MapAgrees`] is not dynamic).
    pub sources: Vec<u8>,
}

impl MaskLayers {
    /// The mask of the marked `sources` of a frame of `size`, dilated by `border`
    /// pixels; the ring the dilation adds leaves out the pixels `evidence` saw still.
    pub fn dilated(
        mut sources: Vec<u8>,
        size: ImageSize,
        border: u32,
        evidence: Option<&Evidence>,
    ) -> Self {
        let (w, h) = (size.width as usize, size.height as usize);
        let core: Vec<bool> = sources.iter().map(|&s| s != 0).collect();
        let mut dynamic = dilate(&core, w, h, border as usize);
        for (i, (d, &c)) in dynamic.iter_mut().zip(&core).enumerate() {
            // The ring the dilation adds keeps none of the pixels seen still.
            let still = evidence.is_some_and(|e| e.still[i]);
            *d &= c || !still;
            if *d && !c {
                sources[i] |= MaskLayer::Dilation.bit();
            }
        }
        Self { dynamic, sources }
    }

    /// Fuses pixel `i` after all: its depth lies on the static map
    /// ([`MaskLayer::MapAgrees`]).
    pub fn release(&mut self, i: usize) {
        self.dynamic[i] = false;
        self.sources[i] |= MaskLayer::MapAgrees.bit();
    }

    /// Fuses the masked pixels of `frame` whose depth lies on the static map
    /// `volume` holds with at least `release.min_weight` (up to `release.band` in
    /// front of its surface, [`TsdfVolume::on_surface`]); how many. A mover stands in
    /// front of the static scene, or where the map holds nothing yet. Pixels seen
    /// moving by the frames around stay masked whatever the map says, and so do those
    /// of a detected object's body unless `release.bodies_still` says they were seen
    /// still: a mover the map let in once (a leak) would otherwise let itself in again.
    pub fn release_on_map(
        &mut self,
        frame: PosedDepth,
        camera: &PinholeCamera,
        volume: &TsdfVolume,
        release: MapRelease,
    ) -> u64 {
        let depth = frame.depth;
        let w = depth.width as usize;
        let world_from_camera = frame.camera_from_world.inverse();
        let max_depth = volume.settings.max_depth as f32;
        let min_weight = release.min_weight;
        // In truncations; the field says nothing beyond one.
        let band = (release.band / volume.settings.truncation as f32).min(1.0);
        let body = MaskLayer::Objects.bit();
        let kept = |i: usize, bits: u8| {
            bits & MaskLayer::FreeSpace.bit() != 0
                || (bits & body != 0 && !release.bodies_still.is_some_and(|s| s[i]))
        };
        let sources = &self.sources;
        let released: Vec<usize> = self
            .dynamic
            .par_chunks(w)
            .enumerate()
            .flat_map_iter(|(v, row)| {
                let world_from_camera = &world_from_camera;
                row.iter().enumerate().filter_map(move |(u, &masked)| {
                    let i = v * w + u;
                    let d = depth.metres[i];
                    if !masked || d <= 0.0 || d > max_depth || kept(i, sources[i]) {
                        return None;
                    }
                    let d = f64::from(d);
                    let x = (u as f64 - camera.cx) / camera.fx * d;
                    let y = (v as f64 - camera.cy) / camera.fy * d;
                    let p = world_from_camera * nalgebra::Point3::new(x, y, d);
                    volume.on_surface(&p.coords, min_weight, band).then_some(i)
                })
            })
            .collect();
        for &i in &released {
            self.release(i);
        }
        released.len() as u64
    }

    /// Masked pixels.
    pub fn masked(&self) -> u64 {
        self.dynamic.iter().filter(|&&d| d).count() as u64
    }
}

/// Dilation by a square of side `2r + 1` (separable: rows, then columns), with
/// running counts so the cost does not grow with `r`.
pub fn dilate(mask: &[bool], w: usize, h: usize, r: usize) -> Vec<bool> {
    if r == 0 {
        return mask.to_vec();
    }
    let rows = dilate_lines(mask, w, h, r, |line, k| line * w + k);
    dilate_lines(&rows, h, w, r, |line, k| k * w + line)
}

/// One pass of [`dilate`] along `lines` lines of `len` pixels; `at(line, k)` is the
/// index of pixel `k` of a line (generic, so the per-pixel call is inlined).
fn dilate_lines(
    input: &[bool],
    len: usize,
    lines: usize,
    r: usize,
    at: impl Fn(usize, usize) -> usize,
) -> Vec<bool> {
    let mut output = vec![false; input.len()];
    for line in 0..lines {
        let mut count = 0usize;
        for k in 0..len.min(r) {
            count += input[at(line, k)] as usize;
        }
        for k in 0..len {
            if k + r < len {
                count += input[at(line, k + r)] as usize;
            }
            if k > r {
                count -= input[at(line, k - r - 1)] as usize;
            }
            output[at(line, k)] = count > 0;
        }
    }
    output
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dilation_grows_a_pixel_into_a_square() {
        let (w, h) = (9, 7);
        let mut mask = vec![false; w * h];
        mask[3 * w + 4] = true;
        let grown = dilate(&mask, w, h, 2);
        for v in 0..h {
            for u in 0..w {
                let inside = (2..=6).contains(&u) && (1..=5).contains(&v);
                assert_eq!(grown[v * w + u], inside, "({u}, {v})");
            }
        }
    }

    #[test]
    fn the_ring_of_the_dilation_is_its_own_source() {
        let (w, h) = (7, 5);
        let mut sources = vec![0u8; w * h];
        sources[2 * w + 3] = MaskLayer::Objects.bit();
        let layers = MaskLayers::dilated(sources, ImageSize::from((w as u32, h as u32)), 1, None);
        assert_eq!(layers.masked(), 9);
        assert_eq!(layers.sources[2 * w + 3], MaskLayer::Objects.bit());
        assert_eq!(layers.sources[w + 2], MaskLayer::Dilation.bit());
        assert_eq!(layers.sources[0], 0);
        let bits: Vec<u8> = MaskLayer::ALL.iter().map(|l| l.bit()).collect();
        assert_eq!(bits, vec![1, 64, 2, 4, 8, 16, 32]);
    }

    /// A wall 2 m away fused from a few frames; then a frame with a ball in front of
    /// it and the whole image masked by discs: the wall's pixels lie on the map and
    /// are released, the ball's are not; with too high a weight nothing is, and a
    /// detected body's pixels only where seen still.
    #[test]
    fn masked_pixels_on_the_static_map_are_fused() {
        use crate::dense::tsdf::tests::{looking_at, render_depth, small_camera};
        use crate::dense::tsdf::{FrameInput, TsdfSettings};
        use nalgebra::Vector3;
        let camera = small_camera();
        let mut volume = TsdfVolume::new(TsdfSettings::default(), camera);
        let pose = looking_at(Vector3::new(0.0, 0.0, 0.0), Vector3::new(0.0, 0.0, 1.0));
        let colour = image::RgbImage::new(camera.width, camera.height);
        let wall = render_depth(&camera, &pose, &[], Some(2.0));
        for _ in 0..4 {
            volume
                .integrate(&FrameInput {
                    depth: &wall,
                    colour: &colour,
                    dynamic: None,
                    camera_from_world: &pose,
                    weight: 1.0,
                })
                .expect("no spill file");
        }
        let ball = [(Vector3::new(0.0, 0.0, 1.2), 0.3)];
        let depth = render_depth(&camera, &pose, &ball, Some(2.0));
        let (w, h) = (camera.width as usize, camera.height as usize);
        let size = ImageSize::from((camera.width, camera.height));
        // Discs over the whole image (a detected body would stay masked whatever the map
        // says).
        let masked = || MaskLayers::dilated(vec![MaskLayer::Discs.bit(); w * h], size, 0, None);
        let frame = PosedDepth {
            timestamp: 0.0,
            depth: &depth,
            camera_from_world: &pose,
        };
        let mut strict = masked();
        let still = vec![true; w * h];
        let release = |min_weight, bodies: bool| MapRelease {
            min_weight,
            bodies_still: bodies.then_some(still.as_slice()),
            band: 0.02,
        };
        assert_eq!(
            strict.release_on_map(frame, &camera, &volume, release(5.0, false)),
            0
        );
        let mut layers = masked();
        let released = layers.release_on_map(frame, &camera, &volume, release(3.0, false));
        let centre = 60 * w + 80;
        let corner = 10 * w + 10;
        assert!(layers.dynamic[centre], "the ball stays masked");
        assert!(!layers.dynamic[corner], "the wall is fused");
        assert_ne!(layers.sources[corner] & MaskLayer::MapAgrees.bit(), 0);
        let on_ball = (0..w * h).filter(|&i| depth.metres[i] < 1.9).count();
        assert!(on_ball > 1000);
        // The image's outermost pixels fall outside the margin the volume keeps free.
        assert!(released as usize > (w * h - on_ball) * 6 / 10, "{released}");
        assert_eq!(layers.masked() as usize, w * h - released as usize);
        let body = || MaskLayers::dilated(vec![MaskLayer::Objects.bit(); w * h], size, 0, None);
        assert_eq!(
            body().release_on_map(frame, &camera, &volume, release(3.0, false)),
            0
        );
        let mut bodies = body();
        let released = bodies.release_on_map(frame, &camera, &volume, release(3.0, true));
        assert!(bodies.dynamic[centre], "the ball stays masked as a body");
        assert!(!bodies.dynamic[corner], "the wall in its box is fused");
        assert!(released as usize > (w * h - on_ball) * 6 / 10, "{released}");
        // The wall read 3 cm nearer (a sensor's noise far away): on the map within a
        // band of 3.8 cm, not of 2 cm; the ball in front stays masked either way.
        let nearer = render_depth(&camera, &pose, &ball, Some(1.97));
        let frame = PosedDepth {
            depth: &nearer,
            ..frame
        };
        let mut narrow = masked();
        narrow.release_on_map(frame, &camera, &volume, release(3.0, false));
        assert!(narrow.dynamic[corner], "3 cm in front of a 2 cm band");
        let mut wide = masked();
        let within = MapRelease {
            band: 0.038,
            ..release(3.0, false)
        };
        wide.release_on_map(frame, &camera, &volume, within);
        assert!(!wide.dynamic[corner], "3 cm in front within a 3.8 cm band");
        assert!(wide.dynamic[centre], "the ball stays masked");
    }
}
