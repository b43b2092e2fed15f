//! The [`Logger`] that writes a run's recording ([`super::entry`]) on its own
//! thread. The tracking thread only sends: the queue is bounded
//! (`[output] rerun_queue`), and when the logging thread falls behind, images are
//! dropped (counted, and said at the end) while poses and everything else wait for
//! room.

use std::path::Path;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TrySendError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

pub use super::entry::VIEWER_PATIENCE;
use super::entry::{At, Entry, Message, Target};
use super::{OutputConfig, ViewError};

enum Command {
    Log(Box<Message>),
    Stop,
}

/// What a finished recording says about itself.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LogSummary {
    /// Entries logged.
    pub logged: usize,
    /// Images dropped because the logging thread fell behind.
    pub dropped_images: usize,
    /// Whether a viewer stopped taking the recording, so that its end (what the queue
    /// and the SDK still held) was not delivered: given up after [`VIEWER_PATIENCE`],
    /// so that a stalled viewer never holds the run.
    pub viewer_stalled: bool,
    /// Entries given up on before they were queued, once the viewer had stalled.
    pub undelivered: usize,
}

impl LogSummary {
    /// What a user must be told of the recording to `target`: a viewer that stopped
    /// taking it, or images dropped when logging fell behind.
    pub fn warning(&self, target: &Target) -> Option<String> {
        let name = target.name();
        if self.viewer_stalled {
            Some(format!(
                "the Rerun viewer at {name} stopped taking the recording (given up after {} s): the end of the recording was not delivered ({} entries given up on, and what was queued); the run's files are complete",
                VIEWER_PATIENCE.as_secs(),
                self.undelivered,
            ))
        } else if self.dropped_images > 0 {
            Some(format!(
                "the Rerun recording fell behind the run and dropped {} image(s) ({name}); poses and everything else are complete",
                self.dropped_images
            ))
        } else {
            None
        }
    }
}

/// Whether a streamed recording gave up on its viewer, how many entries that cost, and
/// how many the logging thread has handed to the SDK (its progress: a slow viewer that
/// takes entries is waited for, one that takes nothing is not).
#[derive(Default)]
struct Stall {
    stalled: AtomicBool,
    undelivered: AtomicUsize,
    handed: AtomicUsize,
}

impl Stall {
    fn give_up(&self) {
        self.stalled.store(true, Ordering::Relaxed);
        self.undelivered.fetch_add(1, Ordering::Relaxed);
    }

    /// Waits while `pending()` holds, until [`VIEWER_PATIENCE`] passes without
    /// progress; whether it still holds then.
    fn wait_while(&self, mut pending: impl FnMut() -> bool) -> bool {
        let mut seen = self.handed.load(Ordering::Relaxed);
        let mut since = Instant::now();
        while pending() {
            let now = self.handed.load(Ordering::Relaxed);
            if now != seen {
                (seen, since) = (now, Instant::now());
            } else if since.elapsed() >= VIEWER_PATIENCE {
                return true;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        false
    }
}

/// A cloneable way to log into a [`Logger`]'s recording.
#[derive(Clone)]
pub struct LogHandle {
    sender: SyncSender<Command>,
    dropped: Arc<AtomicUsize>,
    /// Images are dropped when the queue is full (a run), or wait (`dopslam view`).
    drops_images: bool,
    /// For a viewer ([`Target::Connect`]): anything waits for room at most
    /// [`VIEWER_PATIENCE`] without progress before the viewer is given up on; for a
    /// file, as long as it takes.
    viewer: bool,
    stall: Arc<Stall>,
    /// The `[output]` settings.
    pub config: Arc<OutputConfig>,
}

impl std::fmt::Debug for LogHandle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("LogHandle")
    }
}

