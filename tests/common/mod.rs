//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The real reference data beside the checkout (`../shared/data`), or where
/// `DOPSLAM_SHARED_DATA` points. `None` (with a message saying why the test skips)
/// when it is absent.
pub fn shared_data(test: &str) -> Option<PathBuf> {
    let path = std::env::var_os("DOPSLAM_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if path.join("README.md").exists() {
        Some(path)
    } else {
        eprintln!(
            "skipping {test}: the shared reference data is not at {} (set DOPSLAM_SHARED_DATA)",
            path.display()
        );
        None
    }
}

/// The Python of the independent writers and readers the tests use (`DOPSLAM_TEST_PYTHON`,
/// else `data/venv`'s, which tools/test.sh fills) when it can import `modules`
/// (comma-separated); `None` (the test skips, saying why) otherwise, unless
/// `DOPSLAM_REQUIRE_RECORDING_WRITERS` is set (tools/test.sh sets it): then the test
/// fails.
pub fn test_python(test: &str, modules: &str) -> Option<PathBuf> {
    let python = std::env::var_os("DOPSLAM_TEST_PYTHON")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("data/venv/bin/python"));
    let ok = std::process::Command::new(&python)
        .args(["-c", &format!("import {modules}")])
        .output()
        .is_ok_and(|o| o.status.success());
    if ok {
        return Some(python);
    }
    let why = format!(
        "{} cannot import {modules} (tools/test.sh installs them)",
        python.display()
    );
    assert!(
        std::env::var_os("DOPSLAM_REQUIRE_RECORDING_WRITERS").is_none(),
        "{test}: {why}"
    );
    eprintln!("skipping {test}: {why}");
    None
}

/// A test's temporary folder: removed with everything in it when dropped (also when
/// the test fails), unless `DOPSLAM_KEEP_TEST_DIRS` is set. A whole run writes some
/// gigabytes of synthetic sequences; left behind they fill the disk of the next run.
/// It dereferences to the folder, or to the path inside it that [`TestDir::child`] chose.
#[must_use = "the folder is removed when this is dropped"]
pub struct TestDir {
    root: PathBuf,
    path: PathBuf,
}

impl TestDir {
    /// The same guard, dereferencing to `name` inside the folder (not created here).
    pub fn child(mut self, name: &str) -> TestDir {
        self.path = self.path.join(name);
        self
    }
}

impl std::ops::Deref for TestDir {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.path
    }
}

impl AsRef<Path> for TestDir {
    fn as_ref(&self) -> &Path {
        &self.path
    }
}

impl Drop for TestDir {
    fn drop(&mut self) {
        if std::env::var_os("DOPSLAM_KEEP_TEST_DIRS").is_none() {
            let _ = std::fs::remove_dir_all(&self.root);
        }
    }
}

/// A fresh, empty temporary folder for one test, removed when the returned guard drops.
pub fn temp_dir(name: &str) -> TestDir {
    let dir = std::env::temp_dir().join(format!("dopslam-it-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    TestDir {
        root: dir.clone(),
        path: dir,
    }
}

/// The files of a folder, sorted by name.
pub fn sorted_files(dir: &std::path::Path) -> Vec<PathBuf> {
    let mut names: Vec<PathBuf> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    names.sort();
    names
}

/// Runs the dopslam binary: `(success, stdout, stderr)`.
pub fn dopslam(args: &[&str]) -> (bool, String, String) {
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_dopslam"))
        .args(args)
        .output()
        .unwrap();
    (
        output.status.success(),
        String::from_utf8_lossy(&output.stdout).into_owned(),
        String::from_utf8_lossy(&output.stderr).into_owned(),
    )
}

/// Runs the dopslam binary as [`dopslam`] does, killed (and the test failed) when it has
/// not ended after `limit`: for what must not hang.
pub fn dopslam_within(args: &[&str], limit: std::time::Duration) -> (bool, String, String) {
    static CALLS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = temp_dir(&format!("within-{call}"));
    let (out, err) = (dir.join("stdout"), dir.join("stderr"));
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_dopslam"))
        .args(args)
        .stdout(std::fs::File::create(&out).unwrap())
        .stderr(std::fs::File::create(&err).unwrap())
        .spawn()
        .unwrap();
    let start = std::time::Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > limit {
            let _ = child.kill();
            let _ = child.wait();
            panic!(
                "dopslam {args:?} still ran after {limit:?}: {}",
                std::fs::read_to_string(&err).unwrap_or_default()
            );
        }
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    let read = |path: &std::path::Path| std::fs::read_to_string(path).unwrap_or_default();
    (status.success(), read(&out), read(&err))
}

/// A static room of `frames` frames written by `dopslam synth` into `seq`.
pub fn synth_static_room(seq: &std::path::Path, frames: usize) {
    let preset =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/static_room.toml");
    synth_preset(&preset, seq, frames);
}

/// `frames` frames of the synth preset at `preset` written by `dopslam synth` into `seq`.
pub fn synth_preset(preset: &std::path::Path, seq: &std::path::Path, frames: usize) {
    let frames = frames.to_string();
    let (ok, _, err) = dopslam(&[
        "synth",
        "--config",
        &preset.to_string_lossy(),
        "--out",
        &seq.to_string_lossy(),
        "--frames",
        &frames,
    ]);
    assert!(ok, "{err}");
}

/// `loop_room` at 10 fps for 34 s (340 frames): one turn in 30 s, then 4 s more over
/// the first views, so the three consecutive keyframes a loop needs exist however a
/// real-time run places its keyframes (with 30 s the loop hung on the last two, and a
/// busy machine made a test fail). Generated once per test process and shared by the
/// tests that only read it (tests/global.rs, tests/rerun.rs), which write their runs
/// in folders of their own. Kept for the whole process (a static is never dropped):
/// tools/test.sh removes the temporary folder it gives the test run.
pub fn loop_room_34s() -> &'static Path {
    static SEQUENCE: std::sync::OnceLock<TestDir> = std::sync::OnceLock::new();
    SEQUENCE.get_or_init(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let path = root.join("configs/synth/loop_room.toml");
        let mut synth = dopslam::synth::SynthConfig::load(&path).unwrap();
        synth.sequence.frames = 340;
        synth.sequence.fps = 10.0;
        let seq = temp_dir("loop-room-34s").child("seq");
        dopslam::synth::generate(&synth, &seq, false).unwrap();
        seq
    })
}

/// What tools/read_rerun.py (rerun-sdk, an independent reader) reads from the
/// recording `rrd` with `python`, or its error.
pub fn read_rerun(python: &Path, rrd: &Path) -> Result<serde_json::Value, String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tools/read_rerun.py");
    let output = std::process::Command::new(python)
        .arg(script)
        .arg(rrd)
        .output()
        .map_err(|e| e.to_string())?;
    if !output.status.success() {
        return Err(String::from_utf8_lossy(&output.stderr).into_owned());
    }
    serde_json::from_slice(&output.stdout).map_err(|e| e.to_string())
}
