//! One worker type for the system's helpers (local mapping, place recognition, the
//! keyframe detector): a [`Stage`] runs either inline, each job processed when it is
//! submitted (`--deterministic`: results repeat exactly), or on its own named thread at
//! a lower priority, fed through a channel (real-time mode: tracking never waits for
//! it). Both have one lifecycle: `start`, `submit`, `poll`/`wait`, `is_idle`, `finish`.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

/// Work done on jobs, one at a time, beside tracking.
pub trait Stage: Send + 'static {
    /// What the stage is given.
    type Job: Send + 'static;
    /// What it hands back.
    type Output: Send + 'static;
    /// The thread's name.
    const NAME: &'static str;
    /// How much lower than tracking the thread runs (nice increment).
    const NICE: i32;

    /// Processes one job; what it yields comes back through [`Worker::poll`].
    fn process(&mut self, job: Self::Job, outputs: &mut Vec<Self::Output>);

    /// On a thread, whether a job still queued when a newer one waits is dropped for
    /// it, and what it yields then (`None`: every job is processed).
    fn skip(&self, _job: &Self::Job) -> Option<Self::Output> {
        None
    }

    /// On a thread: the count of jobs submitted and not yet finished (this one
    /// included), for a stage that works less when more wait.
    fn attach_pending(&mut self, _pending: Arc<AtomicUsize>) {}
}

/// Whether the helpers run inline or on their threads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Execution {
    /// Each job done at once on the caller's thread (deterministic).
    Inline,
    /// Each stage on its own thread (real time).
    Threads,
}

impl Execution {
    /// Inline when `deterministic`, else threads.
    pub fn of(deterministic: bool) -> Self {
        if deterministic {
            Self::Inline
        } else {
            Self::Threads
        }
    }
}

/// A stage running inline or on its thread.
pub struct Worker<S: Stage> {
    inner: Inner<S>,
    pending: Arc<AtomicUsize>,
}

enum Inner<S: Stage> {
    Inline {
        /// Shared with [`Submitter`]s; taken out by `finish`.
        stage: Arc<Mutex<Option<S>>>,
        done: Arc<Mutex<Vec<S::Output>>>,
    },
    Thread {
        jobs: Sender<S::Job>,
        outputs: Receiver<S::Output>,
        handle: JoinHandle<S>,
    },
}

/// A handle another stage submits jobs through (local mapping hands its keyframes to
/// place recognition): it processes at once when inline, else sends.
pub enum Submitter<S: Stage> {
    /// Processes each job at once.
    Inline {
        /// The stage.
        stage: Arc<Mutex<Option<S>>>,
        /// What it handed back.
        done: Arc<Mutex<Vec<S::Output>>>,
    },
    /// Sends each job to the stage's thread.
    Thread {
        /// The jobs' channel.
        jobs: Sender<S::Job>,
        /// Jobs sent and not yet done.
        pending: Arc<AtomicUsize>,
    },
}

impl<S: Stage> Submitter<S> {
    /// Hands `job` to the stage.
    pub fn submit(&mut self, job: S::Job) {
        match self {
            Self::Inline { stage, done } => process_inline(stage, done, job),
            Self::Thread { jobs, pending } => {
                pending.fetch_add(1, Ordering::SeqCst);
                // Fails only if the thread panicked, which `finish` reports.
                let _ = jobs.send(job);
            }
        }
    }
}

fn process_inline<S: Stage>(stage: &Mutex<Option<S>>, done: &Mutex<Vec<S::Output>>, job: S::Job) {
    let mut guard = stage.lock().expect("worker stage lock poisoned");
    if let Some(stage) = guard.as_mut() {
        let mut done = done.lock().expect("worker outputs lock poisoned");
        stage.process(job, &mut done);
    }
}

