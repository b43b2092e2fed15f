//! Which frames the dense pass fuses: every tracked frame of the largest map segment
//! (or its keyframes), every `frame_step`-th of them, and of those the ones that add
//! something: the camera moved or turned enough since the last fused frame, or a
//! keyframe, or `frame_max_gap` frames have passed (`frame_still_gap` while the camera
//! stands still) ([`super::config::DenseFrames`]).

use std::collections::VecDeque;

use super::config::{DenseConfig, DenseFrames};
use super::frame_table::FrameTable;
use super::{Chosen, FrameChoice, Fusion};
use crate::geometry::se3::Se3;
use crate::io::IoError;

/// The frames the dense pass takes, in sequence order: counted once, then read again
/// from the [`FrameTable`] by whoever needs them ([`ChosenFrames::candidates`],
/// [`ChosenFrames::fused`]), so no list of them is held.
pub(super) struct ChosenFrames {
    /// Candidates: the frames the masks' own detections are spaced over, so a frame
    /// left out of the fusion can still lend its boxes to the fused frames around it.
    pub candidates: usize,
    /// The frames fused.
    pub fused: usize,
    /// Fused frames taken while the camera stood still ([`DenseFrames::still_gap`]).
    pub still: usize,
    /// The first and the last candidate's index in the sequence.
    pub span: Option<(usize, usize)>,
    every_frame: bool,
    settings: DenseFrames,
}

/// The candidates and the fused frames of `table` (see [`ChosenFrames`]), counted.
pub(super) fn choose_frames(
    table: &FrameTable,
    config: &DenseConfig,
) -> Result<ChosenFrames, IoError> {
    let mut frames = ChosenFrames {
        candidates: 0,
        fused: 0,
        still: 0,
        span: None,
        every_frame: config.frames.which == FrameChoice::All && config.fusion != Fusion::Points,
        settings: config.frames.clone(),
    };
    let mut chooser = Chooser::new(&frames.settings);
    for candidate in frames.candidates(table) {
        let candidate = candidate?;
        frames.candidates += 1;
        let first = frames.span.map_or(candidate.0, |s| s.0);
        frames.span = Some((first, candidate.0));
        frames.fused += usize::from(chooser.offer(&candidate).is_some());
    }
    frames.still = chooser.still;
    Ok(frames)
}

impl ChosenFrames {
    /// The candidates in sequence order: every posed frame (or keyframe), every
    /// `frame_step`-th of them.
    pub fn candidates<'t>(
        &self,
        table: &'t FrameTable,
    ) -> impl Iterator<Item = Result<Chosen, IoError>> + 't {
        let every_frame = self.every_frame;
        let step = self.settings.step.max(1);
        (0..table.len())
            .filter_map(move |i| {
                let is_keyframe = table.is_keyframe(i);
                if !(every_frame || is_keyframe) {
                    return None;
                }
                table
                    .pose(i)
                    .transpose()
                    .map(|pose| Ok((i, pose?, is_keyframe)))
            })
            .step_by(step)
    }

    /// The fused frames in sequence order, each with the candidates it stands for
    /// (itself and those left out since the fused frame before).
    pub fn fused<'t>(
        &'t self,
        table: &'t FrameTable,
    ) -> impl Iterator<Item = Result<(Chosen, f32), IoError>> + 't {
        let mut chooser = Chooser::new(&self.settings);
        self.candidates(table)
            .filter_map(move |candidate| match candidate {
                Ok(candidate) => chooser
                    .offer(&candidate)
                    .map(|weight| Ok((candidate, weight))),
                Err(error) => Some(Err(error)),
            })
    }
}

/// Takes of the candidates, offered in order, those that add something to the last one
/// taken (see [`DenseFrames::min_translation`]; the first always).
struct Chooser<'s> {
    frames: &'s DenseFrames,
    /// The last taken candidate's pose.
    last: Option<Se3>,
    /// Candidates offered since then.
    since: usize,
    /// The poses of the latest `max_gap + 1` candidates (for [`still`]).
    recent: VecDeque<Se3>,
    /// Candidates taken while the camera stood still.
    still: usize,
}

impl<'s> Chooser<'s> {
    fn new(frames: &'s DenseFrames) -> Self {
        Self {
            frames,
            last: None,
            since: 0,
            recent: VecDeque::new(),
            still: 0,
        }
    }

    /// Whether `candidate` is taken: with the candidates it stands for (itself and
    /// those left out just before it).
    fn offer(&mut self, candidate: &Chosen) -> Option<f32> {
        let frames = self.frames;
        self.since += 1;
        if frames.still_gap > 0 {
            self.recent.push_back(candidate.1);
            if self.recent.len() > frames.max_gap + 1 {
                self.recent.pop_front();
            }
        }
        let is_still = still(&self.recent, frames);
        let gap = match is_still {
            true => frames.still_gap,
            false => frames.max_gap,
        };
        let adds = match &self.last {
            None => true,
            Some(last) => candidate.2 || self.since >= gap || moved(last, &candidate.1, frames),
        };
        if !adds {
            return None;
        }
        let weight = self.since as f32;
        self.last = Some(candidate.1);
        self.since = 0;
        self.still += usize::from(is_still);
        Some(weight)
    }
}

/// Whether the camera at `b` lies at least `min_translation` from `a` or is turned
/// at least `min_rotation` from it (both `camera_from_world`).
fn moved(a: &Se3, b: &Se3, frames: &DenseFrames) -> bool {
    moved_by(a, b, frames.min_translation, frames.min_rotation)
}

/// Whether the camera stands still at the latest of the `recent` candidates (see
/// [`DenseFrames::still_gap`]): it moved under a quarter of the fused frames' spacing
/// over the last `max_gap` candidates.
fn still(recent: &VecDeque<Se3>, frames: &DenseFrames) -> bool {
    let (Some(before), Some(now)) = (recent.front(), recent.back()) else {
        return false;
    };
    if recent.len() <= frames.max_gap {
        return false;
    }
    let (reach, turn) = (frames.min_translation / 4.0, frames.min_rotation / 4.0);
    frames.still_gap > 0 && !moved_by(before, now, reach, turn)
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

    /// What a [`Chooser`] took of some candidates.
    struct Taken {
        fused: Vec<Chosen>,
        weights: Vec<f32>,
        still: usize,
    }

    /// The `candidates` offered in order to a [`Chooser`] with `frames`.
    fn adding(candidates: Vec<Chosen>, frames: &DenseFrames) -> Taken {
        let mut chooser = Chooser::new(frames);
        let (mut fused, mut weights) = (Vec::new(), Vec::new());
        for candidate in candidates {
            if let Some(weight) = chooser.offer(&candidate) {
                fused.push(candidate);
                weights.push(weight);
            }
        }
        Taken {
            fused,
            weights,
            still: chooser.still,
        }
    }

    /// The sequence indices of what [`adding`] took (as many as its weights).
    fn indices(taken: Taken) -> Vec<usize> {
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
