//! The stereo rig's disparity offset, found by the tracking pass itself.
//!
//! The global pass can estimate the offset \(\delta\) of a rig's disparities from the
//! map and correct the map ([`crate::global::disparity_offset`]), but a tracking pass
//! that ran all its frames with the offset in its disparities has made its data
//! association at the wrong scale: on the real KITTI 01 clip, about half the real-time
//! DOP runs corrected afterwards kept 2-4 % of scale. So unless the config gives the
//! offset (`[stereo] disparity_offset_px`), the tracking pass looks for it while it
//! runs, within its first `[stereo] disparity_offset_frames` frames: from the 5th
//! keyframe on (then after 2 more, or a quarter more) it estimates the offset from the
//! map as local mapping left it (a probe, under the read lock); once the probe passes
//! the confidence test
//! ([`crate::global::disparity_offset::Estimate::verdict`]), local mapping is let
//! catch up, full BA runs, the estimate is tested again on its map, and when it passes
//! the offset is taken out of the map, the frames tracked so far and the tracker's last
//! frame, and added to every later frame's matches; later probes take out what is
//! left ([`OffsetTest::Residual`]). No frame is tracked twice (`docs/design.md`, "The
//! rig's disparity offset").

use super::setup::Setup;
use crate::global::disparity_offset::{
    offset_frame, OffsetReport, OffsetTest, Verdict, MIN_PAIRS, MIN_PARALLAX_DEG,
};
use crate::global::{full_bundle_adjustment, take_out_disparity_offset};
use crate::io::sequence::SensorKind;
use crate::io::IoError;
use crate::map::record::FrameRecords;
use crate::records::{RigOffset, TakenOut};
use crate::system::System;

/// Probes start once the map has this many keyframes.
const FIRST_PROBE_KEYFRAMES: usize = 5;
/// After a probe, the next waits for this many more keyframes, or for a quarter more
/// keyframes than the map has, whichever is more (a probe reads the whole map).
const PROBE_EVERY_KEYFRAMES: usize = 2;
/// At most this many corrections in one tracking pass.
const MAX_CORRECTIONS: usize = 3;

/// The tracking pass's search for the rig's offset (see the module doc).
pub struct OffsetSearch {
    /// Frames (from the first) within which the offset may be taken out.
    frames: usize,
    /// The threshold of the confidence test, pixels.
    min_px: f64,
    /// The next probe waits for the map to have this many keyframes.
    next_probe: usize,
    /// What the last probe or correction found.
    last: Option<OffsetReport>,
    /// Frames tracked when the last estimate was made.
    at_frame: usize,
    /// Whether the search has ended (called needless, or corrected enough).
    done: bool,
    /// Each correction: the frames tracked then, and the pixels taken out.
    taken: Vec<TakenOut>,
}

impl OffsetSearch {
    /// The search of a run of `setup`: stereo, no offset given, frames to look in, and
    /// the global pass's full BA and estimate turned on; `None` otherwise.
    pub fn of(setup: &Setup) -> Option<Self> {
        let config = &setup.config;
        let wanted = setup.sensor == SensorKind::Stereo
            && setup.disparity_offset.is_none()
            && config.stereo.disparity_offset_frames > 0
            && config.global.enabled
            && config.global.full_ba
            && config.global.disparity_offset;
        wanted.then_some(Self {
            frames: config.stereo.disparity_offset_frames,
            min_px: config.global.disparity_offset_min_px,
            next_probe: FIRST_PROBE_KEYFRAMES,
            last: None,
            at_frame: 0,
            done: false,
            taken: Vec::new(),
        })
    }

