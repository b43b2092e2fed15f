//! Thread priorities: the real-time mode keeps tracking ahead of its helpers by giving
//! the local mapping and detection threads a higher nice value (lower priority), so on
//! a machine with few cores they use the time tracking leaves. And a rayon pool that a
//! pass's own thread works in ([`join_own_pool`]).

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

/// Threads in a pass's own pool (one a core, the calling thread among them): at most
/// this many.
const MAX_POOL_THREADS: usize = 8;

thread_local! {
    /// The pool the calling thread works in (kept alive with the thread).
    static OWN_POOL: std::cell::OnceCell<Option<rayon::ThreadPool>> =
        const { std::cell::OnceCell::new() };
}

/// Makes the calling thread a worker of a rayon pool of its own (one thread a core,
/// itself included), once per thread and for the thread's life; a thread that already
/// works in a pool stays in it.
///
/// Tracking calls rayon from its own thread on every frame (ORB extraction over the
/// pyramid levels). From outside a pool, that thread hands the levels to the global
/// pool and sleeps until they are done, so every frame waits for workers to wake.
/// With nothing keeping the second core busy (a frozen map: no local mapping), that
/// made extraction about 1.7 ms (30 %) slower a frame on average. As a worker, the
/// tracking thread starts on the levels itself at once and the others take what is
/// left (docs/design.md, "Tracking's own thread pool").
pub fn join_own_pool() {
    if rayon::current_thread_index().is_some() {
        return;
    }
    OWN_POOL.with(|own| {
        own.get_or_init(|| {
            let threads = std::thread::available_parallelism()
                .map_or(2, |n| n.get())
                .clamp(2, MAX_POOL_THREADS);
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .thread_name(|k| format!("dopslam-pass-{k}"))
                .use_current_thread()
                .build()
                .ok()
        });
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn a_thread_joins_a_pool_of_its_own_once_and_works_in_it() {
        std::thread::spawn(|| {
            assert_eq!(rayon::current_thread_index(), None);
            join_own_pool();
            assert_eq!(rayon::current_thread_index(), Some(0));
            let threads = rayon::current_num_threads();
            assert!((2..=MAX_POOL_THREADS).contains(&threads));
            join_own_pool();
            assert_eq!(rayon::current_num_threads(), threads);
            // Work split over the pool runs, some of it on this thread (index 0).
            let on: Vec<Option<usize>> = (0..64)
                .into_par_iter()
                .map(|_| rayon::current_thread_index())
                .collect();
            assert!(on.iter().all(|i| i.is_some_and(|i| i < threads)));
            assert!(on.contains(&Some(0)));
        })
        .join()
        .unwrap();
    }

    #[test]
    fn a_worker_of_another_pool_stays_in_it() {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .unwrap();
        pool.install(|| {
            join_own_pool();
            assert_eq!(rayon::current_num_threads(), 3);
        });
    }
}
