//! `report.html`: one self-contained page (pictures embedded, no outside resources)
//! with the results table, each sequence's figures and dense-map previews, and links
//! to every run's folder.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use base64::Engine as _;

use super::results::{GroupSummary, Spread};

/// One sequence's section.
pub struct SequenceSection {
    pub name: String,
    /// PNG figures (trajectories, APE over time, box plots), in order.
    pub figures: Vec<PathBuf>,
    /// Dense-map previews with their captions.
    pub previews: Vec<(String, PathBuf)>,
    /// Run folders, relative to the report, with their labels.
    pub runs: Vec<(String, String)>,
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// An `<img>` with the PNG inlined, or nothing when it cannot be read.
fn image(path: &Path, alt: &str) -> String {
    match std::fs::read(path) {
        Ok(bytes) => format!(
            "<img alt=\"{}\" src=\"data:image/png;base64,{}\">",
            escape(alt),
            base64::engine::general_purpose::STANDARD.encode(bytes)
        ),
        Err(_) => String::new(),
    }
}

fn cell(s: Option<Spread>, digits: usize) -> String {
    match s {
        Some(s) if s.n > 1 => format!("{:.digits$} <small>[{:.digits$}, {:.digits$}]</small>", s.median, s.min, s.max),
        Some(s) => format!("{:.digits$}", s.median),
        None => "-".into(),
    }
}

/// The page.
pub fn report_html(title: &str, header_lines: &[String], groups: &[GroupSummary], sections: &[SequenceSection]) -> String {
    let mut out = String::new();
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>\
body{{font-family:sans-serif;margin:2em;color:#222}}table{{border-collapse:collapse;font-size:14px}}\
td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right}}td:first-child,td:nth-child(2){{text-align:left}}\
th{{background:#eee}}img{{max-width:48%;margin:4px;border:1px solid #ddd}}small{{color:#777}}\
.dop{{color:#1f5fbf}}.no-dop{{color:#c0392b}}.mask-boxes{{color:#e67e22}}\
</style></head><body>\n<h1>{t}</h1>\n",
        t = escape(title)
    );
    for line in header_lines {
        let _ = writeln!(out, "<p>{}</p>", escape(line));
    }
    out += "<h2>Results</h2>\n<table><tr><th>sequence</th><th>mode</th><th>runs (failed)</th><th>ATE RMSE (m) median [min, max]</th><th>tracking-pass ATE (m)</th><th>RPE 1 s (m/s)</th><th>RPE 1 s (deg/s)</th><th>coverage (%)</th><th>tracking ms median / mean</th><th>keyframes</th><th>keypoints removed / frame</th><th>ghost points</th><th>DOP vs no-DOP</th></tr>\n";
    for g in groups {
        let _ = writeln!(
            out,
            "<tr><td><a href=\"#{s}\">{s}</a></td><td class=\"{m}\">{m}</td><td>{} ({})</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{} / {}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
            g.runs,
            g.failed,
            cell(g.ate_rmse, 4),
            cell(g.ate_tracking_rmse, 4),
            cell(g.rpe_translation, 4),
            cell(g.rpe_rotation_deg, 3),
            cell(g.coverage_percent, 1),
            g.median_tracking_ms.map_or("-".into(), |v| format!("{v:.1}")),
            g.mean_tracking_ms.map_or("-".into(), |v| format!("{v:.1}")),
            cell(g.keyframes, 0),
            cell(g.keypoints_removed_per_frame, 1),
            cell(g.ghost_points, 0),
            g.improvement_percent.map_or("-".into(), |p| format!("{p:+.1} %")),
            s = escape(&g.sequence),
            m = g.mode.name(),
        );
    }
    out += "</table>\n";
    for section in sections {
        let _ = writeln!(out, "<h2 id=\"{n}\">{n}</h2>", n = escape(&section.name));
        for figure in &section.figures {
            out += &image(figure, &section.name);
        }
        if !section.previews.is_empty() {
            out += "<h3>Dense maps (ghosts in red)</h3>\n";
            for (caption, path) in &section.previews {
                let _ = write!(out, "<figure style=\"display:inline-block;max-width:48%\">{}<figcaption>{}</figcaption></figure>", image(path, caption).replace("max-width:48%", ""), escape(caption));
            }
        }
        out += "<p>Runs: ";
        let links: Vec<String> = section
            .runs
            .iter()
            .map(|(label, href)| format!("<a href=\"{}\">{}</a>", escape(href), escape(label)))
            .collect();
        out += &links.join(" · ");
        out += "</p>\n";
    }
    let errors: Vec<String> = groups
        .iter()
        .flat_map(|g| g.errors.iter().map(move |e| format!("{} / {}: {e}", g.sequence, g.mode.name())))
        .collect();
    if !errors.is_empty() {
        out += "<h2>Failed runs</h2>\n<ul>\n";
        for e in errors {
            let _ = writeln!(out, "<li>{}</li>", escape(&e));
        }
        out += "</ul>\n";
    }
    out += "</body></html>\n";
    out
}
