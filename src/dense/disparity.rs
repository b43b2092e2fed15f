//! Dense depth of a rectified stereo pair for the dense map: OpenCV's semi-global
//! matcher (Hirschmüller 2008, `StereoSGBM`), disparity \(d\) in pixels to depth
//! \(z = bf / d\); pixels without a valid disparity get no depth.
//!
//! The penalties follow OpenCV's guidance, \(P_1 = 8 b^2\) and \(P_2 = 32 b^2\) for a
//! block side \(b\) on grey images, with a left-right check of 1 pixel, uniqueness
//! 10 %, and speckle filtering over 100-pixel regions.

use image::GrayImage;

use crate::io::image_files::DepthImage;

/// The matcher's settings.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SgbmSettings {
    /// Disparities searched, from 0 (a multiple of 16).
    pub disparities: i32,
    /// Block side (odd).
    pub block: i32,
    /// The pair is matched at 1/`downscale` of its size (1, 2 or 4: each halving
    /// averages 2x2 pixels) with `disparities / downscale` disparities, and the
    /// disparities come back at full size (each small pixel's disparity times
    /// `downscale`, to the pixels it covers).
    pub downscale: u32,
}

/// What the dense pass needs to turn a stereo pair into depth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoDepth {
    /// Baseline times \(f_x\), pixel·metres.
    pub bf: f64,
    /// Pixels added to every disparity: the rig's offset that tracking added
    /// (`crate::run::rig_offset`) and the global pass took out after it
    /// (`crate::global::disparity_offset`), 0 when neither did.
    pub offset: f64,
    /// The semi-global matcher's settings.
    pub sgbm: SgbmSettings,
}

/// The disparity map in pixels (row-major; negative where invalid) of a pair of one
/// size, at the pair's size whatever `settings.downscale` is.
pub fn sgbm_disparity(
    left: &GrayImage,
    right: &GrayImage,
    settings: &SgbmSettings,
) -> Result<Vec<f32>, String> {
    if settings.downscale <= 1 {
        return sgbm_at_size(left, right, settings);
    }
    let (mut small_left, mut small_right) = (half_size(left), half_size(right));
    let mut factor = 2;
    while factor < settings.downscale {
        small_left = half_size(&small_left);
        small_right = half_size(&small_right);
        factor *= 2;
    }
    let small_settings = SgbmSettings {
        disparities: ((settings.disparities / factor as i32 + 15) / 16).max(1) * 16,
        ..*settings
    };
    let small = sgbm_at_size(&small_left, &small_right, &small_settings)
        .map_err(|e| format!("{e} (matched at 1/{factor} size: [stereo] sgbm_downscale)"))?;
    Ok(upsample(
        &small,
        (small_left.width(), small_left.height()),
        (left.width(), left.height()),
        factor,
    ))
}

/// The image at half its size (rounded down), each pixel the mean of a 2x2 block.
fn half_size(image: &GrayImage) -> GrayImage {
    let (width, height) = (image.width() / 2, image.height() / 2);
    GrayImage::from_fn(width.max(1), height.max(1), |x, y| {
        let (x0, y0) = (
            (2 * x).min(image.width() - 1),
            (2 * y).min(image.height() - 1),
        );
        let (x1, y1) = (
            (x0 + 1).min(image.width() - 1),
            (y0 + 1).min(image.height() - 1),
        );
        let sum: u32 = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
            .iter()
            .map(|&(x, y)| image.get_pixel(x, y)[0] as u32)
            .sum();
        image::Luma([((sum + 2) / 4) as u8])
    })
}

/// Disparities of a `small` map back at `full` size: each pixel takes the small
/// pixel that covers it (the last row or column for the ones a halving dropped),
/// its disparity times `factor`; invalid stays invalid.
fn upsample(small: &[f32], small_size: (u32, u32), full: (u32, u32), factor: u32) -> Vec<f32> {
    let (small_width, small_height) = (small_size.0 as usize, small_size.1 as usize);
    let (width, height) = (full.0 as usize, full.1 as usize);
    let columns: Vec<usize> = (0..width)
        .map(|x| (x / factor as usize).min(small_width - 1))
        .collect();
    let mut out = Vec::with_capacity(width * height);
    for y in 0..height {
        let row = &small[(y / factor as usize).min(small_height - 1) * small_width..];
        out.extend(columns.iter().map(|&x| {
            let d = row[x];
            if d > 0.0 {
                d * factor as f32
            } else {
                -1.0
            }
        }));
    }
    out
}

