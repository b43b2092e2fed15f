//! Sparse stereo matching on a rectified pair (ORB-SLAM2's `ComputeStereoMatches`).
//!
//! For each left keypoint \((u_L, v_L)\) at level \(l\), the candidates are the right
//! keypoints on the same rows (within \(\pm 2 s^{l'}\) of their own row) at levels
//! \(l-1 \ldots l+1\) whose column lies in \([u_L - d_{max}, u_L - d_{min}]\), with
//! \(d_{max} = bf / b = f_x\) (nothing closer than one baseline) and \(d_{min} = 0\).
//! The best descriptor within the mid Hamming threshold (75) is refined on the level
//! image by the sum of absolute differences of 11×11 patches, each less its centre
//! value (robust to a brightness offset), over shifts \(-5 \ldots 5\); a parabola
//! through the best SAD and its neighbours gives the sub-pixel shift
//! \(\delta = \frac{s_{-1} - s_{+1}}{2 (s_{-1} + s_{+1} - 2 s_0)}\), kept when
//! \(|\delta| \le 1\) and the best shift is not on the window's edge. The disparity
//! \(d = u_L - u_R\) gives the depth \(z = bf / d\). Last, matches whose SAD exceeds
//! \(1.5 \cdot 1.4 \cdot\) the median SAD are dropped (a robust \(\sigma\) from the median).

use image::GrayImage;

use crate::features::{
    hamming, KeyPoint, OrbExtractor, OrbFeatures, ScalePyramid, TH_HIGH, TH_LOW,
};

/// Half side of the SAD patch, and the half range of the SAD search.
const PATCH: i32 = 5;
const SEARCH: i32 = 5;

/// The stereo depth of each left keypoint.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StereoMatches {
    /// Depth in metres; 0 where no match was kept.
    pub depth: Vec<f32>,
    /// The matched right-image column at level 0; negative where no match was kept.
    pub right_u: Vec<f32>,
}

impl StereoMatches {
    /// How many left keypoints have a depth.
    pub fn matched(&self) -> usize {
        self.depth.iter().filter(|&&z| z > 0.0).count()
    }
}

/// The left and right images' features with their pyramid levels.
pub struct StereoFeatures<'a> {
    /// The left image's features.
    pub left: &'a OrbFeatures,
    /// The right image's features.
    pub right: &'a OrbFeatures,
    /// The left image's pyramid (for the sub-pixel search).
    pub left_levels: &'a [GrayImage],
    /// The right image's pyramid.
    pub right_levels: &'a [GrayImage],
}

/// Matches the left keypoints along rows into the right image; `bf` is the baseline
/// times \(f_x\) in pixel·metres.
pub fn match_stereo(
    features: &StereoFeatures<'_>,
    pyramid: &ScalePyramid,
    bf: f64,
    fx: f64,
) -> StereoMatches {
    let n = features.left.len();
    let mut matches = StereoMatches {
        depth: vec![0.0; n],
        right_u: vec![-1.0; n],
    };
    let Some(level0) = features.left_levels.first() else {
        return matches;
    };
    let rows = row_table(features.right, pyramid, level0.height());
    // ORB-SLAM2's mid threshold: the mean of the upper and lower ones.
    let threshold = (TH_HIGH + TH_LOW) / 2;
    let (min_d, max_d) = (0.0f32, fx as f32);
    let mut sads: Vec<(u32, usize)> = Vec::with_capacity(n);
    for (i, left) in features.left.keypoints.iter().enumerate() {
        let row = left.y.round();
        if row < 0.0 || row as usize >= rows.len() {
            continue;
        }
        let (min_u, max_u) = (left.x - max_d, left.x - min_d);
        if max_u < 0.0 {
            continue;
        }
        let level = left.level as i32;
        let mut best = (TH_HIGH, usize::MAX);
        for &j in &rows[row as usize] {
            let right = &features.right.keypoints[j as usize];
            if (right.level as i32 - level).abs() > 1 || right.x < min_u || right.x > max_u {
                continue;
            }
            let distance = hamming(
                &features.left.descriptors[i],
                &features.right.descriptors[j as usize],
            );
            if distance < best.0 {
                best = (distance, j as usize);
            }
        }
        if best.0 >= threshold {
            continue;
        }
        let right_u0 = features.right.keypoints[best.1].x;
        let Some((right_u, sad)) = refine(
            features,
            pyramid,
            left.level as usize,
            (left.x, left.y),
            right_u0,
        ) else {
            continue;
        };
        let mut disparity = left.x - right_u;
        if disparity < min_d || disparity >= max_d {
            continue;
        }
        let mut right_u = right_u;
        if disparity <= 0.0 {
            disparity = 0.01;
            right_u = left.x - 0.01;
        }
        matches.depth[i] = (bf / disparity as f64) as f32;
        matches.right_u[i] = right_u;
        sads.push((sad, i));
    }
    drop_outliers(&mut matches, &mut sads);
    matches
}

