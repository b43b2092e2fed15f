//! The tracker's own tests (private state: the DOP gate in the pose, the keyframe
//! decision with waiting points, the geometric check).

use super::*;
use crate::dop::consistency::Judgement;
use crate::dop::DopConfig;
use crate::dynamics::frames::{geometric_check, Participation};
use crate::dynamics::tracked::DopFigures;
use crate::geometry::camera::PinholeCamera;
use crate::geometry::se3::Se3;
use crate::map::{KeyFrame, Map, MapPoint, MapPointKey};
use nalgebra::Vector3;

/// A point at (0, 0, 1) made by keyframe `first`.
fn made_by(map: &mut Map, first: usize) -> MapPointKey {
    map.insert_point(MapPoint::new(
        Vector3::z(),
        [0; 4],
        Vector3::z(),
        (0.1, 10.0),
        first,
    ))
}

fn map_with_points(n: usize) -> (Map, Vec<MapPointKey>) {
    let mut map = Map::default();
    let keys = (0..n).map(|_| made_by(&mut map, 0)).collect();
    (map, keys)
}

/// A tracker with the default config on TUM fr3's camera (`bf` = 40 pixel metres).
fn fr3_tracker() -> (PinholeCamera, Tracker) {
    let pinhole = PinholeCamera::tum_fr3();
    let tracker = Tracker::new(
        TrackerConfig::default(),
        StereoCamera::new(&pinhole, 40.0),
        ScalePyramid::new(8, 1.2),
        pinhole.width,
        pinhole.height,
    );
    (pinhole, tracker)
}

/// Verdicts: the first `outliers` points inconsistent, the others consistent.
fn checks(keys: &[MapPointKey], outliers: usize) -> Vec<(MapPointKey, Judgement)> {
    judged(keys, outliers, Judgement::Inconsistent)
}

/// Verdicts: the first `n` points `first`, the others consistent.
fn judged(keys: &[MapPointKey], n: usize, first: Judgement) -> Vec<(MapPointKey, Judgement)> {
    keys.iter()
        .enumerate()
        .map(|(i, k)| (*k, if i < n { first } else { Judgement::Consistent }))
        .collect()
}

#[test]
fn geometric_check_raises_points_that_stay_outliers() {
    let dop = DopConfig::default();
    let (mut map, keys) = map_with_points(10);
    // Points 0 and 1 are outliers, the rest inliers.
    assert_eq!(
        geometric_check(&dop, &mut map, &checks(&keys, 2), 0.0),
        (0, 0)
    );
    assert_eq!(map.points()[keys[0]].consistency.outlier_run, 1);
    // The second frame in a row raises them: 0.5 -> 0.65.
    assert_eq!(
        geometric_check(&dop, &mut map, &checks(&keys, 2), 0.1),
        (2, 0)
    );
    assert!((map.points()[keys[0]].moving - 0.65).abs() < 1e-6);
    assert!((map.points()[keys[2]].moving - 0.5).abs() < 1e-6);
    // Now dynamic, they are not raised again.
    assert_eq!(
        geometric_check(&dop, &mut map, &checks(&keys, 2), 0.2),
        (0, 0)
    );
    assert_eq!(
        geometric_check(&dop, &mut map, &checks(&keys, 2), 0.3),
        (0, 0)
    );
    // A consistent frame resets the count.
    let (mut map, keys) = map_with_points(10);
    geometric_check(&dop, &mut map, &checks(&keys, 1), 0.0);
    geometric_check(&dop, &mut map, &checks(&keys, 0), 0.1);
    assert_eq!(map.points()[keys[0]].consistency.outlier_run, 0);
}

