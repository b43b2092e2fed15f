//! A contact sheet of a generated sequence: a few frames in rows, colour, depth and
//! mask side by side at half resolution, so a person can see what the test bed is.

use std::path::Path;

use image::{imageops, Rgb, RgbImage};

use crate::io::file_list::read_file_list;
use crate::io::image_files::{read_depth, read_rgb};
use crate::io::IoError;

/// Colours of instance ids 1, 2, … in the mask column (0 stays black).
const INSTANCE_COLOURS: [[u8; 3]; 6] = [
    [230, 60, 60],
    [60, 200, 90],
    [70, 110, 240],
    [240, 200, 40],
    [200, 80, 220],
    [40, 210, 220],
];

/// Builds the contact sheet of `rows` evenly spaced frames of the sequence in `dir`
/// (which must hold rgb.txt, depth.txt and masks/), depth shown grey from 0 to 5 m.
pub fn contact_sheet(dir: &Path, rows: usize) -> Result<RgbImage, IoError> {
    let rgb_list = read_file_list(&dir.join("rgb.txt"), 1)?;
    let depth_list = read_file_list(&dir.join("depth.txt"), 1)?;
    if rgb_list.is_empty() || rgb_list.len() != depth_list.len() {
        return Err(IoError::invalid(
            dir,
            "rgb.txt and depth.txt must list the same, non-zero number of frames",
        ));
    }
    let rows = rows.clamp(1, rgb_list.len());
    let picks: Vec<usize> = (0..rows)
        .map(|i| i * (rgb_list.len() - 1) / rows.max(2).saturating_sub(1).max(1))
        .map(|i| i.min(rgb_list.len() - 1))
        .collect();
    let first = read_rgb(&dir.join(&rgb_list[0].fields[0]))?;
    let (w, h) = (first.width() / 2, first.height() / 2);
    let mut sheet = RgbImage::from_pixel(3 * w, rows as u32 * h, Rgb([255, 255, 255]));
    for (row, &index) in picks.iter().enumerate() {
        let rgb = read_rgb(&dir.join(&rgb_list[index].fields[0]))?;
        let depth = read_depth(&dir.join(&depth_list[index].fields[0]), 5000.0)?;
        let depth_image = RgbImage::from_fn(depth.width, depth.height, |x, y| {
            let grey = (255.0 * (1.0 - depth.at(x, y) / 5.0)).clamp(0.0, 255.0) as u8;
            if depth.at(x, y) > 0.0 {
                Rgb([grey; 3])
            } else {
                Rgb([0, 0, 0])
            }
        });
        let mask_path = dir
            .join("masks")
            .join(format!("{:.6}.png", rgb_list[index].timestamp));
        let mask = image::open(&mask_path)
            .map_err(|e| IoError::Image {
                path: mask_path.clone(),
                message: e.to_string(),
            })?
            .to_luma8();
        let mask_image = RgbImage::from_fn(mask.width(), mask.height(), |x, y| {
            match mask.get_pixel(x, y)[0] {
                0 => Rgb([0, 0, 0]),
                id => Rgb(INSTANCE_COLOURS[(id as usize - 1) % INSTANCE_COLOURS.len()]),
            }
        });
        for (column, image) in [rgb, depth_image, mask_image].iter().enumerate() {
            let small = imageops::resize(image, w, h, imageops::FilterType::Triangle);
            imageops::replace(
                &mut sheet,
                &small,
                (column as u32 * w) as i64,
                (row as u32 * h) as i64,
            );
        }
    }
    Ok(sheet)
}
