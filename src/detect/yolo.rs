//! What is specific to each YOLO model family, around one ONNX session: how an image
//! becomes the input tensor, how the output tensor becomes boxes, and one NMS.
//!
//! Both resize with Pillow's antialiased bilinear filter ([`resize_rgb`]), which the
//! reference figures were computed with.
//!
//! - **YOLOv4 (Darknet, converted by `tools/darknet_to_onnx.py`)**: input RGB / 255,
//!   plain resize to the network size; output `[1, N, 85]` already decoded: cx, cy, w, h
//!   in network pixels, objectness, class scores. Score = objectness x class.
//! - **YOLOX**: input BGR 0-255, letterbox at the top left with ratio
//!   \(r = \min(H/h, W/w)\) padded with 114; output `[1, N, 85]` raw on grids of strides
//!   8, 16, 32 (row-major): \(c_x = (t_x + g_x) s\), \(w = e^{t_w} s\); objectness and
//!   class scores already through the logistic. Boxes are divided by \(r\).

use image::RgbImage;
use serde::{Deserialize, Serialize};

use super::{coco, Detection};
use crate::geometry::camera::ImageSize;

/// Which model family (and so which pre-processing and decoder).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Layout {
    /// Darknet YOLOv4 / YOLOv4-tiny converted by our tool (decoded in the graph).
    Yolov4,
    /// Megvii YOLOX (raw grid output).
    Yolox,
    /// DEIMv2 (end to end, no NMS): inputs `images` (RGB / 255, plain resize) and
    /// `orig_target_sizes` (int64 `[W, H]` of the image); outputs `labels` (COCO index),
    /// `boxes` (x1, y1, x2, y2 in image pixels) and `scores`, 300 each.
    Deimv2,
}

/// An input tensor (NCHW, f32) and how to map boxes back to the image.
pub struct Input {
    /// The tensor's values, NCHW.
    pub data: Vec<f32>,
    /// Image pixels per input pixel, x.
    pub scale_x: f32,
    /// Image pixels per input pixel, y.
    pub scale_y: f32,
}

impl Layout {
    /// The number of predictions the layout gives for a `width` x `height` input, or
    /// `None` when any count is possible (YOLOv4 heads depend on the cfg).
    pub fn predictions(self, width: usize, height: usize) -> Option<usize> {
        match self {
            Layout::Yolov4 | Layout::Deimv2 => None,
            Layout::Yolox => Some([8, 16, 32].iter().map(|s| (width / s) * (height / s)).sum()),
        }
    }

    /// The input tensor of `image` for a `width` x `height` network.
    pub fn prepare(self, image: &RgbImage, width: u32, height: u32) -> Input {
        let plane = (width * height) as usize;
        let mut data = vec![0f32; 3 * plane];
        match self {
            Layout::Yolov4 | Layout::Deimv2 => {
                let resized = resize_rgb(image, width, height);
                for (i, p) in resized.pixels().enumerate() {
                    for c in 0..3 {
                        data[c * plane + i] = p[c] as f32 / 255.0;
                    }
                }
                Input {
                    data,
                    scale_x: image.width() as f32 / width as f32,
                    scale_y: image.height() as f32 / height as f32,
                }
            }
            Layout::Yolox => {
                let r = (height as f32 / image.height() as f32)
                    .min(width as f32 / image.width() as f32);
                let (w, h) = (
                    (image.width() as f32 * r) as u32,
                    (image.height() as f32 * r) as u32,
                );
                data.iter_mut().for_each(|v| *v = 114.0);
                let resized = resize_rgb(image, w, h);
                for (x, y, p) in resized.enumerate_pixels() {
                    let i = (y * width + x) as usize;
                    // BGR order.
                    for c in 0..3 {
                        data[c * plane + i] = p[2 - c] as f32;
                    }
                }
                Input {
                    data,
                    scale_x: 1.0 / r,
                    scale_y: 1.0 / r,
                }
            }
        }
    }

