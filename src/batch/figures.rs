//! A sequence's figures (`plots/<sequence>/*.png`) and its section of `report.html`:
//! each mode's median-ATE run evaluated again from its files, the APE of all its runs
//! pooled, the dense-map previews.

use std::path::{Path, PathBuf};

use super::execute::{evaluate_trajectory, ground_truth};
use super::html;
use super::manifest::PlannedSequence;
use super::plots;
use super::BatchError;
use crate::dop::Mode;
use crate::eval::ate::PoseRelation;
use crate::eval::report::{Evaluation, RpeSpec};
use crate::io::run_dir::RunDir;
use crate::records::{RunRecord, RunStatus};

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

/// A sequence's figures and its report section.
pub fn sequence_section(
    sequence: &PlannedSequence,
    sequence_dir: &Path,
    runs: &[&RunRecord],
    out: &Path,
    modes: &[Mode],
    rpe: RpeSpec,
) -> Result<html::SequenceSection, BatchError> {
    let mut section = html::SequenceSection {
        name: sequence.name.clone(),
        figures: Vec::new(),
        previews: Vec::new(),
        runs: runs
            .iter()
            .map(|r| {
                let dir = r.dir(out);
                let href = dir.strip_prefix(out).unwrap_or(&dir).display().to_string();
                (format!("{} r{}", r.mode.name(), r.repetition), href)
            })
            .collect(),
    };
    let Ok(Some(reference)) = ground_truth(sequence_dir, &sequence.config) else {
        return Ok(section);
    };
    let mut medians = Vec::new();
    let mut pooled = Vec::new();
    for &mode in modes {
        let of_mode: Vec<&RunRecord> = runs
            .iter()
            .copied()
            .filter(|r| r.mode == mode && r.status == RunStatus::Ok)
            .collect();
        let median = median_run(&of_mode);
        let mut errors = Vec::new();
        for &run in &of_mode {
            let path = RunDir::new(run.dir(out)).trajectory();
            let relation = PoseRelation::TransPart;
            let Ok(report) =
                evaluate_trajectory(&reference, &path, &sequence.config, rpe, relation)
            else {
                continue;
            };
            errors.extend_from_slice(&report.series.ape.errors);
            if median.is_some_and(|m| std::ptr::eq(m, run)) {
                medians.push((mode, report));
            }
        }
        pooled.push((mode, errors));
        if let Some(median) = median {
            let preview = median.dir(out).join("map_compare/compare_perspective.png");
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
    section.figures = plot_sequence(out, &sequence.name, &medians, &pooled)?;
    Ok(section)
}

/// The sequence's plots under `OUT/plots/NAME/`: the median runs' trajectories and APE
/// over time, and each mode's pooled APE; their paths.
fn plot_sequence(
    out: &Path,
    name: &str,
    medians: &[(Mode, Evaluation)],
    pooled: &[(Mode, Vec<f64>)],
) -> Result<Vec<PathBuf>, BatchError> {
    let dir = out.join("plots").join(name);
    std::fs::create_dir_all(&dir).map_err(BatchError::file("create", &dir))?;
    let by_mode: Vec<(Mode, &Evaluation)> = medians.iter().map(|(m, r)| (*m, r)).collect();
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
        pooled,
    )?;
    Ok(paths.to_vec())
}
