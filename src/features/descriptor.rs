//! Oriented BRIEF: 256 intensity comparisons \(I(p_k) < I(q_k)\) between point pairs of
//! a fixed pattern rotated by the keypoint's angle, on the Gaussian-smoothed level
//! image; and the keypoint angle from the intensity centroid (Rosin 1999):
//! \(\theta = \operatorname{atan2}(m_{01}, m_{10})\), \(m_{pq} = \sum x^p y^q I(x, y)\) over a
//! disc of radius 15.
//!
//! The pattern is drawn once from an isotropic Gaussian (\(\sigma = 31/5\) px, BRIEF's
//! G II sampling) with a fixed seed, each point within 13 px so that every rotation stays
//! inside the 31×31 patch.

use std::sync::OnceLock;

use image::GrayImage;

use crate::random::Rng;

/// A 256-bit binary descriptor.
pub type Descriptor = [u64; 4];

/// The radius of the orientation disc (ORB's half patch size).
pub const HALF_PATCH: i32 = 15;
/// Pattern points keep within this radius.
const PATTERN_RADIUS: f64 = 13.0;

/// The largest Hamming distance accepted by a projection search (ORB-SLAM's 100).
pub const TH_HIGH: u32 = 100;
/// The largest Hamming distance accepted by brute-force matching (ORB-SLAM's 50).
pub const TH_LOW: u32 = 50;

/// The number of differing bits.
#[inline]
pub fn hamming(a: &Descriptor, b: &Descriptor) -> u32 {
    (a[0] ^ b[0]).count_ones()
        + (a[1] ^ b[1]).count_ones()
        + (a[2] ^ b[2]).count_ones()
        + (a[3] ^ b[3]).count_ones()
}

/// The 256 point pairs `(x1, y1, x2, y2)` of the comparison pattern.
pub fn pattern() -> &'static [[f32; 4]; 256] {
    static PATTERN: OnceLock<[[f32; 4]; 256]> = OnceLock::new();
    PATTERN.get_or_init(|| {
        let mut rng = Rng::new(0x0B_41EF);
        let mut point = || loop {
            let (x, y) = (rng.normal() * 31.0 / 5.0, rng.normal() * 31.0 / 5.0);
            if x * x + y * y <= PATTERN_RADIUS * PATTERN_RADIUS {
                return (x.round() as f32, y.round() as f32);
            }
        };
        let mut pairs = [[0f32; 4]; 256];
        for pair in pairs.iter_mut() {
            loop {
                let (a, b) = (point(), point());
                if a != b {
                    *pair = [a.0, a.1, b.0, b.1];
                    break;
                }
            }
        }
        pairs
    })
}

/// Half-widths of the orientation disc per row offset `v` in `-15..=15`.
fn disc_half_widths() -> &'static [i32; (2 * HALF_PATCH + 1) as usize] {
    static WIDTHS: OnceLock<[i32; (2 * HALF_PATCH + 1) as usize]> = OnceLock::new();
    WIDTHS.get_or_init(|| {
        let mut widths = [0; (2 * HALF_PATCH + 1) as usize];
        let r2 = (HALF_PATCH * HALF_PATCH) as f64 + 0.5;
        for (i, w) in widths.iter_mut().enumerate() {
            let v = i as i32 - HALF_PATCH;
            *w = (r2 - (v * v) as f64).sqrt().floor() as i32;
        }
        widths
    })
}

/// The intensity-centroid angle (radians) at integer pixel `(x, y)`, which must be at
/// least [`HALF_PATCH`] pixels from every border.
pub fn orientation(image: &GrayImage, x: i32, y: i32) -> f32 {
    let w = image.width() as i32;
    let src = image.as_raw();
    let widths = disc_half_widths();
    // Column weights u = -15..=15; each row's slice is summed plainly and weighted by u.
    const U: [i32; (2 * HALF_PATCH + 1) as usize] = {
        let mut u = [0; (2 * HALF_PATCH + 1) as usize];
        let mut i = 0;
        while i < u.len() {
            u[i] = i as i32 - HALF_PATCH;
            i += 1;
        }
        u
    };
    let (mut m01, mut m10) = (0i32, 0i32);
    for v in -HALF_PATCH..=HALF_PATCH {
        let half = widths[(v + HALF_PATCH) as usize];
        let start = ((y + v) * w + x - half) as usize;
        let row = &src[start..start + (2 * half + 1) as usize];
        let weights = &U[(HALF_PATCH - half) as usize..(HALF_PATCH + half + 1) as usize];
        let (mut sum, mut moment) = (0i32, 0i32);
        for (&value, &u) in row.iter().zip(weights) {
            sum += value as i32;
            moment += u * value as i32;
        }
        m10 += moment;
        m01 += v * sum;
    }
    (m01 as f32).atan2(m10 as f32)
}

