//! Procedural multi-scale textures: value noise summed over octaves plus hard-edged
//! blobs and stripes, so that FAST finds corners at every pyramid level.
//!
//! A texel is a pure function of (texture id, u, v): rendering is deterministic and
//! needs no stored images.

/// A 2-D integer hash (a variant of the PCG output permutation).
fn hash(id: u32, x: i64, y: i64) -> u32 {
    let mut h = (x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
        ^ (id as u64).wrapping_mul(0x1656_67B1_9E37_79F9);
    h ^= h >> 33;
    h = h.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
    h ^= h >> 33;
    (h & 0xFFFF_FFFF) as u32
}

/// \(\lfloor x \rfloor\) without a libm call (the hot loop of the renderer).
#[inline]
fn floor(x: f64) -> f64 {
    let truncated = x as i64 as f64;
    if truncated > x {
        truncated - 1.0
    } else {
        truncated
    }
}

fn lattice(id: u32, x: i64, y: i64) -> f64 {
    hash(id, x, y) as f64 / u32::MAX as f64
}

/// Bilinear value noise in [0, 1] at (x, y) in lattice units.
pub(super) fn value_noise(id: u32, x: f64, y: f64) -> f64 {
    let (x0, y0) = (floor(x), floor(y));
    let (fx, fy) = (x - x0, y - y0);
    let (xi, yi) = (x0 as i64, y0 as i64);
    let a = lattice(id, xi, yi);
    let b = lattice(id, xi + 1, yi);
    let c = lattice(id, xi, yi + 1);
    let d = lattice(id, xi + 1, yi + 1);
    let top = a + (b - a) * fx;
    let bottom = c + (d - c) * fx;
    top + (bottom - top) * fy
}

/// The colour (RGB in [0, 1]) of texture `id` at surface coordinates (u, v) in metres.
///
/// Four octaves of value noise (cell sizes 0.4 m to 0.05 m) modulate a per-texture base
/// colour; on top, a grid of hard-edged blobs ("posters", "books") with random colours
/// gives sharp corners at 2-10 cm scale.
///
/// `footprint` is the size of the pixel on the surface in metres: rectangle edges are
/// blended over it (the area a camera pixel integrates), so edges and corners land at
/// sub-pixel positions as in a real image instead of snapping to the pixel grid.
pub fn texel(id: u32, u: f64, v: f64, footprint: f64) -> [f64; 3] {
    // Hard-edged rectangles on a 0.15 m grid: present in about half the cells.
    let cell = 0.15;
    let (cx, cy) = (floor(u / cell) as i64, floor(v / cell) as i64);
    let h = hash(id ^ 0xABCD, cx, cy);
    let mut rectangle = None;
    if h.is_multiple_of(2) {
        let (fu, fv) = (u / cell - cx as f64, v / cell - cy as f64);
        let (w, hgt) = (
            0.3 + 0.6 * ((h >> 8) & 0xFF) as f64 / 255.0,
            0.3 + 0.6 * ((h >> 16) & 0xFF) as f64 / 255.0,
        );
        // Coverage of the pixel footprint by [0, w) x [0, hgt), per axis a linear ramp.
        let f = (footprint / cell).max(1e-6);
        let ramp = |x: f64| (x / f + 0.5).clamp(0.0, 1.0);
        let coverage = ramp(fu).min(ramp(w - fu)) * ramp(fv).min(ramp(hgt - fv));
        if coverage > 0.0 {
            let shade = ((h >> 24) & 0xFF) as f64 / 255.0;
            let colour = [shade, lattice(id, cx, cy), 1.0 - shade];
            if coverage >= 1.0 {
                return colour;
            }
            rectangle = Some((colour, coverage));
        }
    }
    let background = noise_colour(id, u, v);
    match rectangle {
        Some((colour, c)) => std::array::from_fn(|k| colour[k] * c + background[k] * (1.0 - c)),
        None => background,
    }
}

/// The multi-octave noise colour under the rectangles.
fn noise_colour(id: u32, u: f64, v: f64) -> [f64; 3] {
    let base = [lattice(id, -7, 3), lattice(id, 11, -5), lattice(id, 2, 17)];
    let mut noise = 0.0;
    let mut amplitude = 0.5;
    let mut frequency = 2.5;
    for octave in 0..4 {
        noise +=
            amplitude * value_noise(id.wrapping_add(octave * 101), u * frequency, v * frequency);
        amplitude *= 0.5;
        frequency *= 2.0;
    }
    base.map(|b| ((0.25 + 0.5 * b) * (0.55 + 0.9 * noise)).clamp(0.0, 1.0))
}

/// A surface of the `room` look ([`crate::synth::scene::Look::Room`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Surface {
    /// The floor.
    Floor,
    /// A wall.
    Wall,
    /// The ceiling.
    Ceiling,
    /// Furniture keeps the multi-scale texture of its id (boxes, books, shelves).
    Furniture(u32),
}

/// Coverage in [0, 1] of a pixel footprint `f` (in units of the pattern) by
/// \([0, w)\) around coordinate `x`: a linear ramp at each edge, as in [`texel`].
pub(super) fn coverage(x: f64, w: f64, f: f64) -> f64 {
    let ramp = |x: f64| (x / f + 0.5).clamp(0.0, 1.0);
    ramp(x).min(ramp(w - x))
}

fn mix(a: [f64; 3], b: [f64; 3], t: f64) -> [f64; 3] {
    std::array::from_fn(|k| a[k] * (1.0 - t) + b[k] * t)
}

