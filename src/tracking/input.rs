//! Checks on a frame's images before tracking, and the picture kept for the detector.

use image::{GrayImage, RgbImage};

use super::TrackingState;
use crate::io::image_files::DepthImage;
use crate::io::orbslam_settings::Calibration;

/// Catches a wrong depth scale early: a first frame whose median depth no RGB-D sensor
/// gives, or ten depth images without any depth before tracking starts.
#[derive(Debug, Default)]
pub struct DepthCheck {
    frames_without_depth: usize,
}

impl DepthCheck {
    /// `Err` with the message to stop on.
    pub fn check(
        &mut self,
        index: usize,
        depth: &DepthImage,
        state: TrackingState,
        calibration: &Calibration,
    ) -> Result<(), String> {
        let scale = calibration.depth_scale.unwrap_or(5000.0);
        if index == 0 {
            if let Some(median) = median_depth(depth) {
                if !(0.05..=100.0).contains(&median) {
                    return Err(format!(
                        "frame {index}: the median depth is {median:.3} m, which no RGB-D sensor gives: is depth_scale right ({scale} raw units per metre)?"
                    ));
                }
            }
        }
        if depth.valid_fraction() == 0.0 {
            self.frames_without_depth += 1;
            if state == TrackingState::NotInitialised && self.frames_without_depth >= 10 {
                return Err(format!(
                    "the first {} depth images hold no depth at all: is depth_scale right ({scale}), and does depth.txt list depth maps?",
                    self.frames_without_depth
                ));
            }
        }
        Ok(())
    }
}

/// The median of the valid depths, if any.
fn median_depth(depth: &DepthImage) -> Option<f64> {
    let mut valid: Vec<f64> = depth
        .metres
        .iter()
        .filter(|&&z| z > 0.0)
        .map(|&z| z as f64)
        .collect();
    if valid.is_empty() {
        return None;
    }
    valid.sort_by(f64::total_cmp);
    Some(crate::eval::stats::median_of_sorted(&valid))
}

/// The image a frame shows the detector and the debug drawings: the colour image of
/// an RGB-D frame, the left image of a stereo pair.
#[derive(Debug, Clone)]
pub enum Picture {
    /// A colour image (RGB-D).
    Colour(RgbImage),
    /// A grey image (stereo).
    Grey(GrayImage),
}

impl Picture {
    /// The picture in colour (a grey one with its value in all three channels).
    pub fn into_colour(self) -> RgbImage {
        match self {
            Picture::Colour(rgb) => rgb,
            Picture::Grey(grey) => image::DynamicImage::ImageLuma8(grey).to_rgb8(),
        }
    }
}
