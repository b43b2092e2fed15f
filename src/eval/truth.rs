//! Keypoints and detections scored against the ground truth of a synthetic sequence
//! (`dopslam synth` writes `masks/`, one instance mask per frame, and
//! `detections_oracle/`, the class of each instance): which keypoints lie on movers and
//! which the tracker called dynamic, and which people a keyframe's dynamic boxes found.
//! Pure counting; the run's scorer (`run::truth`) feeds it frame by frame.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::detect::FrameDetections;

/// Keypoints called dynamic (removed) against the ground-truth masks.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub struct Classification {
    /// Frames counted.
    pub frames: usize,
    /// Mover keypoints removed.
    pub true_positives: usize,
    /// Static keypoints removed.
    pub false_positives: usize,
    /// Mover keypoints kept.
    pub false_negatives: usize,
    /// Mover keypoints removed over all removed.
    pub precision: f64,
    /// Mover keypoints removed over all mover keypoints.
    pub recall: f64,
}

impl Classification {
    /// Adds one frame's counts.
    pub fn add(&mut self, counts: &TruthCounts) {
        self.frames += 1;
        self.true_positives += counts.mover_removed;
        self.false_positives += counts.static_removed;
        self.false_negatives += counts.mover_keypoints - counts.mover_removed;
        let tp = self.true_positives as f64;
        self.precision = tp / (tp + self.false_positives as f64).max(1.0);
        self.recall = tp / (tp + self.false_negatives as f64).max(1.0);
    }
}

/// One tracked frame's keypoints against its ground-truth mover mask: how many lie on
/// the static scene and on movers, how many of each were called dynamic (removed), and
/// how many of each took part in the pose as inliers. Keypoints outside the mask (an
/// undistorted position off the image) are not counted.
#[derive(Debug, Clone, Copy, Default, Serialize, Deserialize)]
pub struct TruthCounts {
    /// Keypoints on the static scene.
    pub static_keypoints: usize,
    /// Keypoints on movers.
    pub mover_keypoints: usize,
    /// Static keypoints removed.
    pub static_removed: usize,
    /// Mover keypoints removed.
    pub mover_removed: usize,
    /// Static keypoints in the pose.
    pub static_in_pose: usize,
    /// Mover keypoints in the pose.
    pub mover_in_pose: usize,
    /// Static keypoints in the pose within [`NEAR_MOVER_PIXELS`] of a mover's pixel:
    /// corners on a mover's outline against the background move with the mover though
    /// their own pixel is static.
    pub near_mover_in_pose: usize,
}

/// How close (pixels, in x and y) to a mover a static keypoint counts as on its outline.
const NEAR_MOVER_PIXELS: i64 = 4;

impl TruthCounts {
    /// The counts of keypoints at `positions` under the truth `mask`, with which were `called` moving and which are `in_pose`.
    pub fn new(
        mask: &image::ImageBuffer<image::Luma<u16>, Vec<u16>>,
        positions: &[(f32, f32)],
        called: &[bool],
        in_pose: &[u32],
    ) -> Self {
        // Some(true) on a mover, Some(false) on the static scene, None off the mask.
        let on_mover = |(x, y): (f32, f32)| {
            let (u, v) = (x.round() as u32, y.round() as u32);
            (u < mask.width() && v < mask.height()).then(|| mask.get_pixel(u, v)[0] != 0)
        };
        let mut counts = Self::default();
        for (&position, &removed) in positions.iter().zip(called) {
            match on_mover(position) {
                Some(true) => {
                    counts.mover_keypoints += 1;
                    counts.mover_removed += removed as usize;
                }
                Some(false) => {
                    counts.static_keypoints += 1;
                    counts.static_removed += removed as usize;
                }
                None => {}
            }
        }
        let near_mover = |(x, y): (f32, f32)| {
            let (u, v) = (x.round() as i64, y.round() as i64);
            let r = NEAR_MOVER_PIXELS;
            (v - r..=v + r).any(|y| {
                (u - r..=u + r).any(|x| {
                    x >= 0
                        && y >= 0
                        && x < mask.width() as i64
                        && y < mask.height() as i64
                        && mask.get_pixel(x as u32, y as u32)[0] != 0
                })
            })
        };
        for &i in in_pose {
            let position = positions[i as usize];
            match on_mover(position) {
                Some(true) => counts.mover_in_pose += 1,
                Some(false) => {
                    counts.static_in_pose += 1;
                    counts.near_mover_in_pose += near_mover(position) as usize;
                }
                None => {}
            }
        }
        counts
    }
}

