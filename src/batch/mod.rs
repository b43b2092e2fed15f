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
//! This layer sits above the run (`crate::run`): it starts `dopslam run` processes and reads
//! what they wrote; nothing below imports it.

pub mod error;
pub mod execute;
pub mod figures;
pub mod fingerprint;
pub mod html;
pub mod machine;
pub mod manifest;
pub mod plots;

pub mod results;
pub mod sessions;
pub mod shard;
pub mod slurm;

use std::path::{Path, PathBuf};

use crate::dop::Mode;
use crate::records::{RunRecord, RunStatus};
pub use error::BatchError;
use execute::{Executed, Executor, JobMap, RunJob};
use machine::{budget_jobs, machine_description};
use manifest::{absolute, Manifest, ManifestError, MapFrom, PlannedSequence, SequenceSource};
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
    /// Show progress.
    pub progress: bool,
    /// Run only this part of the runs, and write no tables ([`shard`]).
    pub shard: Option<shard::Shard>,
    /// Run nothing: make the tables, plots and report from the finished runs.
    pub collect: bool,
    /// Keep finished runs whose inputs differ from the manifest's (marked stale in
    /// the tables) instead of running them again.
    pub keep_stale: bool,
}

/// What a batch did.
#[derive(Debug)]
pub struct BatchSummary {
    /// The batch's folder.
    pub out: PathBuf,
    /// Runs in the plan.
    pub runs_planned: usize,
    /// Runs found finished from an earlier invocation.
    pub runs_skipped: usize,
    /// What this invocation ran.
    pub executed: Executed,
    /// Runs at a time.
    pub jobs: usize,
    /// Per sequence and mode: medians and spreads.
    pub groups: Vec<GroupSummary>,
    /// Figures or sequences that could not be made, and why.
    pub notes: Vec<String>,
    /// Runs of the whole batch with no `run.json` (not run, or not finished), and
    /// those whose record says they failed, as `sequence/mode/r<k>`.
    pub missing: Vec<String>,
    /// Runs recorded failed, as `sequence/mode/r<k>`.
    pub failed: Vec<String>,
    /// Whether tables were written (not for a shard).
    pub tables: bool,
    /// Sequences that could not be read or generated (their runs are recorded failed).
    pub unavailable: usize,
}

/// A batch's plan: the manifest, its sequences, the output folder and every run.
pub struct BatchPlan {
    /// The manifest.
    pub manifest: Manifest,
    /// Its sequences, planned.
    pub planned: Vec<PlannedSequence>,
    /// The output folder.
    pub out: PathBuf,
    /// Every run.
    pub runs: Vec<RunJob>,
}

impl BatchPlan {
    /// Reads the manifest at `path` and plans its runs into `out` (else the manifest's
    /// `out`, else `outputs/batch/<manifest name>`).
    pub fn new(path: &Path, out: Option<&Path>) -> Result<Self, ManifestError> {
        let manifest = Manifest::load(path)?;
        let planned = manifest.plan().map_err(|problem| ManifestError::Invalid {
            path: path.to_path_buf(),
            problem: Box::new(problem),
        })?;
        let out = match (out, &manifest.batch.out) {
            (Some(out), _) => out.to_path_buf(),
            (None, Some(out)) => manifest.resolve(out),
            (None, None) => Path::new("outputs/batch").join(
                path.file_stem()
                    .map_or("batch".into(), |s| s.to_string_lossy().into_owned()),
            ),
        };
        let out = absolute(&out);
        let runs = run_list(&planned, &out);
        Ok(Self {
            manifest,
            planned,
            out,
            runs,
        })
    }

    /// A run's label, `sequence/mode/r<k>`.
    pub fn label(&self, job: &RunJob) -> String {
        format!(
            "{}/{}/r{}",
            self.planned[job.sequence].name,
            job.mode.name(),
            job.repetition
        )
    }
}