/// Makes the keypoints farther than `depth` metres bearings only: they keep their depth
/// (which places the points a keyframe makes from them) but lose their right column,
/// so the optimisers weigh only their image position, \((u, v)\), not the disparity
/// residual \(u_R - (u - bf/z)\). `depth` 0 leaves every keypoint as it is.
///
/// Why: a constant disparity error \(\delta\) (the rectification of a real rig) moves
/// the depth by \(\Delta z \approx z^2 \delta / bf\), a share \(z\delta/bf\) of it
/// that grows with the distance. As residuals the far disparities pull the scale of
/// every pose and point that shares them; on the real KITTI clips the path grew 6 %
/// over 51 frames with them, and the ATE halved without them beyond 22 baselines
/// (`docs/design.md`, "Stereo on real images").
pub fn bearings_beyond(matches: &mut StereoMatches, depth: f32) {
    if depth <= 0.0 {
        return;
    }
    for (z, u) in matches.depth.iter().zip(matches.right_u.iter_mut()) {
        if *z > depth {
            *u = -1.0;
        }
    }
}

/// The disparity `d` pixels with the rig's offset added, kept above 0.01 px (as stereo
/// matching keeps it).
pub fn offset_disparity(d: f64, offset: f64) -> f64 {
    (d + offset).max(0.01)
}

/// Adds the rig's disparity `offset` (pixels) to every match of the left `keypoints`:
/// depth \(bf / (d + \delta)\), right column \(u - d - \delta\).
pub fn add_disparity_offset(
    matches: &mut StereoMatches,
    keypoints: &[KeyPoint],
    bf: f64,
    offset: f64,
) {
    if offset == 0.0 {
        return;
    }
    for ((kp, z), u) in keypoints
        .iter()
        .zip(matches.depth.iter_mut())
        .zip(matches.right_u.iter_mut())
    {
        if *u >= 0.0 {
            let d = offset_disparity((kp.x - *u) as f64, offset);
            *z = (bf / d) as f32;
            *u = kp.x - d as f32;
        }
    }
}

/// A rectified stereo pair: the left camera's image and the right camera's.
#[derive(Clone, Copy)]
pub struct StereoPair<'a> {
    /// The left camera's image.
    pub left: &'a GrayImage,
    /// The right camera's image.
    pub right: &'a GrayImage,
}

/// How a stereo frame's keypoint depths are finished: the rig's disparity offset added,
/// and the depth beyond which keypoints are bearings only.
#[derive(Debug, Clone, Copy)]
pub struct DepthSettings {
    /// Keypoints farther than this many metres lose their right column (0: none do).
    pub bearing_depth: f32,
    /// Pixels added to every disparity.
    pub disparity_offset: f64,
}

/// Extracts ORB from both images of a rectified pair (in parallel) and matches the
/// left keypoints into the right image: the left features and their stereo depths.
pub fn extract_and_match(
    pair: StereoPair,
    extractor: &OrbExtractor,
    bf: f64,
    fx: f64,
) -> (OrbFeatures, StereoMatches) {
    let ((left_features, left_levels), (right_features, right_levels)) = rayon::join(
        || extractor.extract_with_levels(pair.left),
        || extractor.extract_with_levels(pair.right),
    );
    let stereo = StereoFeatures {
        left: &left_features,
        right: &right_features,
        left_levels: &left_levels,
        right_levels: &right_levels,
    };
    let matches = match_stereo(&stereo, &extractor.pyramid, bf, fx);
    (left_features, matches)
}

