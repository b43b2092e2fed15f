//! What a keyframe's detections do to the map when they come back from the detection
//! thread (possibly several frames after the keyframe was made):
//! - DOP: each map point the keyframe observes gets the update
//!   \(P_t(X) = (1-\alpha) P_{t-1}(X) + \alpha S_t(x)\) with \(S_t\) from the refined
//!   boxes ([`crate::dop::boxes`]); points that reach the cull threshold are removed.
//! - Mask boxes (the naive method): every map point seen inside a dynamic box goes.

use crate::detect::Detection;
use crate::dop::boxes::{verdicts, Keypoint, ObjectBox};
use crate::dop::{update, DopConfig, Mode};
use crate::map::{KeyFrameKey, Map};

/// Map points updated and removed by one keyframe's detections.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DetectionEffect {
    pub updated: usize,
    pub removed: usize,
}

/// Applies `detections` of keyframe `key`; `dynamic_classes` are COCO names.
pub fn apply_detections(
    map: &mut Map,
    key: KeyFrameKey,
    detections: &[Detection],
    dynamic_classes: &[String],
    config: &DopConfig,
    alpha: f32,
) -> DetectionEffect {
    let mut effect = DetectionEffect::default();
    let Some(kf) = map.keyframes.get(key) else {
        return effect;
    };
    let boxes: Vec<ObjectBox> = detections
        .iter()
        .map(|d| ObjectBox {
            bbox: d.bbox,
            dynamic: dynamic_classes.contains(&d.class),
        })
        .collect();
    if !boxes.iter().any(|b| b.dynamic) && config.mode == Mode::MaskBoxes {
        return effect;
    }
    let frame = &kf.frame;
    let keypoints: Vec<Keypoint> = frame
        .keypoints
        .iter()
        .zip(&frame.depth)
        .map(|(k, z)| Keypoint {
            x: k.x,
            y: k.y,
            depth: *z,
        })
        .collect();
    let verdict: Vec<Option<bool>> = match config.mode {
        Mode::Off => return effect,
        Mode::MaskBoxes => keypoints
            .iter()
            .map(|k| {
                Some(boxes.iter().any(|b| {
                    b.dynamic
                        && k.x >= b.bbox[0]
                        && k.x < b.bbox[2]
                        && k.y >= b.bbox[1]
                        && k.y < b.bbox[3]
                }))
            })
            .collect(),
        Mode::Dop => verdicts(config, &keypoints, &boxes),
    };
    let observed: Vec<(usize, crate::map::MapPointKey)> = kf
        .map_points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| p.map(|p| (i, p)))
        .collect();
    for (i, point) in observed {
        let Some(s) = verdict[i] else { continue };
        let remove = match config.mode {
            Mode::MaskBoxes => s,
            _ => {
                let Some(p) = map.points.get_mut(point) else {
                    continue;
                };
                p.moving = update(p.moving, s, alpha);
                effect.updated += 1;
                p.moving >= config.cull_threshold
            }
        };
        if remove && map.points.contains_key(point) {
            map.remove_point(point);
            effect.removed += 1;
        }
    }
    effect
}