/// A point just outside the pose's gate (within `geometric_gate` times it) frame
/// after frame is never raised: on real images a static point whose stereo depth is
/// a little off sits there. It is not consistent either (no verified-static run), but
/// it held still (the standing test's run). One unclear frame breaks a row of
/// outliers.
#[test]
fn points_just_outside_the_gate_are_neither_raised_nor_consistent() {
    let dop = DopConfig::default();
    let (mut map, keys) = map_with_points(10);
    for n in 0..4 {
        let done = geometric_check(
            &dop,
            &mut map,
            &judged(&keys, 2, Judgement::Unclear),
            f64::from(n) * 0.1,
        );
        assert_eq!(done, (0, 0));
    }
    let c = map.points()[keys[0]].consistency;
    assert_eq!(
        (c.tested, c.inlier_run, c.outlier_run, c.steady_run),
        (4, 0, 0, 4)
    );
    assert!((map.points()[keys[0]].moving - 0.5).abs() < 1e-6);
    // Outlier, unclear, outlier: no two outliers in a row, no raise; the outliers
    // end the steady run.
    let (mut map, keys) = map_with_points(10);
    for (n, first) in [
        Judgement::Inconsistent,
        Judgement::Unclear,
        Judgement::Inconsistent,
    ]
    .into_iter()
    .enumerate()
    {
        let done = geometric_check(&dop, &mut map, &judged(&keys, 2, first), n as f64 * 0.1);
        assert_eq!(done, (0, 0));
    }
    let c = map.points()[keys[0]].consistency;
    assert_eq!((c.outlier_run, c.steady_run), (1, 0));
}

#[test]
fn geometric_check_skips_frames_where_the_pose_is_in_doubt() {
    let dop = DopConfig::default();
    let (mut map, keys) = map_with_points(10);
    // 4 of 10 outliers: above geometric_max_outliers (0.35).
    for n in 0..3 {
        assert_eq!(
            geometric_check(&dop, &mut map, &checks(&keys, 4), f64::from(n)),
            (0, 0)
        );
    }
    assert!(keys
        .iter()
        .all(|k| map.points()[*k].consistency == Default::default()));
    // Dynamic points do not count towards the share: 4 dynamic outliers of 10 do
    // not put the pose in doubt.
    for k in &keys[..4] {
        map.point_mut(*k).moving = 0.9;
    }
    geometric_check(&dop, &mut map, &checks(&keys, 4), 4.0);
    assert_eq!(map.points()[keys[9]].consistency.inlier_run, 1);
}