impl LogHandle {
    /// Logs `entry` under `prefix` at `at`. An image is dropped when the queue is
    /// full; anything else waits for room. A recording whose thread stopped (its
    /// error is reported by [`Logger::finish`]) takes nothing more.
    pub fn log(&self, prefix: impl Into<std::borrow::Cow<'static, str>>, at: At, entry: Entry) {
        let prefix = prefix.into();
        let command = Command::Log(Box::new(Message { prefix, at, entry }));
        let droppable =
            self.drops_images && matches!(&command, Command::Log(m) if m.entry.droppable());
        if droppable {
            if let Err(TrySendError::Full(_)) = self.sender.try_send(command) {
                self.dropped.fetch_add(1, Ordering::Relaxed);
            }
        } else {
            self.send_waiting(command);
        }
    }

    /// Sends `command`, waiting for room: as long as it takes for a file; for a viewer,
    /// until [`VIEWER_PATIENCE`] passes without progress, then the viewer is given up on
    /// (this and all later entries counted as undelivered).
    fn send_waiting(&self, command: Command) {
        if !self.viewer {
            let _ = self.sender.send(command);
            return;
        }
        if self.stall.stalled.load(Ordering::Relaxed) {
            self.stall.undelivered.fetch_add(1, Ordering::Relaxed);
            return;
        }
        let mut command = Some(command);
        let full =
            self.stall.wait_while(
                || match self.sender.try_send(command.take().expect("held")) {
                    Err(TrySendError::Full(back)) => {
                        command = Some(back);
                        true
                    }
                    _ => false,
                },
            );
        if full {
            self.stall.give_up();
        }
    }
}

/// The recording and its logging thread. Dropped without [`Logger::finish`] (a run
/// that stopped on an error), it still writes what was queued and closes the file.
pub struct Logger {
    handle: LogHandle,
    thread: Option<JoinHandle<Result<(usize, bool), ViewError>>>,
    /// Where the recording goes.
    pub target: Target,
}

impl std::fmt::Debug for Logger {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Logger({:?})", self.target)
    }
}

impl Drop for Logger {
    fn drop(&mut self) {
        if self.thread.is_none() {
            return;
        }
        match self.close() {
            Err(e) => eprintln!("warning: {e}"),
            Ok(summary) => {
                if let Some(warning) = summary.warning(&self.target) {
                    eprintln!("warning: {warning}");
                }
            }
        }
    }
}

impl Logger {
    /// Opens the recording: a file is created now (an error names it when it exists
    /// or cannot be written); a viewer that refuses the connection is an error the
    /// caller may turn into a warning. Without the `rerun` feature: an error saying so.
    pub fn open(
        target: Target,
        config: &OutputConfig,
        name: &'static str,
    ) -> Result<Self, ViewError> {
        if !super::AVAILABLE {
            return Err(ViewError::NotBuilt);
        }
        if let Target::File(path) = &target {
            check_new_file(path)?;
        }
        let stream = super::entities::open_stream(&target, name)?;
        let (sender, receiver) = sync_channel(config.rerun_queue);
        let settings = config.clone();
        let viewer = matches!(target, Target::Connect(_));
        let stall = Arc::new(Stall::default());
        let progress = Arc::clone(&stall);
        let thread = std::thread::Builder::new()
            .name("rerun-log".into())
            .spawn(move || write_all(stream, receiver, &settings, &progress.handed))
            .map_err(|e| ViewError::Thread(format!("cannot start: {e}")))?;
        Ok(Self {
            handle: LogHandle {
                sender,
                dropped: Arc::new(AtomicUsize::new(0)),
                drops_images: true,
                viewer,
                stall,
                config: Arc::new(config.clone()),
            },
            thread: Some(thread),
            target,
        })
    }

    /// A handle that drops images when the logging thread falls behind (a run).
    pub fn handle(&self) -> LogHandle {
        self.handle.clone()
    }

    /// A handle whose images wait for room like everything else (`dopslam view`,
    /// which has no real time to keep).
    pub fn waiting_handle(&self) -> LogHandle {
        LogHandle {
            drops_images: false,
            ..self.handle.clone()
        }
    }

    /// Writes what is queued, closes the recording and says what it held.
    pub fn finish(mut self) -> Result<LogSummary, ViewError> {
        self.close()
    }

