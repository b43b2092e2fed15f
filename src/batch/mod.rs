//! Batch runs (`dopslam batch MANIFEST.toml`): many sequences, several modes, repeated
//! runs, scheduled within a core and memory budget, resumable, then the tables
//! (`results.csv/json/md`, `runs.csv`), figures (`plots/<sequence>/*.png`) and
//! `report.html` a lab report needs.
//!
//! Layout of the output folder:
//!
//! ```text
//! OUT/manifest.toml                       the manifest the batch ran with
//! OUT/sequences/<name>/                   generated synthetic sequences
//! OUT/runs/<sequence>/<mode>/r<k>/        dopslam run's files, log.txt, config.toml,
//!                                         eval.json, eval_rotation.json, run.json
//! OUT/plots/<sequence>/{trajectories,ape_time,ape_box}.png
//! OUT/results.csv results.json results.md runs.csv report.html
//! ```
//!
//! This layer sits above the pipeline: it starts `dopslam run` processes and reads
//! what they wrote; nothing below imports it.

pub mod execute;
pub mod figures;
pub mod html;
pub mod machine;
pub mod manifest;
pub mod plots;
pub mod record;
pub mod results;

use std::path::{Path, PathBuf};

use execute::{Executed, Executor, RunJob};
use machine::{budget_jobs, machine_description};
use manifest::{absolute, Manifest, PlannedSequence, RunMode, SequenceSource};
use record::{RunRecord, RunStatus};
use results::GroupSummary;

use crate::eval::report::RpeSpec;
use crate::eval::rpe::DeltaUnit;
use crate::io::atomic::write_atomic;

/// How `dopslam batch` runs.
#[derive(Debug, Clone)]
pub struct BatchOptions {
    /// The `dopslam` program each run is started with.
    pub program: PathBuf,
    /// Output folder (else the manifest's `out`, else `outputs/batch/<manifest name>`).
    pub out: Option<PathBuf>,
    /// Runs at a time (else the manifest's, else the budgets').
    pub jobs: Option<usize>,
    /// Run again the runs that failed before (finished runs are otherwise skipped).
    pub retry_failed: bool,
    /// Evaluate the finished runs again from their files (no run is repeated).
    pub reevaluate: bool,
    pub progress: bool,
}

/// What a batch did.
#[derive(Debug)]
pub struct BatchSummary {
    pub out: PathBuf,
    pub runs_planned: usize,
    /// Runs found finished from an earlier invocation.
    pub runs_skipped: usize,
    pub executed: Executed,
    pub jobs: usize,
    pub groups: Vec<GroupSummary>,
    /// Figures or sequences that could not be made, and why.
    pub notes: Vec<String>,
}