/// Runs the batch described by the manifest at `path`: every run (or a shard's), then
/// the tables; with `options.collect`, the tables alone.
pub fn run_batch(path: &Path, options: &BatchOptions) -> Result<BatchSummary, BatchError> {
    let plan = BatchPlan::new(path, options.out.as_deref())?;
    let out = &plan.out;
    check_not_an_input(&plan)?;
    std::fs::create_dir_all(out).map_err(BatchError::file("create", out))?;
    let _lock = batch_lock(out, options.shard.is_some())?;
    let _shard_lock = options.shard.map(|s| shard_lock(out, s)).transpose()?;
    keep_manifest(path, out, options.collect)?;
    let mut notes = Vec::new();
    // The runs this invocation is for: a shard's, or all.
    let mine = match options.shard {
        Some(shard) => shard::select(&plan.runs, &plan.planned, shard),
        None => plan.runs.clone(),
    };
    let (sequence_dirs, unavailable) = if options.collect {
        let dirs = plan.planned.iter().map(|p| sequence_dir(p, out)).collect();
        (dirs, vec![None; plan.planned.len()])
    } else {
        prepare_sequences(&plan, &mine, options.progress)
    };
    let batch = &plan.manifest.batch;
    let jobs = (options.jobs.or(batch.jobs))
        .unwrap_or_else(|| budget_jobs(batch.cores_per_run, batch.memory_per_run_gib));
    // One for the whole invocation: the binary and the detector files are hashed once.
    let fingerprinter = fingerprint::Fingerprinter::new(&options.program);
    let (executed, skipped) = if options.collect {
        (Executed::default(), 0)
    } else {
        let work = Work {
            mine: &mine,
            options,
            sequence_dirs: &sequence_dirs,
            unavailable: &unavailable,
            jobs,
            fingerprinter: &fingerprinter,
        };
        execute(&plan, work)?
    };
    let mut summary = BatchSummary {
        out: out.clone(),
        runs_planned: plan.runs.len(),
        runs_skipped: skipped,
        executed,
        jobs,
        groups: Vec::new(),
        notes: Vec::new(),
        missing: Vec::new(),
        failed: Vec::new(),
        tables: options.shard.is_none(),
        unavailable: unavailable.iter().filter(|u| u.is_some()).count(),
    };
    for job in &plan.runs {
        match RunRecord::read(&job.dir) {
            None => summary.missing.push(plan.label(job)),
            Some(r) if r.status == RunStatus::Failed => summary.failed.push(plan.label(job)),
            Some(_) => {}
        }
    }
    for (sequence, problem) in plan.planned.iter().zip(&unavailable) {
        if let Some(problem) = problem {
            notes.push(format!("{}: {problem}", sequence.name));
        }
    }
    if summary.tables {
        let tables = Tables {
            path,
            fingerprinter: &fingerprinter,
            sequence_dirs: &sequence_dirs,
            options,
        };
        summary.groups = write_tables(&plan, &tables, &mut notes)?;
    }
    summary.notes = notes;
    Ok(summary)
}

/// Keeps a copy of the manifest at `path` as `OUT/manifest.toml`; with `collect`
/// (tables only), refuses an output folder whose copy is another manifest's.
fn keep_manifest(path: &Path, out: &Path, collect: bool) -> Result<(), BatchError> {
    let text = std::fs::read(path).map_err(BatchError::file("read", path))?;
    let own = out.join("manifest.toml");
    if !collect {
        return Ok(write_atomic(&own, &text)?);
    }
    if std::fs::read(&own).is_ok_and(|copy| copy != text) {
        return Err(BatchError::OtherManifest {
            out: out.to_path_buf(),
            copy: own,
            manifest: path.to_path_buf(),
        });
    }
    Ok(())
}

/// Refuses an output folder that is, or lies inside, one of the batch's recorded
/// sequence folders or a run folder whose map a sequence loads: a batch never writes
/// into its inputs.
fn check_not_an_input(plan: &BatchPlan) -> Result<(), BatchError> {
    for sequence in &plan.planned {
        if let SequenceSource::Folder(input) = &sequence.source {
            if crate::io::output::is_within(&plan.out, input) {
                return Err(BatchError::OutputInInput {
                    out: plan.out.clone(),
                    input: input.clone(),
                    sequence: sequence.name.clone(),
                });
            }
        }
        if let Some(MapFrom::Run(map)) = sequence.map.as_ref().map(|m| &m.from) {
            if crate::io::output::is_within(&plan.out, map) {
                return Err(BatchError::OutputInMap {
                    out: plan.out.clone(),
                    map: map.clone(),
                    sequence: sequence.name.clone(),
                });
            }
        }
    }
    Ok(())
}