    /// Boxes (image pixels) and scores above `threshold` from the output rows.
    pub fn decode(
        self,
        output: &[f32],
        rows: usize,
        width: usize,
        height: usize,
        input: &Input,
        threshold: f32,
    ) -> Vec<Detection> {
        let per = output.len() / rows.max(1);
        let classes = per - 5;
        let mut grid = Vec::new();
        if self == Layout::Yolox {
            for s in [8usize, 16, 32] {
                for gy in 0..height / s {
                    for gx in 0..width / s {
                        grid.push((gx as f32, gy as f32, s as f32));
                    }
                }
            }
        }
        let mut found = Vec::new();
        for (n, row) in output.chunks_exact(per).enumerate() {
            let objectness = row[4];
            if objectness < threshold {
                continue;
            }
            let (class, best) = row[5..5 + classes]
                .iter()
                .enumerate()
                .fold((0, f32::MIN), |a, (i, &v)| if v > a.1 { (i, v) } else { a });
            let score = objectness * best;
            if score < threshold {
                continue;
            }
            let (cx, cy, w, h) = match self {
                Layout::Yolov4 | Layout::Deimv2 => (row[0], row[1], row[2], row[3]),
                Layout::Yolox => {
                    let (gx, gy, s) = grid[n];
                    (
                        (row[0] + gx) * s,
                        (row[1] + gy) * s,
                        row[2].exp() * s,
                        row[3].exp() * s,
                    )
                }
            };
            let class_id = class as u32;
            found.push(Detection {
                class: coco::class_name(class_id).unwrap_or("unknown").to_string(),
                class_id,
                score,
                bbox: [
                    (cx - w / 2.0) * input.scale_x,
                    (cy - h / 2.0) * input.scale_y,
                    (cx + w / 2.0) * input.scale_x,
                    (cy + h / 2.0) * input.scale_y,
                ],
                instance: None,
            });
        }
        found
    }
}

/// The detections of an end-to-end model's outputs (DEIMv2: `labels`, `boxes` in image
/// pixels, `scores`, one entry per query) scoring at least `threshold`; labels outside
/// COCO's 80 classes are dropped.
pub fn decode_end_to_end(
    labels: &[i64],
    boxes: &[f32],
    scores: &[f32],
    threshold: f32,
) -> Vec<Detection> {
    labels
        .iter()
        .zip(boxes.chunks_exact(4))
        .zip(scores)
        .filter(|(_, &score)| score >= threshold)
        .filter_map(|((&label, b), &score)| {
            let class_id = u32::try_from(label).ok()?;
            Some(Detection {
                class: coco::class_name(class_id)?.to_string(),
                class_id,
                score,
                bbox: [b[0], b[1], b[2], b[3]],
                instance: None,
            })
        })
        .collect()
}

/// Fixed-point bits of the resampling weights (as Pillow).
const PRECISION_BITS: u32 = 22;

/// Per output index: the first input index and the fixed-point weights of the
/// triangle filter widened by the downscale factor (antialiased bilinear).
fn coefficients(input: u32, output: u32) -> Vec<(usize, Vec<i32>)> {
    let scale = input as f64 / output as f64;
    let filter_scale = scale.max(1.0);
    let support = filter_scale;
    (0..output)
        .map(|x| {
            let centre = (x as f64 + 0.5) * scale;
            let min = ((centre - support + 0.5) as i64).max(0) as usize;
            let max = ((centre + support + 0.5) as i64).min(input as i64) as usize;
            let weights: Vec<f64> = (min..max)
                .map(|i| (1.0 - ((i as f64 - centre + 0.5) / filter_scale).abs()).max(0.0))
                .collect();
            let total: f64 = weights.iter().sum();
            let fixed = weights
                .iter()
                .map(|w| {
                    let v = w / total * (1u64 << PRECISION_BITS) as f64;
                    (if v < 0.0 { v - 0.5 } else { v + 0.5 }) as i32
                })
                .collect();
            (min, fixed)
        })
        .collect()
}

fn clip8(sum: i64) -> u8 {
    (sum >> PRECISION_BITS).clamp(0, 255) as u8
}

/// Antialiased bilinear resize, the same arithmetic as Pillow's `Image.resize(...,
/// BILINEAR)` (horizontal pass, rounding to 8 bits, vertical pass), which the
/// reference detections were computed with.
pub fn resize_rgb(image: &RgbImage, width: u32, height: u32) -> RgbImage {
    let (w0, h0) = image.dimensions();
    let columns = coefficients(w0, width);
    let rows = coefficients(h0, height);
    let half = 1i64 << (PRECISION_BITS - 1);
    let source = image.as_raw();
    let mut horizontal = vec![0u8; (width * h0 * 3) as usize];
    for y in 0..h0 as usize {
        let row = &source[y * w0 as usize * 3..(y + 1) * w0 as usize * 3];
        for (x, (start, weights)) in columns.iter().enumerate() {
            for c in 0..3 {
                let mut sum = half;
                for (k, w) in weights.iter().enumerate() {
                    sum += row[(start + k) * 3 + c] as i64 * *w as i64;
                }
                horizontal[(y * width as usize + x) * 3 + c] = clip8(sum);
            }
        }
    }
    let mut out = vec![0u8; (width * height * 3) as usize];
    let stride = width as usize * 3;
    for (y, (start, weights)) in rows.iter().enumerate() {
        for i in 0..stride {
            let mut sum = half;
            for (k, w) in weights.iter().enumerate() {
                sum += horizontal[(start + k) * stride + i] as i64 * *w as i64;
            }
            out[y * stride + i] = clip8(sum);
        }
    }
    RgbImage::from_raw(width, height, out).expect("sized buffer")
}

