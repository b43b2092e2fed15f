//! Checks of where outputs go, made before any work: the folder can be written, it is
//! not an input (nor inside the input sequence), no other run writes into it (a lock
//! held for the run's life), and an earlier run's outputs there are moved aside
//! (`previous/`) so that nothing stale sits beside the new ones and nothing computed
//! is lost.

use std::path::{Component, Path, PathBuf};

use super::IoError;

/// The path as the file system will resolve it, also where its tail does not exist
/// yet: the nearest existing ancestor canonicalised, the rest appended.
pub fn resolved(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut existing = absolute.as_path();
    let mut rest = Vec::new();
    loop {
        if let Ok(real) = existing.canonicalize() {
            let mut out = real;
            for part in rest.iter().rev() {
                out.push(part);
            }
            return out;
        }
        match (existing.parent(), existing.components().next_back()) {
            (Some(parent), Some(Component::Normal(name))) => {
                rest.push(name.to_os_string());
                existing = parent;
            }
            _ => return absolute,
        }
    }
}

/// Whether `path` is `input` or inside it.
pub fn is_within(path: &Path, input: &Path) -> bool {
    resolved(path).starts_with(resolved(input))
}

fn invalid(path: &Path, message: impl Into<String>) -> IoError {
    IoError::invalid(path, message)
}

/// Makes `dir` ready for outputs before any work: refuses a file, a symlink loop, a
/// path that is not UTF-8, or a folder that is one of `inputs` or inside one; creates
/// it; writes and removes a probe file to prove it can be written.
pub fn prepare_dir(dir: &Path, what: &str, inputs: &[&Path]) -> Result<(), IoError> {
    if dir.to_str().is_none() {
        return Err(invalid(
            dir,
            format!("the {what} path is not valid UTF-8; choose a folder whose name is"),
        ));
    }
    for input in inputs {
        if is_within(dir, input) {
            return Err(invalid(
                dir,
                format!("the {what} folder is inside the input {}: dopslam never writes into its inputs; choose a folder elsewhere", input.display()),
            ));
        }
    }
    match std::fs::metadata(dir) {
        Ok(meta) if !meta.is_dir() => {
            return Err(invalid(
                dir,
                format!("the {what} path is a file, not a folder"),
            ))
        }
        Err(e) if e.raw_os_error() == Some(libc::ELOOP) => {
            return Err(invalid(
                dir,
                format!("the {what} path is a loop of symbolic links"),
            ))
        }
        _ => {}
    }
    std::fs::create_dir_all(dir).map_err(|e| {
        let why = if e.raw_os_error() == Some(libc::ELOOP) {
            "a loop of symbolic links".to_string()
        } else {
            e.to_string()
        };
        invalid(dir, format!("cannot create the {what} folder: {why}"))
    })?;
    let probe = dir.join(format!(".dopslam-write-test-{}", std::process::id()));
    std::fs::write(&probe, b"")
        .and_then(|_| std::fs::remove_file(&probe))
        .map_err(|e| invalid(dir, format!("the {what} folder cannot be written: {e}")))
}

/// Checks before any work that a file can be written at `path`: its folder can be
/// made and written, and it is none of `inputs`.
pub fn check_file(path: &Path, what: &str, inputs: &[&Path]) -> Result<(), IoError> {
    if inputs.iter().any(|input| resolved(path) == resolved(input)) {
        return Err(invalid(
            path,
            format!("the {what} would replace an input file"),
        ));
    }
    if path.is_dir() {
        return Err(invalid(path, format!("the {what} path is a folder")));
    }
    let parent = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    prepare_dir(parent, &format!("{what}'s"), &[])
}

/// An exclusive lock on `OUT/.dopslam.lock`, held while alive (released when the
/// process ends, however it ends).
#[derive(Debug)]
pub struct DirLock {
    _file: std::fs::File,
}

impl DirLock {
    /// Takes the lock or says that another process holds it.
    pub fn take(dir: &Path) -> Result<Self, IoError> {
        let path = dir.join(".dopslam.lock");
        match lock_file(&path, LockMode::Try) {
            Ok(Some(file)) => Ok(Self { _file: file }),
            Ok(None) => Err(invalid(
                dir,
                "another dopslam run is writing into this folder; wait for it or choose another --out",
            )),
            Err(e) => Err(invalid(&path, format!("cannot lock: {e}"))),
        }
    }
}

/// How [`lock_file`] takes its lock.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LockMode {
    /// Exclusive, waiting for another holder.
    Wait,
    /// Exclusive, `Ok(None)` while another holds it.
    Try,
    /// Shared with other shared holders, `Ok(None)` while an exclusive one holds it.
    TryShared,
}

