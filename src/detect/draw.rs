//! Boxes with labels drawn onto an image, so a person can look at what was detected.
//! Labels use a built-in 5x7 bitmap font (upper-case letters, digits, '.', ' '),
//! drawn at twice its size.

use image::{Rgb, RgbImage};

use super::Detection;

/// 5x7 glyphs, one byte a column, bit 0 at the top.
fn glyph(c: char) -> [u8; 5] {
    match c.to_ascii_uppercase() {
        '0' => [0x3E, 0x51, 0x49, 0x45, 0x3E],
        '1' => [0x00, 0x42, 0x7F, 0x40, 0x00],
        '2' => [0x42, 0x61, 0x51, 0x49, 0x46],
        '3' => [0x21, 0x41, 0x45, 0x4B, 0x31],
        '4' => [0x18, 0x14, 0x12, 0x7F, 0x10],
        '5' => [0x27, 0x45, 0x45, 0x45, 0x39],
        '6' => [0x3C, 0x4A, 0x49, 0x49, 0x30],
        '7' => [0x01, 0x71, 0x09, 0x05, 0x03],
        '8' => [0x36, 0x49, 0x49, 0x49, 0x36],
        '9' => [0x06, 0x49, 0x49, 0x29, 0x1E],
        'A' => [0x7E, 0x11, 0x11, 0x11, 0x7E],
        'B' => [0x7F, 0x49, 0x49, 0x49, 0x36],
        'C' => [0x3E, 0x41, 0x41, 0x41, 0x22],
        'D' => [0x7F, 0x41, 0x41, 0x22, 0x1C],
        'E' => [0x7F, 0x49, 0x49, 0x49, 0x41],
        'F' => [0x7F, 0x09, 0x09, 0x09, 0x01],
        'G' => [0x3E, 0x41, 0x49, 0x49, 0x7A],
        'H' => [0x7F, 0x08, 0x08, 0x08, 0x7F],
        'I' => [0x00, 0x41, 0x7F, 0x41, 0x00],
        'J' => [0x20, 0x40, 0x41, 0x3F, 0x01],
        'K' => [0x7F, 0x08, 0x14, 0x22, 0x41],
        'L' => [0x7F, 0x40, 0x40, 0x40, 0x40],
        'M' => [0x7F, 0x02, 0x0C, 0x02, 0x7F],
        'N' => [0x7F, 0x04, 0x08, 0x10, 0x7F],
        'O' => [0x3E, 0x41, 0x41, 0x41, 0x3E],
        'P' => [0x7F, 0x09, 0x09, 0x09, 0x06],
        'Q' => [0x3E, 0x41, 0x51, 0x21, 0x5E],
        'R' => [0x7F, 0x09, 0x19, 0x29, 0x46],
        'S' => [0x46, 0x49, 0x49, 0x49, 0x31],
        'T' => [0x01, 0x01, 0x7F, 0x01, 0x01],
        'U' => [0x3F, 0x40, 0x40, 0x40, 0x3F],
        'V' => [0x1F, 0x20, 0x40, 0x20, 0x1F],
        'W' => [0x3F, 0x40, 0x38, 0x40, 0x3F],
        'X' => [0x63, 0x14, 0x08, 0x14, 0x63],
        'Y' => [0x07, 0x08, 0x70, 0x08, 0x07],
        'Z' => [0x61, 0x51, 0x49, 0x45, 0x43],
        '.' => [0x00, 0x60, 0x60, 0x00, 0x00],
        _ => [0; 5],
    }
}

/// A distinct colour per class.
fn colour(class_id: u32) -> Rgb<u8> {
    const PALETTE: [[u8; 3]; 6] = [
        [230, 25, 75],
        [60, 180, 75],
        [0, 130, 200],
        [245, 130, 48],
        [145, 30, 180],
        [240, 50, 230],
    ];
    Rgb(PALETTE[class_id as usize % PALETTE.len()])
}

fn fill(image: &mut RgbImage, (x0, y0, x1, y1): (i64, i64, i64, i64), c: Rgb<u8>) {
    let (w, h) = (image.width() as i64, image.height() as i64);
    for y in y0.max(0)..y1.min(h) {
        for x in x0.max(0)..x1.min(w) {
            image.put_pixel(x as u32, y as u32, c);
        }
    }
}

/// Draws `text` with its top-left corner at `(x, y)`, `scale` pixels a font dot.
pub fn draw_text(image: &mut RgbImage, x: i64, y: i64, text: &str, scale: i64, c: Rgb<u8>) {
    for (n, ch) in text.chars().enumerate() {
        for (col, bits) in glyph(ch).iter().enumerate() {
            for row in 0..7 {
                if bits >> row & 1 == 1 {
                    let px = x + (n as i64 * 6 + col as i64) * scale;
                    let py = y + row * scale;
                    fill(image, (px, py, px + scale, py + scale), c);
                }
            }
        }
    }
}

/// Draws each detection's box (3 px) and a label "CLASS 0.97" above it.
pub fn draw_detections(image: &mut RgbImage, detections: &[Detection]) {
    for d in detections {
        let c = colour(d.class_id);
        let [x1, y1, x2, y2] = d.bbox.map(|v| v.round() as i64);
        for t in 0..3 {
            fill(image, (x1, y1 + t, x2, y1 + t + 1), c);
            fill(image, (x1, y2 - 1 - t, x2, y2 - t), c);
            fill(image, (x1 + t, y1, x1 + t + 1, y2), c);
            fill(image, (x2 - 1 - t, y1, x2 - t, y2), c);
        }
        let label = format!("{} {:.2}", d.class, d.score);
        let (width, height) = (label.len() as i64 * 12 + 4, 18);
        let top = if y1 >= height { y1 - height } else { y1 };
        fill(image, (x1, top, x1 + width, top + height), c);
        draw_text(image, x1 + 2, top + 2, &label, 2, Rgb([255, 255, 255]));
    }
}

/// Draws each keypoint of `frame` as a 5x5 square coloured by its DOP state.
pub fn draw_keypoints(
    image: &mut RgbImage,
    frame: &crate::frame::Frame,
    dop: &crate::dop::DopConfig,
) {
    use crate::dop::State;
    for (k, p) in frame.keypoints.iter().zip(&frame.moving) {
        let c = match dop.state(*p) {
            State::StaticHigh => Rgb([0, 200, 0]),
            State::StaticLow => Rgb([230, 230, 0]),
            State::DynamicLow => Rgb([255, 140, 0]),
            State::DynamicHigh => Rgb([230, 0, 0]),
        };
        let (x, y) = (k.x.round() as i64, k.y.round() as i64);
        fill(image, (x - 2, y - 2, x + 3, y + 3), c);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn boxes_and_labels_land_where_they_should() {
        let mut image = RgbImage::new(100, 80);
        let d = Detection {
            class: "person".into(),
            class_id: 0,
            score: 0.5,
            bbox: [10.0, 30.0, 60.0, 70.0],
            instance: None,
        };
        draw_detections(&mut image, &[d]);
        assert_eq!(*image.get_pixel(30, 30), colour(0));
        assert_eq!(*image.get_pixel(10, 50), colour(0));
        assert_eq!(*image.get_pixel(35, 50), Rgb([0, 0, 0]));
        // The label sits above the box: white dots of the text on its colour.
        let label = (12..30u32)
            .flat_map(|y| (10..100u32).map(move |x| (x, y)))
            .filter(|&(x, y)| *image.get_pixel(x, y) == Rgb([255, 255, 255]))
            .count();
        assert!(label > 50, "{label} text pixels");
    }
}