/// The area of a `[x1, y1, x2, y2]` box (0 when empty).
pub fn area(b: &[f32; 4]) -> f32 {
    (b[2] - b[0]).max(0.0) * (b[3] - b[1]).max(0.0)
}

/// The intersection of two boxes (empty: `area` 0).
pub fn intersection(a: &[f32; 4], b: &[f32; 4]) -> [f32; 4] {
    [
        a[0].max(b[0]),
        a[1].max(b[1]),
        a[2].min(b[2]),
        a[3].min(b[3]),
    ]
}

/// Intersection over union of two `[x1, y1, x2, y2]` boxes.
pub fn iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let inter = area(&intersection(a, b));
    let union = area(a) + area(b) - inter;
    if union > 0.0 {
        inter / union
    } else {
        0.0
    }
}

/// Whether `outer` is a group box: it holds (each at least [`GROUP_INSIDE`] inside it)
/// two or more of `kept`'s boxes of its class, which together cover at least
/// [`GROUP_COVER`] of it. YOLO answers two people side by side with a low-scored box
/// around both, whose depth refinement then takes the wall between them for the
/// object; a person close to the camera with people far behind is not one (they cover
/// little of the box).
fn is_group_box(outer: &Detection, kept: &[Detection]) -> bool {
    let inside: Vec<[f32; 4]> = kept
        .iter()
        .filter(|k| k.class_id == outer.class_id)
        .filter_map(|k| {
            let part = intersection(&k.bbox, &outer.bbox);
            (area(&part) >= GROUP_INSIDE * area(&k.bbox)).then_some(part)
        })
        .collect();
    if inside.len() < 2 {
        return false;
    }
    // Union by inclusion-exclusion over pairs (a lower bound beyond two boxes).
    let mut covered: f32 = inside.iter().map(area).sum();
    for (i, a) in inside.iter().enumerate() {
        for b in &inside[i + 1..] {
            covered -= area(&intersection(a, b));
        }
    }
    covered >= GROUP_COVER * area(&outer.bbox)
}

/// A box is inside a group box when this share of it is.
const GROUP_INSIDE: f32 = 0.8;
/// A group box is covered this much by the boxes inside it.
const GROUP_COVER: f32 = 0.5;

/// The boxes scored at least `threshold`, and the narrow ones touching the image's left
/// or right border (within [`BORDER_TOUCH`] pixels of column 0 or `width`, at most
/// [`BORDER_WIDTH_SHARE`] of the image wide) scored at least `border_threshold`. A
/// person cut by the border shows the network a shoulder and a leg, not a person, and
/// scores lower for it: at the same threshold the cut-out presets lost most of their
/// missed people there. Wide weak boxes from a border are kept out: they are boxes
/// around the whole scene, whose masks took the wall (docs/design.md, "People cut by
/// the border").
pub fn keep_confident(
    mut detections: Vec<Detection>,
    threshold: f32,
    border_threshold: f32,
    width: u32,
) -> Vec<Detection> {
    let right = width as f32 - BORDER_TOUCH;
    let widest = BORDER_WIDTH_SHARE * width as f32;
    detections.retain(|d| {
        let [x1, _, x2, _] = d.bbox;
        let cut =
            (x1 <= BORDER_TOUCH || x2 >= right) && x2.min(width as f32) - x1.max(0.0) <= widest;
        d.score >= threshold || (d.score >= border_threshold && cut)
    });
    detections
}

/// A box this close (pixels) to the left or right image border touches it.
const BORDER_TOUCH: f32 = 2.0;
/// The widest box (share of the image width) kept from the border threshold.
const BORDER_WIDTH_SHARE: f32 = 0.3;