/// Opens (creating) the file at `path` and locks it as `mode` says (`flock` on Unix:
/// the lock goes with the returned handle, and with the process however it ends).
pub fn lock_file(path: &Path, mode: LockMode) -> std::io::Result<Option<std::fs::File>> {
    let file = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(path)?;
    let taken = match mode {
        LockMode::Wait => {
            file.lock()?;
            return Ok(Some(file));
        }
        LockMode::Try => file.try_lock(),
        LockMode::TryShared => file.try_lock_shared(),
    };
    match taken {
        Ok(()) => Ok(Some(file)),
        Err(std::fs::TryLockError::WouldBlock) => Ok(None),
        Err(std::fs::TryLockError::Error(e)) => Err(e),
    }
}

pub use super::run_dir::RUN_OUTPUTS;

/// Refuses an output folder `dir` where one of `inputs` lies at the name of a run's
/// output or of `previous/` (a sequence at `OUT/detections` would be moved aside, or
/// written into, as if it were an output).
pub fn check_inputs_clear(dir: &Path, inputs: &[&Path]) -> Result<(), IoError> {
    let names = RUN_OUTPUTS.iter().chain([&super::run_dir::names::PREVIOUS]);
    for name in names {
        let place = dir.join(name);
        if let Some(input) = inputs.iter().find(|input| is_within(input, &place)) {
            return Err(invalid(
                input,
                format!("the input lies at {} in the output folder, where a run writes or moves its outputs; move it, or choose another output folder", place.display()),
            ));
        }
    }
    Ok(())
}

/// Moves an earlier run's outputs in `dir` into a folder of their own under
/// `dir/previous/`, named by when that run last wrote ([`utc_stamp`] of the newest
/// modification time among them; `-2`, `-3` … added when that name is taken). Nothing
/// is ever deleted: every earlier run stays, and files the tool did not write (a
/// user's `previous/notes.txt`) are not touched. Returns the names moved and the folder
/// they went to (`None` when there was nothing to move).
pub fn move_previous_outputs(
    dir: &Path,
    keep: &[&str],
) -> Result<(Vec<String>, Option<PathBuf>), IoError> {
    let present: Vec<&str> = RUN_OUTPUTS
        .iter()
        .copied()
        .filter(|name| !keep.contains(name) && dir.join(name).symlink_metadata().is_ok())
        .collect();
    if present.is_empty() {
        return Ok((Vec::new(), None));
    }
    let previous = dir.join(super::run_dir::names::PREVIOUS);
    if previous
        .symlink_metadata()
        .is_ok_and(|m| m.file_type().is_symlink())
    {
        return Err(invalid(
            &previous,
            "a symbolic link: earlier outputs are moved only into a real folder of the output folder (it could point into an input); make it a folder or move it",
        ));
    }
    let written = present
        .iter()
        .filter_map(|name| dir.join(name).symlink_metadata().ok()?.modified().ok())
        .max()
        .unwrap_or_else(std::time::SystemTime::now);
    let stamp = utc_stamp(written);
    let target = (1..)
        .map(|n| match n {
            1 => previous.join(&stamp),
            n => previous.join(format!("{stamp}-{n}")),
        })
        .find(|candidate| candidate.symlink_metadata().is_err())
        .expect("an unused name");
    std::fs::create_dir_all(&target).map_err(|e| invalid(&target, e.to_string()))?;
    for name in &present {
        std::fs::rename(dir.join(name), target.join(name)).map_err(|e| {
            invalid(
                &dir.join(name),
                format!("cannot move into {}: {e}", target.display()),
            )
        })?;
    }
    Ok((
        present.iter().map(|s| s.to_string()).collect(),
        Some(target),
    ))
}

