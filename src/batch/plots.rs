//! The batch's figures per sequence, as PNG (plotters): the trajectories of every mode
//! over the ground truth seen from above, the APE over time, and box plots of the APE
//! per mode (the paper's Figs. 5-8). Text needs a TrueType font: DejaVu Sans from the
//! system (Debian `fonts-dejavu-core`, which `tools/setup.sh` installs) or the file
//! named by `DOPSLAM_FONT`.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::dop::Mode;
use crate::eval::plot::view_axes;
use crate::eval::report::Evaluation;

const SIZE: (u32, u32) = (900, 640);

pub use crate::eval::plot::{ensure_font, PlotError};

/// The colour of a mode in every figure.
pub fn mode_colour(mode: Mode) -> RGBColor {
    match mode {
        Mode::Dop => RGBColor(31, 95, 191),
        Mode::Off => RGBColor(192, 57, 43),
        Mode::MaskBoxes => RGBColor(230, 126, 34),
    }
}

fn error_text<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> PlotError + '_ {
    move |e| PlotError::Draw {
        path: path.to_path_buf(),
        problem: e.to_string(),
    }
}

fn canvas(path: &Path) -> Result<DrawingArea<BitMapBackend<'_>, Shift>, PlotError> {
    ensure_font()?;
    let root = BitMapBackend::new(path, SIZE).into_drawing_area();
    root.fill(&WHITE).map_err(error_text(path))?;
    Ok(root)
}

/// The index ranges of `timestamps` between gaps (lost tracking): a gap is longer than
/// ten times the median interval and than 0.5 s. Lines are not drawn across gaps.
pub fn unbroken(timestamps: &[f64]) -> Vec<std::ops::Range<usize>> {
    if timestamps.len() < 2 {
        return std::iter::once(0..timestamps.len()).collect();
    }
    let mut intervals: Vec<f64> = timestamps.windows(2).map(|w| w[1] - w[0]).collect();
    intervals.sort_by(f64::total_cmp);
    let gap = (10.0 * intervals[intervals.len() / 2]).max(0.5);
    let mut ranges = Vec::new();
    let mut start = 0;
    for i in 1..timestamps.len() {
        if timestamps[i] - timestamps[i - 1] > gap {
            ranges.push(start..i);
            start = i;
        }
    }
    ranges.push(start..timestamps.len());
    ranges
}

/// A range padded by 5 % (and widened when empty).
fn padded(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        let c = if lo.is_finite() { lo } else { 0.0 };
        return (c - 0.5, c + 0.5);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// The ranges `x` and `y` widened to equal metres per pixel in the plotting area
/// (about 800 x 540 pixels), about their centres: `[x0, x1, y0, y1]`.
fn equal_aspect(x: (f64, f64), y: (f64, f64)) -> [f64; 4] {
    let per_pixel = ((x.1 - x.0) / 800.0).max((y.1 - y.0) / 540.0);
    let (cx, cy) = (0.5 * (x.0 + x.1), 0.5 * (y.0 + y.1));
    [
        cx - 400.0 * per_pixel,
        cx + 400.0 * per_pixel,
        cy - 270.0 * per_pixel,
        cy + 270.0 * per_pixel,
    ]
}

/// The trajectories of each mode's median run (aligned) over the ground truth, seen
/// along the axis of least motion, with equal metres per pixel on both axes.
pub fn trajectories(
    path: &Path,
    title: &str,
    runs: &[(Mode, &Evaluation)],
) -> Result<(), PlotError> {
    // The ground truth as far as the most complete run matched it.
    let Some(fullest) = runs
        .iter()
        .map(|(_, r)| &r.series.reference)
        .max_by_key(|r| r.len())
    else {
        return Ok(());
    };
    let reference = fullest.positions();
    let (a, b) = view_axes(&reference);
    let all = runs
        .iter()
        .flat_map(|(_, r)| r.series.aligned_estimate.positions())
        .chain(reference.iter().copied());
    let [x0, x1, y0, y1] =
        equal_aspect(padded(all.clone().map(|p| p[a])), padded(all.map(|p| p[b])));
    let root = canvas(path)?;
    let err = error_text(path);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(&err)?;
    chart
        .configure_mesh()
        .x_desc(format!("{} (m)", ["x", "y", "z"][a]))
        .y_desc(format!("{} (m)", ["x", "y", "z"][b]))
        .draw()
        .map_err(&err)?;
    let grey = RGBColor(90, 90, 90);
    let pieces = |timestamps: &[f64], points: &[nalgebra::Vector3<f64>], style: ShapeStyle| {
        unbroken(timestamps)
            .into_iter()
            .map(|r| {
                PathElement::new(
                    points[r].iter().map(|p| (p[a], p[b])).collect::<Vec<_>>(),
                    style,
                )
            })
            .collect::<Vec<_>>()
    };
    chart
        .draw_series(pieces(
            &fullest.timestamps,
            &reference,
            grey.stroke_width(2),
        ))
        .map_err(&err)?
        .label("ground truth")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], grey.stroke_width(2)));
    for (mode, report) in runs {
        let colour = mode_colour(*mode);
        let label = format!(
            "{} (ATE {:.4} m)",
            mode.name(),
            report.report.ape.statistics.rmse
        );
        let estimate = &report.series.aligned_estimate;
        chart
            .draw_series(pieces(
                &estimate.timestamps,
                &estimate.positions(),
                colour.stroke_width(1),
            ))
            .map_err(&err)?
            .label(label)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    legend(&mut chart).map_err(&err)?;
    root.present().map_err(&err)
}

