//! Running the batch: each run is a `dopslam run` child process (its own threads and
//! memory, its log in `log.txt`; a crash fails that run alone), several at a time
//! within the core and memory budgets, under one progress bar. A run that finished
//! (its `run.json` exists) is skipped, so a batch killed midway resumes where it was.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

use super::manifest::PlannedSequence;
use super::BatchError;
use crate::config::Config;
use crate::dense::compare_maps::{compare_maps, CompareInputs};
use crate::dense::map_figures::CompareSettings;
use crate::dop::Mode;
use crate::eval::ate::PoseRelation;
use crate::eval::report::{evaluate_with_series, EvalOptions, Evaluation, RpeSpec};
use crate::eval::rpe::DeltaUnit;
use crate::io::atomic::write_atomic;
use crate::io::run_dir::{names, RunDir};
use crate::io::trajectory::TrajectoryFormat;
use crate::io::{IoError, Trajectory};
use crate::records::run_alignment;
use crate::records::{MapFigures, RunFigures, RunRecord, RunStatus};

/// One run to do.
#[derive(Debug, Clone)]
pub struct RunJob {
    /// Index into the planned sequences.
    pub sequence: usize,
    /// The mode.
    pub mode: Mode,
    /// 1-based.
    pub repetition: usize,
    /// The run's folder.
    pub dir: PathBuf,
    /// What decides its result ([`super::fingerprint`]); filled in before it runs.
    pub inputs: super::fingerprint::RunInputs,
    /// The map it loads (`--map`), if any.
    pub map: Option<JobMap>,
}

/// The map a run loads.
#[derive(Debug, Clone, PartialEq)]
pub struct JobMap {
    /// The run folder whose `slam_map.bin` it loads.
    pub run: PathBuf,
    /// That run's sequence, when it is a run of the batch (which must finish first).
    pub sequence: Option<usize>,
    /// `--map-frozen`.
    pub frozen: bool,
    /// The run that fixed the map's frame (its first keyframe is the origin): the head
    /// of a `map_from` chain, or `run` itself.
    pub origin: PathBuf,
    /// That run's sequence, when it is a run of the batch.
    pub origin_sequence: Option<usize>,
}

/// How the runs are executed.
pub struct Executor<'a> {
    /// The `dopslam` program the runs are started with.
    pub program: &'a Path,
    /// The planned sequences.
    pub sequences: &'a [PlannedSequence],
    /// The folder each sequence is read from (generated ones under the batch's output).
    pub sequence_dirs: &'a [PathBuf],
    /// Runs at a time.
    pub jobs: usize,
    /// Cores per run (`RAYON_NUM_THREADS`).
    pub cores_per_run: usize,
    /// Runs with `--deterministic`.
    pub deterministic: bool,
    /// How frames are paced.
    pub pace: crate::pacing::Pace,
    /// The RPE's delta, seconds.
    pub rpe_seconds: f64,
    /// Show the progress bar.
    pub progress: bool,
}

/// The runs not started yet, and the folders of those running.
struct Pending {
    queue: VecDeque<RunJob>,
    running: Vec<PathBuf>,
}

/// What a worker does next.
enum Next {
    /// Nothing is left.
    Done,
    /// Every run left waits for a map being made.
    Wait,
    /// This run.
    Run(RunJob),
    /// This run cannot start: the run whose map it loads failed (why).
    Fail(RunJob, String),
}

impl Pending {
    /// The first run whose map (if it loads one from the batch) is made, marked running.
    fn take(&mut self) -> Next {
        if self.queue.is_empty() {
            return Next::Done;
        }
        for k in 0..self.queue.len() {
            let state = self.map_state(&self.queue[k]);
            let Some(job) = (state != MapState::Waiting)
                .then(|| self.queue.remove(k))
                .flatten()
            else {
                continue;
            };
            self.running.push(job.dir.clone());
            return match state {
                MapState::Failed(why) => Next::Fail(job, why),
                _ => Next::Run(job),
            };
        }
        Next::Wait
    }

