//! What a keyframe's detections do to the map when they come back from the detection
//! thread (possibly several frames after the keyframe was made):
//! - DOP: each map point the keyframe observes gets the update
//!   \(P_t(X) = (1-\alpha) P_{t-1}(X) + \alpha S_t(x)\) with \(S_t\) from the refined
//!   boxes ([`crate::dop::boxes`]); points that reach the cull threshold are removed.
//!   A point the geometric check has verified static ([`crate::dop::consistency`])
//!   counts as \(S_t = 0\) even inside a dynamic object (a parked car).
//! - Mask boxes (the naive method): every map point seen inside a dynamic box goes.
//! - Late and missed detections ([`DynamicObjects`], DOP only): the detected people
//!   become 3-D objects followed across keyframes ([`crate::dop::tracks`]). Followed
//!   people the detector missed on this keyframe get their predicted box; the
//!   keyframes made since this one (its detections came back late) get the boxes of
//!   these objects predicted to their time and projected into them, so the points
//!   made on people meanwhile are updated too.

use std::collections::HashSet;

use crate::detect::Detection;
use crate::dop::boxes::{
    in_dynamic_box, in_moved_box, object_depth, verdicts, Keypoint, ObjectBox,
};
use crate::dop::standing::mark_standing;
use crate::dop::tracks::{FollowedObjects, Object, ObjectTracks};
use crate::dop::{update, DopConfig, Mode};
use crate::geometry::camera::PinholeCamera;
use crate::map::{KeyFrameKey, Map};

/// Map points updated and removed by one keyframe's detections.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DetectionEffect {
    /// Map points whose moving probability changed.
    pub updated: usize,
    /// Map points removed as dynamic.
    pub removed: usize,
    /// Points on a detected dynamic object that the geometric check had verified
    /// static: their update counts as \(S_t = 0\).
    pub verified_static: usize,
    /// Detected boxes of a dynamic class that stood: static on their keyframe
    /// ([`crate::dop::standing`]).
    pub standing_boxes: usize,
}

impl std::ops::AddAssign for DetectionEffect {
    fn add_assign(&mut self, other: Self) {
        self.updated += other.updated;
        self.removed += other.removed;
        self.verified_static += other.verified_static;
        self.standing_boxes += other.standing_boxes;
    }
}

/// The model's boxes of `detections`; `dynamic_classes` are COCO names.
pub fn object_boxes(detections: &[Detection], dynamic_classes: &[String]) -> Vec<ObjectBox> {
    detections
        .iter()
        .map(|d| ObjectBox {
            bbox: d.bbox,
            dynamic: dynamic_classes.contains(&d.class),
            depth: None,
            moved: false,
        })
        .collect()
}

/// [`object_boxes`] with the boxes of `config.never_static_classes` marked moved.
fn model_boxes(
    detections: &[Detection],
    dynamic_classes: &[String],
    config: &DopConfig,
) -> Vec<ObjectBox> {
    let mut boxes = object_boxes(detections, dynamic_classes);
    for (b, d) in boxes.iter_mut().zip(detections) {
        b.moved = config.moves_on_its_own(&d.class);
    }
    boxes
}

/// Marks the boxes that stand on keyframe `key` (whose DOP keypoints are `keypoints`)
/// static ([`mark_standing`]) and returns how many did.
fn stand(
    map: &Map,
    key: KeyFrameKey,
    keypoints: &[Keypoint],
    boxes: &mut [ObjectBox],
    config: &DopConfig,
) -> usize {
    let Some(kf) = map.keyframes().get(key) else {
        return 0;
    };
    let judged: Vec<_> = kf
        .map_points
        .iter()
        .map(|p| p.and_then(|p| map.points().get(p)).map(|p| p.consistency))
        .collect();
    mark_standing(config, keypoints, &judged, boxes)
}

/// The dynamic ones of `boxes`: where new points wait ([`ObjectsEffect::zones`]).
fn zones_of(boxes: &[ObjectBox]) -> Vec<ObjectBox> {
    boxes.iter().filter(|b| b.dynamic).copied().collect()
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
    let mut boxes = model_boxes(detections, dynamic_classes, config);
    let keypoints = keypoints_of(map, key).unwrap_or_default();
    let standing_boxes = stand(map, key, &keypoints, &mut boxes, config);
    DetectionEffect {
        standing_boxes,
        ..apply_boxes(map, key, &boxes, config, alpha)
    }
}

/// The keypoints of keyframe `key` as the DOP model sees them.
fn keypoints_of(map: &Map, key: KeyFrameKey) -> Option<Vec<Keypoint>> {
    Some(map.keyframes().get(key)?.frame.dop_keypoints())
}

