//! `dopslam demo`: the bundled example trajectories, generated and evaluated.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use dopslam::eval::ate::PoseRelation;
use dopslam::io::trajectory::TrajectoryFormat;

use super::eval::{run_eval, EvalArgs};

#[derive(Args)]
pub struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "outputs/demo")]
    out: PathBuf,
    /// Seed of the generated drift and noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
}

pub fn run_demo(args: DemoArgs) -> Result<()> {
    let (ground_truth, estimate) = dopslam::demo::demo_trajectories(args.seed, 30.0, 0.004);
    let gt_path = args.out.join("groundtruth.txt");
    let est_path = args.out.join("estimate.txt");
    ground_truth.write(&gt_path, TrajectoryFormat::Tum)?;
    estimate.write(&est_path, TrajectoryFormat::Tum)?;
    println!(
        "generated {} ({} poses) and {} ({} poses)",
        gt_path.display(),
        ground_truth.len(),
        est_path.display(),
        estimate.len()
    );
    run_eval(EvalArgs {
        reference: gt_path,
        estimate: est_path,
        format: TrajectoryFormat::Tum,
        times: None,
        config: None,
        association: None,
        max_diff: None,
        offset: 0.0,
        align: None,
        n_align: None,
        pose_relation: PoseRelation::TransPart,
        rpe: vec!["1f".into(), "1s".into()],
        rpe_relation: PoseRelation::TransPart,
        min_coverage: None,
        json: false,
        plot: Some(args.out.join("plots")),
        save_report: Some(args.out.join("report.json")),
    })
}