/// The ground-truth mover mask of a frame, when the sequence has one.
pub fn ground_truth_mask(
    sequence_dir: Option<&Path>,
    timestamp: f64,
) -> Option<image::ImageBuffer<image::Luma<u16>, Vec<u16>>> {
    crate::io::image_files::read_instance_mask(
        &sequence_dir?.join(format!("masks/{timestamp:.6}.png")),
    )
}

/// People found on keyframes against the ground truth.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct Recall {
    /// Keyframes with people.
    pub keyframes: usize,
    /// People on them.
    pub people: usize,
    /// People a dynamic box found.
    pub found: usize,
    /// `found` over `people`.
    pub recall: f64,
    /// People covering over 20 % of the image that were missed.
    pub missed_large: usize,
    /// Every person missed, in keyframe order (what to look at when recall is low).
    pub misses: Vec<Miss>,
}

/// A person on a keyframe that no dynamic box found with IoU >= 0.5.
#[derive(Debug, Clone, Copy, Serialize, Deserialize)]
pub struct Miss {
    /// The keyframe's time.
    pub timestamp: f64,
    /// The person's tight box from the ground-truth mask.
    pub person: [f32; 4],
    /// Share of the image the box covers.
    pub share: f32,
    /// The best IoU of any dynamic box with it, and that box.
    pub best_iou: f32,
    /// That box.
    pub best_box: Option<[f32; 4]>,
}

impl Recall {
    /// Counts the people of one keyframe's truth mask against its dynamic boxes.
    pub fn add(
        &mut self,
        timestamp: f64,
        people: &[[f32; 4]],
        boxes: &[[f32; 4]],
        image_area: f32,
    ) {
        self.keyframes += 1;
        for person in people {
            self.people += 1;
            let best = boxes
                .iter()
                .map(|b| (crate::detect::yolo::iou(person, b), *b))
                .max_by(|a, b| a.0.total_cmp(&b.0));
            let best_iou = best.map_or(0.0, |(iou, _)| iou);
            if best_iou >= 0.5 {
                self.found += 1;
                continue;
            }
            let area = crate::detect::yolo::area(person);
            if area > 0.2 * image_area {
                self.missed_large += 1;
            }
            self.misses.push(Miss {
                timestamp,
                person: *person,
                share: area / image_area,
                best_iou,
                best_box: best.map(|(_, b)| b),
            });
        }
        self.recall = self.found as f64 / self.people.max(1) as f64;
    }
}

/// The tight boxes of the people in a synthetic frame's mask that cover at least 1 %
/// of it (the class of each instance from the frame's oracle file).
pub fn ground_truth_people(
    sequence_dir: Option<&Path>,
    timestamp: f64,
) -> Option<(Vec<[f32; 4]>, f32)> {
    let dir = sequence_dir?;
    let mask = ground_truth_mask(Some(dir), timestamp)?;
    let text = std::fs::read_to_string(crate::detect::cache_file(
        &dir.join("detections_oracle"),
        timestamp,
    ))
    .ok()?;
    let oracle: FrameDetections = serde_json::from_str(&text).ok()?;
    let people: std::collections::HashSet<u16> = oracle
        .detections
        .iter()
        .filter(|d| d.class == "person")
        .filter_map(|d| d.instance)
        .collect();
    let mut boxes: std::collections::BTreeMap<u16, ([u32; 4], usize)> = Default::default();
    for (x, y, p) in mask.enumerate_pixels() {
        let id = p[0];
        if id == 0 || !people.contains(&id) {
            continue;
        }
        let entry = boxes.entry(id).or_insert(([x, y, x + 1, y + 1], 0));
        entry.0 = [
            entry.0[0].min(x),
            entry.0[1].min(y),
            entry.0[2].max(x + 1),
            entry.0[3].max(y + 1),
        ];
        entry.1 += 1;
    }
    let image_area = (mask.width() * mask.height()) as f32;
    let people = boxes
        .into_values()
        .filter(|(_, count)| *count as f32 >= 0.01 * image_area)
        .map(|(b, _)| b.map(|v| v as f32))
        .collect();
    Some((people, image_area))
}