    fn close(&mut self) -> Result<LogSummary, ViewError> {
        let Some(thread) = self.thread.take() else {
            return Err(ViewError::Closed);
        };
        self.handle.send_waiting(Command::Stop);
        let dropped_images = self.handle.dropped.load(Ordering::Relaxed);
        let undelivered = || self.handle.stall.undelivered.load(Ordering::Relaxed);
        // A viewer that takes nothing holds the logging thread in its send: it is left
        // behind (the process ends it), and what it still held is not delivered.
        if self.handle.viewer && self.handle.stall.wait_while(|| !thread.is_finished()) {
            return Ok(LogSummary {
                logged: 0,
                dropped_images,
                viewer_stalled: true,
                undelivered: undelivered(),
            });
        }
        let (logged, delivered) = thread
            .join()
            .map_err(|_| ViewError::Thread("panicked".into()))??;
        Ok(LogSummary {
            logged,
            dropped_images,
            viewer_stalled: !delivered || self.handle.stall.stalled.load(Ordering::Relaxed),
            undelivered: undelivered(),
        })
    }
}

/// A recording file is made new next to nothing the user has: an existing file is an
/// error, and so is a folder that cannot be written (checked by creating the file).
fn check_new_file(path: &Path) -> Result<(), ViewError> {
    if path.exists() {
        return Err(ViewError::Exists(path.to_path_buf()));
    }
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|error| ViewError::Folder {
            path: path.to_path_buf(),
            folder: parent.to_path_buf(),
            error,
        })?;
    }
    std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(path)
        .map(drop)
        .map_err(|error| ViewError::Create {
            path: path.to_path_buf(),
            error: error.to_string(),
        })
}

/// The logging thread: logs each message until told to stop (or every sender is
/// gone), then flushes. Returns how many entries it logged, and whether the flush
/// delivered them (a viewer may stop taking them).
fn write_all(
    stream: super::entities::Stream,
    receiver: Receiver<Command>,
    config: &OutputConfig,
    handed: &AtomicUsize,
) -> Result<(usize, bool), ViewError> {
    let mut logged = 0;
    while let Ok(Command::Log(message)) = receiver.recv() {
        stream.log(&message, config)?;
        logged += 1;
        handed.fetch_add(1, Ordering::Relaxed);
    }
    let delivered = stream.close()?;
    Ok((logged, delivered))
}

#[cfg(all(test, feature = "rerun"))]
mod tests {
    use super::*;
    use crate::view::entry::At;

    /// A queue of one: images sent faster than they are encoded are dropped and
    /// counted, poses never are, and what was logged plus what was dropped is all
    /// that was sent.
    #[test]
    fn behind_it_drops_images_only_and_counts_them() {
        let dir = std::env::temp_dir().join(format!("dopslam-rerun-log-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let path = dir.join("t.rrd");
        let config = OutputConfig {
            rerun_queue: 1,
            rerun_image_scale: 1.0,
            ..OutputConfig::default()
        };
        let logger = Logger::open(Target::File(path.clone()), &config, "test").unwrap();
        let log = logger.handle();
        let image = image::RgbImage::from_pixel(640, 480, image::Rgb([90, 120, 200]));
        let (images, poses) = (60, 60);
        for index in 0..images.max(poses) {
            let at = At::Frame {
                index,
                seconds: index as f64 / 30.0,
            };
            log.log("", at, Entry::Image(image.clone()));
            let world_from_camera = crate::geometry::se3::Se3::identity();
            log.log("", at, Entry::Camera { world_from_camera });
        }
        drop(log);
        let summary = logger.finish().unwrap();
        assert!(summary.dropped_images > 0, "{summary:?}");
        assert_eq!(summary.logged + summary.dropped_images, images + poses);
        assert!(summary.logged >= poses);
        assert!(std::fs::metadata(&path).unwrap().len() > 0);
        // The file exists now: a second recording there is refused.
        let again = Logger::open(Target::File(path), &config, "test")
            .err()
            .unwrap();
        assert!(matches!(again, ViewError::Exists(_)), "{again}");
        assert!(again.to_string().contains("exists"), "{again}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
