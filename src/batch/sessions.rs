//! Groups of sequences tracked in one map (`map_from` in a manifest): each run's ATE
//! in the map's frame, the frame it was placed at, and one merged dense map per
//! group, mode and repetition (`dopslam merge` of the group's runs into
//! `OUT/merged/<group>/<mode>/r<k>/`), made when the tables are.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use serde::Serialize;

use super::execute::compare_with_static_scene;
use super::manifest::{root_sequence, MapFrom, PlannedSequence};
use super::results::{spread_text, Spread};
use super::{BatchError, BatchPlan};
use crate::dense::merge::MergeReport;
use crate::dop::Mode;
use crate::records::{MapFigures, RunRecord, RunStatus};

/// A sequence tracked in another's map, in one mode, over its repetitions.
#[derive(Debug, Clone, Serialize)]
pub struct InMapSummary {
    /// The sequence.
    pub sequence: String,
    /// The mode.
    pub mode: Mode,
    /// The sequence (or run folder) whose map its runs loaded.
    pub map_of: String,
    /// Localisation only.
    pub frozen: bool,
    /// Runs finished.
    pub runs: usize,
    /// ATE RMSE in the map's frame without alignment, m.
    pub ate_map_frame_rmse: Option<Spread>,
    /// ATE RMSE after SE(3) alignment, m.
    pub ate_rmse: Option<Spread>,
    /// The frame it was placed at.
    pub placed_at_frame: Option<Spread>,
}

/// One merged map of a group (`OUT/merged/<group>/<mode>/r<k>/`).
#[derive(Debug, Clone, Serialize)]
pub struct MergedMap {
    /// The group: the sequence whose runs made the first map.
    pub group: String,
    /// The mode.
    pub mode: Mode,
    /// The repetition.
    pub repetition: usize,
    /// The sequences merged, the group's first first.
    pub sequences: Vec<String>,
    /// The merged map's folder.
    pub dir: PathBuf,
    /// The run folders merged, in the order of `sequences`.
    pub runs: Vec<PathBuf>,
    /// Mesh vertices.
    pub mesh_vertices: Option<usize>,
    /// Frames that carved free space, over all recordings.
    pub carving_frames: Option<usize>,
    /// Merging took, seconds (`dense.json`'s total).
    pub seconds: Option<f64>,
    /// On a synthetic sequence: the merged map against the group's first sequence's
    /// static scene.
    pub map: Option<MapFigures>,
    /// Why it was not made.
    pub error: Option<String>,
}

/// The sequences that load a batch sequence's map, per mode.
pub fn in_map_summaries(
    planned: &[PlannedSequence],
    records: &[RunRecord],
    modes: &[Mode],
) -> Vec<InMapSummary> {
    let mut rows = Vec::new();
    for sequence in planned {
        let Some(map) = &sequence.map else { continue };
        let map_of = match &map.from {
            MapFrom::Run(run) => run.display().to_string(),
            MapFrom::Sequence(r) => planned[*r].name.clone(),
        };
        for &mode in modes.iter().filter(|m| sequence.modes.contains(m)) {
            let figures: Vec<_> = records
                .iter()
                .filter(|r| r.sequence == sequence.name && r.mode == mode)
                .filter(|r| r.status == RunStatus::Ok)
                .filter_map(|r| r.figures.as_ref())
                .collect();
            let spread = |f: &dyn Fn(&crate::records::RunFigures) -> Option<f64>| {
                Spread::of(figures.iter().filter_map(|r| f(r)))
            };
            rows.push(InMapSummary {
                sequence: sequence.name.clone(),
                mode,
                map_of: map_of.clone(),
                frozen: map.frozen,
                runs: figures.len(),
                ate_map_frame_rmse: spread(&|f| f.ate_map_frame_rmse),
                ate_rmse: spread(&|f| f.ate_rmse),
                placed_at_frame: spread(&|f| f.placed_at_frame.map(|p| p as f64)),
            });
        }
    }
    rows
}

/// The groups: each sequence that heads a `map_from` chain, with the sequences that
/// load its map (directly or down the chain), in the manifest's order.
fn groups(planned: &[PlannedSequence]) -> Vec<(usize, Vec<usize>)> {
    let mut groups: Vec<(usize, Vec<usize>)> = Vec::new();
    for k in 0..planned.len() {
        let Some(MapFrom::Sequence(_)) = planned[k].map.as_ref().map(|m| &m.from) else {
            continue;
        };
        let Some(root) = root_sequence(planned, k) else {
            continue;
        };
        match groups.iter_mut().find(|(r, _)| *r == root) {
            Some((_, members)) => members.push(k),
            None => groups.push((root, vec![k])),
        }
    }
    groups
}

