//! The batch's tables: per sequence and mode, the median and spread over repetitions
//! (`results.csv`, `results.json`, `results.md`), and every run (`runs.csv`).

use std::fmt::Write as _;
use std::path::Path;

use serde::Serialize;

use crate::dop::Mode;
use crate::eval::stats::median_of_sorted;
use crate::io::atomic::write_atomic;
use crate::io::IoError;
use crate::records::{RunFigures, RunRecord, RunStatus};

/// Median, minimum and maximum of a figure over a group's runs.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Spread {
    /// The median.
    pub median: f64,
    /// The smallest.
    pub min: f64,
    /// The largest.
    pub max: f64,
    /// How many runs had the figure.
    pub n: usize,
}

impl Spread {
    /// `None` for no values.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let mut v: Vec<f64> = values.into_iter().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(Self {
            median: median_of_sorted(&v),
            min: v[0],
            max: v[v.len() - 1],
            n: v.len(),
        })
    }
}

/// One sequence in one mode, over its repetitions.
#[derive(Debug, Clone, Serialize)]
pub struct GroupSummary {
    /// The sequence.
    pub sequence: String,
    /// The mode.
    pub mode: Mode,
    /// Runs finished.
    pub runs: usize,
    /// Runs failed.
    pub failed: usize,
    /// ATE RMSE, m.
    pub ate_rmse: Option<Spread>,
    /// ATE RMSE of the tracking pass alone, m.
    pub ate_tracking_rmse: Option<Spread>,
    /// RPE RMSE, translation (m/s).
    pub rpe_translation: Option<Spread>,
    /// RPE RMSE, rotation (deg/s).
    pub rpe_rotation_deg: Option<Spread>,
    /// KITTI's relative errors, where the path reaches 100 m.
    pub kitti_translation_percent: Option<Spread>,
    /// KITTI's rotation error, degrees per 100 m.
    pub kitti_rotation_deg_per_100m: Option<Spread>,
    /// Tracked frames, %.
    pub coverage_percent: Option<Spread>,
    /// Median of the runs' median tracking times, and mean of their means (ms).
    pub median_tracking_ms: Option<f64>,
    /// Mean tracking time per frame, ms.
    pub mean_tracking_ms: Option<f64>,
    /// Keyframes.
    pub keyframes: Option<Spread>,
    /// Keypoints removed as dynamic per tracked frame.
    pub keypoints_removed_per_frame: Option<Spread>,
    /// Map points removed as dynamic.
    pub map_points_removed: Option<Spread>,
    /// Loops closed.
    pub loops: Option<Spread>,
    /// Dense map accuracy (median), m.
    pub map_accuracy_median: Option<Spread>,
    /// Ghost points in the dense map.
    pub ghost_points: Option<Spread>,
    /// Mover pixels kept out of the dense map, %.
    pub dynamic_removed_percent: Option<Spread>,
    /// The improvement of this mode's median ATE over no-DOP's, in % (the paper's
    /// `(ORB-SLAM2 - ours) / ORB-SLAM2`).
    pub improvement_percent: Option<f64>,
    /// Runs kept with `--keep-stale` although made with other settings (their figures
    /// count; `runs.csv` and `results.md` say why each is stale).
    pub stale: usize,
    /// The failed runs' errors.
    pub errors: Vec<String>,
}

/// Summaries of `records` per sequence and mode, in the order given.
pub fn summarise(records: &[RunRecord], sequences: &[String], modes: &[Mode]) -> Vec<GroupSummary> {
    let mut groups = Vec::new();
    for sequence in sequences {
        for &mode in modes {
            let runs: Vec<&RunRecord> = records
                .iter()
                .filter(|r| &r.sequence == sequence && r.mode == mode)
                .collect();
            if runs.is_empty() {
                continue;
            }
            groups.push(summarise_group(sequence, mode, &runs));
        }
    }
    for i in 0..groups.len() {
        let baseline = groups
            .iter()
            .find(|g| g.sequence == groups[i].sequence && g.mode == Mode::Off)
            .and_then(|g| g.ate_rmse);
        if groups[i].mode == Mode::Off {
            continue;
        }
        if let (Some(base), Some(this)) = (baseline, groups[i].ate_rmse) {
            if base.median > 0.0 {
                groups[i].improvement_percent =
                    Some(100.0 * (base.median - this.median) / base.median);
            }
        }
    }
    groups
}