/// Whether a pair looks swapped (its right image is the left camera's): each left
/// keypoint's best descriptor match along its rows, at either sign of disparity
/// within \(\pm f_x\) (and the mid threshold, neighbouring levels), points the wrong
/// way for most keypoints: at least 100 matches with a negative disparity (below -1
/// px) and twice as many as with a positive one. The real KITTI 06 pair swapped gives
/// 1382 against 315 (counting only matches at a positive disparity, as before, gave
/// 697 swapped against 1060 as given: no warning). The counts `(positive, negative)`
/// when it looks swapped.
pub fn looks_swapped(
    pair: StereoPair,
    extractor: &OrbExtractor,
    fx: f64,
) -> Option<(usize, usize)> {
    let ((lf, _), (rf, _)) = rayon::join(
        || extractor.extract_with_levels(pair.left),
        || extractor.extract_with_levels(pair.right),
    );
    let height = pair.left.height();
    let (positive, negative) = disparity_signs(&lf, &rf, &extractor.pyramid, height, fx);
    (negative >= 100 && negative >= 2 * positive).then_some((positive, negative))
}

/// How many left keypoints' best matches along their rows (see [`looks_swapped`]) lie
/// at a disparity above 1 px and below -1 px.
fn disparity_signs(
    left: &OrbFeatures,
    right: &OrbFeatures,
    pyramid: &ScalePyramid,
    height: u32,
    fx: f64,
) -> (usize, usize) {
    let rows = row_table(right, pyramid, height);
    let threshold = (TH_HIGH + TH_LOW) / 2;
    let (mut positive, mut negative) = (0, 0);
    for (i, l) in left.keypoints.iter().enumerate() {
        let Some(row) = rows.get(l.y.round().max(0.0) as usize) else {
            continue;
        };
        let best = row
            .iter()
            .map(|&j| (j as usize, &right.keypoints[j as usize]))
            .filter(|(_, r)| {
                (r.level as i32 - l.level as i32).abs() <= 1 && (l.x - r.x).abs() as f64 <= fx
            })
            .map(|(j, r)| {
                (
                    hamming(&left.descriptors[i], &right.descriptors[j]),
                    l.x - r.x,
                )
            })
            .min_by_key(|&(distance, _)| distance);
        match best {
            Some((distance, d)) if distance < threshold && d > 1.0 => positive += 1,
            Some((distance, d)) if distance < threshold && d < -1.0 => negative += 1,
            _ => {}
        }
    }
    (positive, negative)
}

/// For each level-0 row, the right keypoints whose row band \(y \pm 2 s^l\) covers it.
fn row_table(right: &OrbFeatures, pyramid: &ScalePyramid, height: u32) -> Vec<Vec<u32>> {
    let mut rows = vec![Vec::new(); height as usize];
    for (j, k) in right.keypoints.iter().enumerate() {
        let band = 2.0 * pyramid.factors[k.level as usize] as f32;
        let first = (k.y - band).floor().max(0.0) as usize;
        let last = ((k.y + band).ceil().max(0.0) as usize).min(rows.len().saturating_sub(1));
        for row in rows.iter_mut().take(last + 1).skip(first) {
            row.push(j as u32);
        }
    }
    rows
}

/// Level coordinate of a level-0 coordinate (the inverse of the extractor's
/// \(x_0 = (x + 0.5) s - 0.5\)).
fn to_level(x: f32, scale: f32) -> f32 {
    (x + 0.5) / scale - 0.5
}