/// Real time: the points of a keyframe whose detection has not come back take no
/// part in the pose while enough others remain. Here they sit on a person who
/// moved 10 cm and outnumber the room's points; held out, the pose is the room's.
#[test]
fn points_awaiting_their_detection_stay_out_of_the_pose() {
    let pinhole = PinholeCamera::tum_fr3();
    let camera = StereoCamera::new(&pinhole, 40.0);
    let mut tracker = Tracker::new(
        TrackerConfig::default(),
        camera,
        ScalePyramid::new(8, 1.2),
        pinhole.width,
        pinhole.height,
    );
    let dop = DopConfig::default();
    let gate = Participation {
        dop: Some(&dop),
        ..Participation::default()
    };
    let (room, person) = (80, 120);
    let mut map = Map::default();
    let (mut keypoints, mut keys) = (Vec::new(), Vec::new());
    for i in 0..room + person {
        let (x, y) = (20.0 + (i % 20) as f64 * 30.0, 20.0 + (i / 20) as f64 * 40.0);
        let z = 2.0 + (i % 7) as f64 * 0.3;
        let seen = pinhole.unproject(&nalgebra::Vector2::new(x, y), z);
        // The person's points were made where the person stood a frame ago.
        let (position, first) = if i < room {
            (seen, 0)
        } else {
            (seen + Vector3::new(0.1, 0.0, 0.0), 7)
        };
        keys.push(Some(map.insert_point(MapPoint::new(
            position,
            [0; 4],
            Vector3::z(),
            (0.1, 10.0),
            first,
        ))));
        keypoints.push(crate::features::KeyPoint {
            x: x as f32,
            y: y as f32,
            ..Default::default()
        });
    }
    let n = keypoints.len();
    let frame = Frame::from_parts(
        1,
        0.1,
        keypoints,
        vec![[0; 4]; n],
        vec![0.0; n],
        vec![-1.0; n],
        (pinhole.width, pinhole.height),
    );
    let error_with = |tracker: &Tracker, map: &Map, keys: &[Option<MapPointKey>]| {
        let input = TrackInput {
            map,
            frame: &frame,
            gate: &gate,
        };
        let estimate = tracker.optimise(input, &Se3::identity(), keys, &mut Timing::default());
        estimate.camera_from_world.translation.vector.norm()
    };
    let mixed = error_with(&tracker, &map, &keys);
    assert!(mixed > 0.02, "the person pulls the pose: {mixed}");
    map.await_detection(7);
    assert!(error_with(&tracker, &map, &keys) < 1e-3);
    // With too few other points the awaiting ones join, but only those that agree
    // with the pose the others give on their own: not the person's.
    tracker.config.held_out_min_points = room + 1;
    assert!(error_with(&tracker, &map, &keys) < 1e-3);
    // With too few for a pose of their own, all join.
    let few: Vec<Option<MapPointKey>> = keys
        .iter()
        .enumerate()
        .map(|(i, k)| k.filter(|_| i < 10 || i >= room))
        .collect();
    map.detection_came_back(7);
    let few_mixed = error_with(&tracker, &map, &few);
    map.await_detection(7);
    assert!((error_with(&tracker, &map, &few) - few_mixed).abs() < 1e-9);
    assert!(few_mixed > 0.02, "{few_mixed}");
}

/// A still camera whose reference keyframe made 400 points on a person the
/// detector has not reported yet: the frame tracks the room's 100. Counted, those
/// 400 make the frame look very weak (a keyframe, which makes more such points);
/// while they wait for their detection they do not count.
#[test]
fn points_that_wait_do_not_make_keyframes() {
    let (pinhole, mut tracker) = fr3_tracker();
    let dop = DopConfig::default();
    let gate = Participation {
        dop: Some(&dop),
        ..Participation::default()
    };
    let (room, person) = (100, 400);
    let n = room + person;
    let frame = Frame::blank(n, (pinhole.width, pinhole.height));
    let mut map = Map::default();
    let mut keyframe = KeyFrame::new(frame.clone(), Se3::identity());
    for (i, slot) in keyframe.map_points.iter_mut().enumerate() {
        let first = if i < room { 0 } else { 7 };
        *slot = Some(map.insert_point(MapPoint::new(
            Vector3::z(),
            [0; 4],
            Vector3::z(),
            (0.1, 10.0),
            first,
        )));
    }
    let tracked: Vec<Option<MapPointKey>> = (0..n)
        .map(|i| keyframe.map_points[i].filter(|_| i < room))
        .collect();
    tracker.reference = Some(map.add_keyframe(keyframe));
    tracker.frames_since_keyframe = 5;
    let need = |map: &Map| {
        let input = TrackInput {
            map,
            frame: &frame,
            gate: &gate,
        };
        let state = Settling {
            mapping_idle: true,
            ..Default::default()
        };
        tracker.need_keyframe(input, &Se3::identity(), &tracked, room, state)
    };
    assert!(need(&map), "100 of 500 points: very weak");
    map.await_detection(7);
    assert!(!need(&map));
}

#[test]
fn dynamic_points_that_stay_consistent_are_lowered_back_into_the_pose() {
    let dop = DopConfig::default();
    let (mut map, keys) = map_with_points(10);
    // Two points on a parked car: detected, dynamic, but they never move.
    for k in &keys[..2] {
        map.point_mut(*k).moving = 0.75;
    }
    let mut lowered = 0;
    for n in 0..30 {
        lowered += geometric_check(&dop, &mut map, &checks(&keys, 0), f64::from(n) * 0.1).1;
    }
    assert!(lowered > 0);
    assert!(keys[..2]
        .iter()
        .all(|k| !dop.removed(map.points()[*k].moving)));
    assert!(keys[..2]
        .iter()
        .all(|k| map.points()[*k].consistency.verified_static(&dop)));
}

