//! Keypoint matches between two keyframes through the vocabulary (ORB-SLAM's
//! `SearchByBoW`): only features under the same tree node are compared, each keeps its
//! best match when it is within `TH_LOW` bits and clearly better than the second
//! (ratio test), and each keypoint of the other keyframe is used once.

use crate::bow::FeatureVector;
use crate::features::hamming;
use crate::features::TH_LOW;
use crate::map::{KeyFrame, Map, MapPointKey};

/// The static map point a keypoint observes, if any.
pub fn static_point(
    map: &Map,
    kf: &KeyFrame,
    index: usize,
    removal_threshold: f32,
) -> Option<MapPointKey> {
    kf.map_points[index].filter(|p| {
        map.points()
            .get(*p)
            .is_some_and(|x| x.moving <= removal_threshold)
    })
}

/// A keyframe with its vocabulary words (the feature vector's node to keypoints).
pub struct Worded<'a> {
    /// The keyframe.
    pub keyframe: &'a KeyFrame,
    /// Its feature vector.
    pub words: &'a FeatureVector,
}

/// Pairs `(index in a, index in b)` of keypoints that both observe static map points.
pub fn match_by_words(
    map: &Map,
    a: Worded,
    b: Worded,
    ratio: f32,
    removal_threshold: f32,
) -> Vec<(usize, usize)> {
    let (
        Worded {
            keyframe: a,
            words: words_a,
        },
        Worded {
            keyframe: b,
            words: words_b,
        },
    ) = (a, b);
    // Keypoints of b already used, or without a static point: never candidates.
    let mut taken: Vec<bool> = (0..b.frame.len())
        .map(|i| static_point(map, b, i, removal_threshold).is_none())
        .collect();
    let mut matches = Vec::new();
    let (mut i, mut j) = (0, 0);
    while i < words_a.len() && j < words_b.len() {
        match words_a[i].0.cmp(&words_b[j].0) {
            std::cmp::Ordering::Less => i += 1,
            std::cmp::Ordering::Greater => j += 1,
            std::cmp::Ordering::Equal => {
                for &ia in &words_a[i].1 {
                    let ia = ia as usize;
                    if static_point(map, a, ia, removal_threshold).is_none() {
                        continue;
                    }
                    let d = &a.frame.descriptors[ia];
                    let (mut best, mut second, mut best_index) = (u32::MAX, u32::MAX, usize::MAX);
                    for &ib in &words_b[j].1 {
                        let ib = ib as usize;
                        if taken[ib] {
                            continue;
                        }
                        let dist = hamming(d, &b.frame.descriptors[ib]);
                        if dist < best {
                            (second, best, best_index) = (best, dist, ib);
                        } else if dist < second {
                            second = dist;
                        }
                    }
                    if best <= TH_LOW && (best as f32) < ratio * second as f32 {
                        taken[best_index] = true;
                        matches.push((ia, best_index));
                    }
                }
                i += 1;
                j += 1;
            }
        }
    }
    matches
}
