//! Image files: 8-bit colour and grey images, 16-bit depth maps scaled to metres.

use std::path::Path;

use image::{GrayImage, RgbImage};

use super::IoError;

/// A depth map in metres, row-major; 0 marks a pixel without depth.
#[derive(Debug, Clone, PartialEq)]
pub struct DepthImage {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Depth per pixel, row-major, metres (0: none).
    pub metres: Vec<f32>,
}

impl DepthImage {
    /// A depth map without depth.
    pub fn new(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            metres: vec![0.0; (width * height) as usize],
        }
    }

    /// The depth at pixel `(u, v)` in metres; 0 when invalid.
    pub fn at(&self, u: u32, v: u32) -> f32 {
        self.metres[(v * self.width + u) as usize]
    }

    /// The fraction of pixels that hold a depth.
    pub fn valid_fraction(&self) -> f64 {
        let valid = self.metres.iter().filter(|&&d| d > 0.0).count();
        valid as f64 / self.metres.len().max(1) as f64
    }
}

fn open(path: &Path) -> Result<image::DynamicImage, IoError> {
    open_as(path, "image file listed by the sequence")
}

/// Opens an image; `what` says what the missing file was meant to be.
fn open_as(path: &Path, what: &str) -> Result<image::DynamicImage, IoError> {
    super::errors::check_exists(path, what)?;
    image::open(path).map_err(|e| IoError::Image {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Reads a colour image (any 8-bit layout; grey is expanded to RGB).
pub fn read_rgb(path: &Path) -> Result<RgbImage, IoError> {
    Ok(open(path)?.into_rgb8())
}

/// Reads an 8-bit image with an alpha channel (a cut-out); `what` names its use in
/// the error when the file is missing.
pub fn read_rgba(path: &Path, what: &str) -> Result<image::RgbaImage, IoError> {
    let image = open_as(path, what)?;
    if !image.color().has_alpha() {
        return Err(IoError::Image {
            path: path.to_path_buf(),
            message: format!(
                "a cut-out needs an alpha channel, found {:?}",
                image.color()
            ),
        });
    }
    Ok(image.to_rgba8())
}

/// Reads a ground-truth instance mask (`masks/*.png` of a synthetic sequence) as ids:
/// an 8-bit mask is widened without scaling; `None` when absent or unreadable.
pub fn read_instance_mask(path: &Path) -> Option<image::ImageBuffer<image::Luma<u16>, Vec<u16>>> {
    match image::open(path).ok()? {
        image::DynamicImage::ImageLuma8(m) => Some(image::ImageBuffer::from_fn(
            m.width(),
            m.height(),
            |x, y| image::Luma([m.get_pixel(x, y)[0] as u16]),
        )),
        other => Some(other.to_luma16()),
    }
}

/// The file beside the instance masks naming each instance's class (`id class` a
/// line, `#` comments).
pub const INSTANCES: &str = "instances.txt";

/// Reads `masks/instances.txt` (see [`INSTANCES`]): each instance id and its class;
/// `Ok(None)` when the file is absent (masks written before it existed).
pub fn read_instance_classes(masks: &Path) -> Result<Option<Vec<(u16, String)>>, IoError> {
    let path = masks.join(INSTANCES);
    let text = match std::fs::read_to_string(&path) {
        Ok(text) => text,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(source) => return Err(IoError::Read { path, source }),
    };
    let mut classes = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let parsed = line
            .split_once(' ')
            .and_then(|(id, class)| Some((id.parse::<u16>().ok()?, class.trim().to_string())));
        let Some(entry) = parsed else {
            return Err(IoError::Parse {
                path,
                line: n + 1,
                message: format!("expected `instance class`, got {line:?}"),
            });
        };
        classes.push(entry);
    }
    Ok(Some(classes))
}

/// Reads an image as 8-bit grey.
pub fn read_gray(path: &Path) -> Result<GrayImage, IoError> {
    Ok(open(path)?.into_luma8())
}

/// The grey image of a colour image with the sRGB luma weights, rounded,
/// \(Y = \operatorname{round}(0.2126 R + 0.7152 G + 0.0722 B)\), in integers and one pass
/// over the pixels. The `image` crate's `to_luma8` (which needs an owned copy and goes
/// through floats) agrees within one grey level.
pub fn grey_from_rgb(rgb: &RgbImage) -> GrayImage {
    let grey = rgb
        .as_raw()
        .chunks_exact(3)
        .map(|p| {
            ((2126 * p[0] as u32 + 7152 * p[1] as u32 + 722 * p[2] as u32 + 5000) / 10000) as u8
        })
        .collect();
    GrayImage::from_raw(rgb.width(), rgb.height(), grey).expect("one grey value a pixel")
}

/// Reads a 16-bit depth PNG and divides by `depth_scale` (5000 for TUM: a value of
/// 5000 is one metre). An 8-bit image is refused: it cannot be a depth map.
pub fn read_depth(path: &Path, depth_scale: f64) -> Result<DepthImage, IoError> {
    let image = open(path)?;
    let raw = match image {
        image::DynamicImage::ImageLuma16(raw) => raw,
        other => {
            return Err(IoError::Image {
                path: path.to_path_buf(),
                message: format!(
                    "a depth map must be a 16-bit single-channel PNG, found {:?}",
                    other.color()
                ),
            })
        }
    };
    let scale = (1.0 / depth_scale) as f32;
    Ok(DepthImage {
        width: raw.width(),
        height: raw.height(),
        metres: raw.as_raw().iter().map(|&d| d as f32 * scale).collect(),
    })
}

/// Writes a depth map as a 16-bit PNG with the given scale (values rounded, clamped to
/// 65535; 0 stays invalid).
pub fn depth_to_png16(
    depth: &DepthImage,
    depth_scale: f64,
) -> image::ImageBuffer<image::Luma<u16>, Vec<u16>> {
    let data = depth
        .metres
        .iter()
        .map(|&d| {
            if d > 0.0 {
                (d as f64 * depth_scale).round().min(65535.0) as u16
            } else {
                0
            }
        })
        .collect();
    image::ImageBuffer::from_raw(depth.width, depth.height, data).expect("buffer size matches")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn grey_from_rgb_is_within_a_level_of_the_image_crates_conversion() {
        let mut rng = crate::random::Rng::new(3);
        let mut value = || (rng.uniform() * 256.0).min(255.0) as u8;
        let mut rgb = RgbImage::from_fn(31, 17, |_, _| image::Rgb([value(), value(), value()]));
        rgb.put_pixel(0, 0, image::Rgb([255, 255, 255]));
        let expected = image::DynamicImage::ImageRgb8(rgb.clone()).to_luma8();
        let ours = grey_from_rgb(&rgb);
        for ((a, b), p) in ours.pixels().zip(expected.pixels()).zip(rgb.pixels()) {
            assert!(a.0[0].abs_diff(b.0[0]) <= 1, "{p:?}: {a:?} against {b:?}");
        }
        let extremes = RgbImage::from_fn(2, 1, |x, _| image::Rgb([255 * x as u8; 3]));
        assert_eq!(grey_from_rgb(&extremes).as_raw(), &vec![0, 255]);
    }

    #[test]
    fn depth_roundtrip_and_errors() {
        let dir = std::env::temp_dir().join(format!("dopslam-img-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut depth = DepthImage::new(4, 3);
        depth.metres[5] = 1.25;
        depth.metres[7] = 3.0;
        let path = dir.join("d.png");
        depth_to_png16(&depth, 5000.0).save(&path).unwrap();
        let back = read_depth(&path, 5000.0).unwrap();
        assert_eq!(back, depth);
        assert!((back.valid_fraction() - 2.0 / 12.0).abs() < 1e-12);

        let rgb_path = dir.join("c.png");
        RgbImage::new(2, 2).save(&rgb_path).unwrap();
        let message = read_depth(&rgb_path, 5000.0).unwrap_err().to_string();
        assert!(
            message.contains("c.png") && message.contains("16-bit"),
            "{message}"
        );

        let corrupt = dir.join("corrupt.png");
        std::fs::write(&corrupt, b"\x89PNG\r\n\x1a\nnot really").unwrap();
        let message = read_rgb(&corrupt).unwrap_err().to_string();
        assert!(message.contains("corrupt.png"), "{message}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