/// The colour of a surface of a furnished room at (u, v) metres: a wooden floor of
/// staggered planks with grain and dark seams, plaster walls with framed pictures
/// (the pictures carry [`texel`]'s multi-scale texture, so that FAST still finds
/// corners on the walls), a ceiling of tiles, and furniture as [`texel`] gives it.
pub fn room_texel(surface: Surface, u: f64, v: f64, footprint: f64) -> [f64; 3] {
    match surface {
        Surface::Furniture(id) => texel(id, u, v, footprint),
        Surface::Floor => floor_texel(u, v, footprint),
        Surface::Wall => wall_texel(u, v, footprint),
        Surface::Ceiling => {
            let tile = 0.6;
            let (fu, fv) = (u / tile - floor(u / tile), v / tile - floor(v / tile));
            let f = (footprint / tile).max(1e-6);
            let seam = 0.012 / tile;
            let inside = coverage(fu - seam, 1.0 - seam, f) * coverage(fv - seam, 1.0 - seam, f);
            let grain = 0.04 * value_noise(901, u * 12.0, v * 12.0);
            mix(
                [0.55, 0.55, 0.56],
                [0.86 + grain, 0.86 + grain, 0.84 + grain],
                inside,
            )
        }
    }
}

/// Planks 0.14 m wide along v, 1.2 m long along u, each row's joints staggered.
fn floor_texel(u: f64, v: f64, footprint: f64) -> [f64; 3] {
    let (width, length) = (0.14, 1.2);
    let row = floor(v / width);
    let shift = lattice(77, row as i64, 0) * length;
    let column = floor((u + shift) / length);
    let h = hash(78, column as i64, row as i64);
    let tone = 0.8 + 0.3 * (h & 0xFF) as f64 / 255.0;
    let grain = value_noise(79 + (h >> 8) % 7, u * 3.0, v * 60.0);
    let knots = value_noise(80, u * 9.0, v * 9.0).powi(6);
    let wood = [0.56, 0.38, 0.22]
        .map(|c| (c * tone * (0.85 + 0.3 * grain) * (1.0 - 0.5 * knots)).clamp(0.0, 1.0));
    let (fu, fv) = ((u + shift) / length - column, v / width - row);
    let inside = coverage(fu - 0.004, 1.0 - 0.008, footprint / length).min(coverage(
        fv - 0.02,
        1.0 - 0.04,
        footprint / width,
    ));
    mix([0.16, 0.10, 0.06], wood, inside)
}

/// Plaster with framed pictures, posters and notes on a 0.8 m x 0.7 m grid (most
/// cells): a lab's wall, with enough corners for tracking.
fn wall_texel(u: f64, v: f64, footprint: f64) -> [f64; 3] {
    let tone = 0.88
        + 0.12 * value_noise(501, u * 1.5, v * 1.5)
        + 0.06 * value_noise(502, u * 25.0, v * 25.0);
    let plaster = [0.80, 0.76, 0.68].map(|c| (c * tone).clamp(0.0, 1.0));
    let (cell_u, cell_v) = (0.8, 0.7);
    let (cu, cv) = (floor(u / cell_u), floor(v / cell_v));
    let h = hash(503, cu as i64, cv as i64);
    if h % 100 >= 80 {
        return plaster;
    }
    // The picture: size and place in its cell, a frame 3-5 cm wide.
    let (w, hgt) = (
        0.3 + 0.4 * (h >> 8 & 0xFF) as f64 / 255.0,
        0.25 + 0.35 * (h >> 16 & 0xFF) as f64 / 255.0,
    );
    let (x, y) = (
        u - cu * cell_u - 0.5 * (cell_u - w),
        v - cv * cell_v - 0.5 * (cell_v - hgt),
    );
    let frame = 0.03 + 0.02 * (h >> 24 & 0x3) as f64 / 3.0;
    let outer = coverage(x, w, footprint) * coverage(y, hgt, footprint);
    if outer <= 0.0 {
        return plaster;
    }
    let inner = coverage(x - frame, w - 2.0 * frame, footprint)
        * coverage(y - frame, hgt - 2.0 * frame, footprint);
    let wood = [0.22, 0.15, 0.09].map(|c| c * (0.8 + 0.4 * value_noise(504, u * 30.0, v * 30.0)));
    let painting = texel(600 + h % 50, u * 2.0, v * 2.0, footprint * 2.0);
    let framed = mix(wood, painting, inner);
    mix(plaster, framed, outer)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn deterministic_and_in_range() {
        for i in 0..200 {
            let (u, v) = (i as f64 * 0.037, i as f64 * -0.051);
            let a = texel(3, u, v, 0.001);
            assert_eq!(a, texel(3, u, v, 0.001));
            assert!(a.iter().all(|c| (0.0..=1.0).contains(c)));
        }
        assert_ne!(texel(1, 0.3, 0.3, 0.001), texel(2, 0.3, 0.3, 0.001));
    }

    #[test]
    fn room_surfaces_are_in_range_and_floors_differ_from_walls() {
        let mut differ = 0;
        for i in 0..400 {
            let (u, v) = (i as f64 * 0.093, i as f64 * -0.071);
            let colours = [
                Surface::Floor,
                Surface::Wall,
                Surface::Ceiling,
                Surface::Furniture(17),
            ]
            .map(|s| room_texel(s, u, v, 0.002));
            for c in colours {
                assert!(c.iter().all(|x| (0.0..=1.0).contains(x)), "{c:?}");
            }
            differ += (colours[0] != colours[1]) as usize;
        }
        assert!(differ > 390, "{differ}");
    }
}
