//! FAST-9 corners (Rosten and Drummond 2006): a pixel \(p\) is a corner at threshold
//! \(t\) when 9 contiguous pixels of the 16 on the Bresenham circle of radius 3 are all
//! brighter than \(I_p + t\) or all darker than \(I_p - t\). The score of a corner is the
//! largest such \(t\) (so a corner found at threshold \(t\) has score \(> t\)), which
//! lets one pass at the fallback threshold serve both ORB-SLAM thresholds.

use image::GrayImage;

/// The circle of radius 3, clockwise from the top.
const CIRCLE: [(isize, isize); 16] = [
    (0, -3),
    (1, -3),
    (2, -2),
    (3, -1),
    (3, 0),
    (3, 1),
    (2, 2),
    (1, 3),
    (0, 3),
    (-1, 3),
    (-2, 2),
    (-3, 1),
    (-3, 0),
    (-3, -1),
    (-2, -2),
    (-1, -3),
];

/// A corner at integer pixel `(x, y)` with its score.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Corner {
    /// Column.
    pub x: u32,
    /// Row.
    pub y: u32,
    /// FAST score: the largest threshold at which the pixel is still a corner.
    pub score: u8,
}

/// Whether the 16-bit circle mask has 9 contiguous set bits (with wrap-around).
fn has_arc_of_nine(mask: u32) -> bool {
    let doubled = mask | (mask << 16);
    let mut run = doubled;
    for shift in 1..9 {
        run &= doubled >> shift;
    }
    run != 0
}

/// The largest \(t\) for which the arc test holds: the best over the 16 arcs of the
/// smallest difference on the arc, for brighter and darker arcs.
fn score(differences: &[i16; 16]) -> u8 {
    arc_score(differences).clamp(0, 255) as u8
}

/// [`score`] before clamping: negative where no arc is uniformly brighter or darker.
///
/// The minimum over each arc of 9 comes from minima over windows of 2, 4 and 8
/// (\(m_{2k}(i) = \min(m_k(i), m_k(i + k))\)), on the circle written out twice: about 70
/// element-wise operations on fixed arrays, which vectorise, in place of 16 × 9.
fn arc_score(differences: &[i16; 16]) -> i16 {
    let mut twice = [0i16; 25];
    for (i, t) in twice.iter_mut().enumerate() {
        *t = differences[i % 16];
    }
    // Brighter arcs: the best minimum of d; darker ones: the best minimum of -d, that is
    // minus the smallest maximum of d.
    let mut low = [0i16; 24];
    let mut high = [0i16; 24];
    for i in 0..24 {
        low[i] = twice[i].min(twice[i + 1]);
        high[i] = twice[i].max(twice[i + 1]);
    }
    for i in 0..22 {
        low[i] = low[i].min(low[i + 2]);
        high[i] = high[i].max(high[i + 2]);
    }
    for i in 0..18 {
        low[i] = low[i].min(low[i + 4]);
        high[i] = high[i].max(high[i + 4]);
    }
    let mut best = i16::MIN;
    for i in 0..16 {
        let brighter = low[i].min(twice[i + 8]);
        let darker = -high[i].max(twice[i + 8]);
        best = best.max(brighter).max(darker);
    }
    best
}

/// The arc score at any interior pixel (at least 3 from the border): negative where no
/// arc is uniformly brighter or darker.
pub fn score_at(image: &GrayImage, x: u32, y: u32) -> i16 {
    let w = image.width() as isize;
    let src = image.as_raw();
    let i = y as isize * w + x as isize;
    let p = src[i as usize] as i16;
    let mut differences = [0i16; 16];
    for (k, (dx, dy)) in CIRCLE.iter().enumerate() {
        differences[k] = src[(i + dy * w + dx) as usize] as i16 - p;
    }
    arc_score(&differences)
}

