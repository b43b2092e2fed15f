//! Ctrl-C and SIGTERM: the first one asks long work to stop at the next frame and
//! write what it has (a run's trajectory so far, its report marked as stopped); the
//! work itself checks [`requested`]. A second one ends the process at once (exit
//! status 130), except while outputs are being written ([`Writing`]): then it ends
//! the process as soon as the writing is done, so that no half-written set of outputs
//! and no temporary file is left behind. The handler only touches atomics and
//! `_exit`, all async-signal-safe.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);
/// Outputs being written (nested sections count).
static WRITING: AtomicUsize = AtomicUsize::new(0);
/// A second signal came while outputs were being written.
static EXIT_AFTER_WRITING: AtomicBool = AtomicBool::new(false);

#[cfg(unix)]
extern "C" fn on_signal(_: libc::c_int) {
    if REQUESTED.swap(true, Ordering::SeqCst) {
        if WRITING.load(Ordering::SeqCst) > 0 {
            EXIT_AFTER_WRITING.store(true, Ordering::SeqCst);
            return;
        }
        // SAFETY: _exit is async-signal-safe and ends the process without unwinding.
        unsafe { libc::_exit(130) }
    }
}

/// While alive, a second Ctrl-C waits for the outputs being written (see the module
/// doc): `let _writing = Writing::start();` around a set of files that belong together.
pub struct Writing(());

impl Writing {
    /// Marks the start of a set of files written together.
    pub fn start() -> Self {
        WRITING.fetch_add(1, Ordering::SeqCst);
        Writing(())
    }
}

impl Drop for Writing {
    fn drop(&mut self) {
        if WRITING.fetch_sub(1, Ordering::SeqCst) == 1 && EXIT_AFTER_WRITING.load(Ordering::SeqCst)
        {
            // SAFETY: as in the handler; the outputs are complete.
            unsafe { libc::_exit(130) }
        }
    }
}

/// Routes SIGINT and SIGTERM to the flag (the command line calls this for the
/// commands that check it: `run` and `fuse`).
pub fn install() {
    #[cfg(unix)]
    // SAFETY: the handler only stores into an atomic, which is async-signal-safe;
    // `signal` takes the handler's address, valid for the program's life.
    unsafe {
        let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
    }
}

/// Whether a stop was asked for.
pub fn requested() -> bool {
    REQUESTED.load(Ordering::SeqCst)
}

/// The message for work that stopped on a signal.
pub const MESSAGE: &str = "interrupted (SIGINT/SIGTERM): stopped early";