    /// Whether the batch run whose map `job` loads is finished.
    fn map_state(&self, job: &RunJob) -> MapState {
        let Some(map) = job.map.as_ref().filter(|m| m.sequence.is_some()) else {
            return MapState::Ready;
        };
        let pending = self.queue.iter().any(|j| j.dir == map.run);
        if pending || self.running.contains(&map.run) {
            return MapState::Waiting;
        }
        match RunRecord::read(&map.run) {
            Some(r) if r.status == RunStatus::Ok => MapState::Ready,
            Some(r) => MapState::Failed(format!(
                "not run: the run whose map it loads ({}) failed: {}",
                map.run.display(),
                r.error.as_deref().unwrap_or("?")
            )),
            None => MapState::Failed(format!(
                "not run: the run whose map it loads ({}) did not finish",
                map.run.display()
            )),
        }
    }
}

/// Where the map a run loads stands.
#[derive(Debug, PartialEq)]
enum MapState {
    Ready,
    Waiting,
    Failed(String),
}

/// What a pass over the runs did.
#[derive(Debug, Default)]
pub struct Executed {
    /// Runs finished.
    pub done: usize,
    /// Runs failed.
    pub failed: usize,
    /// Runs left undone because the batch was interrupted.
    pub interrupted: usize,
}

