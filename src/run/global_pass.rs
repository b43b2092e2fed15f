//! The global pass after a complete tracking pass: loop closing on the candidates
//! place recognition found, essential graph, full BA, frames refined
//! ([`crate::global::run`]), on the map the system handed over unlocked.

use super::error::RunError;
use super::outputs::write_tracking_trajectory;
use super::setup::Setup;
use super::tracking_pass::TrackingPass;
use crate::global::GlobalReport;
use crate::io::run_dir::RunDir;
use crate::io::Trajectory;

/// Runs the global pass when the tracking pass went to the end and place recognition
/// ran beside it; the tracking pass's trajectory is written first. Returns the pass's
/// report with that trajectory.
pub fn global_pass(
    pass: &mut TrackingPass,
    setup: &Setup,
    run: &RunDir,
) -> Result<Option<(GlobalReport, Trajectory)>, RunError> {
    if pass.stop.is_some() {
        return Ok(None);
    }
    let Some(recognised) = pass.tracked.recognised.take() else {
        return Ok(None);
    };
    let tracking = write_tracking_trajectory(run, &pass.tracked.map, &pass.records)?;
    let inputs = setup.global_inputs();
    let report = crate::global::run(
        &mut pass.tracked.map,
        &inputs,
        &setup.config.global,
        recognised,
        &mut pass.records,
    )?;
    Ok(Some((report, tracking)))
}
