//! Dynamic objects followed across keyframes in 3-D, so that a detection reaches the
//! keyframes it was not run on and a person survives a keyframe where the detector
//! misses them (an extension of the paper; every parameter is in `[dop]`).
//!
//! A detected dynamic box with object depth \(z_{obj}\) (the refined depth of
//! [`super::boxes`]) becomes an object: its centre pixel \((u, v)\) back-projected,
//! \(c_w = T_{wc} \, z_{obj} K^{-1} (u, v, 1)^T\), and its size in metres,
//! \(w = (x_2 - x_1) z_{obj} / f_x\), \(h = (y_2 - y_1) z_{obj} / f_y\).
//! Tracks are matched to the objects of the next detected keyframe by the distance of
//! the predicted centre \(c + v \Delta t\) (nearest first, within `track_gate` metres
//! plus what `track_max_speed` allows in \(\Delta t\)); a matched track takes the new
//! centre and the velocity \(v \leftarrow (v + (c' - c) / \Delta t) / 2\), clamped to
//! `track_max_speed`. A track seen within `track_seconds` but missing from a keyframe's
//! detections is predicted there and projected back into a box whose object depth is
//! the predicted centre's depth; the margin grows with the time since it was seen
//! (\(\Delta t \cdot\) `track_max_speed`).
//!
//! A track whose centre has been at least `track_moved_metres` from its first centre
//! \(c_0\) (\(\max_t \lVert c_t - c_0 \rVert\)) has *moved*; its objects and boxes say so,
//! and the map points they hold are never verified static while it is followed
//! ([`super::consistency`]).

use nalgebra::{Point3, Vector2, Vector3};

use super::boxes::ObjectBox;
use super::DopConfig;
use crate::geometry::camera::PinholeCamera;
use crate::geometry::se3::Se3;

/// A dynamic object seen (or predicted) at one time, in the world frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Object {
    /// The object's centre in the world frame, metres.
    pub centre: Vector3<f64>,
    /// Width and height in metres.
    pub size: (f64, f64),
    /// Extra margin on every side of its box, metres (uncertainty of a prediction).
    pub margin: f64,
    /// Whether its track has moved `track_moved_metres` (false for a new object), or
    /// its class moves on its own (`never_static_classes`).
    pub moved: bool,
    /// Its class moves on its own (`never_static_classes`: people).
    pub self_moving: bool,
    /// The track that follows it ([`ObjectTracks::update`] numbers them from 1; `None`
    /// before it went through one): the same number in two detected frames is the
    /// same object.
    pub track: Option<u32>,
}

impl Object {
    /// The object of a box `[x1, y1, x2, y2]` at depth `z` in a camera at `world_from_camera`.
    pub fn from_box(
        bbox: [f32; 4],
        z: f32,
        camera: &PinholeCamera,
        world_from_camera: &Se3,
    ) -> Self {
        let [x1, y1, x2, y2] = bbox.map(f64::from);
        let z = z as f64;
        let centre_pixel = Vector2::new((x1 + x2) / 2.0, (y1 + y2) / 2.0);
        let centre_camera = camera.unproject(&centre_pixel, z);
        Self {
            centre: (world_from_camera * Point3::from(centre_camera)).coords,
            size: ((x2 - x1) * z / camera.fx, (y2 - y1) * z / camera.fy),
            margin: 0.0,
            moved: false,
            self_moving: false,
            track: None,
        }
    }

    /// Whether it is a track's prediction (a margin for the time since the track was
    /// seen), not a detection.
    pub fn predicted(&self) -> bool {
        self.margin > 0.0
    }

    /// Its box in a camera at `camera_from_world` (clipped to the image), with the
    /// object depth set; `None` behind the camera or outside the image.
    pub fn to_box(&self, camera: &PinholeCamera, camera_from_world: &Se3) -> Option<ObjectBox> {
        let c = camera_from_world * Point3::from(self.centre);
        if c.z < 0.1 {
            return None;
        }
        let centre = camera.project(&c.coords);
        let half_w = (self.size.0 / 2.0 + self.margin) * camera.fx / c.z;
        let half_h = (self.size.1 / 2.0 + self.margin) * camera.fy / c.z;
        let (w, h) = (camera.width as f64, camera.height as f64);
        let bbox = [
            (centre.x - half_w).max(0.0),
            (centre.y - half_h).max(0.0),
            (centre.x + half_w).min(w),
            (centre.y + half_h).min(h),
        ];
        (bbox[0] < bbox[2] && bbox[1] < bbox[3]).then(|| ObjectBox {
            bbox: bbox.map(|v| v as f32),
            dynamic: true,
            depth: Some(c.z as f32),
            moved: self.moved,
        })
    }
}