/// A room of `n` points in front of the camera, each with its own descriptor.
fn fixture_room(n: usize) -> Vec<(Vector3<f64>, crate::features::Descriptor)> {
    let mut rng = crate::random::Rng::new(11);
    (0..n)
        .map(|i| {
            let (column, row) = ((i % 30) as f64, (i / 30) as f64);
            let position = Vector3::new(
                -1.0 + column * 0.07,
                -0.7 + row * 0.07,
                2.5 + (i % 7) as f64 * 0.25,
            );
            let descriptor = std::array::from_fn(|_| rng.next_u64());
            (position, descriptor)
        })
        .collect()
}

/// The frame a camera at `camera_from_world` sees of `room`: every point in the image,
/// with its descriptor, depth and right coordinate (`bf` = 40 pixel metres).
fn fixture_frame(
    index: usize,
    pinhole: &PinholeCamera,
    room: &[(Vector3<f64>, crate::features::Descriptor)],
    camera_from_world: &Se3,
) -> Frame {
    let (mut keypoints, mut descriptors, mut depth, mut right_u) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for (position, descriptor) in room {
        let p = camera_from_world * nalgebra::Point3::from(*position);
        let pixel = pinhole.project(&p.coords);
        if p.z <= 0.0 || pixel.x < 1.0 || pixel.y < 1.0 {
            continue;
        }
        if pixel.x >= pinhole.width as f64 - 1.0 || pixel.y >= pinhole.height as f64 - 1.0 {
            continue;
        }
        keypoints.push(crate::features::KeyPoint {
            x: pixel.x as f32,
            y: pixel.y as f32,
            ..Default::default()
        });
        descriptors.push(*descriptor);
        depth.push(p.z as f32);
        right_u.push((pixel.x - 40.0 / p.z) as f32);
    }
    Frame::from_parts(
        index,
        index as f64 * 0.1,
        keypoints,
        descriptors,
        depth,
        right_u,
        (pinhole.width, pinhole.height),
    )
}

/// [`Tracker::locate`] then [`Tracker::settle`], as the system calls them without the
/// DOP model.
fn track_fixture(tracker: &mut Tracker, map: &SharedMap, frame: Frame) -> TrackedFrame {
    let gate = Participation::default();
    match tracker.locate(map, frame, &gate) {
        Located::Started(done) => *done,
        Located::Searched(search) => {
            let mut map = map.write().unwrap();
            tracker.settle(&mut map, &gate, *search, DopFigures::default(), true)
        }
    }
}