/// The SAD of the left patch centred at `(ul, vl)` and the right one at `(ur, vl)`,
/// each less its centre value; `None` when a patch leaves the image.
fn sad(left: &GrayImage, right: &GrayImage, (ul, vl): (i32, i32), ur: i32) -> Option<u32> {
    let inside = |image: &GrayImage, u: i32| {
        u - PATCH >= 0
            && vl - PATCH >= 0
            && u + PATCH < image.width() as i32
            && vl + PATCH < image.height() as i32
    };
    if !inside(left, ul) || !inside(right, ur) {
        return None;
    }
    let (lw, rw) = (left.width() as usize, right.width() as usize);
    let (l, r) = (left.as_raw(), right.as_raw());
    let lc = l[vl as usize * lw + ul as usize] as i32;
    let rc = r[vl as usize * rw + ur as usize] as i32;
    let mut total = 0u32;
    for dv in -PATCH..=PATCH {
        let v = (vl + dv) as usize;
        let lrow = &l[v * lw + (ul - PATCH) as usize..=v * lw + (ul + PATCH) as usize];
        let rrow = &r[v * rw + (ur - PATCH) as usize..=v * rw + (ur + PATCH) as usize];
        for (&a, &b) in lrow.iter().zip(rrow) {
            total += ((a as i32 - lc) - (b as i32 - rc)).unsigned_abs();
        }
    }
    Some(total)
}

/// Refines a match by SAD on the keypoint's level: the sub-pixel right column at
/// level 0 and the best SAD.
fn refine(
    features: &StereoFeatures<'_>,
    pyramid: &ScalePyramid,
    level: usize,
    (ul, vl): (f32, f32),
    right_u0: f32,
) -> Option<(f32, u32)> {
    let scale = pyramid.factors[level] as f32;
    let (left, right) = (&features.left_levels[level], &features.right_levels[level]);
    let sul = to_level(ul, scale).round() as i32;
    let svl = to_level(vl, scale).round() as i32;
    let sur0 = to_level(right_u0, scale).round() as i32;
    let mut distances = [0u32; (2 * SEARCH + 1) as usize];
    let mut best = (u32::MAX, 0i32);
    for shift in -SEARCH..=SEARCH {
        let distance = sad(left, right, (sul, svl), sur0 + shift)?;
        distances[(shift + SEARCH) as usize] = distance;
        if distance < best.0 {
            best = (distance, shift);
        }
    }
    if best.1 == -SEARCH || best.1 == SEARCH {
        return None;
    }
    let at = (best.1 + SEARCH) as usize;
    let (d1, d2, d3) = (
        distances[at - 1] as f32,
        distances[at] as f32,
        distances[at + 1] as f32,
    );
    let curvature = 2.0 * (d1 + d3 - 2.0 * d2);
    let delta = if curvature > 0.0 {
        (d1 - d3) / curvature
    } else {
        0.0
    };
    if !(-1.0..=1.0).contains(&delta) {
        return None;
    }
    let level_u = (sur0 + best.1) as f32 + delta;
    Some(((level_u + 0.5) * scale - 0.5, best.0))
}

