//! The stereo rig's disparity offset, known or found before tracking.
//!
//! The global pass can estimate the offset \(\delta\) of a rig's disparities from the
//! map and correct the map ([`crate::global::disparity_offset`]), but a tracking pass
//! that ran with the offset in its disparities has already made its data association
//! with the wrong scale: on the real KITTI 01 clip, 8 of 14 real-time DOP runs
//! corrected afterwards kept 2-4 % of scale (ATE 0.23-0.62 m against 0.08-0.13 m). So unless the config gives the offset (`[stereo]
//! disparity_offset_px`), the first `[stereo] disparity_offset_frames` frames are
//! tracked once, deterministic, without detector or DOP, their map bundle-adjusted and
//! the offset estimated from it; when it reaches `[global] disparity_offset_min_px`,
//! the run's tracking pass adds it to every stereo match (`docs/design.md`, "The rig's
//! disparity offset").

use super::error::RunError;
use super::global_pass::global_inputs;
use super::options::RunOptions;
use super::plan::RunPlan;
use super::setup::Setup;
use super::tracking_pass::{tracking_pass, TrackingInputs};
use crate::io::sequence::SensorKind;
use crate::records::RigOffset;

/// Whether a run of `setup` estimates the offset before tracking: stereo, no offset
/// given, frames to estimate from, and the global pass's estimate turned on.
fn wanted(setup: &Setup) -> bool {
    let config = &setup.config;
    setup.sensor == SensorKind::Stereo
        && setup.disparity_offset.is_none()
        && config.stereo.disparity_offset_frames > 0
        && config.global.enabled
        && config.global.full_ba
        && config.global.disparity_offset
}

/// Tracks the first frames of `sequence` once and estimates the rig's offset from
/// their map ([`crate::global::disparity_offset_of`]); `None` when the plan does not
/// want it, or the frames did not track to the end, or their map had too few points
/// with parallax. Nothing is written into the run folder.
pub fn estimate(plan: &RunPlan) -> Result<Option<RigOffset>, RunError> {
    let (sequence, setup, options) = (plan.sequence, &plan.setup, &plan.options);
    if !wanted(setup) {
        return Ok(None);
    }
    let frames = setup
        .config
        .stereo
        .disparity_offset_frames
        .min(options.max_frames.unwrap_or(usize::MAX))
        .min(sequence.len());
    if options.progress {
        eprintln!(
            "the rig's disparity offset: tracking the first {frames} frames once to estimate it ([stereo] disparity_offset_px skips this)"
        );
    }
    let quiet = RunOptions {
        max_frames: Some(frames),
        progress: false,
        deterministic: true,
        debug_frames: None,
        dense: false,
        rerun: None,
        ..options.clone()
    };
    let prefix = setup.for_offset_estimate();
    let inputs = TrackingInputs {
        sequence,
        setup: &prefix,
        detector: None,
        options: &quiet,
        run: &plan.run,
    };
    let mut pass = tracking_pass(inputs, &mut [])?;
    if pass.stop.is_some() {
        return Ok(None);
    }
    let inputs = global_inputs(&prefix);
    let found =
        crate::global::disparity_offset_of(&mut pass.tracked.map, &inputs, &prefix.config.global);
    Ok(found.map(|estimate| RigOffset {
        offset_px: estimate.offset_px,
        source: "estimated".into(),
        frames: Some(frames),
        estimate: Some(estimate),
    }))
}
