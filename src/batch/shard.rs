//! Batches over several machines: `--shard K/N` runs one part of a batch into the
//! shared output folder, `--collect` makes the tables from what all parts finished.
//!
//! The partition is stable: the runs are ordered by their key (sequence name, mode,
//! repetition), which does not depend on the order the manifest lists its sequences in,
//! and run \(i\) of that order goes to shard \((i \bmod N) + 1\). Every run is in exactly
//! one shard, and the shards' sizes differ by at most one. A run that loads another
//! batch run's map (`map_from`) takes the key of the first run of its chain, so a chain
//! is one unit of the partition and stays in one shard (sizes then differ by at most a
//! chain).
//!
//! Synthetic sequences are generated once, whatever the number of shards that start
//! together: a shard takes an exclusive `flock` on `sequences/<name>.lock`, generates
//! into a folder of its own and renames it into place; the others wait on the lock and
//! then find the folder there. A lock dies with its process, so a killed shard leaves
//! no stale lock, and never a half-written sequence.

use std::path::Path;

use super::execute::RunJob;
use super::manifest::{root_sequence, PlannedSequence};
use super::BatchError;

/// Part `index` (1-based) of `count`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// K, from 1.
    pub index: usize,
    /// N.
    pub count: usize,
}

/// A `--shard` value that is not `K/N` with 1 <= K <= N.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("--shard {0:?}: expected K/N with 1 <= K <= N (as Slurm's $SLURM_ARRAY_TASK_ID/N with --array=1-N)")]
pub struct BadShard(pub String);

impl std::str::FromStr for Shard {
    type Err = BadShard;

    /// `K/N` with 1 <= K <= N.
    fn from_str(text: &str) -> Result<Self, BadShard> {
        let parsed = text.split_once('/').and_then(|(k, n)| {
            Some((
                k.trim().parse::<usize>().ok()?,
                n.trim().parse::<usize>().ok()?,
            ))
        });
        match parsed {
            Some((index, count)) if count >= 1 && (1..=count).contains(&index) => {
                Ok(Self { index, count })
            }
            _ => Err(BadShard(text.to_string())),
        }
    }
}