/// Runs the batch described by the manifest at `path`.
pub fn run_batch(path: &Path, options: &BatchOptions) -> Result<BatchSummary, String> {
    let manifest = Manifest::load(path)?;
    let planned = manifest.plan()?;
    let out = match (&options.out, &manifest.batch.out) {
        (Some(out), _) => out.clone(),
        (None, Some(out)) => manifest.resolve(out),
        (None, None) => Path::new("outputs/batch").join(
            path.file_stem()
                .map_or("batch".into(), |s| s.to_string_lossy().into_owned()),
        ),
    };
    let out = absolute(&out);
    std::fs::create_dir_all(&out).map_err(|e| format!("cannot create {}: {e}", out.display()))?;
    let text = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    write_atomic(&out.join("manifest.toml"), &text).map_err(|e| e.to_string())?;

    let mut notes = Vec::new();
    let mut sequence_dirs = Vec::new();
    let mut unavailable: Vec<Option<String>> = Vec::new();
    for sequence in &planned {
        let (dir, problem) = prepare_sequence(sequence, &out, options.progress);
        sequence_dirs.push(dir);
        unavailable.push(problem);
    }

    let jobs = options.jobs.or(manifest.batch.jobs).unwrap_or_else(|| {
        budget_jobs(
            manifest.batch.cores_per_run,
            manifest.batch.memory_per_run_gib,
        )
    });
    let all_runs = run_list(&planned, &out);
    let mut todo = Vec::new();
    let mut skipped = 0;
    let mut unavailable_runs = 0;
    for job in &all_runs {
        match RunRecord::read(&job.dir) {
            Some(r) if r.status == RunStatus::Ok || !options.retry_failed => skipped += 1,
            _ => match &unavailable[job.sequence] {
                Some(problem) => {
                    record_unavailable(job, &planned[job.sequence], problem)?;
                    unavailable_runs += 1;
                }
                None => todo.push(job.clone()),
            },
        }
    }
    if options.progress {
        eprintln!(
            "batch {}: {} runs ({} finished before), {} to do, {jobs} at a time",
            out.display(),
            all_runs.len(),
            skipped,
            todo.len()
        );
    }
    let executor = Executor {
        program: &options.program,
        sequences: &planned,
        sequence_dirs: &sequence_dirs,
        jobs,
        cores_per_run: manifest.batch.cores_per_run,
        deterministic: manifest.batch.deterministic,
        pace: manifest.batch.pace,
        rpe_seconds: manifest.batch.rpe_seconds,
        progress: options.progress,
    };
    if options.reevaluate {
        for job in &all_runs {
            if let Some(record) = RunRecord::read(&job.dir).filter(|r| r.status == RunStatus::Ok) {
                executor.reevaluate(job, record)?;
            }
        }
    }
    let mut executed = executor.run_all(todo);
    executed.failed += unavailable_runs;

    let records: Vec<RunRecord> = all_runs
        .iter()
        .filter_map(|j| RunRecord::read(&j.dir))
        .collect();
    let names: Vec<String> = planned.iter().map(|p| p.name.clone()).collect();
    let mut modes: Vec<RunMode> = manifest.batch.modes.clone();
    for p in &planned {
        for m in &p.modes {
            if !modes.contains(m) {
                modes.push(*m);
            }
        }
    }
    let groups = results::summarise(&records, &names, &modes);
    let header = header_lines(&manifest, &planned, path, (records.len(), all_runs.len()));
    results::write_results(
        &out,
        &records,
        &groups,
        &format!("# Batch results\n\n{}", header.join("  \n")),
    )
    .map_err(|e| e.to_string())?;
    let rpe = RpeSpec {
        delta: manifest.batch.rpe_seconds,
        unit: DeltaUnit::Seconds,
    };
    let mut sections = Vec::new();
    for (k, sequence) in planned.iter().enumerate() {
        let runs: Vec<&RunRecord> = records
            .iter()
            .filter(|r| r.sequence == sequence.name)
            .collect();
        match figures::sequence_section(sequence, &sequence_dirs[k], &runs, &out, &modes, rpe) {
            Ok(section) => sections.push(section),
            Err(e) => notes.push(format!("{}: figures not made: {e}", sequence.name)),
        }
    }
    let html = html::report_html("dopslam batch report", &header, &groups, &sections);
    write_atomic(&out.join("report.html"), html.as_bytes()).map_err(|e| e.to_string())?;
    for (sequence, problem) in planned.iter().zip(&unavailable) {
        if let Some(problem) = problem {
            notes.push(format!("{}: {problem}", sequence.name));
        }
    }
    Ok(BatchSummary {
        out,
        runs_planned: all_runs.len(),
        runs_skipped: skipped,
        executed,
        jobs,
        groups,
        notes,
    })
}

/// Every run of the batch, repetition by repetition (an interrupted batch has whole
/// rounds), in the manifest's order of sequences and modes.
fn run_list(planned: &[PlannedSequence], out: &Path) -> Vec<RunJob> {
    let rounds = planned.iter().map(|p| p.repetitions).max().unwrap_or(0);
    let mut jobs = Vec::new();
    for repetition in 1..=rounds {
        for (k, sequence) in planned.iter().enumerate() {
            if repetition > sequence.repetitions {
                continue;
            }
            for &mode in &sequence.modes {
                jobs.push(RunJob {
                    sequence: k,
                    mode,
                    repetition,
                    dir: record::run_dir(out, &sequence.name, mode, repetition),
                });
            }
        }
    }
    jobs
}

