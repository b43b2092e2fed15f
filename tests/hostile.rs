//! The hostile inputs and situations of issue 34, each as a user or a careless script
//! would meet it: the command, its exit status, the key words of its message, and that
//! nothing computed was lost or overwritten. `cargo test --release --test suite hostile:: -- --nocapture`
//! prints one table row per case.

use crate::common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use common::temp_dir;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_dopslam"))
}

fn s(path: &Path) -> String {
    path.to_string_lossy().into_owned()
}

/// Runs `dopslam ARGS` and checks the outcome: success or not, and every key word in
/// the output (standard error and output together, lower case).
#[track_caller]
fn case(name: &str, args: &[&str], succeeds: bool, words: &[&str]) -> String {
    let output = bin().args(args).output().unwrap();
    check(name, &output, succeeds, words)
}

#[track_caller]
fn check(name: &str, output: &Output, succeeds: bool, words: &[&str]) -> String {
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stderr),
        String::from_utf8_lossy(&output.stdout)
    );
    let lower = text.to_lowercase();
    assert!(!lower.contains("panicked"), "{name}: {text}");
    assert_eq!(output.status.success(), succeeds, "{name}: {text}");
    if !succeeds {
        assert!(
            output.status.code().is_some_and(|c| c != 134),
            "{name}: aborted: {text}"
        );
    }
    for word in words {
        assert!(
            lower.contains(&word.to_lowercase()),
            "{name}: {word:?} not in: {text}"
        );
    }
    let message = text
        .lines()
        .find(|l| l.starts_with("error"))
        .unwrap_or("")
        .trim();
    println!(
        "| {name} | exit {} | {} |",
        output.status.code().unwrap_or(-1),
        message.replace('|', "/")
    );
    text
}

/// A 12-frame static room (with oracle boxes and ground truth).
fn room(base: &Path, name: &str) -> PathBuf {
    let seq = base.join(name);
    common::synth_static_room(&seq, 12);
    seq
}

fn run_args<'a>(seq: &'a str, out: &'a str) -> Vec<&'a str> {
    vec![
        "run",
        seq,
        "--out",
        out,
        "--detections",
        "none",
        "--no-dense",
        "--no-loops",
        "--deterministic",
    ]
}

/// [`case`] for `dopslam run SEQ` ([`run_args`]) with one more option and its file.
#[track_caller]
fn run_case(
    name: &str,
    (seq, out): (&str, &str),
    (option, file): (&str, &Path),
    succeeds: bool,
    words: &[&str],
) {
    let file = s(file);
    let mut args = run_args(seq, out);
    args.extend([option, file.as_str()]);
    case(name, &args, succeeds, words);
}

fn png(path: &Path, width: u32, height: u32, value: u8) {
    image::GrayImage::from_pixel(width, height, image::Luma([value]))
        .save(path)
        .unwrap();
}