/// Drops matches whose SAD exceeds \(1.5 \cdot 1.4\) times the median SAD.
fn drop_outliers(matches: &mut StereoMatches, sads: &mut [(u32, usize)]) {
    if sads.is_empty() {
        return;
    }
    sads.sort_unstable();
    let median = sads[sads.len() / 2].0 as f32;
    let limit = 1.5 * 1.4 * median;
    for &(sad, i) in sads.iter().rev() {
        if (sad as f32) <= limit {
            break;
        }
        matches.depth[i] = 0.0;
        matches.right_u[i] = -1.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::{OrbConfig, OrbExtractor};

    #[test]
    fn the_rigs_offset_moves_every_match_and_only_matches() {
        let keypoints: Vec<KeyPoint> = [100.0, 50.0, 20.0]
            .iter()
            .map(|&x| KeyPoint {
                x,
                ..KeyPoint::default()
            })
            .collect();
        // Disparities 10 and 0.5 px, and a keypoint without a match.
        let mut matches = StereoMatches {
            depth: vec![10.0, 200.0, 0.0],
            right_u: vec![90.0, 49.5, -1.0],
        };
        add_disparity_offset(&mut matches, &keypoints, 100.0, 1.0);
        assert!((matches.depth[0] - 100.0 / 11.0).abs() < 1e-4);
        assert!((matches.right_u[0] - 89.0).abs() < 1e-4);
        assert!((matches.depth[1] - 100.0 / 1.5).abs() < 1e-3);
        assert_eq!((matches.depth[2], matches.right_u[2]), (0.0, -1.0));
        // A negative offset larger than a disparity keeps it at 0.01 px.
        add_disparity_offset(&mut matches, &keypoints, 100.0, -3.0);
        assert!((matches.depth[1] - 100.0 / 0.01).abs() < 1.0);
        assert!((matches.right_u[0] - 92.0).abs() < 1e-4);
    }

    /// A textured image and the same shifted left by a disparity that falls with the
    /// row (a slanted plane): the right image of a pair whose depth is known.
    fn pair(width: u32, height: u32) -> (GrayImage, GrayImage, impl Fn(f32) -> f32) {
        let texture = |x: f32, y: f32| -> u8 {
            let seed = ((x * 0.37).sin() * 43758.5 + (y * 0.71).cos() * 12345.6)
                .fract()
                .abs();
            let blocks =
                (((x / 7.0).floor() as i32 * 31 + (y / 5.0).floor() as i32 * 17) % 97) as f32;
            (blocks * 2.0 + seed * 60.0).clamp(0.0, 255.0) as u8
        };
        let disparity = move |y: f32| 20.0 + 10.0 * y / height as f32;
        let left = GrayImage::from_fn(width, height, |x, y| {
            image::Luma([texture(x as f32, y as f32)])
        });
        let right = GrayImage::from_fn(width, height, |x, y| {
            // Right pixel x sees the left pixel x + d; linear interpolation between texels.
            let xs = x as f32 + disparity(y as f32);
            let (x0, t) = (xs.floor(), xs.fract());
            let a = texture(x0, y as f32) as f32;
            let b = texture(x0 + 1.0, y as f32) as f32;
            image::Luma([(a * (1.0 - t) + b * t).round() as u8])
        });
        (left, right, disparity)
    }

    #[test]
    fn matches_recover_the_disparity_of_a_shifted_image() {
        let (left, right, disparity) = pair(320, 200);
        let extractor = OrbExtractor::new(&OrbConfig {
            n_features: 800,
            ..OrbConfig::default()
        });
        let (lf, ll) = extractor.extract_with_levels(&left);
        let (rf, rl) = extractor.extract_with_levels(&right);
        let features = StereoFeatures {
            left: &lf,
            right: &rf,
            left_levels: &ll,
            right_levels: &rl,
        };
        let bf = 40.0;
        let matches = match_stereo(&features, &extractor.pyramid, bf, 500.0);
        let matched = matches.matched();
        assert!(
            matched * 5 > lf.len() * 2,
            "{matched} of {} matched",
            lf.len()
        );
        let mut errors: Vec<f32> = lf
            .keypoints
            .iter()
            .zip(&matches.right_u)
            .filter(|(_, &u)| u >= 0.0)
            .map(|(k, &u)| ((k.x - u) - disparity(k.y)).abs())
            .collect();
        errors.sort_by(f32::total_cmp);
        let median = errors[errors.len() / 2];
        assert!(median < 0.5, "median disparity error {median} px");
        for (z, u) in matches.depth.iter().zip(&matches.right_u) {
            assert_eq!(*z > 0.0, *u >= 0.0);
        }
    }

    #[test]
    fn far_keypoints_keep_their_depth_and_lose_their_right_column() {
        let mut matches = StereoMatches {
            depth: vec![5.0, 11.0, 30.0, 0.0],
            right_u: vec![100.0, 200.0, 300.0, -1.0],
        };
        let unchanged = matches.clone();
        bearings_beyond(&mut matches, 0.0);
        assert_eq!(matches, unchanged);
        bearings_beyond(&mut matches, 11.8);
        assert_eq!(matches.depth, unchanged.depth);
        assert_eq!(matches.right_u, vec![100.0, 200.0, -1.0, -1.0]);
    }

    #[test]
    fn nothing_matches_without_a_right_image() {
        let (left, _, _) = pair(200, 120);
        let extractor = OrbExtractor::new(&OrbConfig::default());
        let (lf, ll) = extractor.extract_with_levels(&left);
        let empty = OrbFeatures::default();
        let features = StereoFeatures {
            left: &lf,
            right: &empty,
            left_levels: &ll,
            right_levels: &ll,
        };
        let matches = match_stereo(&features, &extractor.pyramid, 40.0, 500.0);
        assert_eq!(matches.matched(), 0);
        assert_eq!(matches.depth.len(), lf.len());
    }
}
