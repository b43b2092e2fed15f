//! What a keyframe's detections do to the map when they come back from the detection
//! thread (possibly several frames after the keyframe was made):
//! - DOP: each map point the keyframe observes gets the update
//!   \(P_t(X) = (1-\alpha) P_{t-1}(X) + \alpha S_t(x)\) with \(S_t\) from the refined
//!   boxes ([`crate::dop::boxes`]); points that reach the cull threshold are removed.
//! - Mask boxes (the naive method): every map point seen inside a dynamic box goes.

use crate::detect::Detection;
use crate::dop::boxes::{in_dynamic_box, verdicts, Keypoint, ObjectBox};
use crate::dop::{update, DopConfig, Mode};
use crate::map::{KeyFrameKey, Map};

/// Map points updated and removed by one keyframe's detections.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DetectionEffect {
    pub updated: usize,
    pub removed: usize,
}

/// The model's boxes of `detections`; `dynamic_classes` are COCO names.
pub fn object_boxes(detections: &[Detection], dynamic_classes: &[String]) -> Vec<ObjectBox> {
    detections
        .iter()
        .map(|d| ObjectBox {
            bbox: d.bbox,
            dynamic: dynamic_classes.contains(&d.class),
        })
        .collect()
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
    let boxes = object_boxes(detections, dynamic_classes);
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
            .map(|k| Some(in_dynamic_box(&boxes, k.x, k.y)))
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::KeyPoint;
    use crate::map::{KeyFrame, MapPoint};
    use crate::tracking::Frame;
    use nalgebra::Vector3;

    /// A keyframe whose keypoints lie at `(x, y, depth)`, each observing a map point.
    fn map_with(keypoints: &[(f32, f32, f32)]) -> (Map, KeyFrameKey, Vec<crate::map::MapPointKey>) {
        let n = keypoints.len();
        let frame = Frame::from_parts(
            0,
            0.0,
            keypoints
                .iter()
                .map(|&(x, y, _)| KeyPoint {
                    x,
                    y,
                    ..KeyPoint::default()
                })
                .collect(),
            vec![[0; 4]; n],
            keypoints.iter().map(|k| k.2).collect(),
            vec![-1.0; n],
            (640, 480),
        );
        let mut map = Map::default();
        let key = map.add_keyframe(KeyFrame::new(frame, crate::geometry::se3::Se3::identity()));
        let points = (0..n)
            .map(|i| {
                let p = map.points.insert(MapPoint::new(
                    Vector3::z(),
                    [0; 4],
                    Vector3::z(),
                    (0.1, 10.0),
                    0,
                ));
                map.add_observation(p, key, i);
                p
            })
            .collect();
        (map, key, points)
    }

    fn person() -> Vec<Detection> {
        vec![Detection {
            class: "person".into(),
            class_id: 0,
            score: 0.9,
            bbox: [80.0, 80.0, 160.0, 240.0],
            instance: None,
        }]
    }

    /// Four keypoints on a person 2 m away, one on the wall 5 m behind inside the box,
    /// one outside the box.
    const SCENE: [(f32, f32, f32); 6] = [
        (110.0, 130.0, 2.0),
        (120.0, 150.0, 2.0),
        (130.0, 170.0, 2.05),
        (115.0, 190.0, 1.95),
        (125.0, 140.0, 5.0),
        (400.0, 300.0, 3.0),
    ];

    #[test]
    fn dop_updates_by_hand_and_culls_points_that_stay_dynamic() {
        let (mut map, key, points) = map_with(&SCENE);
        let config = DopConfig::default();
        let classes = vec!["person".to_string()];
        // P on the person: 0.65, 0.755, 0.8285, 0.87995, then 0.915965 >= 0.9: culled.
        let expected = [0.65, 0.755, 0.8285, 0.87995];
        for (n, p) in expected.iter().enumerate() {
            let effect = apply_detections(&mut map, key, &person(), &classes, &config, 0.3);
            assert_eq!(
                effect,
                DetectionEffect {
                    updated: 6,
                    removed: 0
                },
                "update {n}"
            );
            for &point in &points[..4] {
                assert!((map.points[point].moving - p).abs() < 1e-5);
            }
        }
        // The wall behind the person and the point outside the box decay towards 0:
        // 0.5 * 0.7^4.
        for &point in &points[4..] {
            assert!((map.points[point].moving - 0.12005).abs() < 1e-5);
        }
        let effect = apply_detections(&mut map, key, &person(), &classes, &config, 0.3);
        assert_eq!(
            effect,
            DetectionEffect {
                updated: 6,
                removed: 4
            }
        );
        assert!(points[..4].iter().all(|p| !map.points.contains_key(*p)));
        assert!(points[4..].iter().all(|p| map.points.contains_key(*p)));
    }

    #[test]
    fn mask_boxes_removes_everything_in_the_box_at_once() {
        let (mut map, key, points) = map_with(&SCENE);
        let config = DopConfig {
            mode: Mode::MaskBoxes,
            ..DopConfig::default()
        };
        let classes = vec!["person".to_string()];
        let effect = apply_detections(&mut map, key, &person(), &classes, &config, 0.3);
        assert_eq!(
            effect,
            DetectionEffect {
                updated: 0,
                removed: 5
            }
        );
        assert!(map.points.contains_key(points[5]));
        // A static class removes nothing.
        let (mut map, key, _) = map_with(&SCENE);
        let chair = vec![Detection {
            class: "chair".into(),
            ..person()[0].clone()
        }];
        let effect = apply_detections(&mut map, key, &chair, &classes, &config, 0.3);
        assert_eq!(effect, DetectionEffect::default());
    }
}