#[test]
fn config_values_and_arguments() {
    let base = temp_dir("hostile-config");
    let seq = room(&base, "seq");
    let (seq_s, out_s) = (s(&seq), s(&base.join("out")));
    for (key, section, value) in [
        ("th_depth", "tracking", "nan"),
        ("motion_search_radius", "tracking", "-1.0"),
        ("gamma", "dop", "nan"),
        ("voxel", "dense", "-1.0"),
    ] {
        let config = base.join(format!("{key}.toml"));
        std::fs::write(&config, format!("[{section}]\n{key} = {value}\n")).unwrap();
        let name = format!("config {section}.{key} = {value}");
        run_case(
            &name,
            (&seq_s, &out_s),
            ("--config", &config),
            false,
            &[&format!("{section}.{key}")],
        );
    }
    let config = base.join("sgbm.toml");
    std::fs::write(&config, "[stereo]\nsgbm_disparities = 2048\n").unwrap();
    run_case(
        "sgbm_disparities = 2048",
        (&seq_s, &out_s),
        ("--config", &config),
        false,
        &["stereo.sgbm_disparities", "1024"],
    );
    assert!(!base.join("out").exists(), "a refused run writes nothing");
    let mut args = run_args(&seq_s, &out_s);
    args.extend(["--frames", "0"]);
    case("run --frames 0", &args, false, &["--frames", "at least 1"]);
    case(
        "graph sphere --rings 0",
        &["graph", "sphere", &s(&base.join("g.g2o")), "--rings", "0"],
        false,
        &["--rings"],
    );
    case(
        "graph sphere --per-ring 0",
        &[
            "graph",
            "sphere",
            &s(&base.join("g.g2o")),
            "--per-ring",
            "0",
        ],
        false,
        &["--per-ring"],
    );
    case(
        "vocab train --depth 0",
        &["vocab", "train", &seq_s, "--depth", "0"],
        false,
        &["--depth"],
    );
    case(
        "vocab train --branching 1",
        &["vocab", "train", &seq_s, "--branching", "1"],
        false,
        &["--branching"],
    );
    case(
        "detect --every 0",
        &["detect", &seq_s, "--every", "0"],
        false,
        &["--every"],
    );
    let img = base.join("one.png");
    png(&img, 1, 1, 128);
    let kitti =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/calibration/Stereo_KITTI00-02.yaml");
    case(
        "stereo --features 0",
        &[
            "stereo",
            &s(&img),
            &s(&img),
            "--settings",
            &s(&kitti),
            "--features",
            "0",
        ],
        false,
        &["--features"],
    );
    case(
        "stereo on 1x1 images",
        &["stereo", &s(&img), &s(&img), "--settings", &s(&kitti)],
        false,
        &["too small", "sgbm_disparities"],
    );
    let bad_bf = base.join("bf.yaml");
    std::fs::write(&bad_bf, "%YAML:1.0\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nCamera.bf: -40\n").unwrap();
    run_case(
        "Camera.bf: -40",
        (&seq_s, &out_s),
        ("--settings", &bad_bf),
        false,
        &["Camera.bf", "positive"],
    );
    let twice = base.join("twice.yaml");
    std::fs::write(&twice, "%YAML:1.0\nCamera.fx: 500\nCamera.fy: 500\nCamera.cx: 320\nCamera.cy: 240\nCamera.fx: 510\n").unwrap();
    run_case(
        "Camera.fx twice",
        (&seq_s, &out_s),
        ("--settings", &twice),
        false,
        &["Camera.fx", "twice"],
    );
}

fn tum_lines(times: &[f64]) -> String {
    times
        .iter()
        .map(|t| format!("{t:.4} 0 0 0 0 0 0 1\n"))
        .collect()
}