impl Executor<'_> {
    /// Runs `jobs` (those without `run.json`), `self.jobs` at a time; a run that loads
    /// another run's map starts once that run finished (and fails, saying so, when it
    /// failed).
    pub fn run_all(&self, jobs: Vec<RunJob>) -> Executed {
        let total = jobs.len();
        let queue = Mutex::new(Pending {
            queue: VecDeque::from(jobs),
            running: Vec::new(),
        });
        let bar = if self.progress {
            ProgressBar::new(total as u64)
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(
            ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {bar:30} {pos}/{len} runs (eta {eta}) {msg}",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        );
        bar.enable_steady_tick(Duration::from_millis(500));
        let running = Mutex::new(Vec::<String>::new());
        let executed = Mutex::new(Executed::default());
        std::thread::scope(|scope| {
            for _ in 0..self.jobs.max(1) {
                scope.spawn(|| loop {
                    if crate::interrupt::requested() {
                        return;
                    }
                    let next = queue.lock().map_or(Next::Done, |mut q| q.take());
                    let (job, blocked) = match next {
                        Next::Done => return,
                        Next::Wait => {
                            std::thread::sleep(Duration::from_millis(200));
                            continue;
                        }
                        Next::Run(job) => (job, None),
                        Next::Fail(job, why) => (job, Some(why)),
                    };
                    let label = self.label(&job);
                    if let Ok(mut r) = running.lock() {
                        r.push(label.clone());
                        bar.set_message(r.join(", "));
                    }
                    let outcome = match blocked {
                        None => self.run_one(&job),
                        Some(why) => Some(self.record_blocked(&job, why)),
                    };
                    if let Ok(mut q) = queue.lock() {
                        q.running.retain(|dir| dir != &job.dir);
                    }
                    if let Ok(mut r) = running.lock() {
                        r.retain(|l| l != &label);
                        bar.set_message(r.join(", "));
                    }
                    let Ok(mut e) = executed.lock() else { return };
                    match outcome {
                        Some(record) if record.status == RunStatus::Failed => {
                            e.failed += 1;
                            bar.println(format!(
                                "failed: {label}: {}",
                                record.error.as_deref().unwrap_or("?")
                            ));
                        }
                        Some(_) => e.done += 1,
                        None => e.interrupted += 1,
                    }
                    bar.inc(1);
                });
            }
        });
        bar.finish_and_clear();
        let mut executed = executed.into_inner().unwrap_or_default();
        executed.interrupted += queue.into_inner().map_or(0, |q| q.queue.len());
        executed
    }

    /// A run not started because the run whose map it loads did not finish: recorded
    /// failed with `why`.
    fn record_blocked(&self, job: &RunJob, why: String) -> RunRecord {
        let name = &self.sequences[job.sequence].name;
        record_failed(job, name, why, job.inputs.clone()).unwrap_or_else(|e| {
            let mut record = RunRecord::new(name, job.mode, job.repetition);
            record.error = Some(e.to_string());
            record
        })
    }

    fn label(&self, job: &RunJob) -> String {
        format!(
            "{}/{}/r{}",
            self.sequences[job.sequence].name,
            job.mode.name(),
            job.repetition
        )
    }

    /// One run: the child process, then its evaluation; `None` when interrupted.
    fn run_one(&self, job: &RunJob) -> Option<RunRecord> {
        let sequence = &self.sequences[job.sequence];
        let start = Instant::now();
        let mut record = RunRecord::new(&sequence.name, job.mode, job.repetition);
        record.inputs = job.inputs.clone();
        if let Some(map) = &job.map {
            // The map as it is now that its run finished.
            let now = super::fingerprint::map_input(&map.run, map.frozen);
            record.inputs.insert("map".into(), now);
        }
        let result = self
            .start(job)
            .and_then(|child| wait(child, &job.dir))
            .and_then(|finished| {
                if !finished {
                    return Ok(None);
                }
                self.figures(job).map(Some)
            });
        match result {
            Ok(None) => return None,
            Ok(Some(figures)) => {
                record.status = RunStatus::Ok;
                record.figures = Some(figures);
            }
            Err(e) => record.error = Some(e.to_string()),
        }
        record.seconds = start.elapsed().as_secs_f64();
        if let Err(e) = record.write(&job.dir) {
            record.status = RunStatus::Failed;
            record.error = Some(e.to_string());
        }
        Some(record)
    }

    /// Evaluates a finished run's folder again (after a change of evaluation settings or
    /// of dopslam's figures) and rewrites its `run.json`; the run itself is not repeated.
    pub fn reevaluate(&self, job: &RunJob, mut record: RunRecord) -> Result<(), BatchError> {
        match self.figures(job) {
            Ok(figures) => record.figures = Some(figures),
            Err(e) => {
                record.status = RunStatus::Failed;
                record.error = Some(e.to_string());
            }
        }
        Ok(record.write(&job.dir)?)
    }

    /// Starts `dopslam run` for `job` in a clean folder, with the sequence's config.
    fn start(&self, job: &RunJob) -> Result<Child, BatchError> {
        let sequence = &self.sequences[job.sequence];
        if job.dir.exists() {
            std::fs::remove_dir_all(&job.dir).map_err(BatchError::file("clear", &job.dir))?;
        }
        std::fs::create_dir_all(&job.dir).map_err(BatchError::file("create", &job.dir))?;
        let config_path = job.dir.join("config.toml");
        let config = run_config(sequence, job.mode);
        let text = toml::to_string(&config)?;
        write_atomic(&config_path, text.as_bytes())?;
        let log_path = job.dir.join("log.txt");
        let log =
            std::fs::File::create(&log_path).map_err(BatchError::file("create", &log_path))?;
        let log_err = log
            .try_clone()
            .map_err(BatchError::file("open", &log_path))?;
        let mut command = Command::new(self.program);
        command
            .arg("run")
            .arg(&self.sequence_dirs[job.sequence])
            .arg("--out")
            .arg(&job.dir)
            .arg("--config")
            .arg(&config_path)
            .arg(job.mode.flag());
        if let Some(frames) = sequence.frames {
            command.arg("--frames").arg(frames.to_string());
        }
        if let Some(map) = &job.map {
            command.arg("--map").arg(&map.run);
            if map.frozen {
                command.arg("--map-frozen");
            }
        }
        if self.deterministic {
            command.arg("--deterministic");
        } else if self.pace == crate::pacing::Pace::Recording {
            command.arg("--pace").arg("recording");
        }
        command
            .env("RAYON_NUM_THREADS", self.cores_per_run.to_string())
            .stdin(Stdio::null())
            .stdout(log)
            .stderr(log_err);
        #[cfg(target_os = "linux")]
        {
            use std::os::unix::process::CommandExt;
            // SAFETY: prctl is async-signal-safe; the child asks to be ended when the
            // thread that started it (a batch worker, which waits for it) goes away.
            unsafe {
                command.pre_exec(|| {
                    libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM);
                    Ok(())
                });
            }
        }
        command.spawn().map_err(|source| BatchError::Process {
            action: "start",
            program: self.program.to_path_buf(),
            source,
        })
    }

    /// The figures of a finished run: its report, its evaluation against the
    /// sequence's ground truth (`eval.json`, `eval_rotation.json`) and, on a synthetic
    /// sequence with a static scene, its dense map against it (`map_compare/`).
    fn figures(&self, job: &RunJob) -> Result<RunFigures, BatchError> {
        let sequence = &self.sequences[job.sequence];
        let mut figures = RunFigures::from_run(&job.dir)?;
        let sequence_dir = &self.sequence_dirs[job.sequence];
        if let Some(reference) = ground_truth(sequence_dir, &sequence.config)? {
            let rpe = RpeSpec {
                delta: self.rpe_seconds,
                unit: DeltaUnit::Seconds,
            };
            let evaluate_file = |name: &str, relation| {
                evaluate_trajectory(
                    &reference,
                    &job.dir.join(name),
                    &sequence.config,
                    rpe,
                    relation,
                )
                .map(|e| e.report)
            };
            let translation = evaluate_file(names::TRAJECTORY, PoseRelation::TransPart)?;
            let rotation = evaluate_file(names::TRAJECTORY, PoseRelation::AngleDeg)?;
            for (name, report) in [
                ("eval.json", &translation),
                ("eval_rotation.json", &rotation),
            ] {
                let json =
                    serde_json::to_string_pretty(report).expect("an evaluation report is JSON");
                write_atomic(&job.dir.join(name), json.as_bytes())?;
            }
            figures.ate_rmse = Some(translation.ape.statistics.rmse);
            figures.rpe_translation = translation.rpe.first().map(|m| m.statistics.rmse);
            figures.rpe_rotation_deg = rotation.rpe.first().map(|m| m.statistics.rmse);
            figures.kitti_translation_percent =
                translation.kitti.as_ref().map(|k| k.translation_percent);
            figures.kitti_rotation_deg_per_100m =
                translation.kitti.as_ref().map(|k| k.rotation_deg_per_100m);
            if RunDir::new(&job.dir).tracking_trajectory().exists() {
                let report = evaluate_file(names::TRACKING_TRAJECTORY, PoseRelation::TransPart)?;
                figures.ate_tracking_rmse = Some(report.ape.statistics.rmse);
            }
            if let Some(map) = &job.map {
                figures.ate_map_frame_rmse = self.ate_in_map_frame(job, map, &reference)?;
            }
        }
        if let Some(map) =
            compare_with_static_scene(&job.dir, sequence_dir, run_alignment(&job.dir))?
        {
            let dense = figures.map.take().unwrap_or_default();
            figures.map = Some(MapFigures {
                dynamic_removed_percent: dense.dynamic_removed_percent,
                ..map
            });
        }
        Ok(figures)
    }
}