/// Merges each group's runs of each mode and repetition whose runs all finished with
/// a dense map, with `program merge`; a merged map newer than every run it merges is
/// kept. Says what it does when `progress`.
pub fn merge_groups(
    plan: &BatchPlan,
    program: &Path,
    sequence_dirs: &[PathBuf],
    progress: bool,
) -> Vec<MergedMap> {
    let mut merged = Vec::new();
    for (root, members) in groups(&plan.planned) {
        let all: Vec<usize> = std::iter::once(root).chain(members).collect();
        if !all.iter().all(|&k| plan.planned[k].config.dense.enabled) {
            continue;
        }
        for job in plan.runs.iter().filter(|j| j.sequence == root) {
            let runs: Vec<&super::RunJob> = all
                .iter()
                .filter_map(|&k| {
                    plan.runs.iter().find(|j| {
                        j.sequence == k && j.mode == job.mode && j.repetition == job.repetition
                    })
                })
                .collect();
            if runs.len() < 2 {
                continue;
            }
            let label = format!(
                "merged/{}/{}/r{}",
                plan.planned[root].name,
                job.mode.name(),
                job.repetition
            );
            let dir = plan.out.join(&label);
            let mut row = MergedMap {
                group: plan.planned[root].name.clone(),
                mode: job.mode,
                repetition: job.repetition,
                sequences: runs
                    .iter()
                    .map(|j| plan.planned[j.sequence].name.clone())
                    .collect(),
                dir,
                runs: runs.iter().map(|j| j.dir.clone()).collect(),
                mesh_vertices: None,
                carving_frames: None,
                seconds: None,
                map: None,
                error: None,
            };
            let run_dirs: Vec<&Path> = runs.iter().map(|j| j.dir.as_path()).collect();
            let place = Place {
                out: &plan.out,
                label: &label,
            };
            let made = merge_runs(program, &run_dirs, place, progress);
            match made.and_then(|report| {
                let map = compare_with_static_scene(
                    &row.dir,
                    &sequence_dirs[root],
                    crate::records::run_alignment(&job.dir),
                )?;
                Ok((report, map))
            }) {
                Ok((report, map)) => {
                    row.mesh_vertices = Some(report.dense.mesh_vertices);
                    row.carving_frames =
                        Some(report.recordings.iter().map(|r| r.carving_frames).sum());
                    row.seconds = Some(report.dense.total_s);
                    row.map = map;
                }
                Err(e) => row.error = Some(e.to_string()),
            }
            merged.push(row);
        }
    }
    merged
}

/// A line for each merged map that could not be made, saying why.
pub fn merge_notes(merged: &[MergedMap]) -> Vec<String> {
    merged
        .iter()
        .filter_map(|m| {
            let why = m.error.as_deref()?;
            Some(format!(
                "{}/{}/r{}: no merged map: {why}",
                m.group,
                m.mode.name(),
                m.repetition
            ))
        })
        .collect()
}

/// Where a merged map goes: `OUT/<label>`, `label` being `merged/<group>/<mode>/r<k>`.
#[derive(Clone, Copy)]
struct Place<'a> {
    out: &'a Path,
    label: &'a str,
}

/// `program merge RUNS --out DIR` (its output in `DIR.log`), unless `DIR/merge.json`
/// is newer than every run's `run.json`; every run must have finished. An older
/// merged map is moved to `OUT/stale/` first.
fn merge_runs(
    program: &Path,
    runs: &[&Path],
    place: Place,
    progress: bool,
) -> Result<MergeReport, BatchError> {
    let dir = &place.out.join(place.label);
    let mut newest = None;
    for run in runs {
        let record = RunRecord::read(run);
        if record.as_ref().map(|r| r.status) != Some(RunStatus::Ok) {
            let why = format!("{} failed or did not finish", run.display());
            return Err(BatchError::MergeFailed(why));
        }
        let time = std::fs::metadata(run.join("run.json")).and_then(|m| m.modified());
        newest = newest.max(time.ok());
    }
    let report_path = dir.join(crate::io::run_dir::names::MERGE_REPORT);
    let made = std::fs::metadata(&report_path).and_then(|m| m.modified());
    if !made.is_ok_and(|made| Some(made) >= newest) {
        if dir.exists() {
            super::move_to_stale(place.out, place.label, dir)?;
        }
        if progress {
            eprintln!("merging {}", dir.display());
        }
        let output = Command::new(program)
            .arg("merge")
            .args(runs)
            .arg("--out")
            .arg(dir)
            .arg("--config")
            .arg(runs[0].join("config.toml"))
            .output()
            .map_err(|source| BatchError::Process {
                action: "start",
                program: program.to_path_buf(),
                source,
            })?;
        let log = dir.with_extension("log");
        let text = [output.stdout.as_slice(), output.stderr.as_slice()].concat();
        std::fs::write(&log, text).map_err(BatchError::file("write", &log))?;
        if !output.status.success() {
            let said = String::from_utf8_lossy(&output.stderr);
            let error = said.lines().rev().find_map(|l| l.strip_prefix("error: "));
            return Err(BatchError::MergeFailed(error.map_or_else(
                || format!("dopslam merge failed (see {})", log.display()),
                str::to_string,
            )));
        }
    }
    Ok(crate::records::read_merge(
        &crate::io::run_dir::RunDir::new(dir),
    )?)
}

