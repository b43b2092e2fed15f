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
    /// \(s\): the scale between two levels.
    pub scale_factor: f64,
    /// \(s^l\) per level.
    pub factors: Vec<f64>,
    /// \(s^{-l}\) per level.
    pub inverse_factors: Vec<f64>,
    /// \(\sigma_l^2 = s^{2l}\) per level.
    pub sigma2: Vec<f64>,
    /// \(\sigma_l^{-2}\) per level.
    pub inverse_sigma2: Vec<f64>,
}

impl ScalePyramid {
    /// The pyramid of `levels` levels `scale_factor` apart.
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

    /// The number of levels.
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
    // Each source row is resampled across once, into one of two row buffers (the
    // output rows step by less than two source rows); the vertical blend then runs over
    // whole rows.
    let across = |y: usize, buffer: &mut Vec<f32>| {
        let row = &src[y * w..(y + 1) * w];
        buffer.clear();
        buffer.extend(
            taps.iter()
                .map(|&(x0, x1, wx)| row[x0] as f32 * (1.0 - wx) + row[x1] as f32 * wx),
        );
    };
    let (mut rows, mut held) = ([Vec::new(), Vec::new()], [usize::MAX; 2]);
    let mut out = vec![0u8; width as usize * height as usize];
    for (y, out_row) in out.chunks_exact_mut(width as usize).enumerate() {
        let fy = ((y as f32 + 0.5) * sy - 0.5).max(0.0);
        let y0 = (fy as usize).min(h - 1);
        let y1 = (y0 + 1).min(h - 1);
        let wy = fy - y0 as f32;
        // The row below often becomes the row above.
        if held[0] != y0 {
            if held[1] == y0 {
                rows.swap(0, 1);
                held.swap(0, 1);
            } else {
                across(y0, &mut rows[0]);
                held[0] = y0;
            }
        }
        if held[1] != y1 {
            across(y1, &mut rows[1]);
            held[1] = y1;
        }
        for ((o, &top), &bottom) in out_row.iter_mut().zip(&rows[0]).zip(&rows[1]) {
            *o = (top * (1.0 - wy) + bottom * wy + 0.5) as u8;
        }
    }
    GrayImage::from_raw(width, height, out).expect("size matches")
}

/// A separable Gaussian blur (kernel of `2 * radius + 1` taps, borders replicated), in
/// fixed point: the taps are rounded to integers summing to \(2^8\), so the horizontal
/// pass fits `u16` and the vertical one `u32`, and the result is
/// \(\lfloor (\sum_j k_j \sum_i k_i I + 2^{15}) / 2^{16} \rfloor\). Both passes run a tap
/// at a time over whole rows, which vectorises.
pub fn gaussian_blur(image: &GrayImage, sigma: f32, radius: usize) -> GrayImage {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let kernel = fixed_point_kernel(sigma, radius);
    let src = image.as_raw();
    let r = radius;
    // Horizontal pass from a border-replicated copy of each row.
    let mut horizontal = vec![0u16; w * h];
    let mut padded = vec![0u16; w + 2 * r];
    for y in 0..h {
        let row = &src[y * w..(y + 1) * w];
        for (i, p) in padded.iter_mut().enumerate() {
            *p = row[i.saturating_sub(r).min(w - 1)] as u16;
        }
        let out = &mut horizontal[y * w..(y + 1) * w];
        for (i, &k) in kernel.iter().enumerate() {
            for (o, &p) in out.iter_mut().zip(&padded[i..i + w]) {
                *o += k * p;
            }
        }
    }
    // Vertical pass: each output row is a weighted sum of whole input rows.
    let mut out = vec![0u8; w * h];
    let mut accumulator = vec![0u32; w];
    for y in 0..h {
        accumulator.iter_mut().for_each(|a| *a = 1 << 15);
        for (i, &k) in kernel.iter().enumerate() {
            let yy = (y + i).saturating_sub(r).min(h - 1);
            let row = &horizontal[yy * w..(yy + 1) * w];
            for (a, &v) in accumulator.iter_mut().zip(row) {
                *a += k as u32 * v as u32;
            }
        }
        for (o, &a) in out[y * w..(y + 1) * w].iter_mut().zip(&accumulator) {
            *o = (a >> 16) as u8;
        }
    }
    GrayImage::from_raw(w as u32, h as u32, out).expect("size matches")
}

