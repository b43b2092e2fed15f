//! `dopslam stereo LEFT RIGHT --settings FILE.yaml`: the sparse stereo matching of the
//! tracking pass on one rectified pair, against OpenCV's semi-global matcher on the
//! same pair: how many keypoints found a depth, and how their disparities agree.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result};
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
    let sgbm = sgbm_disparity(
        &left,
        &right,
        &dopslam::config::StereoConfig::default().sgbm(),
    )
    .map_err(anyhow::Error::msg)?;
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
    };
    print_figures(&figures);
    if let Some(path) = &args.json {
        write_atomic(path, serde_json::to_string_pretty(&figures)?.as_bytes())?;
    }
    Ok(())
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
        "time: ORB on both images and row matching {:.1} ms, SGBM {:.1} ms",
        figures.orb_and_matching_ms, figures.sgbm_ms
    );
}