/// Sub-pixel position of a corner: the vertex of the parabola through the scores at
/// \(x-1, x, x+1\) (and likewise in y), \(\delta = \frac{s_{-} - s_{+}}{2(s_{-} - 2 s_0 + s_{+})}\),
/// clamped to half a pixel. Removes the bias of integer positions, which at coarse
/// pyramid levels is the same for all points of a translating view.
pub fn refine(image: &GrayImage, corner: &Corner) -> (f32, f32) {
    let (x, y) = (corner.x, corner.y);
    let centre = score_at(image, x, y) as f32;
    let offset = |minus: f32, plus: f32| {
        let curvature = minus - 2.0 * centre + plus;
        if curvature < 0.0 {
            (0.5 * (minus - plus) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let dx = offset(
        score_at(image, x - 1, y) as f32,
        score_at(image, x + 1, y) as f32,
    );
    let dy = offset(
        score_at(image, x, y - 1) as f32,
        score_at(image, x, y + 1) as f32,
    );
    (x as f32 + dx, y as f32 + dy)
}

/// Corners with score above `threshold` inside `[border, width - border)` ×
/// `[border, height - border)`, after 3×3 non-maximum suppression on the score.
pub fn detect(image: &GrayImage, threshold: u8, border: u32) -> Vec<Corner> {
    let (w, h) = (image.width(), image.height());
    let border = border.max(3);
    if w <= 2 * border || h <= 2 * border {
        return Vec::new();
    }
    detect_in(image, threshold, (border, border, w - border, h - border))
}

/// The quick rejection for the pixels `x0..x1` of row `y`, written to `passes` (1 where
/// the pixel may be a corner): an arc of 9 on the circle covers two neighbouring compass
/// points (0 and 4, 4 and 8, 8 and 12, or 12 and 0), both brighter than \(I_p + t\) or
/// both darker than \(I_p - t\). Branch-free over whole rows, so it vectorises.
fn compass_test(
    src: &[u8],
    w: usize,
    y: usize,
    (x0, x1): (usize, usize),
    threshold: u8,
    passes: &mut [u8],
) {
    let n = x1 - x0;
    let centre = &src[y * w + x0..][..n];
    let up = &src[(y - 3) * w + x0..][..n];
    let down = &src[(y + 3) * w + x0..][..n];
    let left = &src[y * w + x0 - 3..][..n];
    let right = &src[y * w + x0 + 3..][..n];
    let passes = &mut passes[..n];
    for i in 0..n {
        let (high, low) = (
            centre[i].saturating_add(threshold),
            centre[i].saturating_sub(threshold),
        );
        let bright = |c: u8| (c > high) as u8;
        let dark = |c: u8| (c < low) as u8;
        let (b0, b4, b8, b12) = (
            bright(up[i]),
            bright(right[i]),
            bright(down[i]),
            bright(left[i]),
        );
        let (d0, d4, d8, d12) = (dark(up[i]), dark(right[i]), dark(down[i]), dark(left[i]));
        passes[i] = (b0 & b4)
            | (b4 & b8)
            | (b8 & b12)
            | (b12 & b0)
            | (d0 & d4)
            | (d4 & d8)
            | (d8 & d12)
            | (d12 & d0);
    }
}

/// Corners with score above `threshold` in the rectangle `[x0, x1) × [y0, y1)`, which
/// must keep 3 pixels from the image borders; non-maximum suppression looks only
/// inside the rectangle.
pub fn detect_in(image: &GrayImage, threshold: u8, rect: (u32, u32, u32, u32)) -> Vec<Corner> {
    let (x0, y0, x1, y1) = (
        rect.0 as usize,
        rect.1 as usize,
        rect.2 as usize,
        rect.3 as usize,
    );
    if x1 <= x0 || y1 <= y0 {
        return Vec::new();
    }
    let w = image.width() as usize;
    let src = image.as_raw();
    let offsets: [isize; 16] = CIRCLE.map(|(dx, dy)| dy * w as isize + dx);
    let t = threshold as i16;
    // Scores of the rectangle with a one-pixel frame of zeros, for the suppression.
    let (rw, rh) = (x1 - x0 + 2, y1 - y0 + 2);
    let mut scores = vec![0u8; rw * rh];
    let mut candidates = Vec::new();
    let mut passes = vec![0u8; x1 - x0];
    for y in y0..y1 {
        compass_test(src, w, y, (x0, x1), threshold, &mut passes);
        for (column, _) in passes.iter().enumerate().filter(|(_, &m)| m != 0) {
            let x = x0 + column;
            let i = y * w + x;
            let p = src[i] as i16;
            let mut differences = [0i16; 16];
            let (mut bright_mask, mut dark_mask) = (0u32, 0u32);
            for (k, d) in differences.iter_mut().enumerate() {
                *d = src[(i as isize + offsets[k]) as usize] as i16 - p;
                bright_mask |= ((*d > t) as u32) << k;
                dark_mask |= ((*d < -t) as u32) << k;
            }
            if has_arc_of_nine(bright_mask) || has_arc_of_nine(dark_mask) {
                let local = (y - y0 + 1) * rw + (x - x0 + 1);
                scores[local] = score(&differences);
                candidates.push(local);
            }
        }
    }
    candidates
        .into_iter()
        .filter(|&i| {
            // A neighbour beats this corner with a higher score, or with an equal one
            // when it comes earlier in raster order.
            let s = scores[i];
            let stride = rw as isize;
            let earlier = [-stride - 1, -stride, -stride + 1, -1];
            let later = [1, stride - 1, stride, stride + 1];
            let at = |o: isize| scores[(i as isize + o) as usize];
            earlier.iter().all(|&o| at(o) < s) && later.iter().all(|&o| at(o) <= s)
        })
        .map(|i| Corner {
            x: (i % rw + x0 - 1) as u32,
            y: (i / rw + y0 - 1) as u32,
            score: scores[i],
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::Rng;
    use proptest::prelude::*;

    /// The arc score by its definition: every arc's minimum, brighter and darker.
    fn arc_score_by_definition(differences: &[i16; 16]) -> i16 {
        let mut best = i16::MIN;
        for start in 0..16 {
            let arc = (0..9).map(|k| differences[(start + k) % 16]);
            let brighter = arc.clone().min().unwrap_or(i16::MIN);
            let darker = arc.map(|d| -d).min().unwrap_or(i16::MIN);
            best = best.max(brighter).max(darker);
        }
        best
    }

    proptest! {
        #[test]
        fn arc_score_equals_its_definition(differences in prop::array::uniform16(-255i16..=255)) {
            prop_assert_eq!(arc_score(&differences), arc_score_by_definition(&differences));
        }

        #[test]
        fn the_compass_test_keeps_every_corner(seed in 0u64..1000, threshold in 1u8..60) {
            // Coarse noise with blocks, so that corners of every kind occur.
            let mut rng = Rng::new(seed);
            let image = GrayImage::from_fn(40, 20, |_, _| image::Luma([(rng.uniform() * 255.0) as u8]));
            let (w, src) = (40usize, image.as_raw());
            let mut passes = vec![0u8; 40 - 6];
            for y in 3..17 {
                compass_test(src, w, y, (3, 37), threshold, &mut passes);
                for x in 3..37 {
                    let p = src[y * w + x] as i16;
                    let (mut bright, mut dark) = (0u32, 0u32);
                    for (k, (dx, dy)) in CIRCLE.iter().enumerate() {
                        let c = src[(y as isize + dy) as usize * w + (x as isize + dx) as usize] as i16;
                        bright |= ((c - p > threshold as i16) as u32) << k;
                        dark |= ((c - p < -(threshold as i16)) as u32) << k;
                    }
                    if has_arc_of_nine(bright) || has_arc_of_nine(dark) {
                        prop_assert_eq!(passes[x - 3], 1, "corner at ({}, {}) rejected", x, y);
                    }
                }
            }
        }
    }

    #[test]
    fn arcs_wrap_around() {
        assert!(has_arc_of_nine(0b1111_1111_1000_0000));
        assert!(has_arc_of_nine(0b1111_0000_0001_1111));
        assert!(!has_arc_of_nine(0b1111_0000_0000_1111));
        assert!(!has_arc_of_nine(0b0101_0101_0101_0101));
    }

    #[test]
    fn a_bright_square_corner_is_found_with_its_score() {
        // A dark image with a bright quadrant: the quadrant's corner is a FAST corner.
        let mut image = GrayImage::from_pixel(40, 40, image::Luma([20]));
        for y in 20..40 {
            for x in 20..40 {
                image.put_pixel(x, y, image::Luma([200]));
            }
        }
        let corners = detect(&image, 20, 3);
        assert!(!corners.is_empty());
        assert!(corners
            .iter()
            .all(|c| (c.x as i32 - 20).abs() <= 2 && (c.y as i32 - 20).abs() <= 2));
        // Differences are 0 or ±180: the best arc's minimum is 180.
        assert_eq!(corners[0].score, 180);
        assert!(detect(&image, 180, 3).is_empty());
        let flat = GrayImage::from_pixel(40, 40, image::Luma([90]));
        assert!(detect(&flat, 7, 3).is_empty());
    }
}