fn summarise_group(sequence: &str, mode: Mode, runs: &[&RunRecord]) -> GroupSummary {
    let ok: Vec<&RunFigures> = runs
        .iter()
        .filter(|r| r.status == RunStatus::Ok)
        .filter_map(|r| r.figures.as_ref())
        .collect();
    let spread =
        |f: &dyn Fn(&RunFigures) -> Option<f64>| Spread::of(ok.iter().filter_map(|r| f(r)));
    let map = |f: &dyn Fn(&crate::records::MapFigures) -> Option<f64>| {
        Spread::of(ok.iter().filter_map(|r| r.map.as_ref().and_then(f)))
    };
    GroupSummary {
        sequence: sequence.to_string(),
        mode,
        runs: runs.len(),
        failed: runs.len() - ok.len(),
        ate_rmse: spread(&|r| r.ate_rmse),
        ate_tracking_rmse: spread(&|r| r.ate_tracking_rmse),
        rpe_translation: spread(&|r| r.rpe_translation),
        rpe_rotation_deg: spread(&|r| r.rpe_rotation_deg),
        kitti_translation_percent: spread(&|r| r.kitti_translation_percent),
        kitti_rotation_deg_per_100m: spread(&|r| r.kitti_rotation_deg_per_100m),
        coverage_percent: spread(&|r| Some(r.coverage_percent)),
        median_tracking_ms: spread(&|r| Some(r.median_tracking_ms)).map(|s| s.median),
        mean_tracking_ms: (!ok.is_empty())
            .then(|| ok.iter().map(|r| r.mean_tracking_ms).sum::<f64>() / ok.len() as f64),
        keyframes: spread(&|r| Some(r.keyframes as f64)),
        keypoints_removed_per_frame: spread(&|r| Some(r.keypoints_removed_per_frame)),
        map_points_removed: spread(&|r| Some(r.map_points_removed as f64)),
        loops: spread(&|r| Some(r.loops as f64)),
        map_accuracy_median: map(&|m| m.accuracy_median),
        ghost_points: map(&|m| m.ghost_points.map(|g| g as f64)),
        dynamic_removed_percent: map(&|m| m.dynamic_removed_percent),
        improvement_percent: None,
        stale: runs.iter().filter(|r| r.stale.is_some()).count(),
        errors: runs.iter().filter_map(|r| r.error.clone()).collect(),
    }
}

/// A number with `digits` decimals, or empty.
fn number(value: Option<f64>, digits: usize) -> String {
    value.map_or(String::new(), |v| format!("{v:.digits$}"))
}

/// The columns of `results.csv`.
const RESULTS_CSV_COLUMNS: [&str; 24] = [
    "sequence",
    "mode",
    "runs",
    "failed",
    "ate_rmse_median",
    "ate_rmse_min",
    "ate_rmse_max",
    "ate_tracking_rmse_median",
    "rpe_translation_median",
    "rpe_rotation_deg_median",
    "coverage_percent_median",
    "median_tracking_ms",
    "mean_tracking_ms",
    "keyframes_median",
    "keypoints_removed_per_frame_median",
    "map_points_removed_median",
    "loops_median",
    "map_accuracy_median",
    "ghost_points_median",
    "dynamic_removed_percent_median",
    "improvement_percent",
    "kitti_translation_percent_median",
    "kitti_rotation_deg_per_100m_median",
    "stale_runs",
];

