//! The ORB extractor: per pyramid level, FAST corners in 30-pixel cells (the initial
//! threshold, else the fallback one), spread by the quadtree to the level's share of the
//! budget, oriented by the intensity centroid and described by rotated BRIEF on the
//! level smoothed with a 7×7 Gaussian (\(\sigma = 2\)). Levels run in parallel.

use std::borrow::Cow;

use image::GrayImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::checks::BadValue;

use super::descriptor::{describe, orientation, Descriptor, HALF_PATCH};
use super::distribute::spread;
use super::fast;
use super::pyramid::{gaussian_blur, ScalePyramid};

/// Side of the cells in which the FAST threshold falls back (pixels).
const CELL: u32 = 30;
/// Keypoints keep this far from the level's borders, so that the orientation disc and
/// the rotated pattern stay inside.
const BORDER: u32 = HALF_PATCH as u32 + 1;

/// ORB extractor parameters (ORB-SLAM2's `ORBextractor.*`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OrbConfig {
    /// Keypoints per image over all pyramid levels.
    pub n_features: usize,
    /// Scale between pyramid levels.
    pub scale_factor: f64,
    /// Pyramid levels (ORB-SLAM2's `nLevels`).
    pub n_levels: usize,
    /// FAST threshold tried first in each cell.
    pub ini_th_fast: u8,
    /// FAST threshold used where the first finds nothing.
    pub min_th_fast: u8,
    /// Ceiling of the per-frame budget, as a multiple of `n_features`, when movers take
    /// keypoints: the tracking pass raises the budget to \(N / \phi\), \(\phi\) the
    /// static share of the last frame's keypoints, so that about `n_features` stay on the
    /// static scene (beyond ORB-SLAM2; 1 turns it off).
    pub max_features_factor: f64,
}

impl Default for OrbConfig {
    fn default() -> Self {
        Self {
            n_features: 1000,
            scale_factor: 1.2,
            n_levels: 8,
            ini_th_fast: 20,
            min_th_fast: 7,
            max_features_factor: 2.0,
        }
    }
}

impl OrbConfig {
    /// Checks each value's range; the error names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        let orb = self;
        crate::checks::at_least_one("orb.n_features", orb.n_features as u64)?;
        if !(orb.scale_factor > 1.0 && orb.scale_factor < 2.0) {
            return Err(BadValue::new(
                "orb.scale_factor",
                format!("must be in (1, 2), got {}", orb.scale_factor),
            ));
        }
        if !(1..=16).contains(&orb.n_levels) {
            return Err(BadValue::new(
                "orb.n_levels",
                format!("must be in 1..=16, got {}", orb.n_levels),
            ));
        }
        if !(1.0..=4.0).contains(&orb.max_features_factor) {
            return Err(BadValue::new(
                "orb.max_features_factor",
                format!("must be in [1, 4], got {}", orb.max_features_factor),
            ));
        }
        if orb.min_th_fast > orb.ini_th_fast {
            return Err(BadValue::new(
                "orb.min_th_fast",
                format!(
                    "({}) must not exceed orb.ini_th_fast ({})",
                    orb.min_th_fast, orb.ini_th_fast
                ),
            ));
        }
        Ok(())
    }
}

/// A keypoint in level-0 pixel coordinates.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct KeyPoint {
    /// Column (level-0 pixels, sub-pixel).
    pub x: f32,
    /// Row (level-0 pixels).
    pub y: f32,
    /// The pyramid level (ORB-SLAM's octave).
    pub level: u8,
    /// Orientation in radians.
    pub angle: f32,
    /// FAST score.
    pub response: f32,
}

/// The keypoints of one image and their descriptors (same order).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct OrbFeatures {
    /// The keypoints.
    pub keypoints: Vec<KeyPoint>,
    /// One descriptor per keypoint.
    pub descriptors: Vec<Descriptor>,
}

impl OrbFeatures {
    /// The number of keypoints.
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    /// Whether there is no keypoint.
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }
}

/// Extracts ORB features with a fixed configuration.
#[derive(Debug, Clone)]
pub struct OrbExtractor {
    /// The settings it extracts with.
    pub config: OrbConfig,
    /// The scale pyramid of `config`.
    pub pyramid: ScalePyramid,
    per_level: Vec<usize>,
}

