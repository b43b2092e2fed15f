//! Thread priorities: the real-time mode keeps tracking ahead of its helpers by giving
//! the local mapping and detection threads a higher nice value (lower priority), so on
//! a machine with few cores they use the time tracking leaves.

/// Raises the calling thread's nice value by `increment` (Linux applies
/// `setpriority(PRIO_PROCESS, 0, ..)` to the calling thread only). Failure is harmless
/// and ignored: the thread just keeps its priority.
pub fn lower_priority(increment: i32) {
    #[cfg(target_os = "linux")]
    // SAFETY: getpriority/setpriority take no pointers; they only read and set the
    // calling thread's scheduling priority.
    unsafe {
        let current = libc::getpriority(libc::PRIO_PROCESS, 0);
        libc::setpriority(libc::PRIO_PROCESS, 0, current + increment);
    }
    #[cfg(not(target_os = "linux"))]
    let _ = increment;
}
