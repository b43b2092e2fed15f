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
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SgbmSettings {
    /// Disparities searched, from 0 (a multiple of 16).
    pub disparities: i32,
    /// Block side (odd).
    pub block: i32,
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
/// size (the readers check it).
#[cfg(feature = "opencv")]
pub fn sgbm_disparity(
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
pub fn sgbm_disparity(
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

    #[test]
    fn a_shifted_texture_gives_its_disparity() {
        // Right pixel x shows left pixel x + 12: disparity 12 everywhere it can be seen.
        let texture = |x: u32, y: u32| ((x * 7919 + y * 104_729) % 251) as u8;
        let left = GrayImage::from_fn(160, 96, |x, y| image::Luma([texture(x, y)]));
        let right = GrayImage::from_fn(160, 96, |x, y| image::Luma([texture(x + 12, y)]));
        let settings = SgbmSettings {
            disparities: 32,
            block: 5,
        };
        let disparity = sgbm_disparity(&left, &right, &settings).unwrap();
        let valid: Vec<f32> = disparity.iter().copied().filter(|&d| d > 0.0).collect();
        assert!(valid.len() > disparity.len() / 2, "{} valid", valid.len());
        let close = valid.iter().filter(|&&d| (d - 12.0).abs() <= 0.5).count();
        assert!(
            close * 10 >= valid.len() * 9,
            "{close} of {} within 0.5 px",
            valid.len()
        );
        let depth = stereo_depth(
            &left,
            &right,
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
}
