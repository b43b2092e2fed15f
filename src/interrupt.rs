//! Ctrl-C and SIGTERM: the first one asks long work to stop at the next frame and
//! write what it has (a run's trajectory so far, its report marked as stopped); the
//! work itself checks [`requested`]. A second one ends the process at once (exit
//! status 130). The handler only touches an atomic flag and `_exit`, both
//! async-signal-safe.

use std::sync::atomic::{AtomicBool, Ordering};

static REQUESTED: AtomicBool = AtomicBool::new(false);

#[cfg(unix)]
extern "C" fn on_signal(_: libc::c_int) {
    if REQUESTED.swap(true, Ordering::SeqCst) {
        // SAFETY: _exit is async-signal-safe and ends the process without unwinding.
        unsafe { libc::_exit(130) }
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
