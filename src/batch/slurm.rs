//! `dopslam batch MANIFEST --slurm`: a Slurm job array over the batch's shards and a
//! collection job that depends on it.
//!
//! `OUT/slurm/array.sbatch` runs `dopslam batch MANIFEST --out OUT --shard
//! $SLURM_ARRAY_TASK_ID/N` as array task K of `--array=1-N` (`%K` with
//! `--max-parallel`); `OUT/slurm/collect.sbatch` runs `--collect` once the array ends
//! (`--dependency=afterany:<array job>`). Each task's resources come from the
//! manifest: `cores_per_run` CPUs and `memory_per_run_gib` memory, one run at a time.
//! The output folder must be on a file system every node sees. A task that Slurm
//! stops (`scancel`, its time limit: SIGTERM) leaves its unfinished runs unfinished,
//! as Ctrl-C does; submitting again runs only those.

use std::path::{Path, PathBuf};
use std::process::Command;

use super::{BatchError, BatchPlan};
use crate::io::atomic::write_atomic;

/// What `--slurm` was asked for.
#[derive(Debug, Clone, Default)]
pub struct SlurmOptions {
    /// `--partition`.
    pub partition: Option<String>,
    /// `--time` of each task, in Slurm's format (`2:00:00`, `1-0`).
    pub time: Option<String>,
    /// Default: the manifest's `cores_per_run`.
    pub cpus_per_task: Option<usize>,
    /// Default: the manifest's `memory_per_run_gib`, in Slurm's format (`4G`, `3500M`).
    pub mem: Option<String>,
    /// Array tasks running at a time (`--array=1-N%K`).
    pub max_parallel: Option<usize>,
    /// Array tasks (shards). Default: one per run, at most 1000.
    pub shards: Option<usize>,
}

/// The scripts written, and the shard count they use.
#[derive(Debug, Clone)]
pub struct SlurmScripts {
    /// The array job's script.
    pub array: PathBuf,
    /// The collection job's script.
    pub collect: PathBuf,
    /// Array tasks.
    pub shards: usize,
}

/// A path or word quoted for bash.
fn quote(text: &str) -> String {
    format!("'{}'", text.replace('\'', r"'\''"))
}

/// What Slurm, or an option for it, refused.
#[derive(Debug, thiserror::Error)]
pub enum SlurmError {
    /// A value with blanks or `#`, which would end its `#SBATCH` line.
    #[error("--{option} {value:?}: not a Slurm value (no blanks or '#')")]
    Value {
        /// The option.
        option: &'static str,
        /// Its value.
        value: String,
    },
    #[error("--shards and --max-parallel must be at least 1")]
    /// `--shards` or `--max-parallel` is 0.
    Zero,
    #[error("cannot run sbatch ({0}): is Slurm installed and on the PATH? The scripts are written; submit them by hand")]
    /// `sbatch` cannot be run.
    NoSbatch(std::io::Error),
    #[error("sbatch {arguments} failed: {stderr}")]
    /// `sbatch` refused a script.
    Refused {
        /// sbatch's arguments.
        arguments: String,
        /// What it printed.
        stderr: String,
    },
    #[error("sbatch printed no job id: {0:?}")]
    /// `sbatch` printed no job id.
    NoJobId(String),
}

/// A value for an `#SBATCH` line: no newlines or blanks that would end the line.
fn checked(option: &'static str, value: &str) -> Result<String, SlurmError> {
    if value.is_empty() || value.chars().any(|c| c.is_whitespace() || c == '#') {
        return Err(SlurmError::Value {
            option,
            value: value.to_string(),
        });
    }
    Ok(value.to_string())
}