impl Executor<'_> {
    /// The ATE of `job`'s trajectory in the frame of the map it loaded, without
    /// alignment: the map's frame is put on the ground truth's by the first pose of
    /// the run that fixed it (the head of a `map_from` chain: exact, its first keyframe
    /// is the map's origin). `None` when that run's sequence has no ground truth.
    fn ate_in_map_frame(
        &self,
        job: &RunJob,
        map: &JobMap,
        truth: &Trajectory,
    ) -> Result<Option<f64>, BatchError> {
        let Some(reference_truth) = self.map_truth(map)? else {
            return Ok(None);
        };
        let origin = RunDir::new(&map.origin).trajectory();
        let made_map = Trajectory::read(&origin, TrajectoryFormat::Tum)?;
        let sequence = &self.sequences[job.sequence];
        let (rule, max_diff) = (
            sequence.config.eval.association,
            sequence.config.eval.max_diff.unwrap_or(0.02),
        );
        let Some(truth_from_map) = frame_on_truth(&made_map, &reference_truth, rule, max_diff)
        else {
            return Ok(None);
        };
        let mut estimate =
            Trajectory::read(&RunDir::new(&job.dir).trajectory(), TrajectoryFormat::Tum)?;
        for pose in &mut estimate.poses {
            *pose = truth_from_map * *pose;
        }
        let mut config = sequence.config.clone();
        config.eval.align = crate::eval::report::AlignMode::None;
        let rpe = RpeSpec {
            delta: self.rpe_seconds,
            unit: DeltaUnit::Seconds,
        };
        let evaluation = evaluate_run(truth, &estimate, &config, rpe, PoseRelation::TransPart)?;
        Ok(Some(evaluation.report.ape.statistics.rmse))
    }

    /// The ground truth of the sequence whose run fixed `map`'s frame: a batch
    /// sequence's, or the one its `report.json` names.
    fn map_truth(&self, map: &JobMap) -> Result<Option<Trajectory>, BatchError> {
        if let Some(r) = map.origin_sequence {
            return Ok(ground_truth(
                &self.sequence_dirs[r],
                &self.sequences[r].config,
            )?);
        }
        let run = RunDir::new(&map.origin);
        let report = crate::records::read_report(&run)?;
        let Some(sequence) = report.sequence_path else {
            return Ok(None);
        };
        let config = Config::load(&run.file("config.toml")).unwrap_or_default();
        Ok(ground_truth(&sequence, &config)?)
    }
}

