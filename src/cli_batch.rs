//! `dopslam batch`: the command line of [`dopslam::batch`].

use std::path::PathBuf;

use anyhow::{bail, Context, Result};
use clap::Args;

#[derive(Args)]
pub struct BatchArgs {
    /// The manifest (TOML): [batch] settings and [[sequence]] entries (configs/batch/ has examples).
    manifest: PathBuf,
    /// Output folder (default: the manifest's `out`, else outputs/batch/<manifest name>).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Runs at a time (default: the manifest's `jobs`, else cores / cores_per_run, bounded by memory).
    #[arg(long)]
    jobs: Option<usize>,
    /// Run again the runs that failed in an earlier invocation (finished ones are skipped).
    #[arg(long)]
    retry_failed: bool,
    /// Evaluate the finished runs again from their files (ATE, RPE, map figures), e.g.
    /// after changing [eval] settings; no run is repeated.
    #[arg(long)]
    reevaluate: bool,
    /// Exit with status 1 when a run failed (the batch still runs them all).
    #[arg(long)]
    strict: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

pub fn run_batch(args: BatchArgs) -> Result<()> {
    if args.jobs == Some(0) {
        bail!("--jobs must be at least 1");
    }
    let program =
        std::env::current_exe().context("cannot find the dopslam program to start runs with")?;
    let options = dopslam::batch::BatchOptions {
        program,
        out: args.out.clone(),
        jobs: args.jobs,
        retry_failed: args.retry_failed,
        reevaluate: args.reevaluate,
        progress: !args.quiet,
    };
    let summary =
        dopslam::batch::run_batch(&args.manifest, &options).map_err(anyhow::Error::msg)?;
    let e = &summary.executed;
    let table = std::fs::read_to_string(summary.out.join("results.md")).unwrap_or_default();
    println!("{table}");
    for note in &summary.notes {
        eprintln!("note: {note}");
    }
    println!(
        "{} runs: {} finished before, {} done now, {} failed now, {} not run ({} at a time)",
        summary.runs_planned, summary.runs_skipped, e.done, e.failed, e.interrupted, summary.jobs
    );
    println!(
        "wrote {}/{{results.md,results.csv,results.json,runs.csv,report.html}}",
        summary.out.display()
    );
    if dopslam::interrupt::requested() || e.interrupted > 0 {
        bail!(
            "interrupted: {} runs not done; run the same command again to finish them",
            e.interrupted
        );
    }
    let failed = summary.groups.iter().map(|g| g.failed).sum::<usize>();
    if args.strict && failed > 0 {
        bail!("{failed} runs failed (see results.md)");
    }
    Ok(())
}
