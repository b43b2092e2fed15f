//! Which frames the dense pass fuses: every tracked frame of the largest map segment
//! (or its keyframes), every `frame_step`-th of them, and of those the ones that add
//! something: the camera moved or turned enough since the last fused frame, or a
//! keyframe, or `frame_max_gap` frames have passed (`frame_still_gap` while the camera
//! stands still) ([`super::config::DenseFrames`]).

use super::config::{DenseConfig, DenseFrames};
use super::inputs::{key, RunInputs};
use super::{Chosen, FrameChoice, Fusion};
use crate::geometry::se3::Se3;
use crate::io::sequence::Sequence;

/// The frames the dense pass takes, in sequence order.
pub(super) struct ChosenFrames {
    /// Every candidate: the frames the masks' own detections are spaced over, so a
    /// frame left out of the fusion can still lend its boxes to the fused frames
    /// around it.
    pub candidates: Vec<Chosen>,
    /// The frames fused.
    pub fused: Vec<Chosen>,
    /// For each fused frame, the candidates it stands for: itself and those left out
    /// since the last fused one.
    pub weights: Vec<f32>,
    /// Fused frames taken while the camera stood still ([`DenseFrames::still_gap`]).
    pub still: usize,
}

/// The candidates (see [`ChosenFrames`]) and those of them fused.
pub(super) fn choose_frames(
    sequence: &dyn Sequence,
    read: &RunInputs,
    config: &DenseConfig,
) -> ChosenFrames {
    let every_frame = config.frames.which == FrameChoice::All && config.fusion != Fusion::Points;
    let candidates: Vec<Chosen> = (0..sequence.len())
        .filter_map(|i| {
            let k = key(sequence.timestamp(i));
            let pose = *read.poses.get(&k)?;
            let is_keyframe = read.keyframe_times.contains(&k);
            (every_frame || is_keyframe).then_some((i, pose, is_keyframe))
        })
        .step_by(config.frames.step)
        .collect();
    adding(candidates, &config.frames)
}

/// The `candidates` with those of them that add something to the last one taken
/// (see [`DenseFrames::min_translation`]; the first always), each with the candidates
/// it stands for (itself and those left out just before it).
fn adding(candidates: Vec<Chosen>, frames: &DenseFrames) -> ChosenFrames {
    let mut taken: Vec<Chosen> = Vec::with_capacity(candidates.len());
    let mut weights = Vec::with_capacity(candidates.len());
    let (mut since, mut still_taken) = (0, 0);
    for (j, &candidate) in candidates.iter().enumerate() {
        since += 1;
        let is_still = still(&candidates, j, frames);
        let gap = match is_still {
            true => frames.still_gap,
            false => frames.max_gap,
        };
        let adds = match taken.last() {
            None => true,
            Some(last) => candidate.2 || since >= gap || moved(&last.1, &candidate.1, frames),
        };
        if adds {
            taken.push(candidate);
            weights.push(since as f32);
            since = 0;
            still_taken += usize::from(is_still);
        }
    }
    ChosenFrames {
        candidates,
        fused: taken,
        weights,
        still: still_taken,
    }
}

/// Whether the camera at `b` lies at least `min_translation` from `a` or is turned
/// at least `min_rotation` from it (both `camera_from_world`).
fn moved(a: &Se3, b: &Se3, frames: &DenseFrames) -> bool {
    moved_by(a, b, frames.min_translation, frames.min_rotation)
}

/// Whether the camera stands still at candidate `j` (see
/// [`DenseFrames::still_gap`]): it moved under a quarter of the fused frames' spacing
/// over the last `max_gap` candidates.
fn still(candidates: &[Chosen], j: usize, frames: &DenseFrames) -> bool {
    let Some(before) = j.checked_sub(frames.max_gap).map(|i| &candidates[i]) else {
        return false;
    };
    let (reach, turn) = (frames.min_translation / 4.0, frames.min_rotation / 4.0);
    frames.still_gap > 0 && !moved_by(&before.1, &candidates[j].1, reach, turn)
}

