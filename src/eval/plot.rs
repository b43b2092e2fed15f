//! SVG plots of an evaluation: the trajectory seen from above against the reference,
//! and the errors over time. Plain SVG, readable in any browser, no plotting library.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Vector3;

use super::report::{EvalReport, EvalSeries, MetricResult, MetricSeries};
use crate::io::atomic::write_atomic;
use crate::io::IoError;

const WIDTH: f64 = 720.0;
const HEIGHT: f64 = 540.0;
const MARGIN: f64 = 60.0;

/// A linear map from data coordinates to the plot's pixel box.
struct Frame {
    x_min: f64,
    x_max: f64,
    y_min: f64,
    y_max: f64,
}

impl Frame {
    fn new(xs: impl Iterator<Item = f64> + Clone, ys: impl Iterator<Item = f64> + Clone) -> Self {
        let range = |v: &mut dyn Iterator<Item = f64>| {
            v.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), x| {
                (lo.min(x), hi.max(x))
            })
        };
        let (mut x_min, mut x_max) = range(&mut xs.clone());
        let (mut y_min, mut y_max) = range(&mut ys.clone());
        if x_max.is_nan() || x_max <= x_min {
            x_min -= 0.5;
            x_max += 0.5;
        }
        if y_max.is_nan() || y_max <= y_min {
            y_min -= 0.5;
            y_max += 0.5;
        }
        let (px, py) = (0.05 * (x_max - x_min), 0.05 * (y_max - y_min));
        Self {
            x_min: x_min - px,
            x_max: x_max + px,
            y_min: y_min - py,
            y_max: y_max + py,
        }
    }

    /// Makes both axes use the same metres per pixel (for a map view).
    fn equal_aspect(mut self) -> Self {
        let sx = (self.x_max - self.x_min) / (WIDTH - 2.0 * MARGIN);
        let sy = (self.y_max - self.y_min) / (HEIGHT - 2.0 * MARGIN);
        let s = sx.max(sy);
        let (cx, cy) = (
            0.5 * (self.x_min + self.x_max),
            0.5 * (self.y_min + self.y_max),
        );
        let (hw, hh) = (
            0.5 * s * (WIDTH - 2.0 * MARGIN),
            0.5 * s * (HEIGHT - 2.0 * MARGIN),
        );
        self.x_min = cx - hw;
        self.x_max = cx + hw;
        self.y_min = cy - hh;
        self.y_max = cy + hh;
        self
    }

    fn px(&self, x: f64) -> f64 {
        MARGIN + (x - self.x_min) / (self.x_max - self.x_min) * (WIDTH - 2.0 * MARGIN)
    }

    fn py(&self, y: f64) -> f64 {
        HEIGHT - MARGIN - (y - self.y_min) / (self.y_max - self.y_min) * (HEIGHT - 2.0 * MARGIN)
    }

    fn polyline(&self, points: impl Iterator<Item = (f64, f64)>, style: &str) -> String {
        let mut d = String::new();
        for (x, y) in points {
            let _ = write!(d, "{:.1},{:.1} ", self.px(x), self.py(y));
        }
        format!(
            "<polyline fill=\"none\" {style} points=\"{}\"/>\n",
            d.trim_end()
        )
    }

    fn axes(&self, x_label: &str, y_label: &str, title: &str) -> String {
        let mut out = String::new();
        let _ = writeln!(out, "<rect x=\"{MARGIN}\" y=\"{MARGIN}\" width=\"{}\" height=\"{}\" fill=\"none\" stroke=\"#444\"/>", WIDTH - 2.0 * MARGIN, HEIGHT - 2.0 * MARGIN);
        for i in 0..=5 {
            let f = i as f64 / 5.0;
            let x = self.x_min + f * (self.x_max - self.x_min);
            let y = self.y_min + f * (self.y_max - self.y_min);
            let _ = writeln!(
                out,
                "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"11\" text-anchor=\"middle\">{}</text>",
                self.px(x),
                HEIGHT - MARGIN + 16.0,
                tick(x)
            );
            let _ = writeln!(
                out,
                "<text x=\"{:.1}\" y=\"{:.1}\" font-size=\"11\" text-anchor=\"end\">{}</text>",
                MARGIN - 6.0,
                self.py(y) + 4.0,
                tick(y)
            );
            let _ = writeln!(
                out,
                "<line x1=\"{MARGIN}\" x2=\"{}\" y1=\"{:.1}\" y2=\"{:.1}\" stroke=\"#eee\"/>",
                WIDTH - MARGIN,
                self.py(y),
                self.py(y)
            );
        }
        let _ = writeln!(
            out,
            "<text x=\"{}\" y=\"{}\" font-size=\"13\" text-anchor=\"middle\">{x_label}</text>",
            WIDTH / 2.0,
            HEIGHT - 18.0
        );
        let _ = writeln!(out, "<text x=\"16\" y=\"{}\" font-size=\"13\" text-anchor=\"middle\" transform=\"rotate(-90 16 {})\">{y_label}</text>", HEIGHT / 2.0, HEIGHT / 2.0);
        let _ = writeln!(
            out,
            "<text x=\"{}\" y=\"30\" font-size=\"15\" text-anchor=\"middle\">{title}</text>",
            WIDTH / 2.0
        );
        out
    }
}