/// The Gaussian's `2 * radius + 1` taps as integers summing to 256: rounded, then the
/// rounding's remainder put on the centre tap.
fn fixed_point_kernel(sigma: f32, radius: usize) -> Vec<u16> {
    let weights: Vec<f32> = (0..=2 * radius)
        .map(|i| {
            let d = i as f32 - radius as f32;
            (-d * d / (2.0 * sigma * sigma)).exp()
        })
        .collect();
    let sum: f32 = weights.iter().sum();
    let mut kernel: Vec<u16> = weights
        .iter()
        .map(|v| (v / sum * 256.0).round() as u16)
        .collect();
    let total: i32 = kernel.iter().map(|&k| k as i32).sum();
    kernel[radius] = (kernel[radius] as i32 + 256 - total) as u16;
    kernel
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
    fn shrinking_samples_each_pixel_bilinearly() {
        let mut rng = crate::random::Rng::new(5);
        let image = GrayImage::from_fn(50, 37, |_, _| image::Luma([(rng.uniform() * 255.0) as u8]));
        for (width, height) in [(42, 31), (25, 18), (50, 37), (7, 5)] {
            let small = resize_bilinear(&image, width, height);
            let (sx, sy) = (50.0 / width as f32, 37.0 / height as f32);
            for (x, y, value) in small.enumerate_pixels() {
                let fx = ((x as f32 + 0.5) * sx - 0.5).max(0.0);
                let fy = ((y as f32 + 0.5) * sy - 0.5).max(0.0);
                let (x0, y0) = ((fx as u32).min(49), (fy as u32).min(36));
                let (x1, y1) = ((x0 + 1).min(49), (y0 + 1).min(36));
                let (wx, wy) = (fx - x0 as f32, fy - y0 as f32);
                let at = |x: u32, y: u32| image.get_pixel(x, y).0[0] as f32;
                let top = at(x0, y0) * (1.0 - wx) + at(x1, y0) * wx;
                let bottom = at(x0, y1) * (1.0 - wx) + at(x1, y1) * wx;
                let expected = (top * (1.0 - wy) + bottom * wy + 0.5) as u8;
                assert_eq!(value.0[0], expected, "({x}, {y}) at {width}x{height}");
            }
        }
    }

    #[test]
    fn the_fixed_point_kernel_sums_to_256_and_is_symmetric() {
        let kernel = fixed_point_kernel(2.0, 3);
        assert_eq!(kernel.iter().map(|&k| k as u32).sum::<u32>(), 256);
        assert!((0..7).all(|i| kernel[i] == kernel[6 - i]));
        assert!(kernel.windows(2).take(3).all(|w| w[0] < w[1]));
    }

    #[test]
    fn shrinking_keeps_a_constant_image_constant() {
        let image = GrayImage::from_pixel(64, 48, image::Luma([77]));
        let small = resize_bilinear(&image, 53, 40);
        assert!(small.as_raw().iter().all(|&v| v == 77));
        let blurred = gaussian_blur(&image, 2.0, 3);
        assert!(blurred.as_raw().iter().all(|&v| v == 77));
        let white = gaussian_blur(&GrayImage::from_pixel(9, 5, image::Luma([255])), 2.0, 3);
        assert!(white.as_raw().iter().all(|&v| v == 255));
        let levels = ScalePyramid::new(4, 1.2).build(&image);
        assert_eq!((levels[3].width(), levels[3].height()), (37, 28));
    }
}
