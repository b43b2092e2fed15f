//! The scale pyramid: level \(l\) is the image shrunk by \(s^l\) (ORB-SLAM2: 8 levels,
//! \(s = 1.2\)), and each level's share of the keypoint budget,
//! \(n_l = N \frac{1 - 1/s}{1 - (1/s)^L} (1/s)^l\), so every level gets the same
//! keypoint density per pixel.

use image::GrayImage;
use serde::{Deserialize, Serialize};

/// Per-level scale factors and the variances the optimiser weighs observations with
/// (\(\sigma_l^2 = s^{2l}\), one pixel at level 0).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScalePyramid {
    pub scale_factor: f64,
    pub factors: Vec<f64>,
    pub inverse_factors: Vec<f64>,
    pub sigma2: Vec<f64>,
    pub inverse_sigma2: Vec<f64>,
}

impl ScalePyramid {
    pub fn new(levels: usize, scale_factor: f64) -> Self {
        let factors: Vec<f64> = (0..levels).map(|l| scale_factor.powi(l as i32)).collect();
        Self {
            scale_factor,
            inverse_factors: factors.iter().map(|f| 1.0 / f).collect(),
            sigma2: factors.iter().map(|f| f * f).collect(),
            inverse_sigma2: factors.iter().map(|f| 1.0 / (f * f)).collect(),
            factors,
        }
    }

    pub fn levels(&self) -> usize {
        self.factors.len()
    }

    /// How many of `total` keypoints each level should get (the sum is `total`).
    pub fn keypoints_per_level(&self, total: usize) -> Vec<usize> {
        let levels = self.levels();
        let shrink = 1.0 / self.scale_factor;
        let first = total as f64 * (1.0 - shrink) / (1.0 - shrink.powi(levels as i32));
        let mut counts: Vec<usize> = (0..levels)
            .map(|l| (first * shrink.powi(l as i32)).round() as usize)
            .collect();
        let assigned: usize = counts[..levels - 1].iter().sum();
        counts[levels - 1] = total.saturating_sub(assigned);
        counts
    }

    /// The pyramid images: level 0 is `image`, each next level a bilinear shrink of the
    /// one before.
    pub fn build(&self, image: &GrayImage) -> Vec<GrayImage> {
        let mut levels = vec![image.clone()];
        for l in 1..self.levels() {
            let width = (image.width() as f64 * self.inverse_factors[l]).round() as u32;
            let height = (image.height() as f64 * self.inverse_factors[l]).round() as u32;
            let shrunk = resize_bilinear(&levels[l - 1], width.max(1), height.max(1));
            levels.push(shrunk);
        }
        levels
    }
}

/// Bilinear resampling with pixel centres aligned (OpenCV's `INTER_LINEAR` rule:
/// source \(x = (x' + 0.5)\,w/w' - 0.5\)).
pub fn resize_bilinear(image: &GrayImage, width: u32, height: u32) -> GrayImage {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let src = image.as_raw();
    let sx = w as f32 / width as f32;
    let sy = h as f32 / height as f32;
    // Precompute the horizontal taps once.
    let taps: Vec<(usize, usize, f32)> = (0..width as usize)
        .map(|x| {
            let fx = ((x as f32 + 0.5) * sx - 0.5).max(0.0);
            let x0 = (fx as usize).min(w - 1);
            let x1 = (x0 + 1).min(w - 1);
            (x0, x1, fx - x0 as f32)
        })
        .collect();
    let mut out = Vec::with_capacity(width as usize * height as usize);
    for y in 0..height as usize {
        let fy = ((y as f32 + 0.5) * sy - 0.5).max(0.0);
        let y0 = (fy as usize).min(h - 1);
        let y1 = (y0 + 1).min(h - 1);
        let wy = fy - y0 as f32;
        let (row0, row1) = (&src[y0 * w..(y0 + 1) * w], &src[y1 * w..(y1 + 1) * w]);
        for &(x0, x1, wx) in &taps {
            let top = row0[x0] as f32 * (1.0 - wx) + row0[x1] as f32 * wx;
            let bottom = row1[x0] as f32 * (1.0 - wx) + row1[x1] as f32 * wx;
            out.push((top * (1.0 - wy) + bottom * wy + 0.5) as u8);
        }
    }
    GrayImage::from_raw(width, height, out).expect("size matches")
}

/// A separable Gaussian blur (kernel of `2 * radius + 1` taps, borders replicated).
/// The interior runs without bounds clamping, and the vertical pass works a whole row
/// at a time, so both vectorise.
pub fn gaussian_blur(image: &GrayImage, sigma: f32, radius: usize) -> GrayImage {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let kernel: Vec<f32> = {
        let k: Vec<f32> = (0..=2 * radius)
            .map(|i| {
                let d = i as f32 - radius as f32;
                (-d * d / (2.0 * sigma * sigma)).exp()
            })
            .collect();
        let sum: f32 = k.iter().sum();
        k.into_iter().map(|v| v / sum).collect()
    };
    let src = image.as_raw();
    let r = radius;
    // Horizontal pass into a padded float row buffer per image row.
    let mut horizontal = vec![0f32; w * h];
    let mut padded = vec![0f32; w + 2 * r];
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for (i, p) in padded.iter_mut().enumerate() {
            *p = row[i.saturating_sub(r).min(w - 1)] as f32;
        }
        let out = &mut horizontal[y * w..(y + 1) * w];
        for (x, o) in out.iter_mut().enumerate() {
            let window = &padded[x..x + 2 * r + 1];
            *o = window.iter().zip(&kernel).map(|(a, k)| a * k).sum();
        }
    }
    // Vertical pass: each output row is a weighted sum of whole input rows.
    let mut out = vec![0u8; w * h];
    let mut accumulator = vec![0f32; w];
    for y in 0..h {
        accumulator.iter_mut().for_each(|a| *a = 0.0);
        for (i, k) in kernel.iter().enumerate() {
            let yy = (y + i).saturating_sub(r).min(h - 1);
            let row = &horizontal[yy * w..(yy + 1) * w];
            for (a, v) in accumulator.iter_mut().zip(row) {
                *a += k * v;
            }
        }
        for (o, a) in out[y * w..(y + 1) * w].iter_mut().zip(&accumulator) {
            *o = (a + 0.5) as u8;
        }
    }
    GrayImage::from_raw(w as u32, h as u32, out).expect("size matches")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn budget_splits_by_area() {
        let pyramid = ScalePyramid::new(8, 1.2);
        let counts = pyramid.keypoints_per_level(1000);
        assert_eq!(counts.iter().sum::<usize>(), 1000);
        // Level 0 gets N (1 - 1/1.2) / (1 - 1.2^-8) = 217.
        assert_eq!(counts[0], 217);
        assert!(counts.windows(2).all(|w| w[0] >= w[1]));
        assert!((pyramid.sigma2[2] - 1.44 * 1.44).abs() < 1e-12);
    }

    #[test]
    fn shrinking_keeps_a_constant_image_constant() {
        let image = GrayImage::from_pixel(64, 48, image::Luma([77]));
        let small = resize_bilinear(&image, 53, 40);
        assert!(small.as_raw().iter().all(|&v| v == 77));
        let blurred = gaussian_blur(&image, 2.0, 3);
        assert!(blurred.as_raw().iter().all(|&v| v == 77));
        let levels = ScalePyramid::new(4, 1.2).build(&image);
        assert_eq!((levels[3].width(), levels[3].height()), (37, 28));
    }
}