/// A shard's own lock (`OUT/.dopslam-shard-K-of-N.lock`): the same shard started twice
/// (a Slurm array task resubmitted while it still runs) is refused, not run twice into
/// the same run folders.
fn shard_lock(out: &Path, shard: shard::Shard) -> Result<std::fs::File, BatchError> {
    use crate::io::output::{lock_file, LockMode};
    let path = out.join(format!(
        ".dopslam-shard-{}-of-{}.lock",
        shard.index, shard.count
    ));
    match lock_file(&path, LockMode::Try) {
        Ok(Some(file)) => Ok(file),
        Ok(None) => Err(BatchError::ShardBusy {
            out: out.to_path_buf(),
            shard: shard.to_string(),
        }),
        Err(e) => Err(BatchError::file("lock", path)(e)),
    }
}

/// The batch's lock on its output folder (`OUT/.dopslam-batch.lock`, held while it
/// runs): a whole batch or a collection holds it alone; the shards of one batch share
/// it (they run together by design), so neither a second batch nor a collection runs
/// beside them.
fn batch_lock(out: &Path, shard: bool) -> Result<std::fs::File, BatchError> {
    use crate::io::output::{lock_file, LockMode};
    let path = out.join(".dopslam-batch.lock");
    let mode = if shard {
        LockMode::TryShared
    } else {
        LockMode::Try
    };
    match lock_file(&path, mode) {
        Ok(Some(file)) => Ok(file),
        Ok(None) => Err(BatchError::Busy(out.to_path_buf())),
        Err(e) => Err(BatchError::file("lock", path)(e)),
    }
}

/// How many of the batch's runs are still to do: no finished `run.json`, or one made
/// with other inputs ([`fingerprint`]) than `program` would run with now.
pub fn runs_to_do(plan: &BatchPlan, program: &Path) -> usize {
    let fingerprinter = fingerprint::Fingerprinter::new(program);
    let dirs: Vec<PathBuf> = plan
        .planned
        .iter()
        .map(|p| sequence_dir(p, &plan.out))
        .collect();
    plan.runs
        .iter()
        .filter(|job| match RunRecord::read(&job.dir) {
            Some(r) if r.status == RunStatus::Ok => {
                r.inputs != run_inputs(&fingerprinter, plan, job, &dirs)
            }
            _ => true,
        })
        .count()
}

/// The sequences the runs `mine` need: each folder, generating synthetic ones once
/// (also when shards start together), and why a sequence cannot be used.
fn prepare_sequences(
    plan: &BatchPlan,
    mine: &[RunJob],
    progress: bool,
) -> (Vec<PathBuf>, Vec<Option<String>>) {
    plan.planned
        .iter()
        .enumerate()
        .map(|(k, sequence)| {
            if mine.iter().any(|j| j.sequence == k) {
                prepare_sequence(sequence, &plan.out, progress)
            } else {
                (sequence_dir(sequence, &plan.out), None)
            }
        })
        .unzip()
}

/// What running a batch's jobs needs beside its plan.
struct Work<'a> {
    /// The batch's runs, or a shard's.
    mine: &'a [RunJob],
    options: &'a BatchOptions,
    /// Each planned sequence's folder, and why it cannot be run (if so).
    sequence_dirs: &'a [PathBuf],
    unavailable: &'a [Option<String>],
    /// Runs at once.
    jobs: usize,
    fingerprinter: &'a fingerprint::Fingerprinter,
}