fn tick(v: f64) -> String {
    let s = format!("{v:.3}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

fn svg(body: &str) -> String {
    format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{WIDTH}\" height=\"{HEIGHT}\" viewBox=\"0 0 {WIDTH} {HEIGHT}\" font-family=\"sans-serif\">\n<rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n{body}</svg>\n"
    )
}

fn legend(entries: &[(&str, &str)]) -> String {
    let mut out = String::new();
    for (i, (label, colour)) in entries.iter().enumerate() {
        let y = MARGIN + 16.0 + 18.0 * i as f64;
        let _ = writeln!(out, "<line x1=\"{}\" x2=\"{}\" y1=\"{y}\" y2=\"{y}\" stroke=\"{colour}\" stroke-width=\"2\"/>", WIDTH - MARGIN - 150.0, WIDTH - MARGIN - 125.0);
        let _ = writeln!(
            out,
            "<text x=\"{}\" y=\"{}\" font-size=\"12\">{label}</text>",
            WIDTH - MARGIN - 118.0,
            y + 4.0
        );
    }
    out
}

/// The two world axes along which the reference moves most (the "top view").
pub fn view_axes(points: &[Vector3<f64>]) -> (usize, usize) {
    let mean = points.iter().sum::<Vector3<f64>>() / points.len().max(1) as f64;
    let spread = points
        .iter()
        .map(|p| (p - mean).abs())
        .fold(Vector3::zeros(), |a, b| a + b);
    let mut axes = [0, 1, 2];
    axes.sort_by(|&a, &b| spread[b].total_cmp(&spread[a]));
    (axes[0].min(axes[1]), axes[0].max(axes[1]))
}

/// The trajectory plot: the reference (grey) and the aligned estimate (blue), seen along
/// the axis of least motion.
pub fn trajectory_svg(report: &EvalReport, series: &EvalSeries) -> String {
    let reference = series.reference.positions();
    let estimate = series.aligned_estimate.positions();
    let (a, b) = view_axes(&reference);
    let all = reference.iter().chain(&estimate);
    let frame = Frame::new(all.clone().map(|p| p[a]), all.map(|p| p[b])).equal_aspect();
    let names = ["x", "y", "z"];
    let mut body = frame.axes(
        &format!("{} (m)", names[a]),
        &format!("{} (m)", names[b]),
        &format!(
            "trajectory, APE RMSE {:.4} {}",
            report.ape.statistics.rmse, report.ape.unit
        ),
    );
    body += &frame.polyline(
        reference.iter().map(|p| (p[a], p[b])),
        "stroke=\"#888\" stroke-width=\"1.5\" stroke-dasharray=\"5,3\"",
    );
    body += &frame.polyline(
        estimate.iter().map(|p| (p[a], p[b])),
        "stroke=\"#1f5fbf\" stroke-width=\"1.5\"",
    );
    body += &legend(&[("reference", "#888"), ("estimate (aligned)", "#1f5fbf")]);
    svg(&body)
}

/// Errors of one metric over time, with its RMSE as a horizontal line.
pub fn errors_svg(metric: &MetricResult, series: &MetricSeries) -> String {
    let t0 = series.timestamps.first().copied().unwrap_or(0.0);
    let points: Vec<(f64, f64)> = series
        .timestamps
        .iter()
        .map(|t| t - t0)
        .zip(series.errors.iter().copied())
        .collect();
    let frame = Frame::new(
        points.iter().map(|p| p.0),
        points.iter().map(|p| p.1).chain([0.0]),
    );
    let mut title = format!("{} w.r.t. {}", metric.metric, metric.relation.label());
    if let Some(spec) = metric.delta {
        let _ = write!(title, ", delta {} {}", spec.delta, spec.unit.symbol());
    }
    let mut body = frame.axes("time (s)", &format!("error ({})", metric.unit), &title);
    body += &frame.polyline(
        points.iter().copied(),
        "stroke=\"#c0392b\" stroke-width=\"1.2\"",
    );
    let rmse = metric.statistics.rmse;
    body += &frame.polyline(
        [(frame.x_min, rmse), (frame.x_max, rmse)].into_iter(),
        "stroke=\"#333\" stroke-dasharray=\"4,4\"",
    );
    body += &legend(&[
        ("error", "#c0392b"),
        (&format!("rmse {}", tick(rmse)), "#333"),
    ]);
    svg(&body)
}

/// Writes `trajectory.svg`, `ape.svg` and `rpe_<n>.svg` into `dir`; returns the paths.
pub fn write_plots(
    report: &EvalReport,
    series: &EvalSeries,
    dir: &Path,
) -> Result<Vec<std::path::PathBuf>, IoError> {
    let mut written = Vec::new();
    let mut put = |name: String, text: String| -> Result<(), IoError> {
        let path = dir.join(name);
        write_atomic(&path, text.as_bytes())?;
        written.push(path);
        Ok(())
    };
    put("trajectory.svg".into(), trajectory_svg(report, series))?;
    put("ape.svg".into(), errors_svg(&report.ape, &series.ape))?;
    for (i, (metric, errors)) in report.rpe.iter().zip(&series.rpe).enumerate() {
        put(format!("rpe_{i}.svg"), errors_svg(metric, errors))?;
    }
    Ok(written)
}

/// Where a font is looked for, after `DOPSLAM_FONT`.
const FONT_FILES: [&str; 4] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
];

