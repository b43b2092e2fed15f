//! `dopslam run --compare-no-dop`: the DOP run's dense map against the baseline's.

use std::path::Path;

use anyhow::Result;
use dopslam::config::Config;
use dopslam::dense::compare_maps::{compare_maps, CompareInputs, Comparison};
use dopslam::dense::map_figures::CompareSettings;
use dopslam::dense::FrameChoice;
use dopslam::dop::Mode;
use dopslam::io::run_dir::{names, RunDir};
use dopslam::io::trajectory::TrajectoryFormat;
use dopslam::io::Trajectory;
use dopslam::records::run_alignment;
use dopslam::run::{dense_pass, DenseSetup};

use super::compare_maps::print_comparison;

/// `run --compare-no-dop`: the dense maps of the run (`dop_mesh`, `dop_cloud`), the
/// run's keyframes fused with its own poses but no masks (`no_masks_cloud`: what the
/// masks keep out, apart from tracking), and the baseline run's cloud (`no_dop_cloud`:
/// tracked and fused without DOP, as ORB-SLAM2 users get it; the baseline for SA),
/// each that exists. In the ground truth's frame when the runs were evaluated,
/// against the sequence's `static_scene.ply` (else the baseline map) and its
/// `movers.ply` when it has them. Pictures: side by side, ghosts in red.
pub fn compare_with_baseline(
    run: &Path,
    baseline: &Path,
    sequence: &dyn dopslam::io::sequence::Sequence,
    sequence_dir: &Path,
    config: &Config,
) -> Result<Comparison> {
    let (mesh, cloud) = (names::DENSE_MESH_PLY, names::DENSE_POINTS);
    let no_masks = run.join(names::NO_MASKS);
    let mut points_only = config.clone();
    points_only.dense.fusion = dopslam::dense::Fusion::Points;
    points_only.dense.frames.which = FrameChoice::Keyframes;
    points_only.dense.outputs.pictures = false;
    let setup = DenseSetup::resolve(sequence, &points_only)?;
    dense_pass(&dopslam::run::DensePass {
        sequence,
        setup: &setup,
        run_dir: run,
        out_dir: &no_masks,
        masking: Mode::Off,
        sequence_dir: None,
        progress: true,
    })?;
    let baseline_map = if baseline.join(cloud).exists() {
        ("no_dop_cloud", baseline.join(cloud))
    } else {
        ("no_dop_mesh", baseline.join(mesh))
    };
    let run_aligned = run_alignment(run);
    let mut maps = Vec::new();
    let mut alignments = Vec::new();
    for (name, path) in [
        ("dop_mesh", run.join(mesh)),
        ("dop_cloud", run.join(cloud)),
        ("no_masks_cloud", no_masks.join(cloud)),
    ] {
        if path.exists() {
            maps.push((name.to_string(), path));
            alignments.push(run_aligned);
        }
    }
    maps.push((baseline_map.0.to_string(), baseline_map.1));
    alignments.push(run_alignment(baseline));
    let static_scene = sequence_dir.join("static_scene.ply");
    let movers = sequence_dir.join("movers.ply");
    let mut cameras =
        Trajectory::read(&RunDir::new(run).trajectory(), TrajectoryFormat::Tum)?.poses;
    if let Some(align) = &alignments[0] {
        cameras.iter_mut().for_each(|pose| *pose = align * *pose);
    }
    let reference = if static_scene.exists() {
        static_scene
    } else {
        maps[maps.len() - 1].1.clone()
    };
    let comparison = compare_maps(&CompareInputs {
        maps: &maps,
        alignments: &alignments,
        reference: &reference,
        movers: movers.exists().then_some(movers.as_path()),
        cameras: Some(&cameras),
        settings: CompareSettings::default(),
        out: &run.join(names::COMPARE_NO_DOP),
    })?;
    print_comparison(&comparison, false)?;
    Ok(comparison)
}

/// The few lines that say what DOP did in a `--compare-no-dop` run: ATE with and
/// without it, the movers left in each map, where the pictures are.
pub fn print_summary(
    dop: &dopslam::run::RunReport,
    no_dop: &dopslam::run::RunReport,
    comparison: &Comparison,
) {
    let ate = |r: &dopslam::run::RunReport| {
        r.ate
            .as_ref()
            .map_or("- (no ground truth)".to_string(), |a| {
                format!("{:.4} m", a.ape.statistics.rmse)
            })
    };
    let movers: Vec<String> = comparison
        .names
        .iter()
        .zip(&comparison.maps)
        .map(|(name, m)| {
            let count = m.mover_points.unwrap_or(m.ghost_points);
            format!("{name} {count} of {}", m.points)
        })
        .collect();
    let what = if comparison.movers.is_some() {
        "mover points"
    } else {
        "ghost points"
    };
    println!("summary:");
    println!(
        "  ATE RMSE with DOP {}, without DOP (ORB-SLAM2 behaviour) {}",
        ate(dop),
        ate(no_dop)
    );
    println!("  {what} in each map: {}", movers.join(", "));
    if let Some(picture) = comparison
        .outputs
        .iter()
        .find(|p| p.ends_with("compare_perspective.png"))
    {
        println!(
            "  picture (left to right as listed, ghosts in red): {}",
            picture.display()
        );
    }
    if let Some(table) = comparison.outputs.first().and_then(|p| p.parent()) {
        println!("  table: {}", table.join("compare.md").display());
    }
}