/// A group's cells under [`RESULTS_CSV_COLUMNS`].
fn results_csv_row(g: &GroupSummary) -> [String; 24] {
    let m = |s: Option<Spread>, d| number(s.map(|s| s.median), d);
    [
        g.sequence.clone(),
        g.mode.name().to_string(),
        g.runs.to_string(),
        g.failed.to_string(),
        m(g.ate_rmse, 6),
        number(g.ate_rmse.map(|s| s.min), 6),
        number(g.ate_rmse.map(|s| s.max), 6),
        m(g.ate_tracking_rmse, 6),
        m(g.rpe_translation, 6),
        m(g.rpe_rotation_deg, 4),
        m(g.coverage_percent, 2),
        number(g.median_tracking_ms, 2),
        number(g.mean_tracking_ms, 2),
        m(g.keyframes, 1),
        m(g.keypoints_removed_per_frame, 2),
        m(g.map_points_removed, 1),
        m(g.loops, 1),
        m(g.map_accuracy_median, 4),
        m(g.ghost_points, 1),
        m(g.dynamic_removed_percent, 2),
        number(g.improvement_percent, 1),
        m(g.kitti_translation_percent, 4),
        m(g.kitti_rotation_deg_per_100m, 4),
        g.stale.to_string(),
    ]
}

/// `results.csv`: one row per sequence and mode.
pub fn results_csv(groups: &[GroupSummary]) -> String {
    let mut out = format!("{}\n", RESULTS_CSV_COLUMNS.join(","));
    for g in groups {
        let _ = writeln!(out, "{}", results_csv_row(g).join(","));
    }
    out
}

/// The columns of `runs.csv`.
const RUNS_CSV_COLUMNS: [&str; 21] = [
    "sequence",
    "mode",
    "repetition",
    "status",
    "seconds",
    "frames",
    "coverage_percent",
    "keyframes",
    "median_tracking_ms",
    "mean_tracking_ms",
    "ate_rmse",
    "ate_tracking_rmse",
    "rpe_translation",
    "rpe_rotation_deg",
    "keypoints_removed_per_frame",
    "map_points_removed",
    "loops",
    "map_accuracy_median",
    "ghost_points",
    "dynamic_removed_percent",
    "error",
];

/// A run's cells under [`RUNS_CSV_COLUMNS`] (the error quoted).
fn runs_csv_row(r: &RunRecord) -> [String; 21] {
    let f = r.figures.clone().unwrap_or_default();
    let map = f.map.clone().unwrap_or_default();
    // A stale run (kept with --keep-stale) says so in `status`, and why in `error`.
    let error = match &r.stale {
        Some(why) => format!("stale: made with other settings ({why})"),
        None => r.error.clone().unwrap_or_default(),
    }
    .replace(['"', '\n'], "'");
    [
        r.sequence.clone(),
        r.mode.name().to_string(),
        r.repetition.to_string(),
        match (r.status, &r.stale) {
            (RunStatus::Ok, None) => "ok",
            (RunStatus::Ok, Some(_)) => "stale",
            _ => "failed",
        }
        .to_string(),
        format!("{:.1}", r.seconds),
        f.frames.to_string(),
        format!("{:.2}", f.coverage_percent),
        f.keyframes.to_string(),
        format!("{:.2}", f.median_tracking_ms),
        format!("{:.2}", f.mean_tracking_ms),
        number(f.ate_rmse, 6),
        number(f.ate_tracking_rmse, 6),
        number(f.rpe_translation, 6),
        number(f.rpe_rotation_deg, 4),
        format!("{:.2}", f.keypoints_removed_per_frame),
        f.map_points_removed.to_string(),
        f.loops.to_string(),
        number(map.accuracy_median, 4),
        number(map.ghost_points.map(|g| g as f64), 0),
        number(map.dynamic_removed_percent, 2),
        format!("\"{error}\""),
    ]
}

/// `runs.csv`: one row per run.
pub fn runs_csv(records: &[RunRecord]) -> String {
    let mut out = format!("{}\n", RUNS_CSV_COLUMNS.join(","));
    for r in records {
        let _ = writeln!(out, "{}", runs_csv_row(r).join(","));
    }
    out
}