/// A time as UTC `YYYY-MM-DDTHH-MM-SSZ` (dashes for colons: a valid folder name
/// everywhere). The date from the days since 1970-01-01 by the civil-calendar
/// arithmetic of eras of 400 years (146097 days).
pub fn utc_stamp(time: std::time::SystemTime) -> String {
    let seconds = time
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0);
    let (days, of_day) = (seconds.div_euclid(86_400), seconds.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let day_of_era = z - era * 146_097;
    let year_of_era =
        (day_of_era - day_of_era / 1460 + day_of_era / 36_524 - day_of_era / 146_096) / 365;
    let day_of_year = day_of_era - (365 * year_of_era + year_of_era / 4 - year_of_era / 100);
    let mp = (5 * day_of_year + 2) / 153;
    let day = day_of_year - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    let year = year_of_era + era * 400 + i64::from(month <= 2);
    format!(
        "{year:04}-{month:02}-{day:02}T{:02}-{:02}-{:02}Z",
        of_day / 3600,
        of_day % 3600 / 60,
        of_day % 60
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outputs_never_go_into_inputs_or_files() {
        let base = std::env::temp_dir().join(format!("dopslam-output-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        let input = base.join("seq");
        std::fs::create_dir_all(input.join("rgb")).unwrap();
        let error = prepare_dir(&input.join("rgb"), "debug frames", &[&input]).unwrap_err();
        assert!(error.to_string().contains("inside the input"), "{error}");
        assert!(!input.join("rgb/x").exists());
        std::fs::write(base.join("file"), b"x").unwrap();
        let error = prepare_dir(&base.join("file"), "output", &[]).unwrap_err();
        assert!(error.to_string().contains("is a file"), "{error}");
        prepare_dir(&base.join("out/sub"), "output", &[&input]).unwrap();
        assert!(base.join("out/sub").is_dir());
        let error = check_file(&input.join("rgb"), "picture", &[]).unwrap_err();
        assert!(error.to_string().contains("folder"), "{error}");
        std::fs::write(input.join("a.png"), b"x").unwrap();
        let error =
            check_file(&input.join("./a.png"), "picture", &[&input.join("a.png")]).unwrap_err();
        assert!(error.to_string().contains("replace an input"), "{error}");
        let lock = DirLock::take(&base.join("out")).unwrap();
        assert!(
            DirLock::take(&base.join("out")).is_err(),
            "a second lock is refused"
        );
        drop(lock);
        assert!(DirLock::take(&base.join("out")).is_ok());
        std::fs::write(base.join("out/trajectory.txt"), b"old").unwrap();
        std::fs::create_dir_all(base.join("out/plots")).unwrap();
        let (moved, to) = move_previous_outputs(&base.join("out"), &[]).unwrap();
        assert_eq!(
            moved,
            vec!["trajectory.txt".to_string(), "plots".to_string()]
        );
        let to = to.unwrap();
        assert_eq!(to.parent().unwrap(), base.join("out/previous"));
        assert_eq!(std::fs::read(to.join("trajectory.txt")).unwrap(), b"old");
        assert!(!base.join("out/trajectory.txt").exists());
        // A `previous` that links elsewhere (into an input, say) is refused, and an
        // input at the name of an output is named.
        std::fs::write(base.join("out/trajectory.txt"), b"old").unwrap();
        std::fs::rename(base.join("out/previous"), base.join("kept")).unwrap();
        std::os::unix::fs::symlink(&input, base.join("out/previous")).unwrap();
        let error = move_previous_outputs(&base.join("out"), &[]).unwrap_err();
        assert!(error.to_string().contains("a symbolic link"), "{error}");
        assert_eq!(
            std::fs::read_dir(&input).unwrap().count(),
            2,
            "nothing moved into it"
        );
        let seq = base.join("out/detections");
        std::fs::create_dir_all(&seq).unwrap();
        let error = check_inputs_clear(&base.join("out"), &[&seq]).unwrap_err();
        assert!(error.to_string().contains("the input lies at"), "{error}");
        // The link into the input is refused by that check too.
        let error = check_inputs_clear(&base.join("out"), &[&input]).unwrap_err();
        assert!(error.to_string().contains("out/previous"), "{error}");
        std::fs::remove_file(base.join("out/previous")).unwrap();
        check_inputs_clear(&base.join("out"), &[&input]).unwrap();
        std::fs::remove_dir_all(&base).unwrap();
    }

    /// A run, then a second, then a third into one folder: both earlier runs are kept,
    /// each in a folder of its own, and a user's file in `previous/` is untouched.
    #[test]
    fn earlier_runs_are_all_kept() {
        let base = std::env::temp_dir().join(format!("dopslam-previous-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&base);
        std::fs::create_dir_all(base.join("previous")).unwrap();
        std::fs::write(base.join("previous/notes.txt"), b"mine").unwrap();
        let mut kept = Vec::new();
        for run in ["first", "second", "third"] {
            let (_, to) = move_previous_outputs(&base, &[]).unwrap();
            kept.extend(to);
            std::fs::write(base.join("trajectory.txt"), run).unwrap();
            std::fs::write(base.join("report.json"), run).unwrap();
        }
        assert_eq!(kept.len(), 2, "{kept:?}");
        assert_ne!(kept[0], kept[1]);
        for (folder, run) in kept.iter().zip(["first", "second"]) {
            assert_eq!(
                std::fs::read_to_string(folder.join("trajectory.txt")).unwrap(),
                run
            );
            assert_eq!(
                std::fs::read_to_string(folder.join("report.json")).unwrap(),
                run
            );
        }
        assert_eq!(
            std::fs::read(base.join("previous/notes.txt")).unwrap(),
            b"mine"
        );
        assert_eq!(
            std::fs::read_to_string(base.join("trajectory.txt")).unwrap(),
            "third"
        );
        std::fs::remove_dir_all(&base).unwrap();
    }

    #[test]
    fn utc_stamps_follow_the_calendar() {
        let at = |s: u64| std::time::UNIX_EPOCH + std::time::Duration::from_secs(s);
        assert_eq!(utc_stamp(at(0)), "1970-01-01T00-00-00Z");
        assert_eq!(utc_stamp(at(951_782_400)), "2000-02-29T00-00-00Z");
        assert_eq!(utc_stamp(at(1_795_779_296)), "2026-11-27T11-34-56Z");
        assert_eq!(utc_stamp(at(4_107_542_399)), "2100-02-28T23-59-59Z");
    }
}