/// Runs what is left of `work.mine`: `(executed, runs finished before)`.
fn execute(plan: &BatchPlan, work: Work) -> Result<(Executed, usize), BatchError> {
    let Work {
        mine,
        options,
        sequence_dirs,
        unavailable,
        jobs,
        fingerprinter,
    } = work;
    let mut todo = Vec::new();
    let mut kept = Vec::new();
    let mut unavailable_runs = 0;
    for job in mine {
        let mut job = job.clone();
        job.inputs = run_inputs(fingerprinter, plan, &job, sequence_dirs);
        if let Some(why) = RunRecord::unreadable(&job.dir) {
            eprintln!("warning: {why}: the run is made again");
        }
        let record = match RunRecord::read(&job.dir) {
            Some(r) if r.inputs != job.inputs && !options.keep_stale => {
                let reasons = fingerprint::differences(&r.inputs, &job.inputs).join(", ");
                set_aside_stale(plan, &job, &reasons)?;
                None
            }
            other => other,
        };
        match record {
            Some(r) if r.status == RunStatus::Ok || !options.retry_failed => kept.push(job),
            _ => match &unavailable[job.sequence] {
                Some(problem) => {
                    record_unavailable(&job, &plan.planned[job.sequence], problem)?;
                    unavailable_runs += 1;
                }
                None => todo.push(job),
            },
        }
    }
    if !options.keep_stale {
        redo_dependents(plan, &mut kept, &mut todo)?;
    }
    let skipped = kept.len();
    if options.progress {
        eprintln!(
            "batch {}{}: {} runs ({} finished before), {} to do, {jobs} at a time",
            plan.out.display(),
            options
                .shard
                .map(|s| format!(", shard {s}"))
                .unwrap_or_default(),
            mine.len(),
            skipped,
            todo.len()
        );
    }
    let batch = &plan.manifest.batch;
    let executor = Executor {
        program: &options.program,
        sequences: &plan.planned,
        sequence_dirs,
        jobs,
        cores_per_run: batch.cores_per_run,
        deterministic: batch.deterministic,
        pace: batch.pace,
        rpe_seconds: batch.rpe_seconds,
        progress: options.progress,
    };
    if options.reevaluate {
        for job in mine {
            if let Some(record) = RunRecord::read(&job.dir).filter(|r| r.status == RunStatus::Ok) {
                executor.reevaluate(job, record)?;
            }
        }
    }
    let mut executed = executor.run_all(todo);
    executed.failed += unavailable_runs;
    Ok((executed, skipped))
}

/// Moves from `kept` to `todo` every finished run whose loaded map's run is to be
/// made again (and so on down a chain): its map will be another.
fn redo_dependents(
    plan: &BatchPlan,
    kept: &mut Vec<RunJob>,
    todo: &mut Vec<RunJob>,
) -> Result<(), BatchError> {
    loop {
        let again = kept.iter().position(|job| {
            job.map
                .as_ref()
                .is_some_and(|map| todo.iter().any(|t| t.dir == map.run))
        });
        let Some(k) = again else {
            return Ok(());
        };
        let job = kept.remove(k);
        if job.dir.exists() {
            set_aside_stale(plan, &job, "the run whose map it loads is made again")?;
        }
        todo.push(job);
    }
}

/// What decides the result of `job` today ([`fingerprint`]).
fn run_inputs(
    fingerprinter: &fingerprint::Fingerprinter,
    plan: &BatchPlan,
    job: &RunJob,
    sequence_dirs: &[PathBuf],
) -> fingerprint::RunInputs {
    let sequence = &plan.planned[job.sequence];
    let execution = fingerprint::Execution {
        deterministic: plan.manifest.batch.deterministic,
        pace: plan.manifest.batch.pace,
    };
    let mut inputs = fingerprinter.inputs(
        &sequence_dirs[job.sequence],
        sequence.frames,
        job.mode.flag(),
        &execute::run_config(sequence, job.mode),
        execution,
    );
    if let Some(map) = &job.map {
        inputs.insert("map".into(), fingerprint::map_input(&map.run, map.frozen));
    }
    inputs
}

/// A finished run made with other inputs than `job`'s: says what differs and moves
/// its folder to `OUT/stale/<sequence>/<mode>/r<k>-<UTC time>/` (never deleted), so
/// that it is run again.
fn set_aside_stale(plan: &BatchPlan, job: &RunJob, reasons: &str) -> Result<(), BatchError> {
    let label = plan.label(job);
    let to = move_to_stale(&plan.out, &label, &job.dir)?;
    eprintln!(
        "{label}: made with other settings ({reasons}): run again; the old run is in {} (--keep-stale keeps such runs)",
        to.display()
    );
    Ok(())
}

/// Moves the folder `from` (never deleted) to `OUT/stale/<label>-<UTC time>` (`label`
/// as `sequence/mode/r<k>`, or `merged/<group>/<mode>/r<k>`); where it went.
fn move_to_stale(out: &Path, label: &str, from: &Path) -> Result<PathBuf, BatchError> {
    let stamp = crate::io::output::utc_stamp(std::time::SystemTime::now());
    let to = out.join("stale").join(label);
    let name = to.file_name().map(|n| n.to_string_lossy().into_owned());
    let to = to.with_file_name(format!("{}-{stamp}", name.unwrap_or_default()));
    let parent = to.parent().unwrap_or(out);
    std::fs::create_dir_all(parent).map_err(BatchError::file("create", parent))?;
    std::fs::rename(from, &to).map_err(BatchError::file("move aside to", &to))?;
    Ok(to)
}

