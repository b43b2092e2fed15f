//! The process's peak memory, for the run report and the long-run benchmark
//! (`tools/bench_memory.sh`), and how the allocator keeps freed memory.

use std::sync::atomic::{AtomicU64, Ordering};

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

/// Hands the free pages inside the heap back to the system (glibc's `malloc_trim`), at
/// a boundary between stages: [`keep_freed_memory`] keeps what one stage freed for
/// the next frames, and a stage that allocates otherwise (the dense pass after
/// tracking) would add its own pages to those; and every few frames while the dense
/// pass fuses, as its blocks go to their spill files. Elsewhere it does nothing.
pub fn release_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only returns free memory; it takes the allocator's locks.
    unsafe {
        libc::malloc_trim(0);
    }
}

/// Allocations above this many bytes are mapped on their own (glibc's largest dynamic
/// threshold on 64-bit systems, 32 MiB).
pub const MMAP_THRESHOLD: i32 = 32 << 20;

/// Free memory above this many bytes at the heap's top goes back to the system.
pub const TRIM_THRESHOLD: i32 = 128 << 20;

/// The peak resident set size of the whole process so far in MiB (`VmHWM` of
/// `/proc/self/status`), where the system reports it (Linux).
pub fn peak_resident_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    parse_peak(&status)
}

/// How often the sampler reads the resident memory.
const SAMPLE_EVERY: std::time::Duration = std::time::Duration::from_millis(10);

/// The largest resident memory sampled since the last part or stage ended, and since
/// the last stage ended (bytes).
static PART_PEAK: AtomicU64 = AtomicU64::new(0);
static STAGE_PEAK: AtomicU64 = AtomicU64::new(0);

/// The resident memory now, bytes (`/proc/self/statm`), where the system reports it.
fn resident_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf only reads a constant of the system.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    Some(pages * u64::try_from(page).ok()?)
}

/// Records the resident memory now into the part's and the stage's peaks.
fn sample() -> Option<u64> {
    let bytes = resident_bytes()?;
    PART_PEAK.fetch_max(bytes, Ordering::Relaxed);
    STAGE_PEAK.fetch_max(bytes, Ordering::Relaxed);
    Some(bytes)
}

/// Starts the thread that samples the resident memory every [`SAMPLE_EVERY`] for
/// [`part_peak_mib`] and [`stage_peak_mib`] (once per process; later calls do
/// nothing). Sampling, not the kernel's high-water mark: resetting that
/// (`/proc/self/clear_refs`) would also reset what `/usr/bin/time` and `getrusage`
/// report for the whole process. A peak shorter than the interval can be missed.
pub fn start_sampling() {
    static STARTED: std::sync::Once = std::sync::Once::new();
    STARTED.call_once(|| {
        if sample().is_none() {
            return;
        }
        let _ = std::thread::Builder::new()
            .name("memory sampler".into())
            .spawn(|| loop {
                std::thread::sleep(SAMPLE_EVERY);
                sample();
            });
    });
}

/// The peak resident memory (MiB) sampled since the last part or stage ended, for a
/// part of a stage (the dense pass's fusion, mesh, cloud, files); the stage it belongs
/// to still sees it ([`stage_peak_mib`]). `None` where the system does not tell.
pub fn part_peak_mib() -> Option<f64> {
    let now = sample()?;
    let peak = PART_PEAK.swap(0, Ordering::Relaxed).max(now);
    Some(peak as f64 / MIB)
}

/// The peak resident memory (MiB) sampled since the last stage ended, its parts
/// included: a run's stages (tracking, global pass, outputs, dense pass) one after
/// another.
pub fn stage_peak_mib() -> Option<f64> {
    let now = sample()?;
    PART_PEAK.store(0, Ordering::Relaxed);
    let peak = STAGE_PEAK.swap(0, Ordering::Relaxed).max(now);
    Some(peak as f64 / MIB)
}

const MIB: f64 = 1024.0 * 1024.0;

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

    /// A part of a stage that holds 64 MiB: its peak is at least that, and the
    /// process's high-water mark no lower, within the kernel's counters' own slack
    /// (they are per-CPU and read approximately: a sample can read a little above
    /// `VmHWM`). Other tests run beside this one and may end a stage of their own, so
    /// nothing finer holds here.
    #[test]
    #[cfg(target_os = "linux")]
    fn a_part_s_peak_holds_what_it_held() {
        start_sampling();
        let held = std::hint::black_box(vec![1u8; 64 << 20]);
        let part = part_peak_mib().unwrap();
        drop(held);
        assert!(part >= 64.0, "part {part} MiB");
        assert!(stage_peak_mib().is_some());
        let high_water = peak_resident_mib().unwrap();
        assert!(
            high_water + 16.0 >= part,
            "VmHWM {high_water} MiB, part {part}"
        );
    }
}