/// The thread's loop: each job in turn (the newest only, for a stage that skips).
fn serve<S: Stage>(
    mut stage: S,
    jobs: Receiver<S::Job>,
    outputs: Sender<S::Output>,
    pending: Arc<AtomicUsize>,
) -> S {
    crate::threads::lower_priority(S::NICE);
    let mut yielded = Vec::new();
    while let Ok(mut job) = jobs.recv() {
        while let Some(skipped) = stage.skip(&job) {
            let Ok(newer) = jobs.try_recv() else { break };
            pending.fetch_sub(1, Ordering::SeqCst);
            if outputs.send(skipped).is_err() {
                return stage;
            }
            job = newer;
        }
        stage.process(job, &mut yielded);
        pending.fetch_sub(1, Ordering::SeqCst);
        for output in yielded.drain(..) {
            if outputs.send(output).is_err() {
                return stage;
            }
        }
    }
    stage
}

impl<S: Stage> Worker<S> {
    /// Starts `stage` inline or on its thread.
    pub fn start(mut stage: S, execution: Execution) -> Self {
        let pending = Arc::new(AtomicUsize::new(0));
        let inner = match execution {
            Execution::Inline => Inner::Inline {
                stage: Arc::new(Mutex::new(Some(stage))),
                done: Arc::default(),
            },
            Execution::Threads => {
                stage.attach_pending(pending.clone());
                let (jobs, job_receiver) = channel::<S::Job>();
                let (output_sender, outputs) = channel::<S::Output>();
                let counter = pending.clone();
                let handle = std::thread::Builder::new()
                    .name(S::NAME.into())
                    .spawn(move || serve(stage, job_receiver, output_sender, counter))
                    .unwrap_or_else(|e| panic!("cannot start the {} thread: {e}", S::NAME));
                Inner::Thread {
                    jobs,
                    outputs,
                    handle,
                }
            }
        };
        Self { inner, pending }
    }

    /// A handle to submit jobs from elsewhere (see [`Submitter`]).
    pub fn submitter(&self) -> Submitter<S> {
        match &self.inner {
            Inner::Inline { stage, done } => Submitter::Inline {
                stage: stage.clone(),
                done: done.clone(),
            },
            Inner::Thread { jobs, .. } => Submitter::Thread {
                jobs: jobs.clone(),
                pending: self.pending.clone(),
            },
        }
    }

    /// Hands a job over (processed at once when inline).
    pub fn submit(&mut self, job: S::Job) {
        match &self.inner {
            Inner::Inline { stage, done } => process_inline(stage, done, job),
            Inner::Thread { jobs, .. } => {
                self.pending.fetch_add(1, Ordering::SeqCst);
                // Fails only if the thread panicked, which `finish` reports.
                let _ = jobs.send(job);
            }
        }
    }

    /// Whether every job handed over has been processed (always when inline).
    pub fn is_idle(&self) -> bool {
        self.pending.load(Ordering::SeqCst) == 0
    }

