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
    pub x: u32,
    pub y: u32,
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
fn arc_score(differences: &[i16; 16]) -> i16 {
    let mut best = i16::MIN;
    for start in 0..16 {
        let (mut brighter, mut darker) = (i16::MAX, i16::MAX);
        for k in 0..9 {
            let d = differences[(start + k) % 16];
            brighter = brighter.min(d);
            darker = darker.min(-d);
        }
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
    for y in y0..y1 {
        for x in x0..x1 {
            let i = y * w + x;
            let p = src[i] as i16;
            let at = |k: usize| src[(i as isize + offsets[k]) as usize] as i16;
            // Quickest rejection: an arc of 9 covers circle point 0 or 8.
            let (top, bottom) = (at(0), at(8));
            if (top - p).abs() <= t && (bottom - p).abs() <= t {
                continue;
            }
            // Then: an arc of 9 covers two neighbouring compass points.
            let compass = [top, at(4), bottom, at(12)];
            let bright = compass.map(|c| c > p + t);
            let dark = compass.map(|c| c < p - t);
            let pair = |b: [bool; 4]| (0..4).any(|k| b[k] && b[(k + 1) % 4]);
            if !pair(bright) && !pair(dark) {
                continue;
            }
            let mut differences = [0i16; 16];
            let (mut bright_mask, mut dark_mask) = (0u32, 0u32);
            for (k, d) in differences.iter_mut().enumerate() {
                *d = at(k) - p;
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