/// Writes `OUT/slurm/array.sbatch` and `OUT/slurm/collect.sbatch` for the batch of
/// `manifest` (see the module doc); `program` is the `dopslam` the tasks start.
pub fn write_scripts(
    plan: &BatchPlan,
    manifest: &Path,
    program: &Path,
    options: &SlurmOptions,
) -> Result<SlurmScripts, BatchError> {
    let batch = &plan.manifest.batch;
    let shards = options.shards.unwrap_or(plan.runs.len().min(1000)).max(1);
    if options.shards == Some(0) || options.max_parallel == Some(0) {
        return Err(SlurmError::Zero.into());
    }
    let cpus = options.cpus_per_task.unwrap_or(batch.cores_per_run).max(1);
    let mem = match &options.mem {
        Some(mem) => checked("mem", mem)?,
        None => format!("{}M", (batch.memory_per_run_gib * 1024.0).ceil() as u64),
    };
    let dir = plan.out.join("slurm");
    let logs = dir.join("logs");
    std::fs::create_dir_all(&logs).map_err(BatchError::file("create", &logs))?;
    let name = manifest
        .file_stem()
        .map_or("batch".into(), |s| s.to_string_lossy().into_owned());
    let name = checked("job-name", &name.replace(char::is_whitespace, "_"))?;
    let manifest = super::manifest::absolute(manifest);
    let common = |job: &str| -> Result<String, SlurmError> {
        let mut lines = vec![
            "#!/bin/bash".to_string(),
            format!("#SBATCH --job-name=dopslam-{name}{job}"),
        ];
        if let Some(p) = &options.partition {
            lines.push(format!("#SBATCH --partition={}", checked("partition", p)?));
        }
        if let Some(t) = &options.time {
            lines.push(format!("#SBATCH --time={}", checked("time", t)?));
        }
        Ok(lines.join("\n"))
    };
    let invocation = format!(
        "{} batch {} --out {}",
        quote(&program.to_string_lossy()),
        quote(&manifest.to_string_lossy()),
        quote(&plan.out.to_string_lossy())
    );
    let throttle = options
        .max_parallel
        .map(|k| format!("%{k}"))
        .unwrap_or_default();
    let array_text = format!(
        "{}\n#SBATCH --array=1-{shards}{throttle}\n#SBATCH --cpus-per-task={cpus}\n#SBATCH --mem={mem}\n#SBATCH --output={}\n\
         # One shard of the batch per array task (dopslam batch --shard K/{shards}); written by dopslam batch --slurm.\n\
         exec {invocation} --shard \"$SLURM_ARRAY_TASK_ID/{shards}\" --jobs 1 --quiet\n",
        common("")?,
        logs.join("shard-%a.out").display(),
    );
    let collect_text = format!(
        "{}\n#SBATCH --cpus-per-task=1\n#SBATCH --mem=2G\n#SBATCH --output={}\n\
         # The tables, plots and report from the finished runs, after the array (afterany).\n\
         exec {invocation} --collect --quiet\n",
        common("-collect")?,
        logs.join("collect.out").display(),
    );
    let scripts = SlurmScripts {
        array: dir.join("array.sbatch"),
        collect: dir.join("collect.sbatch"),
        shards,
    };
    write_atomic(&scripts.array, array_text.as_bytes())?;
    write_atomic(&scripts.collect, collect_text.as_bytes())?;
    Ok(scripts)
}

/// The job id `sbatch --parsable` printed (`123` or `123;cluster`).
fn job_id(stdout: &str) -> Option<String> {
    let id = stdout.trim().split(';').next()?.trim();
    (!id.is_empty() && id.chars().all(|c| c.is_ascii_digit())).then(|| id.to_string())
}

/// Submits the array, then the collection job depending on it: their job ids.
pub fn submit(scripts: &SlurmScripts) -> Result<(String, String), SlurmError> {
    let sbatch = |args: &[&str]| -> Result<String, SlurmError> {
        let output = Command::new("sbatch")
            .arg("--parsable")
            .args(args)
            .output()
            .map_err(SlurmError::NoSbatch)?;
        let stdout = String::from_utf8_lossy(&output.stdout);
        if !output.status.success() {
            return Err(SlurmError::Refused {
                arguments: args.join(" "),
                stderr: String::from_utf8_lossy(&output.stderr).trim().to_string(),
            });
        }
        job_id(&stdout).ok_or_else(|| SlurmError::NoJobId(stdout.to_string()))
    };
    let array = sbatch(&[&scripts.array.to_string_lossy()])?;
    let collect = sbatch(&[
        &format!("--dependency=afterany:{array}"),
        &scripts.collect.to_string_lossy(),
    ])?;
    Ok((array, collect))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn job_ids_and_quoting() {
        assert_eq!(job_id("123\n"), Some("123".into()));
        assert_eq!(job_id("77;cluster\n"), Some("77".into()));
        assert_eq!(job_id("Submitted batch job 5\n"), None);
        assert_eq!(quote("/a b/it's"), r"'/a b/it'\''s'");
        assert!(checked("partition", "gpu debug").is_err());
        assert!(checked("time", "2:00:00").is_ok());
    }
}