    /// Blocks until [`Worker::is_idle`] (at once when inline), or until its thread
    /// has ended (a panic, which [`Worker::finish`] reports).
    pub fn wait_idle(&self) {
        while !self.is_idle() {
            if let Inner::Thread { handle, .. } = &self.inner {
                if handle.is_finished() {
                    return;
                }
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// The outputs finished so far, without waiting.
    pub fn poll(&mut self) -> Vec<S::Output> {
        match &self.inner {
            Inner::Inline { done, .. } => {
                std::mem::take(&mut *done.lock().expect("worker outputs lock poisoned"))
            }
            Inner::Thread { outputs, .. } => outputs.try_iter().collect(),
        }
    }

    /// Waits up to `timeout` for the next output, then returns it with any others
    /// finished (at once when inline).
    pub fn wait(&mut self, timeout: Duration) -> Vec<S::Output> {
        match &self.inner {
            Inner::Inline { .. } => self.poll(),
            Inner::Thread { outputs, .. } => match outputs.recv_timeout(timeout) {
                Ok(first) => std::iter::once(first).chain(outputs.try_iter()).collect(),
                Err(_) => Vec::new(),
            },
        }
    }

    /// Waits for every job handed over (from here and from the [`Submitter`]s, which
    /// must be dropped first for a thread to end) and returns the stage with the
    /// outputs not yet polled.
    pub fn finish(self) -> (S, Vec<S::Output>) {
        match self.inner {
            Inner::Inline { stage, done } => {
                let stage = stage
                    .lock()
                    .expect("worker stage lock poisoned")
                    .take()
                    .expect("a worker's stage is taken once, by finish");
                let done = std::mem::take(&mut *done.lock().expect("worker outputs lock poisoned"));
                (stage, done)
            }
            Inner::Thread {
                jobs,
                outputs,
                handle,
            } => {
                drop(jobs);
                let stage = handle
                    .join()
                    .unwrap_or_else(|_| panic!("the {} thread panicked", S::NAME));
                (stage, outputs.try_iter().collect())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Doubles numbers slowly; with `newest_only`, a queued number gives way to a newer
    /// one and comes back negated.
    struct Doubler {
        newest_only: bool,
        seen_pending: Vec<usize>,
        pending: Option<Arc<AtomicUsize>>,
    }

    impl Stage for Doubler {
        type Job = i64;
        type Output = i64;
        const NAME: &'static str = "doubler";
        const NICE: i32 = 0;

        fn process(&mut self, job: i64, outputs: &mut Vec<i64>) {
            std::thread::sleep(Duration::from_millis(15));
            if let Some(p) = &self.pending {
                self.seen_pending.push(p.load(Ordering::SeqCst));
            }
            outputs.push(2 * job);
        }

        fn skip(&self, job: &i64) -> Option<i64> {
            self.newest_only.then_some(-job)
        }

        fn attach_pending(&mut self, pending: Arc<AtomicUsize>) {
            self.pending = Some(pending);
        }
    }

    fn doubler(newest_only: bool) -> Doubler {
        Doubler {
            newest_only,
            seen_pending: Vec::new(),
            pending: None,
        }
    }

    #[test]
    fn inline_and_thread_give_the_same_outputs_in_order() {
        for execution in [Execution::Inline, Execution::Threads] {
            let mut worker = Worker::start(doubler(false), execution);
            let mut submitter = worker.submitter();
            let mut outputs = Vec::new();
            for job in 0..5 {
                if job % 2 == 0 {
                    worker.submit(job);
                } else {
                    submitter.submit(job);
                }
                if execution == Execution::Inline {
                    assert!(worker.is_idle());
                }
                outputs.extend(worker.wait(Duration::from_secs(5)));
            }
            drop(submitter);
            let (stage, rest) = worker.finish();
            outputs.extend(rest);
            assert_eq!(outputs, vec![0, 2, 4, 6, 8], "{execution:?}");
            // On a thread the stage saw itself counted among the pending jobs.
            let expected = if execution == Execution::Threads {
                5
            } else {
                0
            };
            assert_eq!(stage.seen_pending.len(), expected);
            assert!(stage.seen_pending.iter().all(|&p| p >= 1));
        }
    }

    #[test]
    fn a_busy_thread_that_skips_processes_only_the_newest_waiting_job() {
        let mut worker = Worker::start(doubler(true), Execution::Threads);
        worker.submit(1);
        // Let the thread take job 1 before the others arrive.
        std::thread::sleep(Duration::from_millis(10));
        for job in [2, 3, 4] {
            worker.submit(job);
        }
        assert!(!worker.is_idle());
        let (_, outputs) = worker.finish();
        assert_eq!(outputs, vec![2, -2, -3, 8]);
    }

    #[test]
    fn waiting_for_idle_returns_once_every_job_is_done() {
        let mut worker = Worker::start(doubler(false), Execution::Threads);
        for job in 0..4 {
            worker.submit(job);
        }
        assert!(
            !worker.is_idle(),
            "four jobs of 15 ms each cannot be done yet"
        );
        worker.wait_idle();
        assert!(worker.is_idle());
        // Every job was processed before the wait returned: the stage saw each counted.
        let mut outputs = worker.poll();
        let (stage, rest) = worker.finish();
        outputs.extend(rest);
        assert_eq!(outputs, vec![0, 2, 4, 6]);
        assert_eq!(stage.seen_pending.len(), 4);
    }
}