/// The sequence's folder, generating a synthetic one (into `<out>/sequences/<name>`,
/// via a `.part` folder renamed when complete) if it is not there yet; and why it
/// cannot be used, if it cannot.
fn prepare_sequence(
    sequence: &PlannedSequence,
    out: &Path,
    progress: bool,
) -> (PathBuf, Option<String>) {
    match &sequence.source {
        SequenceSource::Folder(path) => {
            let problem =
                (!path.is_dir()).then(|| format!("{}: no such sequence folder", path.display()));
            (path.clone(), problem)
        }
        SequenceSource::Synthetic {
            preset,
            seed,
            frames,
        } => {
            let dir = out.join("sequences").join(&sequence.name);
            let config = crate::synth::SynthConfig::load(preset).map(|mut config| {
                if let Some(seed) = seed {
                    config.sequence.seed = *seed;
                }
                if let Some(frames) = frames {
                    config.sequence.frames = *frames;
                }
                config
            });
            let config = match config {
                Ok(config) => config,
                Err(problem) => return (dir, Some(problem)),
            };
            // A street is run from its stereo pairs (the KITTI layout it also writes).
            let run_dir = if config.street.enabled && config.stereo.baseline > 0.0 {
                dir.join("kitti/sequences/00")
            } else {
                dir.clone()
            };
            if dir.is_dir() {
                return (run_dir, None);
            }
            let part = out
                .join("sequences")
                .join(format!("{}.part", sequence.name));
            if progress {
                eprintln!("generating {} from {}", sequence.name, preset.display());
            }
            let generated = crate::synth::generate(&config, &part, true)
                .map_err(|e| e.to_string())
                .and_then(|_| {
                    std::fs::rename(&part, &dir)
                        .map_err(|e| format!("cannot rename {}: {e}", part.display()))
                });
            (run_dir, generated.err())
        }
    }
}

/// Records a run of a sequence that cannot be read or generated as failed.
fn record_unavailable(
    job: &RunJob,
    sequence: &PlannedSequence,
    problem: &str,
) -> Result<(), String> {
    std::fs::create_dir_all(&job.dir)
        .map_err(|e| format!("cannot create {}: {e}", job.dir.display()))?;
    let mut record = RunRecord::new(&sequence.name, job.mode, job.repetition);
    record.error = Some(problem.to_string());
    record.write(&job.dir).map_err(|e| e.to_string())
}

/// Where the dense map ran: `on`, `off` or `on for <sequences>`.
fn dense_description(planned: &[PlannedSequence]) -> String {
    let dense: Vec<&str> = planned
        .iter()
        .filter(|p| p.config.dense.enabled)
        .map(|p| p.name.as_str())
        .collect();
    match dense.len() {
        0 => "off".into(),
        n if n == planned.len() => "on".into(),
        _ => format!("on for {}", dense.join(", ")),
    }
}

fn header_lines(
    manifest: &Manifest,
    planned: &[PlannedSequence],
    path: &Path,
    (finished, runs): (usize, usize),
) -> Vec<String> {
    let b = &manifest.batch;
    vec![
        format!("Manifest: {} ({finished} of {runs} runs finished)", path.display()),
        format!(
            "Machine: {}; dopslam {}; {} mode{}, dense map {}, global pass {}",
            machine_description(),
            env!("CARGO_PKG_VERSION"),
            if b.deterministic { "deterministic" } else { "real-time" },
            b.detections
                .map(|d| format!(", detections {d:?}").to_lowercase())
                .unwrap_or_default(),
            dense_description(planned),
            if b.global { "on" } else { "off" },
        ),
        format!(
            "Figures: median over repetitions [min, max]; ATE with SE(3) alignment, RPE over {} s reported per second (TUM), as `dopslam eval` and evo compute them; no-dop runs use no detector (ORB-SLAM2).",
            b.rpe_seconds
        ),
    ]
}
