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
fn value_noise(id: u32, x: f64, y: f64) -> f64 {
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
    if h % 2 == 0 {
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
}