/// A row of the table of runs in a loaded map (`results.md`, `report.html`).
fn in_map_cells(row: &InMapSummary) -> [String; 8] {
    [
        row.sequence.clone(),
        row.mode.name().to_string(),
        row.map_of.clone(),
        if row.frozen { "yes" } else { "no" }.to_string(),
        row.runs.to_string(),
        spread_text(row.ate_map_frame_rmse, 4, "[", "]"),
        spread_text(row.ate_rmse, 4, "[", "]"),
        spread_text(row.placed_at_frame, 0, "[", "]"),
    ]
}

/// What the sessions add to `results.md` and `results.json` (`in_map`, `merged`).
pub fn results(in_map: &[InMapSummary], merged: &[MergedMap]) -> super::results::MoreResults {
    let mut json = Vec::new();
    if !in_map.is_empty() {
        json.push(("in_map", serde_json::json!(in_map)));
    }
    if !merged.is_empty() {
        json.push(("merged", serde_json::json!(merged)));
    }
    super::results::MoreResults {
        markdown: sessions_md(in_map, merged),
        json,
    }
}

/// `results.md`'s sections on sessions: runs in a loaded map and merged maps.
fn sessions_md(in_map: &[InMapSummary], merged: &[MergedMap]) -> String {
    let mut out = String::new();
    if !in_map.is_empty() {
        out += "\n## Runs in a loaded map\n\nATE in the map's frame: no alignment; the map's frame is put on the ground truth's by the first pose of the run at the head of the chain (the map's origin).\n\n\
                | sequence | mode | map of | frozen | runs | ATE in the map's frame (m) | ATE RMSE, aligned (m) | placed at frame |\n|---|---|---|---|---|---|---|---|\n";
        for row in in_map {
            let _ = writeln!(out, "| {} |", in_map_cells(row).join(" | "));
        }
    }
    if !merged.is_empty() {
        out += "\n## Merged maps (one per group, mode and repetition)\n\n\
                | group | mode | run | sequences | mesh vertices | carving frames | ghost points | accuracy, median (m) | seconds | folder |\n|---|---|---|---|---|---|---|---|---|---|\n";
        for m in merged {
            let figures = m.map.as_ref();
            let cell = |v: Option<String>| v.unwrap_or_else(|| "-".into());
            let _ = writeln!(
                out,
                "| {} | {} | r{} | {} | {} | {} | {} | {} | {} | {} |",
                m.group,
                m.mode.name(),
                m.repetition,
                m.sequences.join(", "),
                cell(m.mesh_vertices.map(|v| v.to_string())),
                cell(m.carving_frames.map(|v| v.to_string())),
                cell(figures.and_then(|f| f.ghost_points).map(|v| v.to_string())),
                cell(
                    figures
                        .and_then(|f| f.accuracy_median)
                        .map(|v| format!("{v:.4}"))
                ),
                cell(m.seconds.map(|v| format!("{v:.1}"))),
                m.error
                    .as_deref()
                    .map_or_else(|| m.dir.display().to_string(), |e| format!("not made: {e}")),
            );
        }
    }
    out
}

/// `report.html`'s sections on sessions: the runs in a loaded map, and each merged map
/// beside its recordings' own (their comparison with the static scene, ghosts in red,
/// where the sequence is a render).
pub fn sessions_html(in_map: &[InMapSummary], merged: &[MergedMap]) -> String {
    use super::html::{escape, image};
    let mut out = String::new();
    if !in_map.is_empty() {
        out += "<h2>Runs in a loaded map</h2>\n<p>ATE in the map's frame: no alignment.</p>\n<table><tr><th>sequence</th><th>mode</th><th>map of</th><th>frozen</th><th>runs</th><th>ATE in the map's frame (m)</th><th>ATE, aligned (m)</th><th>placed at frame</th></tr>\n";
        for row in in_map {
            let cells: Vec<String> = in_map_cells(row).iter().map(|c| escape(c)).collect();
            let _ = writeln!(out, "<tr><td>{}</td></tr>", cells.join("</td><td>"));
        }
        out += "</table>\n";
    }
    if !merged.is_empty() {
        out += "<h2>Merged maps (ghosts in red)</h2>\n";
    }
    let picture = |dir: &Path, caption: &str| {
        let path = dir.join("map_compare/compare_perspective.png");
        path.exists().then(|| format!("<figure style=\"display:inline-block;max-width:32%\">{}<figcaption>{}</figcaption></figure>", image(&path, caption), escape(caption)))
    };
    for m in merged {
        let title = format!("{} / {} / r{}", m.group, m.mode.name(), m.repetition);
        let _ = writeln!(out, "<h3>{}</h3>", escape(&title));
        if let Some(error) = &m.error {
            let _ = writeln!(out, "<p>not made: {}</p>", escape(error));
            continue;
        }
        for (sequence, run) in m.sequences.iter().zip(&m.runs) {
            out += &picture(run, &format!("{sequence}'s own")).unwrap_or_default();
        }
        out += &picture(&m.dir, "merged").unwrap_or_default();
        out += "\n";
    }
    out
}