/// One followed object.
#[derive(Debug, Clone, PartialEq)]
struct Track {
    object: Object,
    velocity: Vector3<f64>,
    last_seen: f64,
    /// Where it was first seen.
    origin: Vector3<f64>,
}

impl Track {
    /// The object predicted at time `t`.
    fn at(&self, t: f64, max_speed: f64) -> Object {
        let dt = (t - self.last_seen).max(0.0);
        Object {
            centre: self.object.centre + self.velocity * dt,
            margin: max_speed * dt,
            ..self.object
        }
    }
}

/// The dynamic objects followed so far.
#[derive(Debug, Clone, Default)]
pub struct ObjectTracks {
    tracks: Vec<Track>,
    /// The number of the tracks started so far.
    started: u32,
}

impl ObjectTracks {
    /// Takes the objects detected at time `t`, marks those whose track has moved and
    /// gives each its track's number ([`Object::track`]); returns the tracks that were
    /// not among them but were seen within `track_seconds`, predicted to `t` (the boxes
    /// the detector missed).
    pub fn update(&mut self, t: f64, detected: &mut [Object], config: &DopConfig) -> Vec<Object> {
        let speed = config.track_max_speed as f64;
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (ti, track) in self.tracks.iter().enumerate() {
            let predicted = track.at(t, speed);
            let gate = config.track_gate as f64 + predicted.margin;
            for (oi, object) in detected.iter().enumerate() {
                let d = (object.centre - predicted.centre).norm();
                if d <= gate {
                    pairs.push((d, ti, oi));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (mut track_used, mut object_used) =
            (vec![false; self.tracks.len()], vec![false; detected.len()]);
        for (_, ti, oi) in pairs {
            if track_used[ti] || object_used[oi] {
                continue;
            }
            track_used[ti] = true;
            object_used[oi] = true;
            let track = &mut self.tracks[ti];
            let dt = t - track.last_seen;
            if dt > 1e-3 {
                let velocity =
                    (track.velocity + (detected[oi].centre - track.object.centre) / dt) / 2.0;
                track.velocity = velocity.cap_magnitude(speed);
            }
            let moved = detected[oi].moved
                || track.object.moved
                || (detected[oi].centre - track.origin).norm() >= config.track_moved_metres as f64;
            detected[oi].moved = moved;
            detected[oi].track = track.object.track;
            track.object = detected[oi];
            track.last_seen = t;
        }
        let missed: Vec<Object> = self
            .tracks
            .iter()
            .zip(&track_used)
            .filter(|(track, used)| !**used && t - track.last_seen <= config.track_seconds as f64)
            .map(|(track, _)| track.at(t, speed))
            .collect();
        self.tracks
            .retain(|track| t - track.last_seen <= config.track_seconds as f64);
        for (object, _) in detected
            .iter_mut()
            .zip(&object_used)
            .filter(|(_, used)| !**used)
        {
            self.started += 1;
            object.track = Some(self.started);
            self.tracks.push(Track {
                object: *object,
                velocity: Vector3::zeros(),
                last_seen: t,
                origin: object.centre,
            });
        }
        missed
    }

    /// Every track seen within `track_seconds` of `t`, predicted to `t`.
    pub fn predicted(&self, t: f64, config: &DopConfig) -> Vec<Object> {
        self.predicted_within(t, config.track_seconds as f64, config)
    }

    /// Every track seen within `seconds` of `t`, predicted to `t`.
    fn predicted_within(&self, t: f64, seconds: f64, config: &DopConfig) -> Vec<Object> {
        self.tracks
            .iter()
            .filter(|track| (t - track.last_seen).abs() <= seconds)
            .map(|track| track.at(t, config.track_max_speed as f64))
            .collect()
    }

    /// The number of objects followed.
    pub fn len(&self) -> usize {
        self.tracks.len()
    }

    /// Whether no object is followed.
    pub fn is_empty(&self) -> bool {
        self.tracks.is_empty()
    }
}

/// A copy of the followed objects handed to the tracker after each detection, so that
/// every frame tracked since sees them: their boxes predicted to the frame's time and
/// projected with its pose raise the keypoints that nothing else knows about
/// ([`super::raise_unknown_in_boxes`]).
#[derive(Debug, Clone)]
pub struct FollowedObjects {
    /// The objects and their motion.
    pub tracks: ObjectTracks,
    /// The camera the boxes are predicted in.
    pub camera: PinholeCamera,
    /// The sensor's weight of a detection (`alpha_rgbd` or `alpha_stereo`).
    pub alpha: f32,
}

impl FollowedObjects {
    /// The boxes of the objects followed at time `t` in a camera at `camera_from_world`,
    /// dynamic for those of a class that moves on its own (`never_static_classes`:
    /// people). The others (a car, parked or driving) are left to the detections and
    /// the static check: their boxes are static, so that a keypoint on them, at their
    /// depth, is not taken by a person's wider predicted box. (Whether a car's track has
    /// moved is judged from its depth, which stereo gives poorly at range: a parked car
    /// judged moving would lose every new point to its own box.) Objects seen within
    /// twice `track_seconds` count. A copy is replaced at the next
    /// detection, which comes a keyframe interval plus the detector's latency after the
    /// last (about `track_seconds` with a still camera): with `track_seconds` alone the
    /// boxes would vanish for the frames in between.
    pub fn boxes_at(&self, t: f64, camera_from_world: &Se3, config: &DopConfig) -> Vec<ObjectBox> {
        self.tracks
            .predicted_within(t, 2.0 * config.track_seconds as f64, config)
            .iter()
            .filter_map(|o| {
                let b = o.to_box(&self.camera, camera_from_world)?;
                Some(ObjectBox {
                    dynamic: o.self_moving,
                    ..b
                })
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn camera() -> PinholeCamera {
        PinholeCamera::tum_fr3()
    }

    proptest! {
        /// A box turned into an object and projected back from the same camera is the
        /// same box, with the object's depth.
        #[test]
        fn box_to_object_and_back(
            x1 in 10.0f32..300.0, y1 in 10.0f32..200.0, w in 20.0f32..300.0,
            h in 20.0f32..260.0, z in 0.5f32..6.0,
            xi in crate::geometry::se3::tests::tangent(2.0, 1.0),
        ) {
            let camera = camera();
            let world_from_camera = crate::geometry::se3::exp(&xi);
            let bbox = [x1, y1, x1 + w, y1 + h];
            let object = Object::from_box(bbox, z, &camera, &world_from_camera);
            let back = object.to_box(&camera, &world_from_camera.inverse()).unwrap();
            for (a, b) in back.bbox.iter().zip(bbox) {
                prop_assert!((a - b).abs() < 1e-2, "{:?} vs {:?}", back.bbox, bbox);
            }
            prop_assert!((back.depth.unwrap() - z).abs() < 1e-4);
        }
    }

    /// The tracker's copy: people's boxes are dynamic and a car's static; both stay
    /// for twice `track_seconds` after they were seen, then go.
    #[test]
    fn followed_boxes_are_dynamic_for_people_only_and_outlive_track_seconds() {
        let config = DopConfig::default();
        let mut tracks = ObjectTracks::default();
        let person = Object {
            moved: true,
            self_moving: true,
            ..at(0.0)
        };
        let car = Object {
            moved: true,
            ..at(1.0)
        };
        tracks.update(0.0, &mut [person, car], &config);
        let followed = FollowedObjects {
            tracks,
            camera: camera(),
            alpha: 0.3,
        };
        let pose = Se3::identity();
        let later = 1.5 * config.track_seconds as f64;
        let boxes = followed.boxes_at(later, &pose, &config);
        assert_eq!(boxes.len(), 2);
        assert_eq!(boxes.iter().filter(|b| b.dynamic).count(), 1);
        let person_box = boxes.iter().find(|b| b.dynamic).unwrap();
        // The person's box is centred on the image centre column (x = 0 at 2 m).
        let centre = (person_box.bbox[0] + person_box.bbox[2]) / 2.0;
        assert!((centre - camera().cx as f32).abs() < 1.0, "{person_box:?}");
        let gone = 2.0 * config.track_seconds as f64 + 0.01;
        assert!(followed.boxes_at(gone, &pose, &config).is_empty());
        // Keyframes see a track only within track_seconds.
        assert!(followed.tracks.predicted(later, &config).is_empty());
    }

    fn at(x: f64) -> Object {
        Object {
            centre: Vector3::new(x, 0.0, 2.0),
            size: (0.5, 1.7),
            margin: 0.0,
            moved: false,
            self_moving: false,
            track: None,
        }
    }

    #[test]
    fn a_missed_person_is_predicted_with_their_velocity_until_the_track_expires() {
        let config = DopConfig::default();
        let mut tracks = ObjectTracks::default();
        assert!(tracks.update(0.0, &mut [at(0.0)], &config).is_empty());
        // Walking at 0.8 m/s along x; a second person appears.
        assert!(tracks
            .update(0.25, &mut [at(0.2), at(-1.5)], &config)
            .is_empty());
        assert_eq!(tracks.len(), 2);
        // Both missed at 0.5 s: predicted where they go (the first at half its measured
        // speed, as the velocity is averaged with the initial zero).
        let missed = tracks.update(0.5, &mut [], &config);
        assert_eq!(missed.len(), 2);
        assert!((missed[0].centre.x - 0.3).abs() < 1e-9, "{:?}", missed[0]);
        assert!((missed[0].margin - 0.25 * config.track_max_speed as f64).abs() < 1e-6);
        assert!((missed[1].centre.x + 1.5).abs() < 1e-9);
        // Past track_seconds without a detection the tracks are gone.
        let late = 0.25 + config.track_seconds as f64 + 0.01;
        assert!(tracks.update(late, &mut [], &config).is_empty());
        assert!(tracks.is_empty());
    }

    #[test]
    fn far_objects_start_new_tracks() {
        let config = DopConfig::default();
        let mut tracks = ObjectTracks::default();
        tracks.update(0.0, &mut [at(0.0)], &config);
        let missed = tracks.update(0.1, &mut [at(3.0)], &config);
        assert_eq!(missed.len(), 1, "the first person was missed");
        assert_eq!(tracks.len(), 2);
    }

    /// A person who walks `track_moved_metres` and then stops stays "moved" (their
    /// points must not be verified static during the stop); one who only sways in
    /// place does not, and neither does a new object.
    #[test]
    fn a_track_that_travelled_stays_moved_and_a_swaying_one_does_not() {
        let config = DopConfig::default();
        let mut tracks = ObjectTracks::default();
        let mut walker = [at(0.0)];
        tracks.update(0.0, &mut walker, &config);
        assert!(!walker[0].moved);
        for (i, x) in [0.2, 0.4, 0.6, 0.6, 0.6].into_iter().enumerate() {
            let mut seen = [at(x)];
            tracks.update(0.25 * (i + 1) as f64, &mut seen, &config);
            assert_eq!(
                seen[0].moved,
                x >= config.track_moved_metres as f64,
                "at x = {x}"
            );
        }
        // Missed after stopping: its predicted box still says moved.
        let missed = tracks.update(1.5, &mut [], &config);
        assert!(missed[0].moved);
        let camera = camera();
        let pose = Se3::identity();
        assert!(missed[0].to_box(&camera, &pose).unwrap().moved);
        // Swaying by 0.2 m about one place for a second: never moved.
        let mut tracks = ObjectTracks::default();
        for (i, x) in [0.0, 0.2, -0.1, 0.15, 0.0].into_iter().enumerate() {
            let mut seen = [at(x)];
            tracks.update(0.25 * i as f64, &mut seen, &config);
            assert!(!seen[0].moved);
        }
        // An object of a class that moves on its own comes in moved and its track
        // keeps it, swaying or not.
        let mut tracks = ObjectTracks::default();
        for (i, x) in [0.0, 0.2, -0.1].into_iter().enumerate() {
            let mut seen = [Object {
                moved: i == 0,
                ..at(x)
            }];
            tracks.update(0.25 * i as f64, &mut seen, &config);
            assert!(seen[0].moved, "detection {i}");
        }
    }
}
