//! `dopslam stereo LEFT RIGHT --settings FILE.yaml`: the sparse stereo matching of the
//! tracking pass on one rectified pair, against OpenCV's semi-global matcher on the
//! same pair: how many keypoints found a depth, and how their disparities agree.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
use clap::builder::TypedValueParser;
use clap::Args;
use dopslam::dense::disparity::sgbm_disparity;
use dopslam::features::{OrbConfig, OrbExtractor};
use dopslam::frame::stereo::{extract_and_match, StereoPair};
use dopslam::io::atomic::write_atomic;
use dopslam::io::kitti::read_pair;
use dopslam::io::orbslam_settings::OrbSlamSettings;
use serde::Serialize;

#[derive(Args)]
pub struct StereoArgs {
    /// The left image of a rectified pair.
    pub left: PathBuf,
    /// The right image.
    pub right: PathBuf,
    /// ORB-SLAM2 stereo settings with fx and bf (e.g. configs/calibration/Stereo_KITTI00-02.yaml).
    #[arg(long)]
    pub settings: PathBuf,
    /// Keypoints per image (default: the settings' ORBextractor.nFeatures, else 2000).
    #[arg(long, value_parser = super::values::at_least_one)]
    pub features: Option<usize>,
    /// Also write the figures as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// SGBM matches the pair at 1/this of its size, as `[stereo] sgbm_downscale` does
    /// in the dense pass (1, 2 or 4).
    #[arg(
        long,
        default_value = "1",
        value_parser = clap::builder::PossibleValuesParser::new(["1", "2", "4"])
            .map(|s| s.parse::<u32>().unwrap_or(1))
    )]
    pub downscale: u32,
    /// A true depth image of the left camera (16-bit PNG, `--depth-scale` units a
    /// metre, as `dopslam synth` writes): SGBM's depth is measured against it.
    #[arg(long)]
    pub truth_depth: Option<PathBuf>,
    /// Units a metre in `--truth-depth` (TUM: 5000).
    #[arg(long, default_value_t = 5000.0)]
    pub depth_scale: f64,
    /// Only truth depths up to this many metres count (the dense pass's `max_depth`).
    #[arg(long, default_value_t = 25.0)]
    pub max_depth: f64,
}

/// SGBM's depth against a true depth image, over the pixels whose true depth is within
/// the range.
#[derive(Debug, Serialize)]
struct DepthFigures {
    /// Pixels with a true depth in range.
    truth_pixels: usize,
    /// Of them, the share SGBM gave a depth.
    valid_percent: f64,
    /// Over those: the median and 90th percentile of |SGBM - truth|, metres.
    median_error_m: f64,
    p90_error_m: f64,
    /// The share within 1 % of the true depth plus 5 cm.
    within_tolerance_percent: f64,
}

/// What `dopslam stereo` measures.
#[derive(Debug, Serialize)]
struct StereoFigures {
    keypoints: usize,
    matched: usize,
    matched_percent: f64,
    /// Matched keypoints where SGBM has a disparity too, and how far apart they are.
    compared: usize,
    median_difference_px: f64,
    /// Median of ORB's disparity less SGBM's (a bias of one matcher shows here).
    median_signed_difference_px: f64,
    within_1px_percent: f64,
    sgbm_valid_percent: f64,
    /// ORB on both images and the row matching.
    orb_and_matching_ms: f64,
    sgbm_ms: f64,
    /// At `--downscale`.
    sgbm_downscale: u32,
    /// With `--truth-depth`.
    depth: Option<DepthFigures>,
}