/// A spread as `median [min, max]` (one run: the median alone), or `-`; `open` and
/// `close` go around the range.
pub fn spread_text(s: Option<Spread>, digits: usize, open: &str, close: &str) -> String {
    match s {
        Some(s) if s.n > 1 => format!(
            "{:.digits$} {open}{:.digits$}, {:.digits$}{close}",
            s.median, s.min, s.max
        ),
        Some(s) => format!("{:.digits$}", s.median),
        None => "-".into(),
    }
}

fn spread_cell(s: Option<Spread>, digits: usize) -> String {
    spread_text(s, digits, "[", "]")
}

fn median_cell(s: Option<Spread>, digits: usize) -> String {
    s.map_or("-".into(), |s| format!("{:.digits$}", s.median))
}

/// The columns of the results table (`results.md`, `report.html`).
pub const TABLE_COLUMNS: [&str; 13] = [
    "sequence",
    "mode",
    "runs (failed)",
    "ATE RMSE (m), median [min, max]",
    "tracking-pass ATE (m)",
    "RPE 1 s (m/s)",
    "RPE 1 s (deg/s)",
    "KITTI t_rel (%) / r_rel (deg/100 m)",
    "coverage (%)",
    "tracking ms median / mean",
    "keyframes",
    "keypoints removed / frame",
    "DOP vs no-DOP",
];

/// A group's cells under [`TABLE_COLUMNS`]; `range` writes the ATE's spread.
pub fn table_cells(g: &GroupSummary, range: fn(Option<Spread>, usize) -> String) -> Vec<String> {
    vec![
        g.sequence.clone(),
        g.mode.name().to_string(),
        format!("{} ({})", g.runs, g.failed),
        range(g.ate_rmse, 4),
        median_cell(g.ate_tracking_rmse, 4),
        median_cell(g.rpe_translation, 4),
        median_cell(g.rpe_rotation_deg, 3),
        match (g.kitti_translation_percent, g.kitti_rotation_deg_per_100m) {
            (Some(t), Some(r)) => format!("{:.3} / {:.3}", t.median, r.median),
            _ => "-".into(),
        },
        median_cell(g.coverage_percent, 1),
        format!(
            "{} / {}",
            number(g.median_tracking_ms, 1),
            number(g.mean_tracking_ms, 1)
        ),
        median_cell(g.keyframes, 0),
        median_cell(g.keypoints_removed_per_frame, 1),
        g.improvement_percent
            .map_or("-".into(), |p| format!("{p:+.1} %")),
    ]
}

/// The columns of the dense-map table.
pub const MAP_COLUMNS: [&str; 5] = [
    "sequence",
    "mode",
    "accuracy, median distance (m)",
    "ghost points",
    "mover depth kept out (%)",
];

/// Whether a group has dense-map figures.
pub fn has_map(g: &GroupSummary) -> bool {
    g.ghost_points.is_some() || g.dynamic_removed_percent.is_some()
}

/// A group's cells under [`MAP_COLUMNS`].
pub fn map_cells(g: &GroupSummary) -> Vec<String> {
    vec![
        g.sequence.clone(),
        g.mode.name().to_string(),
        median_cell(g.map_accuracy_median, 4),
        spread_cell(g.ghost_points, 0),
        median_cell(g.dynamic_removed_percent, 2),
    ]
}