/// Applies `boxes` (detected or predicted) to the map points of keyframe `key`.
pub fn apply_boxes(
    map: &mut Map,
    key: KeyFrameKey,
    boxes: &[ObjectBox],
    config: &DopConfig,
    alpha: f32,
) -> DetectionEffect {
    let mut effect = DetectionEffect::default();
    if !boxes.iter().any(|b| b.dynamic) && config.mode == Mode::MaskBoxes {
        return effect;
    }
    let Some(keypoints) = keypoints_of(map, key) else {
        return effect;
    };
    let kf = &map.keyframes()[key];
    let verdict: Vec<Option<bool>> = match config.mode {
        Mode::Off => return effect,
        Mode::MaskBoxes => keypoints
            .iter()
            .map(|k| Some(in_dynamic_box(boxes, k.x, k.y)))
            .collect(),
        Mode::Dop => verdicts(config, &keypoints, boxes),
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
                let Some((moving, consistency)) = map.point_dop_mut(point) else {
                    continue;
                };
                consistency.on_moving_object =
                    s && in_moved_box(boxes, keypoints[i].x, keypoints[i].y);
                // On a dynamic object, but the geometry says it has not moved.
                let verified = consistency.verified_static(config);
                effect.verified_static += usize::from(s && verified);
                *moving = update(*moving, s && !verified, alpha);
                effect.updated += 1;
                // A point that is consistent right now is not "staying dynamic": it
                // keeps its chance to be verified.
                let holding =
                    config.static_check && consistency.inlier_run >= config.geometric_frames;
                *moving >= config.cull_threshold && !holding
            }
        };
        if remove && map.points().contains_key(point) {
            map.remove_point(point);
            effect.removed += 1;
        }
    }
    effect
}

/// What one keyframe's detections did with the followed objects.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ObjectsEffect {
    /// What the boxes did to the map points.
    pub effect: DetectionEffect,
    /// Dynamic boxes used on the keyframe: detected, then predicted for followed
    /// objects the detector missed.
    pub boxes: Vec<[f32; 4]>,
    /// The detection's own dynamic boxes once the standing ones are static (where new
    /// points wait, [`crate::map::Map::set_wait_zones`]).
    pub zones: Vec<ObjectBox>,
    /// Boxes predicted for followed objects the detector missed.
    pub predicted_boxes: usize,
    /// Later keyframes that got this keyframe's objects (a late detection).
    pub later_keyframes: usize,
}

/// The DOP model's memory of dynamic objects across keyframes (see the module doc).
#[derive(Debug, Clone)]
pub struct DynamicObjects {
    camera: PinholeCamera,
    tracks: ObjectTracks,
    /// Keyframes whose own detections were applied, and those that got a later one's.
    detected: HashSet<KeyFrameKey>,
    reached: HashSet<KeyFrameKey>,
}

impl DynamicObjects {
    /// No object followed yet; boxes predicted in `camera`.
    pub fn new(camera: PinholeCamera) -> Self {
        Self {
            camera,
            tracks: ObjectTracks::default(),
            detected: HashSet::new(),
            reached: HashSet::new(),
        }
    }

    /// The objects followed so far, for the tracker's frames.
    pub fn followed(&self, alpha: f32) -> FollowedObjects {
        FollowedObjects {
            tracks: self.tracks.clone(),
            camera: self.camera,
            alpha,
        }
    }