#[test]
fn evaluation_and_graph_files() {
    let base = temp_dir("hostile-eval");
    let gt = base.join("gt.txt");
    std::fs::write(
        &gt,
        tum_lines(&(0..20).map(|i| i as f64 * 0.1).collect::<Vec<_>>()),
    )
    .unwrap();
    let est = base.join("est.txt");
    std::fs::write(&est, tum_lines(&[0.0, 0.1, 0.1, 0.2])).unwrap();
    case(
        "eval: duplicate timestamps in the estimate",
        &["eval", &s(&gt), &s(&est)],
        false,
        &["est.txt", "0.1 is given twice"],
    );
    std::fs::write(
        &est,
        tum_lines(&(0..20).map(|i| i as f64 * 0.1).collect::<Vec<_>>()),
    )
    .unwrap();
    case(
        "eval --max-diff=-1",
        &["eval", &s(&gt), &s(&est), "--max-diff=-1"],
        false,
        &["--max-diff", "negative"],
    );
    case(
        "eval --offset nan",
        &["eval", &s(&gt), &s(&est), "--offset", "nan"],
        false,
        &["--offset", "finite"],
    );
    case(
        "eval --min-coverage nan",
        &["eval", &s(&gt), &s(&est), "--min-coverage", "nan"],
        false,
        &["--min-coverage", "finite"],
    );
    let rotated = base.join("ref.kitti");
    let zero = base.join("zero.kitti");
    std::fs::write(&rotated, "0 -1 0 1 1 0 0 2 0 0 1 3\n".repeat(5)).unwrap();
    std::fs::write(&zero, "0 0 0 1 0 0 0 2 0 0 0 3\n".repeat(5)).unwrap();
    case(
        "eval --format kitti, zero rotations",
        &["eval", "--format", "kitti", &s(&rotated), &s(&zero)],
        false,
        &["zero.kitti:1", "not a rotation"],
    );
    let graph = base.join("sphere.g2o");
    case(
        "graph sphere",
        &[
            "graph",
            "sphere",
            &s(&graph),
            "--rings",
            "5",
            "--per-ring",
            "5",
        ],
        true,
        &[],
    );
    let text = std::fs::read_to_string(&graph).unwrap();
    let negated: String = text
        .lines()
        .map(|l| {
            if l.starts_with("EDGE") {
                let mut f: Vec<String> = l.split_whitespace().map(str::to_string).collect();
                for v in f.iter_mut().skip(10) {
                    *v = format!("-{v}").replace("--", "");
                }
                f.join(" ")
            } else {
                l.to_string()
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    let bad = base.join("negated.g2o");
    std::fs::write(&bad, negated).unwrap();
    case(
        "graph optimise, negated information",
        &["graph", "optimise", &s(&bad)],
        false,
        &["positive definite"],
    );
    let empty = base.join("empty.g2o");
    std::fs::write(&empty, "").unwrap();
    case(
        "graph optimise, empty file",
        &["graph", "optimise", &s(&empty)],
        false,
        &["no VERTEX_SE3:QUAT"],
    );
}

#[test]
fn vocabularies() {
    let base = temp_dir("hostile-vocab");
    let black = base.join("black");
    std::fs::create_dir_all(&black).unwrap();
    for i in 0..3 {
        png(&black.join(format!("{i}.png")), 64, 48, 0);
    }
    let vocab = base.join("v.dbow");
    case(
        "vocab train on black images",
        &["vocab", "train", &s(&black), "-o", &s(&vocab)],
        false,
        &["no ORB keypoints"],
    );
    assert!(!vocab.exists(), "no vocabulary is written");
    case(
        "vocab train -o unwritable",
        &["vocab", "train", &s(&black), "-o", "/proc/dopslam/v.dbow"],
        false,
        &["cannot"],
    );
    // Symbolic-link loops inside the folder: listed once, a link to itself skipped.
    std::os::unix::fs::symlink(&black, black.join("up")).unwrap();
    std::os::unix::fs::symlink(black.join("self"), black.join("self")).unwrap();
    case(
        "vocab train on link loops",
        &["vocab", "train", &s(&black), "-o", &s(&vocab)],
        false,
        &["self", "skipped", "no ORB keypoints"],
    );
    std::fs::remove_file(black.join("up")).unwrap();
    std::fs::remove_file(black.join("self")).unwrap();
    // A vocabulary whose header says k = 0, L = 0.
    let shipped =
        std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("data/vocabulary.dbow")).unwrap();
    let mut edited = shipped.clone();
    edited[8..16].fill(0);
    std::fs::write(&vocab, &edited).unwrap();
    case(
        "vocab info, header k = 0, L = 0",
        &["vocab", "info", &s(&vocab)],
        false,
        &["k = 0"],
    );
    // A run that would load it fails before tracking.
    let seq = room(&base, "seq");
    let config = base.join("c.toml");
    std::fs::write(&config, format!("[global]\nvocabulary = {:?}\n", s(&vocab))).unwrap();
    let out = base.join("out");
    case(
        "run with a 0-word vocabulary",
        &[
            "run",
            &s(&seq),
            "--out",
            &s(&out),
            "--detections",
            "none",
            "--no-dense",
            "--config",
            &s(&config),
        ],
        false,
        &["vocabulary", "--no-loops"],
    );
    assert!(!out.exists(), "nothing written before the check");
}

#[test]
fn sequence_folders() {
    let base = temp_dir("hostile-folders");
    let seq = room(&base, "seq");
    let out_s = s(&base.join("out"));
    let file = base.join("afile");
    std::fs::write(&file, "x").unwrap();
    case(
        "info on a file",
        &["info", &s(&file)],
        false,
        &["a file, not a sequence folder"],
    );
    let looped = base.join("loop");
    std::os::unix::fs::symlink(&looped, &looped).unwrap();
    case(
        "info on a symlink loop",
        &["info", &s(&looped)],
        false,
        &["loop of symbolic links"],
    );
    // The same for a file: a settings file or a trajectory that is a loop says so.
    let seq_s = s(&seq);
    case(
        "run --settings a symlink loop",
        &["run", &seq_s, "--settings", &s(&looped), "--out", &out_s],
        false,
        &["loop of symbolic links"],
    );
    case(
        "eval a symlink loop",
        &["eval", &s(&looped), &s(&looped)],
        false,
        &["loop of symbolic links"],
    );
    let kitti = base.join("kitti");
    std::fs::create_dir_all(kitti.join("sequences/00")).unwrap();
    case(
        "run on a KITTI root",
        &run_args(&s(&kitti), &out_s),
        false,
        &["sequences/00"],
    );
    // rgb.txt naming one timestamp twice with different files.
    let dup = room(&base, "dup");
    let rgb = std::fs::read_to_string(dup.join("rgb.txt")).unwrap();
    let first = rgb
        .lines()
        .find(|l| !l.starts_with('#'))
        .unwrap()
        .to_string();
    let t = first.split_whitespace().next().unwrap();
    std::fs::write(dup.join("rgb.txt"), format!("{rgb}{t} rgb/other.png\n")).unwrap();
    case(
        "rgb.txt: one timestamp, two files",
        &run_args(&s(&dup), &out_s),
        false,
        &["rgb.txt", "with other files"],
    );
    // All-black colour frames.
    let black = room(&base, "black");
    for entry in std::fs::read_dir(black.join("rgb")).unwrap() {
        let path = entry.unwrap().path();
        image::RgbImage::new(640, 480).save(&path).unwrap();
    }
    case(
        "all-black colour frames",
        &run_args(&s(&black), &out_s),
        false,
        &["blank or black"],
    );
    // A path that is not UTF-8.
    use std::os::unix::ffi::OsStrExt;
    let odd = base.join(std::ffi::OsStr::from_bytes(b"seq-\xff"));
    std::fs::rename(room(&base, "odd"), &odd).unwrap();
    let odd_out = base.join("odd-out");
    let output = bin()
        .arg("run")
        .arg(&odd)
        .args(["--out", &s(&odd_out), "--detections", "none", "--no-dense"])
        .output()
        .unwrap();
    check(
        "run on a non-UTF-8 path",
        &output,
        false,
        &["not valid utf-8", "seq-"],
    );
    assert!(!odd_out.exists(), "refused before any work");
    let _ = seq;
}

#[test]
fn outputs_never_overwrite_inputs_or_lose_results() {
    let base = temp_dir("hostile-outputs");
    let seq = room(&base, "seq");
    let seq_s = s(&seq);
    let before: Vec<Vec<u8>> = common::sorted_files(&seq.join("rgb"))
        .iter()
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    let out_s = s(&base.join("out"));
    run_case(
        "run --debug-frames into the input",
        (&seq_s, &out_s),
        ("--debug-frames", &seq.join("rgb")),
        false,
        &["inside the input"],
    );
    let after: Vec<Vec<u8>> = common::sorted_files(&seq.join("rgb"))
        .iter()
        .map(|p| std::fs::read(p).unwrap())
        .collect();
    assert_eq!(before, after, "the input images are untouched");
    case(
        "run --out inside the input",
        &run_args(&seq_s, &s(&seq.join("results"))),
        false,
        &["inside the input"],
    );
    case(
        "run --out not writable",
        &run_args(&seq_s, "/proc/1/dopslam-out"),
        false,
        &["cannot create the output folder"],
    );
    let file = base.join("afile");
    std::fs::write(&file, "x").unwrap();
    case(
        "run --out a file",
        &run_args(&seq_s, &s(&file)),
        false,
        &["is a file"],
    );
    let looped = base.join("loop");
    std::os::unix::fs::symlink(&looped, &looped).unwrap();
    case(
        "run --out a symlink loop",
        &run_args(&seq_s, &s(&looped)),
        false,
        &["loop of symbolic links"],
    );
    // An earlier run's outputs move into previous/ (a dense map the new run does not make).
    std::fs::create_dir_all(base.join("out")).unwrap();
    std::fs::write(base.join("out/dense_mesh.ply"), "old").unwrap();
    std::fs::write(base.join("out/trajectory.txt"), "old").unwrap();
    case(
        "run into an old output folder",
        &run_args(&seq_s, &out_s),
        true,
        &["previous/"],
    );
    let kept = common::sorted_files(&base.join("out/previous"));
    assert_eq!(kept.len(), 1, "one earlier run: {kept:?}");
    assert_eq!(
        std::fs::read_to_string(kept[0].join("dense_mesh.ply")).unwrap(),
        "old"
    );
    assert!(
        !base.join("out/dense_mesh.ply").exists(),
        "no stale dense map beside the new run"
    );
    // A third run keeps both earlier ones (never a deleted finished run), and a user's
    // own file in previous/ stays as it was.
    std::fs::write(base.join("out/previous/notes.txt"), "mine").unwrap();
    let second = std::fs::read(base.join("out/trajectory.txt")).unwrap();
    case(
        "run into it a third time",
        &run_args(&seq_s, &out_s),
        true,
        &["previous/"],
    );
    let kept: Vec<_> = common::sorted_files(&base.join("out/previous"))
        .into_iter()
        .filter(|p| p.is_dir())
        .collect();
    assert_eq!(kept.len(), 2, "both earlier runs kept: {kept:?}");
    assert!(kept
        .iter()
        .any(|k| std::fs::read_to_string(k.join("dense_mesh.ply")).is_ok_and(|t| t == "old")));
    assert!(kept
        .iter()
        .any(|k| std::fs::read(k.join("trajectory.txt")).is_ok_and(|t| t == second)));
    assert_eq!(
        std::fs::read_to_string(base.join("out/previous/notes.txt")).unwrap(),
        "mine"
    );
    // fuse with another sequence's frames.
    let other = base.join("other");
    let synth = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/static_room.toml");
    case(
        "synth another room",
        &[
            "synth",
            "--config",
            &s(&synth),
            "--out",
            &s(&other),
            "--frames",
            "12",
            "--seed",
            "9",
        ],
        true,
        &[],
    );
    let mesh_before = std::fs::read(base.join("out/trajectory.txt")).unwrap();
    case(
        "fuse --sequence another sequence",
        &["fuse", &out_s, "--sequence", &s(&other)],
        false,
        &["not the sequence"],
    );
    assert_eq!(
        std::fs::read(base.join("out/trajectory.txt")).unwrap(),
        mesh_before
    );
    assert!(
        !base.join("out/dense_mesh.ply").exists(),
        "no dense map was written"
    );
    // detect --out the image's folder: the image is not replaced.
    let photo = base.join("photo.png");
    png(&photo, 32, 24, 90);
    let photo_bytes = std::fs::read(&photo).unwrap();
    case(
        "detect IMG --out its folder",
        &["detect", &s(&photo), "--out", &s(&base)],
        false,
        &["replace an input"],
    );
    assert_eq!(std::fs::read(&photo).unwrap(), photo_bytes);
    // A corrupt oracle file: the run writes its outputs, then fails saying why.
    let oracle = room(&base, "oracle");
    let files = common::sorted_files(&oracle.join("detections_oracle"));
    for f in &files {
        std::fs::write(f, "{ not json").unwrap();
    }
    let out2 = base.join("out2");
    case(
        "a corrupt oracle detection file",
        &[
            "run",
            &s(&oracle),
            "--out",
            &s(&out2),
            "--detections",
            "oracle",
            "--no-dense",
            "--no-loops",
            "--deterministic",
        ],
        false,
        &["detection", "failed"],
    );
    assert!(out2.join("trajectory.txt").exists() && out2.join("report.json").exists());
}

/// Waits until `dir` holds `count` files (a run under way shows its debug frames).
fn wait_for_files(dir: &Path, count: usize) {
    let start = Instant::now();
    while std::fs::read_dir(dir).map_or(0, |d| d.count()) < count {
        assert!(
            start.elapsed() < Duration::from_secs(120),
            "the run never got going"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn signals_locks_and_pacing() {
    let base = temp_dir("hostile-signals");
    let seq = base.join("long");
    common::synth_static_room(&seq, 200);
    let spawn = |out: &Path, frames: &Path, extra: &[&str]| {
        bin()
            .args([
                "run",
                &s(&seq),
                "--out",
                &s(out),
                "--detections",
                "none",
                "--no-dense",
                "--deterministic",
            ])
            .args(["--debug-frames", &s(frames)])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap()
    };
    // Two runs on one --out at once: the second is refused.
    let out = base.join("out");
    let first = spawn(&out, &base.join("frames1"), &[]);
    wait_for_files(&base.join("frames1"), 5);
    let second = spawn(&out, &base.join("frames2"), &[])
        .wait_with_output()
        .unwrap();
    check(
        "two runs on one --out at once",
        &second,
        false,
        &["another dopslam run"],
    );
    // Two SIGINTs 50 ms apart: no temporary file, and a trajectory only with its report.
    // SAFETY: kill only signals the child started above.
    unsafe { libc::kill(first.id() as libc::pid_t, libc::SIGINT) };
    std::thread::sleep(Duration::from_millis(50));
    unsafe { libc::kill(first.id() as libc::pid_t, libc::SIGINT) };
    let output = first.wait_with_output().unwrap();
    check("two SIGINTs 0.05 s apart", &output, false, &[]);
    let names: Vec<String> = std::fs::read_dir(&out)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(!names.iter().any(|n| n.contains(".tmp")), "{names:?}");
    assert_eq!(
        names.contains(&"trajectory.txt".to_string()),
        names.contains(&"report.json".to_string()),
        "{names:?}"
    );
    // --pace recording over a 100000 s gap in the timestamps: at most a second's wait.
    let gap = base.join("gap");
    common::synth_static_room(&gap, 12);
    for list in ["rgb.txt", "depth.txt"] {
        let text = std::fs::read_to_string(gap.join(list)).unwrap();
        let shifted: String = text
            .lines()
            .enumerate()
            .map(|(i, l)| match l.split_once(' ') {
                Some((t, rest)) if !l.starts_with('#') && i > 8 => {
                    format!("{:.6} {rest}\n", t.parse::<f64>().unwrap() + 100_000.0)
                }
                _ => format!("{l}\n"),
            })
            .collect();
        std::fs::write(gap.join(list), shifted).unwrap();
    }
    let start = Instant::now();
    let output = bin()
        .args([
            "run",
            &s(&gap),
            "--out",
            &s(&base.join("gap-out")),
            "--detections",
            "none",
            "--no-dense",
            "--no-loops",
            "--pace",
            "recording",
        ])
        .output()
        .unwrap();
    check(
        "run --pace recording over a 100000 s gap",
        &output,
        true,
        &[],
    );
    assert!(
        start.elapsed() < Duration::from_secs(60),
        "{:?}",
        start.elapsed()
    );
}

#[test]
fn batches_with_a_missing_sequence() {
    let base = temp_dir("hostile-batch");
    let manifest = base.join("m.toml");
    std::fs::write(
        &manifest,
        "[batch]\nmodes = [\"no-dop\"]\n\n[[sequence]]\npath = \"nowhere\"\n",
    )
    .unwrap();
    let out = base.join("out");
    let text = case(
        "batch with a missing sequence",
        &["batch", &s(&manifest), "--out", &s(&out), "--quiet"],
        false,
        &["nowhere", "could not be read"],
    );
    assert!(text.contains("0 of 1 runs finished, 1 failed"), "{text}");
}

/// A stereo pair whose left and right images are swapped still tracks (badly): the run
/// says so.
#[test]
fn a_swapped_stereo_pair_is_named() {
    let base = temp_dir("hostile-swapped");
    let preset = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/static_room.toml");
    let text = std::fs::read_to_string(&preset).unwrap();
    let config = base.join("stereo_room.toml");
    std::fs::write(
        &config,
        format!(
            "{}\n[stereo]\nbaseline = 0.12\n",
            text.replace("name = \"static_room\"", "name = \"stereo_room\"")
        ),
    )
    .unwrap();
    case(
        "synth a stereo room",
        &[
            "synth",
            "--config",
            &s(&config),
            "--out",
            &s(&base.join("seq")),
            "--frames",
            "8",
        ],
        true,
        &[],
    );
    let kitti = base.join("seq/kitti/sequences/00");
    std::fs::rename(kitti.join("image_0"), kitti.join("swap")).unwrap();
    std::fs::rename(kitti.join("image_1"), kitti.join("image_0")).unwrap();
    std::fs::rename(kitti.join("swap"), kitti.join("image_1")).unwrap();
    let out = s(&base.join("out"));
    case(
        "a swapped stereo pair",
        &run_args(&s(&kitti), &out),
        true,
        &["looks swapped", "image_0 must be the left camera"],
    );
}