#[cfg(feature = "opencv")]
fn sgbm_at_size(
    left: &GrayImage,
    right: &GrayImage,
    settings: &SgbmSettings,
) -> Result<Vec<f32>, String> {
    use opencv::calib3d::{StereoSGBM, StereoSGBM_MODE_SGBM_3WAY};
    use opencv::core::Mat;
    use opencv::prelude::*;
    let error = |e: opencv::Error| format!("OpenCV StereoSGBM: {e}");
    check_size(left, right, settings)?;
    let (rows, cols) = (left.height() as i32, left.width() as i32);
    let left_mat = Mat::new_rows_cols_with_data(rows, cols, left.as_raw()).map_err(error)?;
    let right_mat = Mat::new_rows_cols_with_data(rows, cols, right.as_raw()).map_err(error)?;
    let b2 = settings.block * settings.block;
    let mut matcher = StereoSGBM::create(
        0,
        settings.disparities,
        settings.block,
        8 * b2,
        32 * b2,
        1,
        63,
        10,
        100,
        2,
        StereoSGBM_MODE_SGBM_3WAY,
    )
    .map_err(error)?;
    let mut disparity = Mat::default();
    matcher
        .compute(&left_mat, &right_mat, &mut disparity)
        .map_err(error)?;
    let fixed: &[i16] = disparity.data_typed().map_err(error)?;
    Ok(fixed.iter().map(|&d| d as f32 / 16.0).collect())
}

/// What OpenCV's matcher needs of a pair, checked here: OpenCV reports a violation by
/// a C++ exception inside its worker threads, which aborts the process.
pub fn check_size(
    left: &GrayImage,
    right: &GrayImage,
    settings: &SgbmSettings,
) -> Result<(), String> {
    if left.dimensions() != right.dimensions() {
        return Err(format!(
            "the stereo pair's images differ in size: {}x{} and {}x{}",
            left.width(),
            left.height(),
            right.width(),
            right.height()
        ));
    }
    let (width, height) = (left.width() as i64, left.height() as i64);
    let block = settings.block as i64;
    if width <= settings.disparities as i64 + block || height < block {
        return Err(format!(
            "a {width}x{height} stereo pair is too small for the matcher's {} disparities and {block}-pixel blocks: it needs more than {} columns and at least {block} rows ([stereo] sgbm_disparities, sgbm_block)",
            settings.disparities,
            settings.disparities as i64 + block
        ));
    }
    Ok(())
}

/// Without OpenCV there is no dense stereo depth.
#[cfg(not(feature = "opencv"))]
fn sgbm_at_size(
    _left: &GrayImage,
    _right: &GrayImage,
    _settings: &SgbmSettings,
) -> Result<Vec<f32>, String> {
    Err("this dopslam was built without OpenCV (cargo feature \"opencv\"), which the dense depth of stereo pairs needs: install libopencv-dev clang libclang-dev (tools/setup.sh does) and build again".into())
}

/// The depth of a stereo pair: \(z = bf / (d + \delta)\) where that is positive
/// (\(\delta\): `stereo.offset`).
pub fn stereo_depth(
    left: &GrayImage,
    right: &GrayImage,
    stereo: &StereoDepth,
) -> Result<DepthImage, String> {
    let disparity = sgbm_disparity(left, right, &stereo.sgbm)?;
    Ok(DepthImage {
        width: left.width(),
        height: left.height(),
        metres: disparity
            .iter()
            .map(|&d| {
                let d = d as f64 + stereo.offset;
                if d > 0.0 {
                    (stereo.bf / d) as f32
                } else {
                    0.0
                }
            })
            .collect(),
    })
}

