//! Detection on overlapping tiles, for the offline dense pass: a far person is a few
//! cells of a small network's grid when the whole image is squeezed into its input.
//!
//! The image is cut into a `grid` x `grid` array of tiles that overlap by `overlap` of
//! a tile's side; each tile \(w_t = \lceil W (1 + o) / g \rceil\) wide (likewise in
//! height) starts at \(x_i = i (W - w_t) / (g - 1)\). The network sees each tile at
//! its own input size, so a person of height \(h\) pixels reaches it at about
//! \(h \cdot s_{in} / h_t\) instead of \(h \cdot s_{in} / H\): \(g / (1 + o)\) times
//! larger. The whole image is detected too (people larger than a tile). A tile's box
//! that touches a side of the tile inside the image is part of an object cut by the
//! tile and is dropped; every other box, moved back into the image, goes through one
//! class-wise NMS.

use image::RgbImage;

use super::yolo::non_maximum_suppression;
use super::{DetectError, Detection, Detector};

/// A detector run on the whole image and on overlapping tiles of it.
pub struct Tiled {
    inner: Box<dyn Detector>,
    grid: u32,
    overlap: f32,
    nms_threshold: f32,
    last_ms: f64,
}

impl Tiled {
    /// `inner` on the whole image and on `grid` x `grid` tiles overlapping by
    /// `overlap` (a share of a tile's side); boxes merged at `nms_threshold` IoU.
    pub fn new(inner: Box<dyn Detector>, grid: u32, overlap: f32, nms_threshold: f32) -> Self {
        Self {
            inner,
            grid: grid.max(1),
            overlap: overlap.clamp(0.0, 1.0),
            nms_threshold,
            last_ms: 0.0,
        }
    }
}

/// Checks a tile grid's side, `key` naming the config key: 1 (the whole image only)
/// to 4.
pub fn check_grid(key: &str, grid: u32) -> Result<(), crate::checks::BadValue> {
    if (1..=4).contains(&grid) {
        return Ok(());
    }
    Err(crate::checks::BadValue::new(
        key,
        format!("must be 1 (the whole image) to 4, got {grid}"),
    ))
}

/// The tiles' rectangles `(x, y, width, height)` of a `width` x `height` image.
pub fn tiles(width: u32, height: u32, grid: u32, overlap: f32) -> Vec<(u32, u32, u32, u32)> {
    if grid <= 1 {
        return Vec::new();
    }
    let side =
        |size: u32| ((size as f32 * (1.0 + overlap) / grid as f32).ceil() as u32).clamp(1, size);
    let (tile_w, tile_h) = (side(width), side(height));
    let start =
        |i: u32, size: u32, tile: u32| (i as u64 * (size - tile) as u64 / (grid - 1) as u64) as u32;
    let mut out = Vec::with_capacity((grid * grid) as usize);
    for row in 0..grid {
        for column in 0..grid {
            out.push((
                start(column, width, tile_w),
                start(row, height, tile_h),
                tile_w,
                tile_h,
            ));
        }
    }
    out
}

/// The sides of a tile that cut through the image (not the image's own border), in
/// the tile's pixels. A box touching one holds part of an object only: its score can
/// beat the whole object's box from another tile or the whole image, and NMS would
/// then keep the part, so such boxes are dropped (the object lies whole in the
/// neighbouring tile when it is narrower than the overlap, else in the whole image).
struct Seams {
    left: bool,
    top: bool,
    right: Option<f32>,
    bottom: Option<f32>,
}

impl Seams {
    /// The seams of the tile at `(x, y)`, `w` by `h`, of an image `width` by `height`.
    fn of(x: u32, y: u32, w: u32, h: u32, width: u32, height: u32) -> Self {
        Self {
            left: x > 0,
            top: y > 0,
            right: (x + w < width).then_some(w as f32),
            bottom: (y + h < height).then_some(h as f32),
        }
    }

    fn touched_by(&self, [x1, y1, x2, y2]: &[f32; 4]) -> bool {
        const TOUCH: f32 = 2.0;
        (self.left && *x1 <= TOUCH)
            || (self.top && *y1 <= TOUCH)
            || self.right.is_some_and(|r| *x2 >= r - TOUCH)
            || self.bottom.is_some_and(|b| *y2 >= b - TOUCH)
    }
}

