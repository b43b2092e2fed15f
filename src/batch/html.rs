//! `report.html`: one self-contained page (pictures embedded, no outside resources)
//! with the results table, each sequence's figures and dense-map previews, and links
//! to every run's folder.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use base64::Engine as _;

use super::results::{
    has_map, map_cells, spread_text, table_cells, GroupSummary, Spread, MAP_COLUMNS, TABLE_COLUMNS,
};

/// One sequence's section.
pub struct SequenceSection {
    /// The sequence's name.
    pub name: String,
    /// PNG figures (trajectories, APE over time, box plots), in order.
    pub figures: Vec<PathBuf>,
    /// Dense-map previews with their captions.
    pub previews: Vec<(String, PathBuf)>,
    /// Run folders, relative to the report, with their labels.
    pub runs: Vec<(String, String)>,
}

/// `text` with HTML's special characters escaped.
pub fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// An `<img>` with the PNG inlined, or nothing when it cannot be read.
pub fn image(path: &Path, alt: &str) -> String {
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
    spread_text(s, digits, "<small>[", "]</small>")
}

/// A sequence's section: its figures, its dense-map previews and links to its runs.
fn section_html(out: &mut String, section: &SequenceSection) {
    let _ = writeln!(out, "<h2 id=\"{n}\">{n}</h2>", n = escape(&section.name));
    for figure in &section.figures {
        *out += &image(figure, &section.name);
    }
    if !section.previews.is_empty() {
        *out += "<h3>Dense maps (ghosts in red)</h3>\n";
        for (caption, path) in &section.previews {
            let _ = write!(out, "<figure style=\"display:inline-block;max-width:48%\">{}<figcaption>{}</figcaption></figure>", image(path, caption), escape(caption));
        }
    }
    *out += "<p>Runs: ";
    let links: Vec<String> = section
        .runs
        .iter()
        .map(|(label, href)| format!("<a href=\"{}\">{}</a>", escape(href), escape(label)))
        .collect();
    *out += &links.join(" · ");
    *out += "</p>\n";
}

/// The page.
pub fn report_html(
    title: &str,
    header_lines: &[String],
    groups: &[GroupSummary],
    sections: &[SequenceSection],
    sessions: &str,
) -> String {
    let mut out = String::new();
    let _ = write!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{t}</title>\n<style>\
body{{font-family:sans-serif;margin:2em;color:#222}}table{{border-collapse:collapse;font-size:14px}}\
td,th{{border:1px solid #bbb;padding:3px 8px;text-align:right}}td:first-child,td:nth-child(2){{text-align:left}}\
th{{background:#eee}}img{{max-width:48%;margin:4px;border:1px solid #ddd}}figure img{{max-width:100%}}small{{color:#777}}\
.dop{{color:#1f5fbf}}.no-dop{{color:#c0392b}}.mask-boxes{{color:#e67e22}}\
</style></head><body>\n<h1>{t}</h1>\n",
        t = escape(title)
    );
    for line in header_lines {
        let _ = writeln!(out, "<p>{}</p>", escape(line));
    }
    let _ = writeln!(
        out,
        "<h2>Results</h2>\n<table><tr><th>{}</th></tr>",
        TABLE_COLUMNS.join("</th><th>")
    );
    for g in groups {
        let mut cells: Vec<String> = table_cells(g, cell).iter().map(|c| escape(c)).collect();
        // The spread's <small> is markup, not text.
        cells[3] = cell(g.ate_rmse, 4);
        cells[0] = format!("<a href=\"#{0}\">{0}</a>", cells[0]);
        cells[1] = format!("<span class=\"{0}\">{0}</span>", cells[1]);
        let _ = writeln!(out, "<tr><td>{}</td></tr>", cells.join("</td><td>"));
    }
    out += "</table>\n";
    let dense: Vec<&GroupSummary> = groups.iter().filter(|g| has_map(g)).collect();
    if !dense.is_empty() {
        let _ = writeln!(
            out,
            "<h2>Dense maps (against the static scene)</h2>\n<table><tr><th>{}</th></tr>",
            MAP_COLUMNS.join("</th><th>")
        );
        for g in dense {
            let cells: Vec<String> = map_cells(g).iter().map(|c| escape(c)).collect();
            let _ = writeln!(out, "<tr><td>{}</td></tr>", cells.join("</td><td>"));
        }
        out += "</table>\n";
    }
    out += sessions;
    for section in sections {
        section_html(&mut out, section);
    }
    let errors: Vec<String> = groups
        .iter()
        .flat_map(|g| {
            g.errors
                .iter()
                .map(move |e| format!("{} / {}: {e}", g.sequence, g.mode.name()))
        })
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