    /// After frame `index` was tracked and its record pushed onto `records`: when it
    /// made a keyframe, a probe, and when the probe and the estimate after full BA pass
    /// the confidence test, the offset taken out of the map and of `records`. Returns
    /// the offset to add to every later frame's matches, pixels, when it was taken out
    /// (`Err`: the records' observations could not be read or written).
    pub fn after_frame(
        &mut self,
        system: &mut System,
        records: &mut FrameRecords,
        setup: &Setup,
        index: usize,
    ) -> Result<Option<f64>, IoError> {
        if self.done || index >= self.frames {
            return Ok(None);
        }
        let is_keyframe = records.last().is_some_and(|r| r.is_keyframe());
        let keyframes = last_keyframes(system);
        if !is_keyframe || keyframes < self.next_probe {
            return Ok(None);
        }
        self.next_probe = (keyframes + PROBE_EVERY_KEYFRAMES).max(keyframes * 5 / 4);
        let inputs = setup.global_inputs();
        let Some(probe) = system.with_map(|map| {
            crate::global::disparity_offset::estimate(map, inputs.camera, inputs.removal_threshold)
        }) else {
            return Ok(None);
        };
        let test = self.test();
        let verdict = probe.verdict(test);
        self.at_frame = index + 1;
        self.last = Some(OffsetReport::first(&probe, &verdict));
        match verdict {
            Verdict::Unsure(_) => Ok(None),
            Verdict::Needless(_) => {
                self.done = true;
                Ok(None)
            }
            Verdict::Apply => self.take_out(system, records, setup, test),
        }
    }

    /// The confidence test: at `[global] disparity_offset_min_px` for the first
    /// correction, [`OffsetTest::Residual`] for what a correction left (a first
    /// estimate from a few keyframes may fall short, the highway preset's 1.2 px rig:
    /// 0.95 px at frame 5, or overshoot, real KITTI 01: 2.09 px at frame 9).
    fn test(&self) -> OffsetTest {
        match self.taken.is_empty() {
            true => OffsetTest::First(self.min_px),
            false => OffsetTest::Residual,
        }
    }

    /// Local mapping let catch up, full BA, then the rounds of estimate, test and
    /// correction on the map ([`take_out_disparity_offset`]); the frames tracked so far
    /// and the tracker's last frame take what was taken out.
    fn take_out(
        &mut self,
        system: &mut System,
        records: &mut FrameRecords,
        setup: &Setup,
        test: OffsetTest,
    ) -> Result<Option<f64>, IoError> {
        let inputs = setup.global_inputs();
        let config = &setup.config.global;
        let bf = inputs.camera.bf;
        let last = records.last().cloned().unwrap_or_default();
        let found = system.edit_map(
            |map| {
                let mut ba = full_bundle_adjustment(map, &inputs, config);
                if ba.is_none() {
                    return Ok(None);
                }
                take_out_disparity_offset(map, &inputs, config, test, &mut ba, records)
            },
            &last,
            |found, frame| {
                let taken = found.as_ref().ok().and_then(Option::as_ref);
                offset_frame(frame, bf, taken.map_or(0.0, |f| f.offset_px))
            },
        )?;
        let Some(found) = found else {
            return Ok(None);
        };
        let taken = found.offset_px;
        self.last = Some(found);
        if taken == 0.0 {
            // Full BA's map did not bear the probe out: wait longer before the next.
            self.next_probe = self.next_probe.max(last_keyframes(system) * 3 / 2);
            return Ok(None);
        }
        self.taken.push(TakenOut {
            frames: self.at_frame,
            offset_px: taken,
        });
        self.done = self.taken.len() >= MAX_CORRECTIONS;
        Ok(Some(taken))
    }

    /// The offset the tracking pass took out, with its evidence: its last estimate and
    /// the confidence test's word on it, or why there was none.
    pub fn finish(self) -> RigOffset {
        let estimate = self.last.unwrap_or_else(|| OffsetReport {
            verdict: format!(
                "no estimate within the first {} frames: the map never had {FIRST_PROBE_KEYFRAMES} keyframes and {MIN_PAIRS} observations of points seen at {MIN_PARALLAX_DEG} degrees of parallax",
                self.frames
            ),
            ..OffsetReport::default()
        });
        RigOffset {
            offset_px: self.taken.iter().map(|t| t.offset_px).sum(),
            source: "estimated".into(),
            frames: Some(self.at_frame),
            estimate: Some(estimate),
            taken: self.taken,
        }
    }
}

/// Keyframes in the system's map.
fn last_keyframes(system: &System) -> usize {
    system.with_map(|map| map.keyframes().len())
}