impl OrbExtractor {
    /// An extractor for `config`, the keypoint budget spread over the levels.
    pub fn new(config: &OrbConfig) -> Self {
        let pyramid = ScalePyramid::new(config.n_levels, config.scale_factor);
        Self {
            per_level: pyramid.keypoints_per_level(config.n_features),
            config: config.clone(),
            pyramid,
        }
    }

    /// The most keypoints [`Self::with_budget`] allows.
    pub fn max_budget(&self) -> usize {
        (self.config.n_features as f64 * self.config.max_features_factor).round() as usize
    }

    /// The same extractor with a budget of `n_features` keypoints (clamped to
    /// `n_features..=`[`Self::max_budget`] of the config); borrowed when the budget is
    /// already that, as on every frame without movers.
    pub fn with_budget(&self, n_features: usize) -> Cow<'_, Self> {
        let n = n_features.clamp(self.config.n_features, self.max_budget());
        if n == self.budget() {
            return Cow::Borrowed(self);
        }
        Cow::Owned(Self {
            per_level: self.pyramid.keypoints_per_level(n),
            config: self.config.clone(),
            pyramid: self.pyramid.clone(),
        })
    }

    /// The keypoint budget over all levels.
    pub fn budget(&self) -> usize {
        self.per_level.iter().sum()
    }

    /// The ORB features of a grey image.
    pub fn extract(&self, image: &GrayImage) -> OrbFeatures {
        self.extract_with_levels(image).0
    }

    /// The ORB features of a grey image and its pyramid levels (level 0 first), which
    /// stereo matching reads patches from.
    pub fn extract_with_levels(&self, image: &GrayImage) -> (OrbFeatures, Vec<GrayImage>) {
        let levels = self.pyramid.build(image);
        let per_level: Vec<(Vec<KeyPoint>, Vec<Descriptor>)> = levels
            .par_iter()
            .enumerate()
            .map(|(level, level_image)| self.extract_level(level, level_image))
            .collect();
        let mut features = OrbFeatures::default();
        for (keypoints, descriptors) in per_level {
            features.keypoints.extend(keypoints);
            features.descriptors.extend(descriptors);
        }
        (features, levels)
    }

    fn extract_level(&self, level: usize, image: &GrayImage) -> (Vec<KeyPoint>, Vec<Descriptor>) {
        let selected = detect_per_cell(image, self.config.ini_th_fast, self.config.min_th_fast);
        let positions: Vec<(f32, f32)> =
            selected.iter().map(|c| (c.x as f32, c.y as f32)).collect();
        let responses: Vec<f32> = selected.iter().map(|c| c.score as f32).collect();
        let rect = (
            BORDER as f32,
            BORDER as f32,
            (image.width() - BORDER) as f32,
            (image.height() - BORDER) as f32,
        );
        let chosen = spread(&positions, &responses, rect, self.per_level[level]);
        if chosen.is_empty() {
            return (Vec::new(), Vec::new());
        }
        let smoothed = gaussian_blur(image, 2.0, 3);
        let scale = self.pyramid.factors[level] as f32;
        chosen
            .into_iter()
            .map(|i| {
                let c = selected[i];
                let (x, y) = (c.x as i32, c.y as i32);
                let angle = orientation(image, x, y);
                let (sub_x, sub_y) = fast::refine(image, &c);
                // Pixel centres of a level map to level 0 as the resize sampled them:
                // x0 = (x + 0.5) s - 0.5.
                let keypoint = KeyPoint {
                    x: (sub_x + 0.5) * scale - 0.5,
                    y: (sub_y + 0.5) * scale - 0.5,
                    level: level as u8,
                    angle,
                    response: c.score as f32,
                };
                (keypoint, describe(&smoothed, x, y, angle))
            })
            .unzip()
    }
}