/// Greedy non-maximum suppression per class: best score first, dropping boxes of the
/// same class that overlap a kept one by more than `threshold` IoU, and group boxes
/// around two or more kept ones ([`is_group_box`]). Boxes are clipped to the image.
pub fn non_maximum_suppression(
    mut detections: Vec<Detection>,
    threshold: f32,
    size: impl Into<ImageSize>,
) -> Vec<Detection> {
    let ImageSize { width, height } = size.into();
    detections.sort_by(|a, b| b.score.total_cmp(&a.score));
    let mut kept: Vec<Detection> = Vec::new();
    for mut d in detections {
        if kept
            .iter()
            .any(|k| k.class_id == d.class_id && iou(&k.bbox, &d.bbox) > threshold)
            || is_group_box(&d, &kept)
        {
            continue;
        }
        d.bbox = [
            d.bbox[0].clamp(0.0, width as f32),
            d.bbox[1].clamp(0.0, height as f32),
            d.bbox[2].clamp(0.0, width as f32),
            d.bbox[3].clamp(0.0, height as f32),
        ];
        kept.push(d);
    }
    kept
}

#[cfg(test)]
mod tests {
    use super::*;

    fn detection(class_id: u32, score: f32, bbox: [f32; 4]) -> Detection {
        Detection {
            class: String::new(),
            class_id,
            score,
            bbox,
            instance: None,
        }
    }

    #[test]
    fn border_boxes_are_kept_from_their_lower_threshold_only_at_the_left_and_right() {
        let found = vec![
            detection(0, 0.5, [200.0, 100.0, 300.0, 400.0]), // confident, inside
            detection(0, 0.1, [200.0, 100.0, 300.0, 400.0]), // weak, inside: dropped
            detection(0, 0.1, [-3.0, 100.0, 40.0, 480.0]),   // weak, left border
            detection(0, 0.1, [610.0, 100.0, 638.5, 480.0]), // weak, right border
            detection(0, 0.1, [300.0, 0.0, 400.0, 100.0]),   // weak, top border: dropped
            detection(0, 0.05, [0.0, 100.0, 40.0, 480.0]),   // below the border's: dropped
            detection(0, 0.1, [0.0, 10.0, 600.0, 480.0]),    // weak, wide from the border: dropped
        ];
        let kept = keep_confident(found.clone(), 0.15, 0.075, 640);
        let boxes: Vec<[f32; 4]> = kept.iter().map(|d| d.bbox).collect();
        assert_eq!(boxes, vec![found[0].bbox, found[2].bbox, found[3].bbox]);
        // Factor 1 (the border threshold equal to the other): the plain threshold.
        assert_eq!(keep_confident(found, 0.15, 0.15, 640).len(), 1);
    }

    #[test]
    fn iou_of_hand_computed_boxes() {
        assert_eq!(iou(&[0.0, 0.0, 2.0, 2.0], &[1.0, 1.0, 3.0, 3.0]), 1.0 / 7.0);
        assert_eq!(iou(&[0.0, 0.0, 1.0, 1.0], &[2.0, 2.0, 3.0, 3.0]), 0.0);
    }

    /// Measured on cutout_rpy: two people and a box of score 0.19 around both, which
    /// took the wall between them for a person. A close person with two small people
    /// far behind stays.
    #[test]
    fn nms_drops_a_box_around_two_people_but_not_a_close_person_before_others() {
        let kept = non_maximum_suppression(
            vec![
                detection(0, 0.95, [4.0, 114.0, 133.0, 477.0]),
                detection(0, 0.58, [359.0, 0.0, 640.0, 466.0]),
                detection(0, 0.19, [0.0, 22.0, 604.0, 480.0]),
            ],
            0.45,
            (640, 480),
        );
        let scores: Vec<f32> = kept.iter().map(|d| d.score).collect();
        assert_eq!(scores, vec![0.95, 0.58]);
        let kept = non_maximum_suppression(
            vec![
                detection(0, 0.9, [300.0, 100.0, 340.0, 200.0]),
                detection(0, 0.8, [400.0, 120.0, 430.0, 200.0]),
                detection(0, 0.6, [150.0, 0.0, 600.0, 480.0]),
            ],
            0.45,
            (640, 480),
        );
        assert_eq!(kept.len(), 3);
    }