fn legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()
}

/// The APE of each mode's median run over time (seconds from the first pose).
pub fn ape_over_time(
    path: &Path,
    title: &str,
    runs: &[(Mode, &Evaluation)],
) -> Result<(), PlotError> {
    let Some(t0) = runs
        .iter()
        .filter_map(|(_, r)| r.series.ape.timestamps.first().copied())
        .reduce(f64::min)
    else {
        return Ok(());
    };
    let (x0, x1) = padded(
        runs.iter()
            .flat_map(|(_, r)| r.series.ape.timestamps.iter().map(|t| t - t0)),
    );
    let y1 = runs
        .iter()
        .flat_map(|(_, r)| r.series.ape.errors.iter().copied())
        .fold(0.0f64, f64::max)
        .max(1e-6)
        * 1.05;
    let root = canvas(path)?;
    let err = error_text(path);
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x0.max(0.0)..x1, 0.0..y1)
        .map_err(&err)?;
    chart
        .configure_mesh()
        .x_desc("time (s)")
        .y_desc("APE (m)")
        .draw()
        .map_err(&err)?;
    for (mode, report) in runs {
        let colour = mode_colour(*mode);
        let (times, errors) = (&report.series.ape.timestamps, &report.series.ape.errors);
        let pieces = unbroken(times).into_iter().map(|r| {
            let points: Vec<(f64, f64)> = r.map(|i| (times[i] - t0, errors[i])).collect();
            PathElement::new(points, colour.stroke_width(1))
        });
        chart
            .draw_series(pieces)
            .map_err(&err)?
            .label(format!(
                "{} (RMSE {:.4} m)",
                mode.name(),
                report.report.ape.statistics.rmse
            ))
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    legend(&mut chart).map_err(&err)?;
    root.present().map_err(&err)
}

/// Tukey's box of a sample: quartiles (linear interpolation, as numpy), whiskers at the
/// farthest samples within 1.5 IQR of the box, and the samples beyond them.
#[derive(Debug, Clone, PartialEq)]
pub struct BoxStats {
    /// First quartile.
    pub q1: f64,
    /// Median.
    pub median: f64,
    /// Third quartile.
    pub q3: f64,
    /// The lower whisker: the lowest value within 1.5 IQR of the box.
    pub low: f64,
    /// The upper whisker.
    pub high: f64,
    /// Values beyond the whiskers.
    pub outliers: Vec<f64>,
}

