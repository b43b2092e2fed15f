//! Standing objects: a detected box of a class that moves, judged by the frames that
//! saw its points (beyond the paper, whose motivation names the case: the detector
//! "fails on a priori dynamic objects that keep static, e.g. parked cars").
//!
//! The geometric check ([`super::consistency`]) tests every matched map point against
//! each trusted frame's pose, points left out as dynamic included. When a keyframe's
//! detection comes back, the points the model would put on a box \(b\) (the verdicts
//! of [`super::boxes::verdicts`]: inside the box, at the object's depth) are counted:
//! \(n_j\) of them were judged in at least `geometric_frames` frames, and \(n_c\) of
//! those held still in each of their last `geometric_frames`: consistent, or unclear
//! (outside the pose's gate but within `geometric_gate` times it: on real images a
//! static point whose stereo depth is a little off is often there). The box *stands* when
//!
//! \[ n_c \ge n_{\min} \quad\text{and}\quad n_c \ge s\, n_j \]
//!
//! with \(n_{\min}\) = `standing_min_points` and \(s\) = `standing_share`. A standing box
//! counts as a static object on that keyframe: its points take \(S_t = 0\), and it is
//! no wait zone for the new points near it. A car that drives at street speed moves
//! metres between frames, so its points are inconsistent, or not matched at all (then
//! not judged): it never stands. Objects of `never_static_classes` (people) and
//! objects followed moving never stand.

use super::boxes::{verdicts, Keypoint, ObjectBox};
use super::consistency::Consistency;
use super::{DopConfig, Mode};

/// Marks the standing boxes of `boxes` static (`dynamic = false`) and returns how many
/// stood; `judged[i]` is the geometric check's record of the map point keypoint `i`
/// observes (`None` without one).
pub fn mark_standing(
    config: &DopConfig,
    keypoints: &[Keypoint],
    judged: &[Option<Consistency>],
    boxes: &mut [ObjectBox],
) -> usize {
    if !config.standing_boxes || config.mode != Mode::Dop || !config.geometric {
        return 0;
    }
    let verdict = verdicts(config, keypoints, boxes);
    let frames = config.geometric_frames;
    let mut standing = 0;
    for b in boxes.iter_mut().filter(|b| b.dynamic && !b.moved) {
        let (mut tested, mut consistent) = (0u32, 0u32);
        for ((k, v), c) in keypoints.iter().zip(&verdict).zip(judged) {
            let Some(c) = c.filter(|c| c.tested >= frames) else {
                continue;
            };
            if *v == Some(true) && b.contains(k.x, k.y) {
                tested += 1;
                consistent += u32::from(c.steady_run >= frames);
            }
        }
        if consistent >= config.standing_min_points
            && consistent as f32 >= config.standing_share * tested as f32
        {
            b.dynamic = false;
            standing += 1;
        }
    }
    standing
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// `n` keypoints on a car 12 m away in the box, `background` on a wall at 30 m
    /// inside it too, each judged as `on_car` and `on_wall` say.
    fn scene(
        n: usize,
        on_car: Consistency,
        background: usize,
    ) -> (Vec<Keypoint>, Vec<Option<Consistency>>) {
        let mut keypoints = Vec::new();
        let mut judged = Vec::new();
        for i in 0..n {
            let x = 110.0 + (i % 10) as f32 * 4.0;
            let y = 130.0 + (i / 10) as f32 * 4.0;
            keypoints.push(Keypoint { x, y, depth: 12.0 });
            judged.push(Some(on_car));
        }
        let wall = Consistency {
            tested: 5,
            steady_run: 5,
            ..Consistency::default()
        };
        for i in 0..background {
            keypoints.push(Keypoint {
                x: 85.0 + i as f32,
                y: 85.0,
                depth: 30.0,
            });
            judged.push(Some(wall));
        }
        (keypoints, judged)
    }

    fn car() -> ObjectBox {
        ObjectBox {
            bbox: [80.0, 80.0, 160.0, 240.0],
            dynamic: true,
            depth: None,
            moved: false,
        }
    }

    fn record(tested: u32, steady_run: u32) -> Consistency {
        Consistency {
            tested,
            steady_run,
            ..Consistency::default()
        }
    }

    #[test]
    fn a_car_whose_points_hold_still_stands_and_a_moving_one_does_not() {
        let config = DopConfig::default();
        let cases = [
            ("parked", record(4, 3), true),
            ("moving: inconsistent", record(4, 0), false),
            ("not judged yet", record(1, 1), false),
            ("consistent once only", record(4, 1), false),
        ];
        for (what, on_car, stands) in cases {
            // The wall behind it is consistent, but it is not the car's depth.
            let (keypoints, judged) = scene(20, on_car, 30);
            let mut boxes = [car()];
            let n = mark_standing(&config, &keypoints, &judged, &mut boxes);
            assert_eq!(n, usize::from(stands), "{what}");
            assert_eq!(boxes[0].dynamic, !stands, "{what}");
        }
        // Too few points to judge: 9 consistent of 9.
        let (keypoints, judged) = scene(9, record(4, 3), 0);
        let mut boxes = [car()];
        assert_eq!(mark_standing(&config, &keypoints, &judged, &mut boxes), 0);
        // A person (moved: never_static_classes) never stands; nor with the rule off.
        let (keypoints, judged) = scene(20, record(4, 3), 0);
        let mut person = [ObjectBox {
            moved: true,
            ..car()
        }];
        assert_eq!(mark_standing(&config, &keypoints, &judged, &mut person), 0);
        let off = DopConfig {
            standing_boxes: false,
            ..DopConfig::default()
        };
        let mut boxes = [car()];
        assert_eq!(mark_standing(&off, &keypoints, &judged, &mut boxes), 0);
        assert!(boxes[0].dynamic);
    }

    proptest! {
        /// The box stands exactly when enough of its judged points are consistent, at
        /// least `standing_min_points` of them; points judged too few times do not
        /// count either way.
        #[test]
        fn stands_exactly_when_the_share_and_the_count_are_met(
            consistent in 0usize..30,
            inconsistent in 0usize..30,
            fresh in 0usize..30,
        ) {
            let config = DopConfig::default();
            let mut keypoints = Vec::new();
            let mut records = Vec::new();
            let kinds = [(consistent, record(3, 2)), (inconsistent, record(3, 0)), (fresh, record(1, 1))];
            for (count, record) in kinds {
                for _ in 0..count {
                    let i = keypoints.len();
                    keypoints.push(Keypoint {
                        x: 100.0 + (i % 40) as f32,
                        y: 150.0 + (i / 40) as f32,
                        depth: 12.0,
                    });
                    records.push(Some(record));
                }
            }
            let mut boxes = [car()];
            let n = mark_standing(&config, &keypoints, &records, &mut boxes);
            let tested = consistent + inconsistent;
            let stands = consistent >= 10 && consistent as f32 >= 0.8 * tested as f32;
            prop_assert_eq!(n == 1, stands);
            prop_assert_eq!(boxes[0].dynamic, !stands);
        }
    }
}