/// A small map and frames built here: the first frame starts the map, the second is
/// tracked at its true pose (against the reference keyframe: no motion model yet), a
/// frame of unknown descriptors is lost with the reason.
#[test]
fn a_fixture_map_tracks_the_true_pose_and_names_why_a_frame_is_lost() {
    let (pinhole, mut tracker) = fr3_tracker();
    let map = SharedMap::default();
    let room = fixture_room(600);
    let first = track_fixture(
        &mut tracker,
        &map,
        fixture_frame(0, &pinhole, &room, &Se3::identity()),
    );
    assert_eq!(first.stats.state, TrackingState::Ok);
    assert!(first.record.keyframe.is_some());
    assert_eq!(map.read().unwrap().points().len(), 600);

    let truth = Se3::from_parts(
        nalgebra::Translation3::new(0.03, -0.01, 0.02),
        nalgebra::Rotation3::from_euler_angles(0.01, -0.02, 0.005),
    );
    let second = track_fixture(
        &mut tracker,
        &map,
        fixture_frame(1, &pinhole, &room, &truth),
    );
    assert_eq!(
        second.stats.state,
        TrackingState::Ok,
        "{:?}",
        second.stats.lost
    );
    let pose = second.record.camera_from_world.expect("tracked");
    let error = pose * truth.inverse();
    assert!(error.translation.vector.norm() < 1e-3, "{error:?}");
    assert!(error.rotation.angle() < 1e-3);
    assert!(second.stats.inliers > 500, "{}", second.stats.inliers);
    assert_eq!(second.record.observations.len(), second.stats.inliers);

    let strangers: Vec<_> = fixture_room(600)
        .into_iter()
        .map(|(position, descriptor)| (position, descriptor.map(|d| !d)))
        .collect();
    let lost = track_fixture(
        &mut tracker,
        &map,
        fixture_frame(2, &pinhole, &strangers, &truth),
    );
    assert_eq!(lost.stats.state, TrackingState::Lost);
    assert!(lost.record.camera_from_world.is_none());
    assert!(
        matches!(lost.stats.lost, Some(Reject::FewMatches { found, .. }) if found < 15),
        "{:?}",
        lost.stats.lost
    );
}

/// A frame is on a revisit when most of its matched points were made by keyframes
/// more than `REVISIT_KEYFRAMES` older than the tracker's newest.
#[test]
fn a_frame_matching_mostly_old_points_is_a_revisit() {
    let mut map = Map::default();
    // Ten points of keyframe 2, four of keyframe 29.
    let old: Vec<_> = (0..10).map(|_| Some(made_by(&mut map, 2))).collect();
    let new: Vec<_> = (0..4).map(|_| Some(made_by(&mut map, 29))).collect();
    let matches = [&old[..], &new[..]].concat();
    assert!(revisit::is_revisit(&map, Some(29), &matches));
    // Three old points against four new ones: new ground.
    let matches = [&old[..3], &new[..]].concat();
    assert!(!revisit::is_revisit(&map, Some(29), &matches));
    // Keyframe 2 is only 20 keyframes older than a newest 22: not old yet.
    assert!(!revisit::is_revisit(&map, Some(22), &old));
    // A tracker that made no keyframe tracks in a map it was given: every point is old.
    assert!(revisit::is_revisit(&map, None, &old));
    // Matches to points removed meanwhile count for nothing.
    assert!(!revisit::is_revisit(&Map::default(), None, &old));
}

/// On a revisit the keyframe decision counts the points of the old keyframe that
/// shares most of the frame's matches, those seen by three keyframes or more.
#[test]
fn a_revisit_is_weighed_against_the_old_keyframe_sharing_most_matches() {
    let mut map = Map::default();
    let blank = || KeyFrame::new(Frame::blank(20, (640, 480)), Se3::identity());
    let keyframes: Vec<_> = (0..30).map(|_| map.add_keyframe(blank())).collect();
    let points: Vec<_> = (0..10).map(|_| made_by(&mut map, 2)).collect();
    // Keyframe 2 sees all ten, keyframe 3 the first six, keyframe 29 (new) the first
    // four: points 0-3 are seen three times, 4-5 twice, 6-9 once.
    for (i, &p) in points.iter().enumerate() {
        map.add_observation(p, keyframes[2], i);
        if i < 6 {
            map.add_observation(p, keyframes[3], i);
        }
        if i < 4 {
            map.add_observation(p, keyframes[29], i);
        }
    }
    let matches: Vec<_> = points.iter().map(|&p| Some(p)).collect();
    let counted = revisit::revisited_points(&map, Some(29), &matches).unwrap();
    let kept: Vec<_> = counted.iter().flatten().copied().collect();
    assert_eq!(kept, points[..4].to_vec());
    // No old keyframe shares a match: nothing to weigh against.
    assert!(revisit::revisited_points(&map, Some(10), &matches).is_none());
}