    #[test]
    fn nms_keeps_the_best_of_overlapping_boxes_of_one_class() {
        let kept = non_maximum_suppression(
            vec![
                detection(0, 0.6, [0.0, 0.0, 10.0, 10.0]),
                detection(0, 0.9, [1.0, 0.0, 11.0, 10.0]),
                detection(2, 0.5, [0.0, 0.0, 10.0, 10.0]),
                detection(0, 0.4, [50.0, 50.0, 60.0, 70.0]),
            ],
            0.45,
            (55, 100),
        );
        let scores: Vec<f32> = kept.iter().map(|d| d.score).collect();
        assert_eq!(scores, vec![0.9, 0.5, 0.4]);
        assert_eq!(kept[2].bbox, [50.0, 50.0, 55.0, 70.0]);
    }

    #[test]
    fn yolox_rows_decode_on_their_grid_and_scale_back() {
        let (w, h) = (64usize, 64usize);
        let rows = Layout::Yolox.predictions(w, h).unwrap();
        assert_eq!(rows, 64 + 16 + 4);
        let mut output = vec![0f32; rows * 85];
        // Row 9 is cell (1, 1) of the stride-8 grid: tx = ty = 0.5, tw = th = ln 2.
        let row = &mut output[9 * 85..10 * 85];
        row[..4].copy_from_slice(&[0.5, 0.5, 2f32.ln(), 2f32.ln()]);
        row[4] = 0.9;
        row[5] = 0.8; // person
        let input = Input {
            data: vec![],
            scale_x: 2.0,
            scale_y: 2.0,
        };
        let found = Layout::Yolox.decode(&output, rows, w, h, &input, 0.3);
        assert_eq!(found.len(), 1);
        // cx = (0.5 + 1) * 8 = 12, w = 2 * 8 = 16: [4, 4, 20, 20] x 2.
        assert_eq!(found[0].bbox, [8.0, 8.0, 40.0, 40.0]);
        assert!((found[0].score - 0.72).abs() < 1e-6);
        assert_eq!(found[0].class, "person");
    }

    #[test]
    fn resizing_keeps_a_flat_image_flat_and_averages_when_shrinking() {
        let flat = RgbImage::from_pixel(37, 23, image::Rgb([200, 100, 7]));
        let small = resize_rgb(&flat, 11, 5);
        assert!(small.pixels().all(|p| p.0 == [200, 100, 7]));
        // A one-pixel checkerboard halved is mid-grey inside (antialiased, not
        // sampled); at the border the filter is cut and renormalised, as in Pillow.
        let board = RgbImage::from_fn(64, 64, |x, y| {
            let v = if (x + y) % 2 == 0 { 255 } else { 0 };
            image::Rgb([v, v, v])
        });
        let half = resize_rgb(&board, 32, 32);
        for (x, y, p) in half.enumerate_pixels() {
            if (1..31).contains(&x) && (1..31).contains(&y) {
                assert!((p.0[0] as i32 - 128).abs() <= 1, "({x}, {y}): {p:?}");
            }
        }
    }

    #[test]
    fn end_to_end_outputs_keep_the_queries_above_the_threshold() {
        let labels = [0i64, 2, 0, 95];
        let boxes = [
            10.0, 20.0, 30.0, 60.0, 1.0, 1.0, 5.0, 5.0, 0.0, 0.0, 9.0, 9.0, 3.0, 3.0, 4.0, 4.0,
        ];
        let scores = [0.9f32, 0.31, 0.2, 0.99];
        let found = decode_end_to_end(&labels, &boxes, &scores, 0.3);
        // The low-scoring person and the label outside COCO are dropped.
        assert_eq!(found.len(), 2);
        assert_eq!(found[0].class, "person");
        assert_eq!(found[0].bbox, [10.0, 20.0, 30.0, 60.0]);
        assert_eq!((found[1].class.as_str(), found[1].class_id), ("car", 2));
    }

    #[test]
    fn letterbox_keeps_the_aspect_and_pads_with_114() {
        let image = RgbImage::from_pixel(80, 40, image::Rgb([10, 20, 30]));
        let input = Layout::Yolox.prepare(&image, 32, 32);
        assert_eq!(input.scale_x, 2.5);
        let plane = 32 * 32;
        // Top-left inside the image: B, G, R planes.
        assert_eq!(input.data[0], 30.0);
        assert_eq!(input.data[plane], 20.0);
        assert_eq!(input.data[2 * plane], 10.0);
        // Below the 16 image rows: padding.
        assert_eq!(input.data[20 * 32], 114.0);
    }
}
