//! The process's peak memory, for the run report and the long-run benchmark
//! (`tools/bench_memory.sh`).

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

    #[test]
    #[cfg(target_os = "linux")]
    fn this_process_has_a_peak() {
        assert!(peak_resident_mib().is_some_and(|m| m > 0.0));
    }
}