impl std::fmt::Display for Shard {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

/// The key that orders runs for the partition: the run's own, or for a run that loads
/// another batch run's map (`map_from`), that of the run at the head of its chain, so
/// that the runs of a chain go to one shard.
fn key(job: &RunJob, planned: &[PlannedSequence]) -> (String, &'static str, usize) {
    let head = root_sequence(planned, job.sequence).unwrap_or(job.sequence);
    (planned[head].name.clone(), job.mode.name(), job.repetition)
}

/// The runs of `shard` among `runs` (see the module doc), in the batch's own order.
pub fn select(runs: &[RunJob], planned: &[PlannedSequence], shard: Shard) -> Vec<RunJob> {
    let keys: Vec<_> = runs.iter().map(|job| key(job, planned)).collect();
    let mut order: Vec<&(String, &str, usize)> = keys.iter().collect();
    order.sort();
    order.dedup();
    runs.iter()
        .zip(&keys)
        .filter(|(_, k)| {
            let rank = order.binary_search(k).unwrap_or(0);
            rank % shard.count + 1 == shard.index
        })
        .map(|(job, _)| job.clone())
        .collect()
}

/// Runs `make` once for the folder `dir` across processes: under an exclusive lock on
/// `dir` + `.lock`, and only when `dir` does not exist yet. `Ok(true)` when this call
/// made it.
pub fn once_per_folder(
    dir: &Path,
    make: impl FnOnce() -> Result<(), BatchError>,
) -> Result<bool, BatchError> {
    if dir.is_dir() {
        return Ok(false);
    }
    let lock_path = dir.with_extension("lock");
    if let Some(parent) = lock_path.parent() {
        std::fs::create_dir_all(parent).map_err(BatchError::file("create", parent))?;
    }
    // Held until this function returns: the lock goes with the file handle.
    let _lock = crate::io::output::lock_file(&lock_path, crate::io::output::LockMode::Wait)
        .map_err(BatchError::file("lock", &lock_path))?;
    // Made by another process while this one waited?
    if dir.is_dir() {
        return Ok(false);
    }
    make()?;
    Ok(true)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dop::Mode;
    use proptest::prelude::*;

    fn planned(names: &[&str]) -> Vec<PlannedSequence> {
        names
            .iter()
            .map(|n| PlannedSequence {
                name: n.to_string(),
                source: crate::batch::manifest::SequenceSource::Folder(n.into()),
                config: crate::config::Config::default(),
                modes: vec![Mode::Dop, Mode::Off, Mode::MaskBoxes],
                repetitions: 1,
                frames: None,
                map: None,
            })
            .collect()
    }

    fn runs(planned: &[PlannedSequence], repetitions: usize) -> Vec<RunJob> {
        let mut jobs = Vec::new();
        for r in 1..=repetitions {
            for (k, p) in planned.iter().enumerate() {
                for mode in [Mode::Dop, Mode::Off, Mode::MaskBoxes] {
                    jobs.push(RunJob {
                        sequence: k,
                        mode,
                        repetition: r,
                        dir: std::path::PathBuf::from(format!("{}/{}/{r}", p.name, mode.name())),
                        inputs: Default::default(),
                        map: None,
                    });
                }
            }
        }
        jobs
    }

    #[test]
    fn shards_parse_and_refuse_nonsense() {
        assert_eq!(
            "2/5".parse::<Shard>().unwrap(),
            Shard { index: 2, count: 5 }
        );
        for bad in ["0/3", "4/3", "1/0", "x/2", "2", "1/2/3", "-1/2"] {
            assert!(bad.parse::<Shard>().is_err(), "{bad}");
        }
    }

    proptest! {
        /// Every run in exactly one shard, sizes within one, for N = 1..7; the same
        /// shards when the manifest lists its sequences in another order.
        #[test]
        fn the_partition_covers_every_run_once_and_is_stable(
            count in 1usize..=7,
            sequences in 1usize..=6,
            repetitions in 1usize..=3,
            rotate in 0usize..6,
        ) {
            let names: Vec<String> = (0..sequences).map(|i| format!("seq{i}")).collect();
            let name_refs: Vec<&str> = names.iter().map(String::as_str).collect();
            let first = planned(&name_refs);
            let all = runs(&first, repetitions);
            let mut seen = std::collections::HashMap::new();
            let mut sizes = Vec::new();
            for index in 1..=count {
                let part = select(&all, &first, Shard { index, count });
                sizes.push(part.len());
                for job in part {
                    *seen.entry(job.dir).or_insert(0) += 1;
                }
            }
            prop_assert_eq!(seen.len(), all.len());
            prop_assert!(seen.values().all(|&n| n == 1));
            prop_assert!(sizes.iter().max().unwrap() - sizes.iter().min().unwrap() <= 1);
            // The same manifest with its sequences in another order.
            let mut reordered = name_refs.clone();
            reordered.rotate_left(rotate % sequences);
            reordered.reverse();
            let second = planned(&reordered);
            let other = runs(&second, repetitions);
            for index in 1..=count {
                let shard = Shard { index, count };
                let mut a: Vec<_> = select(&all, &first, shard).into_iter().map(|j| j.dir).collect();
                let mut b: Vec<_> = select(&other, &second, shard).into_iter().map(|j| j.dir).collect();
                a.sort();
                b.sort();
                prop_assert_eq!(a, b);
            }
        }
    }

    /// The runs of a `map_from` chain go to one shard: the later run needs the map the
    /// earlier one leaves.
    #[test]
    fn a_map_chain_stays_in_one_shard() {
        use crate::batch::manifest::{MapFrom, MapSource};
        let mut planned = planned(&["a", "b", "c", "d"]);
        for (k, from) in [(1, 0), (2, 1)] {
            planned[k].map = Some(MapSource {
                from: MapFrom::Sequence(from),
                frozen: false,
            });
        }
        let all = runs(&planned, 2);
        for count in 1..=4 {
            for index in 1..=count {
                let part = select(&all, &planned, Shard { index, count });
                for job in part.iter().filter(|j| j.sequence > 0 && j.sequence < 3) {
                    let head = (0, job.mode, job.repetition);
                    assert!(
                        part.iter()
                            .any(|j| (j.sequence, j.mode, j.repetition) == head),
                        "{count} shards: {:?} without its chain's head",
                        job.dir
                    );
                }
            }
        }
    }

    #[test]
    fn a_folder_is_made_once_by_concurrent_callers() {
        let base = std::env::temp_dir().join(format!("dopslam-once-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        std::fs::create_dir_all(&base).unwrap();
        let dir = base.join("sequence");
        let made = std::sync::atomic::AtomicUsize::new(0);
        std::thread::scope(|scope| {
            for _ in 0..4 {
                scope.spawn(|| {
                    once_per_folder(&dir, || {
                        made.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
                        std::thread::sleep(std::time::Duration::from_millis(50));
                        std::fs::create_dir(&dir).map_err(BatchError::file("create", &dir))
                    })
                    .unwrap();
                });
            }
        });
        assert_eq!(made.into_inner(), 1);
        std::fs::remove_dir_all(&base).unwrap();
    }
}