impl Detector for Tiled {
    fn detect(&mut self, timestamp: f64, image: &RgbImage) -> Result<Vec<Detection>, DetectError> {
        let start = std::time::Instant::now();
        let mut found = self.inner.detect(timestamp, image)?;
        let (width, height) = (image.width(), image.height());
        for (x, y, w, h) in tiles(width, height, self.grid, self.overlap) {
            let tile = image::imageops::crop_imm(image, x, y, w, h).to_image();
            let seams = Seams::of(x, y, w, h, width, height);
            found.extend(
                self.inner
                    .detect(timestamp, &tile)?
                    .into_iter()
                    .filter(|d| !seams.touched_by(&d.bbox))
                    .map(|mut d| {
                        let [x1, y1, x2, y2] = d.bbox;
                        d.bbox = [x1 + x as f32, y1 + y as f32, x2 + x as f32, y2 + y as f32];
                        d
                    }),
            );
        }
        self.last_ms = start.elapsed().as_secs_f64() * 1e3;
        Ok(non_maximum_suppression(
            found,
            self.nms_threshold,
            (image.width(), image.height()),
        ))
    }

    fn model_times(&self) -> Vec<(String, f64)> {
        vec![(
            format!("tiled {}x{} and the whole image", self.grid, self.grid),
            self.last_ms,
        )]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiles_cover_the_image_and_overlap() {
        let t = tiles(640, 480, 2, 0.25);
        assert_eq!(t.len(), 4);
        assert_eq!(t[0], (0, 0, 400, 300));
        assert_eq!(t[3], (240, 180, 400, 300));
        // Every pixel column and row lies in some tile; neighbours share 160 columns.
        assert!(t.iter().all(|&(x, y, w, h)| x + w <= 640 && y + h <= 480));
        assert_eq!(t[0].0 + t[0].2 - t[1].0, 160);
        assert!(tiles(640, 480, 1, 0.25).is_empty());
    }

    /// A detector that finds a "person" only where a white square is larger than 40
    /// pixels in the image it is given, boxes in that image's pixels.
    struct LargeSquares;

    impl Detector for LargeSquares {
        fn detect(&mut self, _: f64, image: &RgbImage) -> Result<Vec<Detection>, DetectError> {
            let white: Vec<(u32, u32)> = image
                .enumerate_pixels()
                .filter(|(_, _, p)| p.0 == [255, 255, 255])
                .map(|(x, y, _)| (x, y))
                .collect();
            let Some(&(x1, y1)) = white.first() else {
                return Ok(Vec::new());
            };
            let &(x2, y2) = white.last().unwrap();
            // "Resized" to a 160-pixel input: only large enough squares are found.
            let scale = 160.0 / image.width() as f32;
            if (x2 - x1 + 1) as f32 * scale < 20.0 {
                return Ok(Vec::new());
            }
            Ok(vec![Detection {
                class: "person".into(),
                class_id: 0,
                score: 0.9,
                bbox: [x1 as f32, y1 as f32, x2 as f32 + 1.0, y2 as f32 + 1.0],
                instance: None,
            }])
        }
    }

    #[test]
    fn boxes_cut_by_a_seam_inside_the_image_are_dropped() {
        // The top-left tile of 640 x 480: its right and bottom sides are seams.
        let seams = Seams::of(0, 0, 400, 300, 640, 480);
        assert!(
            seams.touched_by(&[300.0, 100.0, 399.5, 200.0]),
            "cut on the right"
        );
        assert!(
            seams.touched_by(&[100.0, 250.0, 150.0, 299.0]),
            "cut at the bottom"
        );
        assert!(
            !seams.touched_by(&[0.0, 0.0, 50.0, 120.0]),
            "the image's own corner"
        );
        // The bottom-right tile: its left and top sides are seams.
        let seams = Seams::of(240, 180, 400, 300, 640, 480);
        assert!(seams.touched_by(&[1.0, 50.0, 60.0, 120.0]));
        assert!(
            !seams.touched_by(&[300.0, 200.0, 400.0, 300.0]),
            "the image's corner"
        );
    }

    #[test]
    fn a_small_object_found_in_a_tile_comes_back_in_image_pixels() {
        let mut image = RgbImage::new(640, 480);
        for y in 400..460 {
            for x in 500..560 {
                image.put_pixel(x, y, image::Rgb([255, 255, 255]));
            }
        }
        assert!(LargeSquares.detect(0.0, &image).unwrap().is_empty());
        let mut tiled = Tiled::new(Box::new(LargeSquares), 2, 0.25, 0.45);
        let found = tiled.detect(0.0, &image).unwrap();
        assert_eq!(found.len(), 1, "{found:?}");
        assert_eq!(found[0].bbox, [500.0, 400.0, 560.0, 460.0]);
    }
}
