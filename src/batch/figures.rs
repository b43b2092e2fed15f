//! A sequence's figures (`plots/<sequence>/*.png`) and its section of `report.html`:
//! each mode's median-ATE run evaluated again from its files, the APE of all its runs
//! pooled, the dense-map previews.

use std::path::{Path, PathBuf};

use super::execute::evaluate_run;
use super::html;
use super::manifest::{PlannedSequence, RunMode};
use super::plots;
use super::record::{RunRecord, RunStatus};
use crate::eval::ate::PoseRelation;
use crate::eval::report::{EvalReport, RpeSpec};
use crate::io::trajectory::TrajectoryFormat;
use crate::io::Trajectory;

/// The run whose ATE is the median of the mode's runs (the lower one of an even count).
fn median_run<'a>(runs: &[&'a RunRecord]) -> Option<&'a RunRecord> {
    let mut with_ate: Vec<(&RunRecord, f64)> = runs
        .iter()
        .filter_map(|r| r.figures.as_ref().and_then(|f| f.ate_rmse).map(|a| (*r, a)))
        .collect();
    with_ate.sort_by(|a, b| a.1.total_cmp(&b.1));
    with_ate
        .get(with_ate.len().saturating_sub(1) / 2)
        .map(|(r, _)| *r)
}

fn run_dir(out: &Path, record: &RunRecord) -> PathBuf {
    out.join("runs")
        .join(&record.sequence)
        .join(record.mode.name())
        .join(format!("r{}", record.repetition))
}

/// A sequence's figures and its report section.
pub fn sequence_section(
    sequence: &PlannedSequence,
    sequence_dir: &Path,
    runs: &[&RunRecord],
    out: &Path,
    modes: &[RunMode],
    rpe: RpeSpec,
) -> Result<html::SequenceSection, String> {
    let mut section = html::SequenceSection {
        name: sequence.name.clone(),
        figures: Vec::new(),
        previews: Vec::new(),
        runs: runs
            .iter()
            .map(|r| {
                let dir = run_dir(out, r);
                let href = dir.strip_prefix(out).unwrap_or(&dir).display().to_string();
                (format!("{} r{}", r.mode.name(), r.repetition), href)
            })
            .collect(),
    };
    let ground_truth = crate::pipeline::open_sequence(sequence_dir, &sequence.config)
        .ok()
        .and_then(|s| s.ground_truth().cloned());
    let Some(reference) = ground_truth else {
        return Ok(section);
    };
    let evaluate = |record: &RunRecord| -> Option<EvalReport> {
        let estimate = Trajectory::read(
            &run_dir(out, record).join("trajectory.txt"),
            TrajectoryFormat::Tum,
        )
        .ok()?;
        evaluate_run(
            &reference,
            &estimate,
            &sequence.config,
            rpe,
            PoseRelation::TransPart,
        )
        .ok()
    };
    let mut medians = Vec::new();
    let mut pooled = Vec::new();
    for &mode in modes {
        let of_mode: Vec<&RunRecord> = runs
            .iter()
            .copied()
            .filter(|r| r.mode == mode && r.status == RunStatus::Ok)
            .collect();
        if let Some(report) = median_run(&of_mode).and_then(evaluate) {
            medians.push((mode, report));
        }
        let errors: Vec<f64> = of_mode
            .iter()
            .filter_map(|r| evaluate(r))
            .flat_map(|r| r.ape.errors)
            .collect();
        pooled.push((mode, errors));
        if let Some(median) = median_run(&of_mode) {
            let preview = run_dir(out, median).join("map_compare/compare_perspective.png");
            if preview.exists() {
                section.previews.push((
                    format!("{} r{} (median ATE)", mode.name(), median.repetition),
                    preview,
                ));
            }
        }
    }
    if medians.is_empty() {
        return Ok(section);
    }
    let dir = out.join("plots").join(&sequence.name);
    std::fs::create_dir_all(&dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let by_mode: Vec<(RunMode, &EvalReport)> = medians.iter().map(|(m, r)| (*m, r)).collect();
    let name = &sequence.name;
    let paths = [
        dir.join("trajectories.png"),
        dir.join("ape_time.png"),
        dir.join("ape_box.png"),
    ];
    plots::trajectories(
        &paths[0],
        &format!("{name}: trajectories (median run per mode)"),
        &by_mode,
    )?;
    plots::ape_over_time(
        &paths[1],
        &format!("{name}: APE over time (median run per mode)"),
        &by_mode,
    )?;
    plots::ape_boxes(
        &paths[2],
        &format!("{name}: APE per mode, all repetitions"),
        &pooled,
    )?;
    section.figures = paths.to_vec();
    Ok(section)
}