/// Whether the camera at `b` lies at least `metres` from `a` or is turned at least
/// `degrees` from it (both `camera_from_world`).
fn moved_by(a: &Se3, b: &Se3, metres: f64, degrees: f64) -> bool {
    let (centre_a, centre_b) = (
        a.inverse().translation.vector,
        b.inverse().translation.vector,
    );
    let turned = (a.rotation * b.rotation.inverse()).angle().to_degrees();
    (centre_a - centre_b).norm() >= metres || turned >= degrees
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, Vector3};

    /// A camera that moves `metres` along x and turns `degrees` about y per frame.
    fn path(n: usize, metres: f64, degrees: f64) -> Vec<Chosen> {
        (0..n)
            .map(|i| {
                let rotation = Rotation3::from_axis_angle(
                    &Vector3::y_axis(),
                    (degrees * i as f64).to_radians(),
                );
                let pose = crate::geometry::se3::from_parts(
                    Vector3::new(metres * i as f64, 0.0, 0.0),
                    *rotation.matrix(),
                );
                (i, pose, false)
            })
            .collect()
    }

    fn settings(min_translation: f64, min_rotation: f64, max_gap: usize) -> DenseFrames {
        DenseFrames {
            which: FrameChoice::All,
            step: 1,
            min_translation,
            min_rotation,
            max_gap,
            still_gap: 0,
        }
    }

    /// The sequence indices of what [`adding`] took (as many as its weights).
    fn indices(taken: ChosenFrames) -> Vec<usize> {
        assert_eq!(taken.fused.len(), taken.weights.len());
        taken.fused.iter().map(|c| c.0).collect()
    }

    #[test]
    fn a_still_camera_is_fused_every_max_gap_frames_and_keyframes_always() {
        let mut still = path(10, 0.0, 0.0);
        still[4].2 = true;
        assert_eq!(
            indices(adding(still.clone(), &settings(0.01, 0.5, 3))),
            [0, 3, 4, 7]
        );
        // Each stands for itself and the frames left out before it.
        assert_eq!(
            adding(still.clone(), &settings(0.01, 0.5, 3)).weights,
            [1.0, 3.0, 1.0, 3.0]
        );
    }

    #[test]
    fn a_moving_camera_is_fused_once_it_moved_or_turned_enough() {
        // 4 mm a frame: every third frame passes 1 cm.
        let slow = path(10, 0.004, 0.0);
        assert_eq!(
            indices(adding(slow.clone(), &settings(0.01, 0.5, 5))),
            [0, 3, 6, 9]
        );
        // 0.3 degrees a frame: every second frame passes 0.5 degrees.
        let turning = path(7, 0.0, 0.3);
        assert_eq!(
            indices(adding(turning.clone(), &settings(0.01, 0.5, 5))),
            [0, 2, 4, 6]
        );
        // Both thresholds at 0: every frame.
        assert_eq!(
            indices(adding(slow.clone(), &settings(0.0, 0.0, 5))).len(),
            10
        );
    }

    #[test]
    fn a_camera_that_stands_still_is_fused_every_still_gap_frames() {
        let with_still_gap = |gap| DenseFrames {
            still_gap: gap,
            ..settings(0.02, 1.0, 3)
        };
        // Still from the start: once `max_gap` frames show it, every frame.
        let still = path(8, 0.0, 0.0);
        assert_eq!(
            indices(adding(still.clone(), &with_still_gap(1))),
            [0, 3, 4, 5, 6, 7]
        );
        assert_eq!(
            indices(adding(still.clone(), &with_still_gap(2))),
            [0, 3, 5, 7]
        );
        assert_eq!(
            indices(adding(still.clone(), &with_still_gap(0))),
            [0, 3, 6]
        );
        // Frames 3-7 came while it stood still (frame 3 too: it has stood 3 frames).
        assert_eq!(adding(still.clone(), &with_still_gap(1)).still, 5);
        assert_eq!(adding(still.clone(), &with_still_gap(0)).still, 0);
        // 2 mm a frame is 6 mm over 3 frames, over a quarter of 2 cm: not still, and
        // the camera is fused once it moved 2 cm or 3 frames passed.
        let creeping = path(8, 0.002, 0.0);
        assert_eq!(
            indices(adding(creeping.clone(), &with_still_gap(1))),
            [0, 3, 6]
        );
        assert_eq!(adding(creeping.clone(), &with_still_gap(1)).still, 0);
        // 1 mm a frame (3 mm over 3 frames): still.
        let jitter = path(8, 0.001, 0.0);
        assert_eq!(indices(adding(jitter.clone(), &with_still_gap(1))).len(), 6);
    }
}