    /// Applies keyframe `key`'s detections (the DOP model's update), with followed
    /// objects the detector missed, then reaches the keyframes made since.
    pub fn receive(
        &mut self,
        map: &mut Map,
        key: KeyFrameKey,
        detections: &[Detection],
        dynamic_classes: &[String],
        config: &DopConfig,
        alpha: f32,
    ) -> ObjectsEffect {
        let mut boxes = model_boxes(detections, dynamic_classes, config);
        // A keyframe culled meanwhile: its boxes still mark where the movers are.
        let mut result = ObjectsEffect {
            zones: zones_of(&boxes),
            ..ObjectsEffect::default()
        };
        let (Some(keypoints), Some(kf)) = (keypoints_of(map, key), map.keyframes().get(key)) else {
            return result;
        };
        self.detected.insert(key);
        if !config.track_boxes {
            let standing_boxes = stand(map, key, &keypoints, &mut boxes, config);
            result.zones = zones_of(&boxes);
            result.effect = DetectionEffect {
                standing_boxes,
                ..apply_boxes(map, key, &boxes, config, alpha)
            };
            result.boxes = dynamic_boxes(&boxes);
            return result;
        }
        let (time, id) = (kf.frame.timestamp, kf.id);
        let world_from_camera = kf.world_from_camera();
        let camera_from_world = kf.camera_from_world;
        // The detected dynamic objects of the followed classes, each with the index of
        // its box.
        let (owners, mut objects): (Vec<usize>, Vec<Object>) = boxes
            .iter()
            .enumerate()
            .filter(|(i, b)| b.dynamic && config.follows(&detections[*i].class))
            .filter_map(|(i, b)| {
                let z = object_depth(config, &keypoints, b)?;
                let object = Object {
                    moved: b.moved,
                    self_moving: b.moved,
                    ..Object::from_box(b.bbox, z, &self.camera, &world_from_camera)
                };
                Some((i, object))
            })
            .unzip();
        let missed = self.tracks.update(time, &mut objects, config);
        for (i, object) in owners.into_iter().zip(&objects) {
            boxes[i].moved = object.moved;
        }
        let standing_boxes = stand(map, key, &keypoints, &mut boxes, config);
        result.zones = zones_of(&boxes);
        let predicted: Vec<ObjectBox> = missed
            .iter()
            .filter_map(|o| o.to_box(&self.camera, &camera_from_world))
            .collect();
        result.predicted_boxes = predicted.len();
        boxes.extend(predicted);
        result.boxes = dynamic_boxes(&boxes);
        result.effect = DetectionEffect {
            standing_boxes,
            ..apply_boxes(map, key, &boxes, config, alpha)
        };
        self.reach_later(map, id, config, alpha, &mut result);
        result
    }

    /// Gives the keyframes made after keyframe `id` whose own detections have not come
    /// back the followed objects' predicted boxes (once each).
    fn reach_later(
        &mut self,
        map: &mut Map,
        id: usize,
        config: &DopConfig,
        alpha: f32,
        result: &mut ObjectsEffect,
    ) {
        let later: Vec<(KeyFrameKey, f64)> = map
            .keyframes()
            .iter()
            .filter(|(k, later)| {
                later.id > id && !self.detected.contains(k) && !self.reached.contains(k)
            })
            .map(|(k, later)| (k, later.frame.timestamp))
            .collect();
        for (later_key, later_time) in later {
            let pose = map.keyframes()[later_key].camera_from_world;
            let boxes: Vec<ObjectBox> = self
                .tracks
                .predicted(later_time, config)
                .iter()
                .filter_map(|o| o.to_box(&self.camera, &pose))
                .collect();
            if boxes.is_empty() {
                continue;
            }
            self.reached.insert(later_key);
            result.later_keyframes += 1;
            result.effect += apply_boxes(map, later_key, &boxes, config, alpha);
        }
    }
}