impl BoxStats {
    /// The box of `values` (`None` when empty).
    pub fn of(values: &[f64]) -> Option<Self> {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let quantile = |q: f64| {
            let pos = q * (v.len() - 1) as f64;
            let (i, frac) = (pos.floor() as usize, pos.fract());
            v[i] + frac * (v[(i + 1).min(v.len() - 1)] - v[i])
        };
        let (q1, median, q3) = (quantile(0.25), quantile(0.5), quantile(0.75));
        let reach = 1.5 * (q3 - q1);
        let inside = |x: &&f64| **x >= q1 - reach && **x <= q3 + reach;
        let low = v.iter().find(inside).copied().unwrap_or(q1);
        let high = v.iter().rev().find(inside).copied().unwrap_or(q3);
        let outliers = v
            .iter()
            .copied()
            .filter(|x| *x < low || *x > high)
            .collect();
        Some(Self {
            q1,
            median,
            q3,
            low,
            high,
            outliers,
        })
    }
}

/// Box plots of the APE per mode, every pose of every repetition pooled ([`BoxStats`],
/// as matplotlib draws them).
pub fn ape_boxes(path: &Path, title: &str, modes: &[(Mode, Vec<f64>)]) -> Result<(), PlotError> {
    let boxes: Vec<(Mode, BoxStats)> = modes
        .iter()
        .filter_map(|(m, v)| BoxStats::of(v).map(|b| (*m, b)))
        .collect();
    if boxes.is_empty() {
        return Ok(());
    }
    let y1 = boxes
        .iter()
        .flat_map(|(_, b)| b.outliers.iter().copied().chain([b.high]))
        .fold(0.0f64, f64::max)
        .max(1e-6)
        * 1.05;
    let root = canvas(path)?;
    let err = error_text(path);
    let names: Vec<&str> = boxes.iter().map(|(m, _)| m.name()).collect();
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..boxes.len() as f64, 0.0..y1)
        .map_err(&err)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(boxes.len() * 2 + 1)
        .x_label_formatter(&|x| {
            let k = x - 0.5;
            if (k - k.round()).abs() < 1e-6 && k >= 0.0 {
                names
                    .get(k.round() as usize)
                    .copied()
                    .unwrap_or_default()
                    .to_string()
            } else {
                String::new()
            }
        })
        .y_desc("APE (m)")
        .draw()
        .map_err(&err)?;
    for (i, (mode, b)) in boxes.iter().enumerate() {
        let colour = mode_colour(*mode);
        let x = i as f64 + 0.5;
        let line = |points: Vec<(f64, f64)>| PathElement::new(points, colour.stroke_width(2));
        chart
            .draw_series([Rectangle::new(
                [(x - 0.2, b.q1), (x + 0.2, b.q3)],
                colour.stroke_width(2),
            )
            .into_dyn()])
            .map_err(&err)?;
        chart
            .draw_series([
                line(vec![(x - 0.2, b.median), (x + 0.2, b.median)]),
                line(vec![(x, b.q3), (x, b.high)]),
                line(vec![(x, b.q1), (x, b.low)]),
                line(vec![(x - 0.1, b.high), (x + 0.1, b.high)]),
                line(vec![(x - 0.1, b.low), (x + 0.1, b.low)]),
            ])
            .map_err(&err)?;
        chart
            .draw_series(
                b.outliers
                    .iter()
                    .map(|&y| Circle::new((x, y), 2, colour.stroke_width(1))),
            )
            .map_err(&err)?;
    }
    root.present().map_err(&err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_break_at_gaps_in_time() {
        let mut t: Vec<f64> = (0..10).map(|i| f64::from(i) / 30.0).collect();
        t.extend((0..5).map(|i| 2.0 + f64::from(i) / 30.0));
        assert_eq!(unbroken(&t), [0..10, 10..15]);
        assert_eq!(unbroken(&t[..10]).len(), 1);
        assert_eq!(unbroken(&[]).len(), 1);
    }

    #[test]
    fn box_statistics_follow_tukey_and_numpy() {
        let mut values: Vec<f64> = (1..=9).map(f64::from).collect();
        values.push(100.0);
        let b = BoxStats::of(&values).unwrap();
        // numpy.percentile([1..9, 100], [25, 50, 75]) = 3.25, 5.5, 7.75
        assert!(
            (b.q1 - 3.25).abs() < 1e-12
                && (b.median - 5.5).abs() < 1e-12
                && (b.q3 - 7.75).abs() < 1e-12
        );
        assert_eq!((b.low, b.high), (1.0, 9.0));
        assert_eq!(b.outliers, [100.0]);
        assert!(BoxStats::of(&[]).is_none());
    }
}
