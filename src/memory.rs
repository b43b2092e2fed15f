//! The process's peak memory, for the run report and the long-run benchmark
//! (`tools/bench_memory.sh`), and how the allocator keeps freed memory.

/// Where glibc's allocator hands memory back at once (its defaults), every frame's
/// images cost fresh pages: freeing a frame's megabytes trims the heap (or unmaps
/// them), and the next frame's touch faults them in again, zeroed by the kernel
/// (43 % of reading a ROS 2 SQLite bag, by `perf`). So allocations up to
/// [`MMAP_THRESHOLD`] come from the heap, and the heap keeps up to [`TRIM_THRESHOLD`]
/// free at its top; the peak memory stays what the frames need. A user's own
/// `MALLOC_MMAP_THRESHOLD_` or `MALLOC_TRIM_THRESHOLD_` is left as it is. Call before
/// any thread starts.
pub fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        let set_by_user = ["MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_"]
            .iter()
            .any(|name| std::env::var_os(name).is_some());
        if !set_by_user {
            // SAFETY: mallopt only sets two of the allocator's parameters; called
            // from `main` before any other thread exists.
            unsafe {
                libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD);
                libc::mallopt(libc::M_TRIM_THRESHOLD, TRIM_THRESHOLD);
            }
        }
    }
}

/// Allocations above this many bytes are mapped on their own (glibc's largest dynamic
/// threshold on 64-bit systems, 32 MiB).
pub const MMAP_THRESHOLD: i32 = 32 << 20;

/// Free memory above this many bytes at the heap's top goes back to the system.
pub const TRIM_THRESHOLD: i32 = 128 << 20;

/// The peak resident set size in MiB (`VmHWM` of `/proc/self/status`), where the
/// system reports it (Linux).
pub fn peak_resident_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    parse_peak(&status)
}

/// `VmHWM:  123456 kB` → MiB.
fn parse_peak(status: &str) -> Option<f64> {
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_the_high_water_mark() {
        let status =
            "Name:\tdopslam\nVmPeak:\t  900000 kB\nVmHWM:\t   204800 kB\nVmRSS:\t 1024 kB\n";
        assert_eq!(parse_peak(status), Some(200.0));
        assert_eq!(parse_peak("Name:\tx\n"), None);
        assert_eq!(parse_peak("VmHWM:\tlots kB\n"), None);
    }

    /// Page faults of this thread so far.
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn minor_faults() -> i64 {
        let mut usage = std::mem::MaybeUninit::<libc::rusage>::zeroed();
        // SAFETY: getrusage fills the struct it is given.
        let usage = unsafe {
            assert_eq!(libc::getrusage(libc::RUSAGE_THREAD, usage.as_mut_ptr()), 0);
            usage.assume_init()
        };
        usage.ru_minflt
    }

    #[test]
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    fn a_frame_freed_leaves_its_pages_to_the_next() {
        keep_freed_memory();
        // 24 MiB: above glibc's default mapping threshold (it rises to this size only
        // after a first such block is freed, and the heap is then trimmed at twice it).
        let bytes = 24 << 20;
        let frame = || std::hint::black_box(vec![1u8; bytes]);
        drop(frame());
        let before = minor_faults();
        drop(frame());
        let faults = minor_faults() - before;
        let pages = (bytes / 4096) as i64;
        assert!(
            faults < pages / 4,
            "{faults} page faults for a {pages}-page frame"
        );
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn this_process_has_a_peak() {
        assert!(peak_resident_mib().is_some_and(|m| m > 0.0));
    }
}