/// `truth_from_map`: the pose that takes the map's frame onto the ground truth's,
/// from the first pose of `made_map` paired with a ground-truth pose (the eval's
/// association, within `max_diff` s).
fn frame_on_truth(
    made_map: &Trajectory,
    truth: &Trajectory,
    rule: crate::eval::associate::AssociationRule,
    max_diff: f64,
) -> Option<crate::geometry::se3::Se3> {
    let pairs = crate::eval::associate::associate(truth, made_map, rule, max_diff, 0.0).pairs;
    let &(r, e) = pairs.first()?;
    Some(truth.poses[r] * made_map.poses[e].inverse())
}

/// Records `job`, a run of the sequence `name`, as failed with `error` without running
/// it: its folder made and its `run.json` written, with `inputs`.
pub fn record_failed(
    job: &RunJob,
    name: &str,
    error: String,
    inputs: super::fingerprint::RunInputs,
) -> Result<RunRecord, BatchError> {
    std::fs::create_dir_all(&job.dir).map_err(BatchError::file("create", &job.dir))?;
    let mut record = RunRecord::new(name, job.mode, job.repetition);
    record.inputs = inputs;
    record.error = Some(error);
    record.write(&job.dir)?;
    Ok(record)
}

/// The config a run of `sequence` in `mode` is given (its `config.toml`): the
/// sequence's, with no detector for ORB-SLAM2 (`no-dop`).
pub fn run_config(sequence: &PlannedSequence, mode: Mode) -> Config {
    let mut config = sequence.config.clone();
    if mode == Mode::Off {
        config.detector.source = crate::detect::Source::None;
    }
    config
}