/// The pattern's coordinates as four columns (first point x, y; second point x, y), so
/// that rotating all 512 points is a loop over plain arrays.
fn pattern_columns() -> &'static [[f32; 256]; 4] {
    static COLUMNS: OnceLock<[[f32; 256]; 4]> = OnceLock::new();
    COLUMNS.get_or_init(|| {
        let mut columns = [[0f32; 256]; 4];
        for (k, pair) in pattern().iter().enumerate() {
            for (column, &value) in columns.iter_mut().zip(pair) {
                column[k] = value;
            }
        }
        columns
    })
}

/// The rotated BRIEF descriptor at integer pixel `(x, y)` of the smoothed image: the
/// pattern rotated by `angle`, each point rounded to the nearest pixel.
pub fn describe(smoothed: &GrayImage, x: i32, y: i32, angle: f32) -> Descriptor {
    let w = smoothed.width() as i32;
    let src = smoothed.as_raw();
    let (sin, cos) = angle.sin_cos();
    let [ax, ay, bx, by] = pattern_columns();
    // Round to nearest without a libm call: shift into positive range and truncate
    // (pattern offsets stay within ±16).
    let round = |x: f32| (x + 64.5) as i32 - 64;
    let offsets = |xs: &[f32; 256], ys: &[f32; 256]| {
        let mut offsets = [0i32; 256];
        for ((o, &px), &py) in offsets.iter_mut().zip(xs).zip(ys) {
            *o = round(px * sin + py * cos) * w + round(px * cos - py * sin);
        }
        offsets
    };
    let (first, second) = (offsets(ax, ay), offsets(bx, by));
    let centre = y * w + x;
    let mut descriptor = [0u64; 4];
    for (word, (first, second)) in descriptor
        .iter_mut()
        .zip(first.chunks_exact(64).zip(second.chunks_exact(64)))
    {
        for (bit, (&a, &b)) in first.iter().zip(second).enumerate() {
            let less = src[(centre + a) as usize] < src[(centre + b) as usize];
            *word |= (less as u64) << bit;
        }
    }
    descriptor
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pattern_stays_inside_the_patch() {
        for p in pattern() {
            for (x, y) in [(p[0], p[1]), (p[2], p[3])] {
                assert!((x * x + y * y).sqrt() <= 13.0 + 0.71);
            }
        }
    }

    #[test]
    fn orientation_points_to_the_bright_side() {
        // Brightness grows with x: the centroid lies along +x, angle 0.
        let image = GrayImage::from_fn(41, 41, |x, _| image::Luma([(x * 5) as u8]));
        assert!(orientation(&image, 20, 20).abs() < 1e-3);
        // Brightness grows with y: angle +90°.
        let image = GrayImage::from_fn(41, 41, |_, y| image::Luma([(y * 5) as u8]));
        assert!((orientation(&image, 20, 20) - std::f32::consts::FRAC_PI_2).abs() < 1e-3);
    }

    #[test]
    fn descriptors_follow_rotation() {
        // A random texture and the same texture rotated by 90°: with the angles found
        // by `orientation`, the descriptors at the centre agree.
        let mut rng = Rng::new(5);
        let base: Vec<u8> = (0..61 * 61)
            .map(|_| (rng.uniform() * 255.0) as u8)
            .collect();
        let image = GrayImage::from_raw(61, 61, base.clone()).unwrap();
        let smooth = super::super::pyramid::gaussian_blur(&image, 2.0, 3);
        // Rotating by +90°: new(x, y) = old(y, 60 - x).
        let rotated = GrayImage::from_fn(61, 61, |x, y| *smooth.get_pixel(y, 60 - x));
        let (a0, a1) = (orientation(&smooth, 30, 30), orientation(&rotated, 30, 30));
        let d0 = describe(&smooth, 30, 30, a0);
        let d1 = describe(&rotated, 30, 30, a1);
        assert!(hamming(&d0, &d1) < 30, "{}", hamming(&d0, &d1));
        assert_eq!(hamming(&d0, &d0), 0);
        let other = describe(&smooth, 25, 33, a0);
        assert!(hamming(&d0, &other) > 60);
    }
}