/// ORB-SLAM2's two thresholds: FAST at the initial threshold over the level, then at the
/// fallback threshold in the 30-pixel cells where the first found nothing.
fn detect_per_cell(image: &GrayImage, initial: u8, fallback: u8) -> Vec<fast::Corner> {
    let mut corners = fast::detect(image, initial, BORDER);
    let (x1, y1) = (
        image.width().saturating_sub(BORDER),
        image.height().saturating_sub(BORDER),
    );
    if x1 <= BORDER || y1 <= BORDER {
        return corners;
    }
    let columns = (x1 - BORDER).div_ceil(CELL) as usize;
    let rows = (y1 - BORDER).div_ceil(CELL) as usize;
    let mut occupied = vec![false; columns * rows];
    for c in &corners {
        occupied[((c.y - BORDER) / CELL) as usize * columns + ((c.x - BORDER) / CELL) as usize] =
            true;
    }
    for row in 0..rows as u32 {
        for column in 0..columns as u32 {
            if occupied[(row * columns as u32 + column) as usize] {
                continue;
            }
            let (cx, cy) = (BORDER + column * CELL, BORDER + row * CELL);
            corners.extend(fast::detect_in(
                image,
                fallback,
                (cx, cy, (cx + CELL).min(x1), (cy + CELL).min(y1)),
            ));
        }
    }
    corners
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::hamming;
    use crate::random::Rng;

    /// A blocky random texture, rich in corners at every scale.
    fn texture(width: u32, height: u32, seed: u64) -> GrayImage {
        let mut rng = Rng::new(seed);
        let cells: Vec<u8> = (0..(width / 8 + 1) * (height / 8 + 1))
            .map(|_| (rng.uniform() * 255.0) as u8)
            .collect();
        GrayImage::from_fn(width, height, |x, y| {
            let big = cells[((y / 32) * (width / 8 + 1) + x / 32) as usize] / 2;
            let small = cells[((y / 8) * (width / 8 + 1) + x / 8) as usize] / 2;
            image::Luma([big + small])
        })
    }

    #[test]
    fn budget_is_met_and_keypoints_fit_the_image() {
        let extractor = OrbExtractor::new(&OrbConfig::default());
        let image = texture(640, 480, 1);
        let features = extractor.extract(&image);
        assert!(
            features.len() > 950 && features.len() <= 1000,
            "{}",
            features.len()
        );
        assert_eq!(features.keypoints.len(), features.descriptors.len());
        for k in &features.keypoints {
            assert!(k.x >= 0.0 && k.x < 640.0 && k.y >= 0.0 && k.y < 480.0);
        }
        let levels: std::collections::BTreeSet<u8> =
            features.keypoints.iter().map(|k| k.level).collect();
        assert_eq!(levels.len(), 8);
    }

    #[test]
    fn a_shifted_image_gives_matching_descriptors() {
        let extractor = OrbExtractor::new(&OrbConfig::default());
        let image = texture(640, 480, 2);
        let shifted = GrayImage::from_fn(640, 480, |x, y| {
            *image.get_pixel((x + 637) % 640, (y + 475) % 480)
        });
        let (a, b) = (extractor.extract(&image), extractor.extract(&shifted));
        // Level-0 keypoints away from the wrap seam: the same corner, moved by (3, 5),
        // has (nearly) the same descriptor.
        let (mut total, mut found, mut matched) = (0, 0, 0);
        for (ka, da) in a.keypoints.iter().zip(&a.descriptors) {
            if ka.level != 0 || ka.x > 600.0 || ka.y > 440.0 {
                continue;
            }
            total += 1;
            if let Some((_, db)) = b
                .keypoints
                .iter()
                .zip(&b.descriptors)
                .find(|(kb, _)| kb.level == 0 && kb.x == ka.x + 3.0 && kb.y == ka.y + 5.0)
            {
                found += 1;
                if hamming(da, db) <= 10 {
                    matched += 1;
                }
            }
        }
        // The quadtree's cells do not move with the image, so not every corner is
        // chosen again; those that are have the same descriptor.
        assert!(total > 100 && found * 10 >= total * 6, "{found}/{total}");
        assert!(matched * 100 >= found * 95, "{matched}/{found}");
    }

    #[test]
    fn a_raised_budget_gives_more_keypoints_within_the_ceiling() {
        let extractor = OrbExtractor::new(&OrbConfig::default());
        let image = texture(640, 480, 3);
        let more = extractor.with_budget(1500);
        assert_eq!(more.budget(), 1500);
        assert_eq!(extractor.with_budget(10).budget(), 1000);
        assert_eq!(extractor.with_budget(9000).budget(), 2000);
        let (a, b) = (extractor.extract(&image).len(), more.extract(&image).len());
        assert!(a <= 1000 && b > 1400 && b <= 1500, "{a} {b}");
    }

    #[test]
    fn bad_settings_are_named() {
        let bad = OrbConfig {
            min_th_fast: 30,
            ..OrbConfig::default()
        };
        assert!(bad.validate().unwrap_err().key == "orb.min_th_fast");
        let bad = OrbConfig {
            max_features_factor: 0.5,
            ..OrbConfig::default()
        };
        assert!(bad.validate().unwrap_err().key == "orb.max_features_factor");
    }
}