pub fn run_stereo(args: StereoArgs) -> Result<()> {
    let settings = OrbSlamSettings::read(&args.settings)?;
    let bf = settings.calibration.bf.with_context(|| {
        format!(
            "{}: no Camera.bf (baseline times fx): not stereo settings",
            args.settings.display()
        )
    })?;
    let fx = settings.calibration.camera.fx;
    let (left, right) = read_pair(&args.left, &args.right)?;
    let extractor = OrbExtractor::new(&OrbConfig {
        n_features: args.features.or(settings.orb.n_features).unwrap_or(2000),
        ..OrbConfig::default()
    });
    let start = Instant::now();
    let (lf, matches) = extract_and_match(
        StereoPair {
            left: &left,
            right: &right,
        },
        &extractor,
        bf,
        fx,
    );
    let orb_and_matching_ms = start.elapsed().as_secs_f64() * 1e3;
    let start = Instant::now();
    let sgbm_settings = dopslam::dense::disparity::SgbmSettings {
        downscale: args.downscale,
        ..dopslam::config::StereoConfig::default().sgbm()
    };
    let sgbm = sgbm_disparity(&left, &right, &sgbm_settings).map_err(anyhow::Error::msg)?;
    let sgbm_ms = start.elapsed().as_secs_f64() * 1e3;
    let width = left.width() as usize;
    let mut signed: Vec<f64> = lf
        .keypoints
        .iter()
        .zip(&matches.right_u)
        .filter(|(_, &u)| u >= 0.0)
        .filter_map(|(k, &u)| {
            let d = sgbm[k.y.round() as usize * width + k.x.round() as usize];
            (d > 0.0).then_some(((k.x - u) - d) as f64)
        })
        .collect();
    let mut differences: Vec<f64> = signed.iter().map(|d| d.abs()).collect();
    differences.sort_by(f64::total_cmp);
    signed.sort_by(f64::total_cmp);
    let matched = matches.matched();
    let figures = StereoFigures {
        keypoints: lf.len(),
        matched,
        matched_percent: 100.0 * matched as f64 / lf.len().max(1) as f64,
        compared: differences.len(),
        median_difference_px: if differences.is_empty() {
            f64::NAN
        } else {
            dopslam::eval::stats::median_of_sorted(&differences)
        },
        median_signed_difference_px: if signed.is_empty() {
            f64::NAN
        } else {
            dopslam::eval::stats::median_of_sorted(&signed)
        },
        within_1px_percent: 100.0 * differences.iter().filter(|&&d| d <= 1.0).count() as f64
            / differences.len().max(1) as f64,
        sgbm_valid_percent: 100.0 * sgbm.iter().filter(|&&d| d > 0.0).count() as f64
            / sgbm.len().max(1) as f64,
        orb_and_matching_ms,
        sgbm_ms,
        sgbm_downscale: args.downscale,
        depth: match &args.truth_depth {
            Some(path) => Some(depth_figures(&sgbm, bf, path, &args)?),
            None => None,
        },
    };
    print_figures(&figures);
    if let Some(path) = &args.json {
        write_atomic(path, serde_json::to_string_pretty(&figures)?.as_bytes())?;
    }
    Ok(())
}

/// SGBM's disparities `sgbm` as depth against the true depth image at `path`.
fn depth_figures(
    sgbm: &[f32],
    bf: f64,
    path: &std::path::Path,
    args: &StereoArgs,
) -> Result<DepthFigures> {
    let truth = dopslam::io::image_files::read_depth(path, args.depth_scale)?;
    anyhow::ensure!(
        truth.metres.len() == sgbm.len(),
        "{}: a {}x{} depth image for a pair of another size",
        path.display(),
        truth.width,
        truth.height
    );
    let in_range: Vec<(f64, f32)> = truth
        .metres
        .iter()
        .zip(sgbm)
        .map(|(&t, &d)| (t as f64, d))
        .filter(|&(t, _)| t > 0.0 && t <= args.max_depth)
        .collect();
    let mut errors: Vec<(f64, f64)> = in_range
        .iter()
        .filter(|&&(_, d)| d > 0.0)
        .map(|&(t, d)| ((bf / d as f64 - t).abs(), t))
        .collect();
    let within = errors
        .iter()
        .filter(|&&(e, t)| e <= 0.01 * t + 0.05)
        .count();
    errors.sort_by(|a, b| a.0.total_cmp(&b.0));
    let quantile = |q: f64| match errors.len() {
        0 => f64::NAN,
        n => errors[((n - 1) as f64 * q).round() as usize].0,
    };
    Ok(DepthFigures {
        truth_pixels: in_range.len(),
        valid_percent: 100.0 * errors.len() as f64 / in_range.len().max(1) as f64,
        median_error_m: quantile(0.5),
        p90_error_m: quantile(0.9),
        within_tolerance_percent: 100.0 * within as f64 / errors.len().max(1) as f64,
    })
}

/// What `dopslam stereo` prints.
fn print_figures(figures: &StereoFigures) {
    println!(
        "{} of {} left keypoints matched ({:.1} %); against SGBM ({:.1} % of pixels valid) on {} of them: median difference {:.3} px (signed {:+.3}), {:.1} % within 1 px",
        figures.matched,
        figures.keypoints,
        figures.matched_percent,
        figures.sgbm_valid_percent,
        figures.compared,
        figures.median_difference_px,
        figures.median_signed_difference_px,
        figures.within_1px_percent
    );
    println!(
        "time: ORB on both images and row matching {:.1} ms, SGBM {:.1} ms (at 1/{} size)",
        figures.orb_and_matching_ms, figures.sgbm_ms, figures.sgbm_downscale
    );
    if let Some(depth) = &figures.depth {
        println!(
            "SGBM depth against the truth: {:.1} % of {} pixels in range have one; |error| median {:.3} m, 90th percentile {:.3} m; {:.1} % within 1 % + 5 cm",
            depth.valid_percent,
            depth.truth_pixels,
            depth.median_error_m,
            depth.p90_error_m,
            depth.within_tolerance_percent
        );
    }
}
