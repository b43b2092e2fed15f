//! The machine a batch runs on: how many runs fit at a time, and its description.

/// Runs at a time that the machine's cores and available memory allow (at least 1).
pub fn budget_jobs(cores_per_run: usize, memory_per_run_gib: f64) -> usize {
    let by_cores = cores() / cores_per_run.max(1);
    let by_memory =
        meminfo_gib("MemAvailable").map_or(usize::MAX, |m| (m / memory_per_run_gib) as usize);
    by_cores.min(by_memory).max(1)
}

/// A line of /proc/meminfo (`MemAvailable`, `MemTotal`), GiB.
fn meminfo_gib(key: &str) -> Option<f64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.split(':').next() == Some(key))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / (1024.0 * 1024.0))
}

fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The machine in one line: processor, cores, memory.
pub fn machine_description() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|t| {
            t.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    let memory = meminfo_gib("MemTotal")
        .map(|g| format!(", {g:.0} GiB"))
        .unwrap_or_default();
    format!("{cpu}, {} cores{memory}", cores())
}