/// What making the tables needs beside the plan.
struct Tables<'a> {
    /// The manifest's file.
    path: &'a Path,
    fingerprinter: &'a fingerprint::Fingerprinter,
    /// Each planned sequence's folder.
    sequence_dirs: &'a [PathBuf],
    options: &'a BatchOptions,
}

/// The tables, plots and report from the finished runs (and the groups' merged maps);
/// the groups' summaries.
fn write_tables(
    plan: &BatchPlan,
    tables: &Tables,
    notes: &mut Vec<String>,
) -> Result<Vec<GroupSummary>, BatchError> {
    let (manifest, planned, out) = (&plan.manifest, &plan.planned, &plan.out);
    let Tables {
        path,
        fingerprinter,
        sequence_dirs,
        options,
    } = *tables;
    let records = finished_records(plan, fingerprinter, sequence_dirs);
    let stale: Vec<String> = records
        .iter()
        .filter_map(|r| {
            Some(format!(
                "{}/{}/r{} ({})",
                r.sequence,
                r.mode.name(),
                r.repetition,
                r.stale.as_ref()?
            ))
        })
        .collect();
    let names: Vec<String> = planned.iter().map(|p| p.name.clone()).collect();
    let modes = all_modes(manifest, planned);
    let groups = results::summarise(&records, &names, &modes);
    let finished = records.iter().filter(|r| r.status == RunStatus::Ok).count();
    let failed = records.len() - finished;
    let mut header = header_lines(manifest, planned, path, finished, failed, plan.runs.len());
    if !stale.is_empty() {
        header.push(format!(
            "**Stale runs** (kept with --keep-stale, made with other settings than this manifest's): {}",
            stale.join("; ")
        ));
    }
    let in_map = sessions::in_map_summaries(planned, &records, &modes);
    let merged = sessions::merge_groups(plan, &options.program, sequence_dirs, options.progress);
    notes.extend(sessions::merge_notes(&merged));
    results::write_results(
        out,
        &records,
        &groups,
        &format!("# Batch results\n\n{}", header.join("  \n")),
        &sessions::results(&in_map, &merged),
    )?;
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
        match figures::sequence_section(sequence, &sequence_dirs[k], &runs, out, &modes, rpe) {
            Ok(section) => sections.push(section),
            Err(e) => notes.push(format!("{}: figures not made: {e}", sequence.name)),
        }
    }
    let sessions = sessions::sessions_html(&in_map, &merged);
    let html = html::report_html(
        "dopslam batch report",
        &header,
        &groups,
        &sections,
        &sessions,
    );
    write_atomic(&out.join("report.html"), html.as_bytes())?;
    Ok(groups)
}

/// The records of the batch's runs that have one, each marked stale when its inputs
/// differ from what the batch would run with now.
fn finished_records(
    plan: &BatchPlan,
    fingerprinter: &fingerprint::Fingerprinter,
    sequence_dirs: &[PathBuf],
) -> Vec<RunRecord> {
    plan.runs
        .iter()
        .filter_map(|j| {
            let mut record = RunRecord::read(&j.dir)?;
            let now = run_inputs(fingerprinter, plan, j, sequence_dirs);
            let reasons = fingerprint::differences(&record.inputs, &now);
            record.stale = (!reasons.is_empty()).then(|| reasons.join(", "));
            Some(record)
        })
        .collect()
}

/// The batch's modes, then any other a sequence runs.
fn all_modes(manifest: &Manifest, planned: &[PlannedSequence]) -> Vec<Mode> {
    let mut modes: Vec<Mode> = manifest.batch.modes.clone();
    for p in planned {
        for m in &p.modes {
            if !modes.contains(m) {
                modes.push(*m);
            }
        }
    }
    modes
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
                let run_of = |k: usize| {
                    crate::records::run::run_dir(out, &planned[k].name, mode, repetition)
                };
                let map = sequence.map.as_ref().map(|source| match &source.from {
                    MapFrom::Run(run) => JobMap {
                        run: run.clone(),
                        sequence: None,
                        frozen: source.frozen,
                        origin: run.clone(),
                        origin_sequence: None,
                    },
                    MapFrom::Sequence(r) => {
                        let origin = manifest::root_sequence(planned, k).unwrap_or(*r);
                        JobMap {
                            run: run_of(*r),
                            sequence: Some(*r),
                            frozen: source.frozen,
                            origin: run_of(origin),
                            origin_sequence: Some(origin),
                        }
                    }
                });
                jobs.push(RunJob {
                    sequence: k,
                    mode,
                    repetition,
                    dir: crate::records::run::run_dir(out, &sequence.name, mode, repetition),
                    inputs: Default::default(),
                    map,
                });
            }
        }
    }
    jobs
}

