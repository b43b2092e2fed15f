//! Descriptor matching for tracking (ORB-SLAM §V): search by projection in a window
//! around a predicted pixel, with the Hamming thresholds of ORB-SLAM (100 for a
//! projection search, 50 for brute force), a ratio test, and a rotation-consistency
//! histogram (30 bins of the keypoint angle difference; only the three fullest bins are
//! kept) for frame-to-frame matches.

use super::{Area, Frame};
use crate::features::{hamming, Descriptor, KeyPoint, TH_HIGH, TH_LOW};

const HISTOGRAM_BINS: usize = 30;

/// A point to look for in a frame: where it should appear, on which levels, how far
/// to search, and its descriptor.
#[derive(Debug, Clone, Copy)]
pub struct Query {
    /// Predicted column (level-0 pixels).
    pub u: f32,
    /// Predicted row.
    pub v: f32,
    /// The lowest pyramid level searched.
    pub min_level: u8,
    /// The highest pyramid level searched.
    pub max_level: u8,
    /// Search radius in level-0 pixels (scaled by the level's factor).
    pub radius: f32,
    /// The point's descriptor.
    pub descriptor: Descriptor,
    /// Predicted right-image coordinate; the match must agree within `radius` when set.
    pub right_u: Option<f32>,
    /// The keypoint angle it had, for the rotation check.
    pub angle: Option<f32>,
}

/// Matches each query to at most one unmatched keypoint of `frame`; `taken[i]` marks
/// keypoints already matched. Returns `(query index, keypoint index)` pairs.
pub fn search_by_projection(
    frame: &Frame,
    queries: &[Query],
    taken: &mut [bool],
    ratio: f32,
    check_rotation: bool,
) -> Vec<(usize, usize)> {
    let mut matches: Vec<(usize, usize)> = Vec::new();
    // Best distance per keypoint so a better query can take over a keypoint.
    let mut owner: Vec<Option<(usize, u32)>> = vec![None; frame.len()];
    for (q, query) in queries.iter().enumerate() {
        let area = Area {
            x: query.u,
            y: query.v,
            radius: query.radius,
            min_level: query.min_level,
            max_level: query.max_level,
        };
        let (mut best, mut best_level, mut second, mut best_index) =
            (u32::MAX, 0u8, u32::MAX, None);
        let mut second_level = 0u8;
        frame.for_features_in_area(area, |i| {
            if taken[i] {
                return;
            }
            if let Some(ur) = query.right_u {
                if frame.right_u[i] > 0.0 && (frame.right_u[i] - ur).abs() > query.radius {
                    return;
                }
            }
            let d = hamming(&query.descriptor, &frame.descriptors[i]);
            if d < best {
                second = best;
                second_level = best_level;
                best = d;
                best_level = frame.keypoints[i].level;
                best_index = Some(i);
            } else if d < second {
                second = d;
                second_level = frame.keypoints[i].level;
            }
        });
        let Some(i) = best_index else { continue };
        if best > TH_HIGH {
            continue;
        }
        if best_level == second_level && second != u32::MAX && best as f32 > ratio * second as f32 {
            continue;
        }
        match owner[i] {
            Some((_, d)) if d <= best => continue,
            _ => owner[i] = Some((q, best)),
        }
    }
    for (i, o) in owner.iter().enumerate() {
        if let Some((q, _)) = o {
            matches.push((*q, i));
        }
    }
    if check_rotation {
        let angles: Vec<Option<f32>> = matches.iter().map(|(q, _)| queries[*q].angle).collect();
        matches = keep_consistent_rotations(&matches, &angles, &frame.keypoints);
    }
    for (_, i) in &matches {
        taken[*i] = true;
    }
    matches
}

/// Keeps the matches whose angle change falls in the three fullest histogram bins.
fn keep_consistent_rotations(
    matches: &[(usize, usize)],
    query_angles: &[Option<f32>],
    keypoints: &[KeyPoint],
) -> Vec<(usize, usize)> {
    let mut bins: Vec<Vec<usize>> = vec![Vec::new(); HISTOGRAM_BINS];
    let mut unchecked = Vec::new();
    for (m, (_, i)) in matches.iter().enumerate() {
        let Some(angle) = query_angles[m] else {
            unchecked.push(m);
            continue;
        };
        let mut change = (keypoints[*i].angle - angle).to_degrees();
        if change < 0.0 {
            change += 360.0;
        }
        let bin = ((change / 360.0 * HISTOGRAM_BINS as f32) as usize).min(HISTOGRAM_BINS - 1);
        bins[bin].push(m);
    }
    let mut order: Vec<usize> = (0..HISTOGRAM_BINS).collect();
    order.sort_by_key(|&b| std::cmp::Reverse(bins[b].len()));
    let top = bins[order[0]].len();
    let mut keep: Vec<usize> = unchecked;
    for (rank, &b) in order.iter().take(3).enumerate() {
        // ORB-SLAM keeps the second and third bins only when they hold at least a
        // tenth of the fullest.
        if rank == 0 || bins[b].len() * 10 >= top {
            keep.extend(&bins[b]);
        }
    }
    keep.sort_unstable();
    keep.into_iter().map(|m| matches[m]).collect()
}

/// Brute-force matching of `queries` (descriptors) against all keypoints of `frame`:
/// the nearest below [`TH_LOW`] that passes the ratio test, one query per keypoint.
pub fn brute_force(frame: &Frame, queries: &[Descriptor], ratio: f32) -> Vec<(usize, usize)> {
    let mut owner: Vec<Option<(usize, u32)>> = vec![None; frame.len()];
    for (q, descriptor) in queries.iter().enumerate() {
        let (mut best, mut second, mut best_index) = (u32::MAX, u32::MAX, 0);
        for (i, d) in frame.descriptors.iter().enumerate() {
            let distance = hamming(descriptor, d);
            if distance < best {
                second = best;
                best = distance;
                best_index = i;
            } else if distance < second {
                second = distance;
            }
        }
        if best <= TH_LOW && (best as f32) < ratio * second as f32 {
            match owner[best_index] {
                Some((_, d)) if d <= best => {}
                _ => owner[best_index] = Some((q, best)),
            }
        }
    }
    owner
        .iter()
        .enumerate()
        .filter_map(|(i, o)| o.map(|(q, _)| (q, i)))
        .collect()
}