/// Waits for the child; on a stop request, passes it on and reports `false` (the run's
/// outputs are partial and it will be run again).
fn wait(mut child: Child, dir: &Path) -> Result<bool, BatchError> {
    let mut asked = false;
    loop {
        match child.try_wait() {
            Ok(Some(status)) if status.success() && !asked => return Ok(true),
            // A stop reaches the run from the terminal or from here: its outputs are
            // partial, it is not recorded and runs again next time.
            Ok(Some(_)) if asked || crate::interrupt::requested() || was_interrupted(dir) => {
                return Ok(false)
            }
            Ok(Some(status)) => return Err(BatchError::RunFailed(failure_message(status, dir))),
            Ok(None) => {}
            Err(source) => {
                return Err(BatchError::Process {
                    action: "wait for",
                    program: PathBuf::from("dopslam run"),
                    source,
                })
            }
        }
        if crate::interrupt::requested() && !asked {
            asked = true;
            #[cfg(unix)]
            // SAFETY: kill takes a pid and a signal number, no pointers.
            unsafe {
                libc::kill(child.id() as libc::pid_t, libc::SIGINT);
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Whether the run's log says it stopped on a signal.
fn was_interrupted(dir: &Path) -> bool {
    std::fs::read_to_string(dir.join("log.txt"))
        .is_ok_and(|log| log.contains(crate::interrupt::MESSAGE))
}

/// The run's own error line from its log, else its exit status.
fn failure_message(status: std::process::ExitStatus, dir: &Path) -> String {
    let log = std::fs::read_to_string(dir.join("log.txt")).unwrap_or_default();
    let error = log
        .lines()
        .rev()
        .find_map(|l| l.trim().strip_prefix("error: "))
        .map(str::to_string);
    match error {
        Some(e) => e,
        None => format!(
            "dopslam run exited with {status} (see {}/log.txt)",
            dir.display()
        ),
    }
}

/// The sequence's ground truth, if it has one.
pub fn ground_truth(dir: &Path, config: &Config) -> Result<Option<Trajectory>, IoError> {
    let sequence = crate::run::open_sequence(dir, config)?;
    Ok(sequence.ground_truth().cloned())
}

/// ATE and one RPE, as `dopslam eval` computes them with the config's `[eval]`
/// association and alignment (every matched pose counts, whatever the coverage). A
/// trajectory too short for the RPE's delta gets the ATE alone.
pub fn evaluate_run(
    reference: &Trajectory,
    estimate: &Trajectory,
    config: &Config,
    rpe: RpeSpec,
    rpe_relation: PoseRelation,
) -> Result<Evaluation, BatchError> {
    let mut options = EvalOptions {
        association: config.eval.association,
        max_diff: config.eval.max_diff,
        offset: 0.0,
        align: config.eval.align,
        n_align: None,
        ape_relation: PoseRelation::TransPart,
        rpe: vec![rpe],
        rpe_relation,
        min_coverage: 0.0,
    };
    evaluate_with_series(reference, estimate, &options)
        .or_else(|_| {
            options.rpe.clear();
            evaluate_with_series(reference, estimate, &options)
        })
        .map_err(BatchError::Evaluation)
}

/// [`evaluate_run`] of a trajectory file (TUM format).
pub fn evaluate_trajectory(
    reference: &Trajectory,
    path: &Path,
    config: &Config,
    rpe: RpeSpec,
    rpe_relation: PoseRelation,
) -> Result<Evaluation, BatchError> {
    let estimate = Trajectory::read(path, TrajectoryFormat::Tum)?;
    evaluate_run(reference, &estimate, config, rpe, rpe_relation)
}

/// The dense map in `run` (a run's folder, or a merged map's) against a synthetic
/// sequence's static scene and movers, its frame put on the scene's by `alignment`.
pub fn compare_with_static_scene(
    run: &Path,
    sequence_dir: &Path,
    alignment: Option<crate::geometry::se3::Se3>,
) -> Result<Option<MapFigures>, BatchError> {
    let static_scene = sequence_dir.join("static_scene.ply");
    let mesh = [names::DENSE_MESH_PLY, names::DENSE_POINTS]
        .into_iter()
        .map(|n| run.join(n))
        .find(|p| p.exists());
    let (true, Some(mesh)) = (static_scene.exists(), mesh) else {
        return Ok(None);
    };
    let movers = sequence_dir.join("movers.ply");
    let maps = [("map".to_string(), mesh)];
    let comparison = compare_maps(&CompareInputs {
        maps: &maps,
        alignments: &[alignment],
        reference: &static_scene,
        movers: movers.exists().then_some(movers.as_path()),
        cameras: None,
        settings: CompareSettings::default(),
        out: &run.join("map_compare"),
    })?;
    Ok(comparison.maps.first().map(|m| MapFigures {
        accuracy_median: Some(m.accuracy_median),
        ghost_points: Some(m.ghost_points),
        ghost_fraction: Some(m.ghost_fraction),
        dynamic_removed_percent: None,
    }))
}
