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
    /// Keep finished runs made with other settings than the manifest's now (another
    /// frame count, config, settings file, detector or dopslam): they are marked stale
    /// in every table instead of being run again.
    #[arg(long)]
    keep_stale: bool,
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
    /// Run only shard K of N of the runs (a stable partition: the same manifest gives
    /// the same shards) into the shared output folder, and write no tables.
    #[arg(long, value_name = "K/N", conflicts_with_all = ["collect", "slurm"])]
    shard: Option<dopslam::batch::shard::Shard>,
    /// Run nothing: build results.*, runs.csv, the plots and report.html from the
    /// finished runs and say which runs are missing or failed (--strict: exit 1 then).
    #[arg(long, conflicts_with = "slurm")]
    collect: bool,
    /// Write OUT/slurm/array.sbatch (one array task per shard) and
    /// OUT/slurm/collect.sbatch (the collection, after the array); --submit submits them.
    #[arg(long)]
    slurm: bool,
    /// With --slurm: submit both scripts through sbatch and print the job ids.
    #[arg(long, requires = "slurm")]
    submit: bool,
    /// With --slurm: the partition.
    #[arg(long, requires = "slurm")]
    partition: Option<String>,
    /// With --slurm: each task's time limit (Slurm's format, e.g. 2:00:00).
    #[arg(long, requires = "slurm")]
    time: Option<String>,
    /// With --slurm: CPUs per task (default: the manifest's cores_per_run).
    #[arg(long, requires = "slurm")]
    cpus_per_task: Option<usize>,
    /// With --slurm: memory per task (Slurm's format, e.g. 4G; default: the manifest's memory_per_run_gib).
    #[arg(long, requires = "slurm")]
    mem: Option<String>,
    /// With --slurm: array tasks at a time (--array=1-N%K).
    #[arg(long, requires = "slurm")]
    max_parallel: Option<usize>,
    /// With --slurm: the number of array tasks (default: one per run, at most 1000).
    #[arg(long, requires = "slurm")]
    shards: Option<usize>,
}

pub fn run_batch(args: BatchArgs) -> Result<()> {
    if args.jobs == Some(0) {
        bail!("--jobs must be at least 1");
    }
    let program =
        std::env::current_exe().context("cannot find the dopslam program to start runs with")?;
    if args.slurm {
        return slurm(&args, &program);
    }
    let options = dopslam::batch::BatchOptions {
        program,
        out: args.out.clone(),
        jobs: args.jobs,
        retry_failed: args.retry_failed,
        keep_stale: args.keep_stale,
        reevaluate: args.reevaluate,
        progress: !args.quiet,
        shard: args.shard,
        collect: args.collect,
    };
    let summary = dopslam::batch::run_batch(&args.manifest, &options)?;
    if let Some(shard) = args.shard {
        return shard_done(&summary, shard);
    }
    if args.collect {
        return collected(&summary, args.strict);
    }
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
    if summary.unavailable > 0 {
        bail!(
            "{} sequence(s) could not be read or generated (see the notes above); their runs are recorded as failed",
            summary.unavailable
        );
    }
    let failed = summary.groups.iter().map(|g| g.failed).sum::<usize>();
    if args.strict && failed > 0 {
        bail!("{failed} runs failed (see results.md)");
    }
    Ok(())
}

/// `--slurm`: the scripts, submitted with `--submit`.
fn slurm(args: &BatchArgs, program: &std::path::Path) -> Result<()> {
    let plan = dopslam::batch::BatchPlan::new(&args.manifest, args.out.as_deref())?;
    let options = dopslam::batch::slurm::SlurmOptions {
        partition: args.partition.clone(),
        time: args.time.clone(),
        cpus_per_task: args.cpus_per_task,
        mem: args.mem.clone(),
        max_parallel: args.max_parallel,
        shards: args.shards,
    };
    let scripts = dopslam::batch::slurm::write_scripts(&plan, &args.manifest, program, &options)?;
    println!(
        "wrote {} ({} array tasks for {} runs) and {}",
        scripts.array.display(),
        scripts.shards,
        plan.runs.len(),
        scripts.collect.display()
    );
    if !args.submit {
        println!(
            "submit: jid=$(sbatch --parsable {}) && sbatch --dependency=afterany:$jid {}",
            scripts.array.display(),
            scripts.collect.display()
        );
        return Ok(());
    }
    if dopslam::batch::runs_to_do(&plan, program) == 0 {
        println!(
            "nothing to submit: all {} runs are finished in {} with this manifest's settings; `dopslam batch {} --out {} --collect` makes the tables",
            plan.runs.len(),
            plan.out.display(),
            args.manifest.display(),
            plan.out.display()
        );
        return Ok(());
    }
    let (array, collect) = dopslam::batch::slurm::submit(&scripts)?;
    println!("submitted: array job {array}, collection job {collect} (after the array)");
    println!(
        "results: {}/results.md once job {collect} ends (squeue -j {array},{collect})",
        plan.out.display()
    );
    Ok(())
}

/// What a shard did.
fn shard_done(
    summary: &dopslam::batch::BatchSummary,
    shard: dopslam::batch::shard::Shard,
) -> Result<()> {
    let e = &summary.executed;
    for note in &summary.notes {
        eprintln!("note: {note}");
    }
    println!(
        "shard {shard} of {}: {} finished before, {} done now, {} failed now, {} not run; tables: dopslam batch MANIFEST --collect",
        summary.out.display(),
        summary.runs_skipped,
        e.done,
        e.failed,
        e.interrupted
    );
    if dopslam::interrupt::requested() || e.interrupted > 0 {
        bail!(
            "interrupted: {} runs not done; run the same shard again to finish them",
            e.interrupted
        );
    }
    Ok(())
}

/// What `--collect` found.
fn collected(summary: &dopslam::batch::BatchSummary, strict: bool) -> Result<()> {
    let table = std::fs::read_to_string(summary.out.join("results.md")).unwrap_or_default();
    println!("{table}");
    for note in &summary.notes {
        eprintln!("note: {note}");
    }
    let finished = summary.runs_planned - summary.missing.len();
    println!(
        "{finished} of {} runs finished ({} failed), {} missing",
        summary.runs_planned,
        summary.failed.len(),
        summary.missing.len()
    );
    for run in &summary.missing {
        println!("missing: {run}");
    }
    for run in &summary.failed {
        println!("failed: {run}");
    }
    println!(
        "wrote {}/{{results.md,results.csv,results.json,runs.csv,report.html}}",
        summary.out.display()
    );
    if strict && !(summary.missing.is_empty() && summary.failed.is_empty()) {
        bail!(
            "{} runs missing, {} failed (--strict)",
            summary.missing.len(),
            summary.failed.len()
        );
    }
    Ok(())
}