/// `results.md`: the tables a report needs.
pub fn results_md(groups: &[GroupSummary], header: &str) -> String {
    let mut out = format!("{header}\n\n| {} |\n", TABLE_COLUMNS.join(" | "));
    out += &format!("|{}\n", "---|".repeat(TABLE_COLUMNS.len()));
    for g in groups {
        let _ = writeln!(out, "| {} |", table_cells(g, spread_cell).join(" | "));
    }
    let dense: Vec<&GroupSummary> = groups.iter().filter(|g| has_map(g)).collect();
    if !dense.is_empty() {
        let _ = write!(
            out,
            "\n## Dense maps (against the static scene)\n\n| {} |\n|{}\n",
            MAP_COLUMNS.join(" | "),
            "---|".repeat(MAP_COLUMNS.len())
        );
        for g in dense {
            let _ = writeln!(out, "| {} |", map_cells(g).join(" | "));
        }
    }
    let failures: Vec<&GroupSummary> = groups.iter().filter(|g| !g.errors.is_empty()).collect();
    if !failures.is_empty() {
        out += "\n## Failed runs\n\n";
        for g in failures {
            for e in &g.errors {
                let _ = writeln!(out, "- {} / {}: {e}", g.sequence, g.mode.name());
            }
        }
    }
    out
}

/// Sections beyond the groups' (the batch's sessions, [`super::sessions`]): appended
/// to `results.md`, and keys of `results.json`.
#[derive(Debug, Default)]
pub struct MoreResults {
    /// Markdown after the tables.
    pub markdown: String,
    /// `results.json`'s further keys and their values.
    pub json: Vec<(&'static str, serde_json::Value)>,
}

/// Writes `results.csv`, `results.json`, `results.md` and `runs.csv` into `out`.
pub fn write_results(
    out: &Path,
    records: &[RunRecord],
    groups: &[GroupSummary],
    header: &str,
    more: &MoreResults,
) -> Result<(), IoError> {
    write_atomic(&out.join("results.csv"), results_csv(groups).as_bytes())?;
    write_atomic(&out.join("runs.csv"), runs_csv(records).as_bytes())?;
    let md = results_md(groups, header) + &more.markdown;
    write_atomic(&out.join("results.md"), md.as_bytes())?;
    let mut json = serde_json::json!({ "groups": groups, "runs": records });
    for (key, value) in &more.json {
        json[key] = value.clone();
    }
    let text = serde_json::to_string_pretty(&json).unwrap_or_default();
    write_atomic(&out.join("results.json"), text.as_bytes())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(mode: Mode, repetition: usize, ate: Option<f64>) -> RunRecord {
        RunRecord {
            schema: crate::records::SCHEMA,
            sequence: "s".into(),
            mode,
            repetition,
            status: if ate.is_some() {
                RunStatus::Ok
            } else {
                RunStatus::Failed
            },
            error: ate.is_none().then(|| "boom".into()),
            seconds: 1.0,
            inputs: Default::default(),
            stale: None,
            figures: ate.map(|a| RunFigures {
                ate_rmse: Some(a),
                coverage_percent: 100.0,
                ..RunFigures::default()
            }),
        }
    }

    #[test]
    fn medians_spreads_and_improvement() {
        let records = [
            record(Mode::Off, 1, Some(0.4)),
            record(Mode::Off, 2, Some(0.2)),
            record(Mode::Off, 3, Some(0.3)),
            record(Mode::Dop, 1, Some(0.03)),
            record(Mode::Dop, 2, None),
            record(Mode::Dop, 3, Some(0.01)),
        ];
        let groups = summarise(&records, &["s".into()], &[Mode::Dop, Mode::Off]);
        assert_eq!(groups.len(), 2);
        let dop = &groups[0];
        assert_eq!((dop.runs, dop.failed), (3, 1));
        let ate = dop.ate_rmse.unwrap();
        assert!((ate.median - 0.02).abs() < 1e-12 && ate.min == 0.01 && ate.max == 0.03);
        assert!((dop.improvement_percent.unwrap() - 100.0 * (0.3 - 0.02) / 0.3).abs() < 1e-9);
        assert_eq!(groups[1].ate_rmse.unwrap().median, 0.3);
        assert!(groups[1].improvement_percent.is_none());
        let md = results_md(&groups, "# t");
        assert!(
            md.contains("0.0200 [0.0100, 0.0300]") && md.contains("boom"),
            "{md}"
        );
        assert_eq!(results_csv(&groups).lines().count(), 3);
        assert_eq!(runs_csv(&records).lines().count(), 7);
    }
}