#[cfg(all(test, feature = "opencv"))]
mod tests {
    use super::*;

    /// A `width` x `height` pair whose right pixel x shows left pixel x + 12: disparity
    /// 12 everywhere it can be seen. The texture changes every `grain` pixels.
    fn shifted_pair(width: u32, height: u32, grain: u32) -> (GrayImage, GrayImage) {
        let texture = |x: u32, y: u32| ((x / grain * 7919 + y / grain * 104_729) % 251) as u8;
        let left = GrayImage::from_fn(width, height, |x, y| image::Luma([texture(x, y)]));
        let right = GrayImage::from_fn(width, height, |x, y| image::Luma([texture(x + 12, y)]));
        (left, right)
    }

    /// Most pixels of `pair` matched with `settings` have a disparity, and 9 in 10 of
    /// them lie within `tolerance` of 12; the disparities.
    fn matched_at_12(
        pair: &(GrayImage, GrayImage),
        settings: &SgbmSettings,
        tolerance: f32,
    ) -> Vec<f32> {
        let disparity = sgbm_disparity(&pair.0, &pair.1, settings).unwrap();
        assert_eq!(disparity.len(), (pair.0.width() * pair.0.height()) as usize);
        let valid: Vec<f32> = disparity.iter().copied().filter(|&d| d > 0.0).collect();
        assert!(valid.len() > disparity.len() / 2, "{} valid", valid.len());
        let close = valid
            .iter()
            .filter(|&&d| (d - 12.0).abs() <= tolerance)
            .count();
        assert!(
            close * 10 >= valid.len() * 9,
            "{close} of {} within {tolerance} px",
            valid.len()
        );
        disparity
    }

    #[test]
    fn a_shifted_texture_gives_its_disparity() {
        let pair = shifted_pair(160, 96, 1);
        let settings = SgbmSettings {
            disparities: 32,
            block: 5,
            downscale: 1,
        };
        matched_at_12(&pair, &settings, 0.5);
        let depth = stereo_depth(
            &pair.0,
            &pair.1,
            &StereoDepth {
                bf: 120.0,
                offset: 0.0,
                sgbm: settings,
            },
        )
        .unwrap();
        let centre = depth.metres[48 * 160 + 100];
        assert!((centre - 10.0).abs() < 0.5, "{centre} m");
    }

    #[test]
    fn a_pair_matched_at_half_size_gives_its_disparity_at_full_size() {
        // An odd size: the last column and row take the small map's last ones.
        let settings = SgbmSettings {
            disparities: 32,
            block: 5,
            downscale: 2,
        };
        let disparity = matched_at_12(&shifted_pair(241, 97, 2), &settings, 1.0);
        assert!(disparity[96 * 241 + 240] > 0.0, "the last pixel has one");
    }

    #[test]
    fn half_size_averages_blocks_and_upsample_scales_back() {
        let image = GrayImage::from_fn(5, 3, |x, y| image::Luma([(10 * x + 100 * y) as u8]));
        let half = half_size(&image);
        assert_eq!(half.dimensions(), (2, 1));
        // (0 + 10 + 100 + 110) / 4 = 55; (20 + 30 + 120 + 130) / 4 = 75.
        assert_eq!((half.get_pixel(0, 0)[0], half.get_pixel(1, 0)[0]), (55, 75));
        let full = upsample(&[3.0, -1.0], (2, 1), (5, 3), 2);
        assert_eq!(full.len(), 15);
        assert_eq!(&full[..5], &[6.0, 6.0, -1.0, -1.0, -1.0]);
        assert_eq!(&full[10..], &full[..5]);
    }

    #[test]
    fn a_pair_too_small_at_its_downscale_is_an_error_naming_the_key() {
        let image = GrayImage::new(100, 40);
        let settings = SgbmSettings {
            disparities: 128,
            block: 5,
            downscale: 2,
        };
        let error = sgbm_disparity(&image, &image, &settings).unwrap_err();
        assert!(error.contains("sgbm_downscale"), "{error}");
    }
}