/// Registers a TrueType font as plotters' "sans-serif" once (for the PNG figures and
/// the labels of the map pictures); the error says what to install.
pub fn ensure_font() -> Result<(), PlotError> {
    use std::path::PathBuf;
    static FONT: std::sync::OnceLock<Result<(), PlotError>> = std::sync::OnceLock::new();
    FONT.get_or_init(|| {
        let candidates: Vec<PathBuf> = std::env::var_os("DOPSLAM_FONT")
            .map(PathBuf::from)
            .into_iter()
            .chain(FONT_FILES.iter().map(PathBuf::from))
            .collect();
        let path = candidates
            .iter()
            .find(|p| p.is_file())
            .ok_or(PlotError::NoFont)?;
        let bytes = std::fs::read(path).map_err(|e| PlotError::Font {
            path: path.clone(),
            problem: e.to_string(),
        })?;
        // plotters keeps the font for the program's life.
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", plotters::style::FontStyle::Normal, bytes)
            .map_err(|_| PlotError::Font {
                path: path.clone(),
                problem: "not a usable TrueType font".into(),
            })
    })
    .clone()
}

/// Why a picture could not be drawn.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PlotError {
    #[error("no TrueType font for the plots: install Debian's fonts-dejavu-core or set DOPSLAM_FONT=/path/to/font.ttf")]
    /// No TrueType font was found.
    NoFont,
    /// The font file at `path` cannot be read or used.
    #[error("font {}: {problem}", path.display())]
    Font {
        /// The font file.
        path: std::path::PathBuf,
        /// What is wrong with it.
        problem: String,
    },
    /// Drawing or writing the picture at `path` failed (plotters' message).
    #[error("plot {}: {problem}", path.display())]
    Draw {
        /// The picture's file.
        path: std::path::PathBuf,
        /// plotters' message.
        problem: String,
    },
}