/// The pixel boxes of the dynamic ones.
fn dynamic_boxes(boxes: &[ObjectBox]) -> Vec<[f32; 4]> {
    boxes.iter().filter(|b| b.dynamic).map(|b| b.bbox).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::KeyPoint;
    use crate::frame::Frame;
    use crate::map::{KeyFrame, MapPoint};
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
        let points = observed_points(&mut map, key, n);
        (map, key, points)
    }

    /// A new map point for each of the first `n` keypoints of keyframe `key`.
    fn observed_points(map: &mut Map, key: KeyFrameKey, n: usize) -> Vec<crate::map::MapPointKey> {
        (0..n)
            .map(|i| {
                let p = map.insert_point(MapPoint::new(
                    Vector3::z(),
                    [0; 4],
                    Vector3::z(),
                    (0.1, 10.0),
                    0,
                ));
                map.add_observation(p, key, i);
                p
            })
            .collect()
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

    /// A car where [`person`] has its box.
    fn car() -> Vec<Detection> {
        vec![Detection {
            class: "car".into(),
            ..person()[0].clone()
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
                    removed: 0,
                    ..Default::default()
                },
                "update {n}"
            );
            for &point in &points[..4] {
                assert!((map.points()[point].moving - p).abs() < 1e-5);
            }
        }
        // The wall behind the person and the point outside the box decay towards 0:
        // 0.5 * 0.7^4.
        for &point in &points[4..] {
            assert!((map.points()[point].moving - 0.12005).abs() < 1e-5);
        }
        let effect = apply_detections(&mut map, key, &person(), &classes, &config, 0.3);
        assert_eq!(
            effect,
            DetectionEffect {
                updated: 6,
                removed: 4,
                ..Default::default()
            }
        );
        assert!(points[..4].iter().all(|p| !map.points().contains_key(*p)));
        assert!(points[4..].iter().all(|p| map.points().contains_key(*p)));
    }

    /// A second keyframe at time `t`, seeing the same scene from the same pose.
    fn add_keyframe_like(map: &mut Map, t: f64) -> (KeyFrameKey, Vec<crate::map::MapPointKey>) {
        let (source, first, _) = map_with(&SCENE);
        let mut frame = source.keyframes()[first].frame.clone();
        frame.timestamp = t;
        let key = map.add_keyframe(KeyFrame::new(frame, crate::geometry::se3::Se3::identity()));
        (key, observed_points(map, key, SCENE.len()))
    }

    #[test]
    fn a_late_detection_reaches_later_keyframes_and_a_missed_person_keeps_a_box() {
        let (mut map, first, _) = map_with(&SCENE);
        // Keyframes made at 0.1 s and 0.2 s while the first one's detection was away.
        let (_, second_points) = add_keyframe_like(&mut map, 0.1);
        let config = DopConfig::default();
        let classes = vec!["person".to_string()];
        let mut objects = DynamicObjects::new(crate::geometry::camera::PinholeCamera::tum_fr3());
        let done = objects.receive(&mut map, first, &person(), &classes, &config, 0.3);
        assert_eq!(done.later_keyframes, 1);
        assert_eq!(done.predicted_boxes, 0);
        // The second keyframe's points on the person went up, the wall behind and the
        // point outside the (predicted, widened) box went down or stayed.
        for &p in &second_points[..4] {
            assert!((map.points()[p].moving - 0.65).abs() < 1e-5);
        }
        assert!((map.points()[second_points[4]].moving - 0.35).abs() < 1e-5);
        assert!(map.points()[second_points[5]].moving <= 0.5);
        // The detector misses the person at 0.5 s: the followed object gives the box.
        let (third, third_points) = add_keyframe_like(&mut map, 0.5);
        let done = objects.receive(&mut map, third, &[], &classes, &config, 0.3);
        assert_eq!(done.predicted_boxes, 1);
        assert_eq!(done.boxes.len(), 1);
        for &p in &third_points[..4] {
            assert!((map.points()[p].moving - 0.65).abs() < 1e-5);
        }
        // Past track_seconds the object is forgotten.
        let (fourth, fourth_points) = add_keyframe_like(&mut map, 2.0);
        let done = objects.receive(&mut map, fourth, &[], &classes, &config, 0.3);
        assert_eq!(done.predicted_boxes, 0);
        assert!(fourth_points[..4]
            .iter()
            .all(|&p| map.points()[p].moving < 0.5));
    }

    /// A car is not followed by default (`track_classes`): its box acts on the
    /// keyframe it was detected in, but reaches no later keyframe and leaves no
    /// predicted box where it was missed; listed in `track_classes`, it is followed.
    #[test]
    fn only_the_followed_classes_reach_other_keyframes() {
        let car: Vec<Detection> = person()
            .into_iter()
            .map(|d| Detection {
                class: "car".into(),
                class_id: 2,
                ..d
            })
            .collect();
        let classes = vec!["car".to_string()];
        for (track_classes, followed) in [(vec![], false), (vec!["car".to_string()], true)] {
            let (mut map, first, first_points) = map_with(&SCENE);
            let (_, second_points) = add_keyframe_like(&mut map, 0.1);
            let config = DopConfig {
                track_classes,
                ..DopConfig::default()
            };
            let camera = crate::geometry::camera::PinholeCamera::tum_fr3();
            let mut objects = DynamicObjects::new(camera);
            let done = objects.receive(&mut map, first, &car, &classes, &config, 0.3);
            assert!((map.points()[first_points[0]].moving - 0.65).abs() < 1e-5);
            assert_eq!(done.later_keyframes, usize::from(followed));
            let raised = map.points()[second_points[0]].moving > 0.5;
            assert_eq!(raised, followed);
            let (third, _) = add_keyframe_like(&mut map, 0.5);
            let done = objects.receive(&mut map, third, &[], &classes, &config, 0.3);
            assert_eq!(done.predicted_boxes, usize::from(followed));
        }
    }

    /// A point the geometric check verified static counts as S = 0 inside the box of
    /// an object that never moved, but not inside the box of one followed moving: there
    /// it takes S = 1 and is no longer verified static.
    #[test]
    fn verified_static_points_yield_to_objects_followed_moving() {
        let config = DopConfig::default();
        let verify = |map: &mut Map, points: &[crate::map::MapPointKey]| {
            for &p in points {
                let c = &mut map.point_mut(p).consistency;
                c.inlier_run = 40;
                c.since = 0.0;
                c.until = 2.0;
                assert!(c.verified_static(&config));
            }
        };
        let person = |moved| ObjectBox {
            bbox: [100.0, 100.0, 200.0, 300.0],
            dynamic: true,
            depth: None,
            moved,
        };
        for moved in [false, true] {
            let (mut map, key, points) = map_with(&SCENE);
            verify(&mut map, &points);
            let effect = apply_boxes(&mut map, key, &[person(moved)], &config, 0.3);
            for &p in &points[..4] {
                let point = &map.points()[p];
                let expected = if moved { 0.65 } else { 0.35 };
                assert!((point.moving - expected).abs() < 1e-5, "moved {moved}");
                assert_eq!(point.consistency.on_moving_object, moved);
                assert_eq!(point.consistency.verified_static(&config), !moved);
            }
            assert_eq!(effect.verified_static, if moved { 0 } else { 4 });
            // The wall behind stays verified either way.
            assert!(map.points()[points[4]].consistency.verified_static(&config));
            // A later keyframe that puts the points elsewhere ends the flag.
            apply_boxes(&mut map, key, &[], &config, 0.3);
            assert!(points[..4]
                .iter()
                .all(|&p| !map.points()[p].consistency.on_moving_object));
        }
    }

    /// A person is never verified static, even before their track has moved (a seated
    /// person); a parked car is, and the rule follows `never_static_classes`.
    #[test]
    fn people_are_never_verified_static_but_parked_cars_are() {
        let classes = vec!["person".to_string(), "car".to_string()];
        let car = car();
        let nobody = DopConfig {
            never_static_classes: Vec::new(),
            ..DopConfig::default()
        };
        for (detections, config, verified) in [
            (person(), DopConfig::default(), false),
            (car, DopConfig::default(), true),
            (person(), nobody, true),
        ] {
            let (mut map, key, points) = map_with(&SCENE);
            for &p in &points {
                let c = &mut map.point_mut(p).consistency;
                (c.inlier_run, c.since, c.until) = (40, 0.0, 2.0);
            }
            let effect = apply_detections(&mut map, key, &detections, &classes, &config, 0.3);
            let class = &detections[0].class;
            assert_eq!(
                effect.verified_static,
                if verified { 4 } else { 0 },
                "{class}"
            );
            for &p in &points[..4] {
                let point = &map.points()[p];
                assert_eq!(point.consistency.verified_static(&config), verified);
                assert_eq!(point.moving > 0.5, !verified, "{class}");
            }
        }
    }

    /// A car 8 m away: 12 points in its box (the first keyframe's), judged as given.
    fn car_scene(tested: u32, steady_run: u32) -> (Map, KeyFrameKey, Vec<crate::map::MapPointKey>) {
        let car: Vec<(f32, f32, f32)> = (0..12)
            .map(|i| {
                (
                    105.0 + (i % 4) as f32 * 10.0,
                    130.0 + (i / 4) as f32 * 30.0,
                    8.0,
                )
            })
            .collect();
        let (mut map, key, points) = map_with(&car);
        for &p in &points {
            let c = &mut map.point_mut(p).consistency;
            (c.tested, c.steady_run) = (tested, steady_run);
        }
        (map, key, points)
    }

    /// A parked car whose points held still in the frames since they were made stands:
    /// its points go down and it is no wait zone; a car whose points did not hold
    /// still is raised and stays one.
    #[test]
    fn a_car_whose_points_hold_still_stands_on_its_keyframe() {
        let classes = vec!["person".to_string(), "car".to_string()];
        let car = car();
        let config = DopConfig::default();
        for (steady_run, stands) in [(3, true), (0, false)] {
            let (mut map, key, points) = car_scene(4, steady_run);
            let mut objects =
                DynamicObjects::new(crate::geometry::camera::PinholeCamera::tum_fr3());
            let done = objects.receive(&mut map, key, &car, &classes, &config, 0.5);
            assert_eq!(done.effect.standing_boxes, usize::from(stands));
            assert_eq!(done.zones.len(), usize::from(!stands));
            assert_eq!(done.boxes.is_empty(), stands);
            for &p in &points {
                assert_eq!(map.points()[p].moving < 0.5, stands, "stands: {stands}");
            }
            // The same without the followed objects.
            let (mut map, key, _) = car_scene(4, steady_run);
            let effect = apply_detections(&mut map, key, &car, &classes, &config, 0.5);
            assert_eq!(effect.standing_boxes, usize::from(stands));
        }
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
                removed: 5,
                ..Default::default()
            }
        );
        assert!(map.points().contains_key(points[5]));
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