/// The folder a sequence's runs read (a generated street is run from the KITTI layout
/// it also writes), without generating anything.
fn sequence_dir(sequence: &PlannedSequence, out: &Path) -> PathBuf {
    match &sequence.source {
        SequenceSource::Folder(path) => path.clone(),
        SequenceSource::Synthetic { preset, .. } => {
            let config = crate::synth::SynthConfig::load(preset);
            synthetic_run_dir(sequence, out, config.as_ref().ok())
        }
    }
}

/// Where the runs read a generated sequence: its folder, or for a street the KITTI
/// layout it also writes (a street is run from its stereo pairs).
fn synthetic_run_dir(
    sequence: &PlannedSequence,
    out: &Path,
    config: Option<&crate::synth::SynthConfig>,
) -> PathBuf {
    let dir = out.join("sequences").join(&sequence.name);
    if config.is_some_and(|c| c.street.enabled && c.stereo.baseline > 0.0) {
        dir.join("kitti/sequences/00")
    } else {
        dir
    }
}

/// The sequence's folder, generating a synthetic one (into `<out>/sequences/<name>`,
/// via a folder of this process renamed when complete, once across processes: see
/// [`shard::once_per_folder`]) if it is not there yet; and why it cannot be used, if
/// it cannot.
fn prepare_sequence(
    sequence: &PlannedSequence,
    out: &Path,
    progress: bool,
) -> (PathBuf, Option<String>) {
    match &sequence.source {
        SequenceSource::Folder(path) => {
            let readable =
                path.is_dir() || (crate::io::recording::is_recording(path) && path.exists());
            let problem = (!readable)
                .then(|| format!("{}: no such sequence folder or recording", path.display()));
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
                Err(problem) => return (dir, Some(problem.to_string())),
            };
            let part =
                out.join("sequences")
                    .join(format!("{}.part{}", sequence.name, std::process::id()));
            let generated = shard::once_per_folder(&dir, || {
                if progress {
                    eprintln!("generating {} from {}", sequence.name, preset.display());
                }
                crate::synth::generate(&config, &part, true)?;
                std::fs::rename(&part, &dir).map_err(BatchError::file("rename", &part))
            });
            let problem = generated.err().map(|e| e.to_string());
            (synthetic_run_dir(sequence, out, Some(&config)), problem)
        }
    }
}

/// Records a run of a sequence that cannot be read or generated as failed.
fn record_unavailable(
    job: &RunJob,
    sequence: &PlannedSequence,
    problem: &str,
) -> Result<(), BatchError> {
    let no_inputs = Default::default();
    execute::record_failed(job, &sequence.name, problem.to_string(), no_inputs).map(drop)
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
    finished: usize,
    failed: usize,
    runs: usize,
) -> Vec<String> {
    let b = &manifest.batch;
    vec![
        format!(
            "Manifest: {} ({finished} of {runs} runs finished, {failed} failed, {} not run)",
            path.display(),
            runs - finished - failed
        ),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A shard already running holds its lock: the same shard again is refused by name,
    /// another shard of the batch is not.
    #[test]
    fn the_same_shard_twice_is_refused() {
        let out = std::env::temp_dir().join(format!("dopslam-shard-lock-{}", std::process::id()));
        std::fs::create_dir_all(&out).unwrap();
        let first = shard::Shard { index: 1, count: 2 };
        let held = shard_lock(&out, first).unwrap();
        let error = shard_lock(&out, first).unwrap_err().to_string();
        assert!(
            error.contains("shard 1/2") && error.contains("already running"),
            "{error}"
        );
        assert!(shard_lock(&out, shard::Shard { index: 2, count: 2 }).is_ok());
        drop(held);
        assert!(shard_lock(&out, first).is_ok());
        std::fs::remove_dir_all(&out).unwrap();
    }
}
