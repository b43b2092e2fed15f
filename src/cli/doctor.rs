//! `dopslam doctor`: where the runtime data directory is, what it holds and what is
//! missing, with the command that installs it.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use dopslam::config::Config;
use dopslam::detect::Model;
use dopslam::io::data_dir::{self, DataDir, DataOrigin};

#[derive(Args)]
pub struct DoctorArgs {
    /// A TOML config whose explicit paths (`[detector] model_path`, `ort_library`,
    /// `[global] vocabulary`) are checked instead of the data directory's files.
    #[arg(long)]
    config: Option<PathBuf>,
}

/// One file the tool loads at run time.
struct Needed {
    what: &'static str,
    path: PathBuf,
    /// Whether a default run needs it (else it is an option).
    required: bool,
    /// How it is loaded to check it.
    load: Load,
}

/// How `doctor` loads a file: as a run would, so that a corrupt file is found here.
#[derive(Clone, Copy)]
enum Load {
    Runtime,
    Model(dopslam::detect::yolo::Layout),
    Vocabulary,
}

/// `Ok` when `needed` loads (a session opened on one blank image, the vocabulary read
/// whole, the library loaded), else what is wrong; `None` when the file is missing.
fn load_check(needed: &Needed, library: &Path) -> Option<Result<(), String>> {
    if !needed.path.is_file() {
        return None;
    }
    Some(match needed.load {
        Load::Runtime => {
            dopslam::detect::onnx::check_runtime(&needed.path).map_err(|e| e.to_string())
        }
        Load::Model(layout) => {
            dopslam::detect::onnx::OnnxDetector::load(&needed.path, layout, library, 1)
                .map(|_| ())
                .map_err(|e| e.to_string())
        }
        Load::Vocabulary => dopslam::bow::vocabulary::Vocabulary::read(&needed.path)
            .and_then(|v| match v.is_empty() {
                true => Err(dopslam::io::IoError::invalid(
                    &needed.path,
                    "holds no words",
                )),
                false => Ok(()),
            })
            .map_err(|e| e.to_string()),
    })
}

/// Prints the search order and each runtime file; fails when a file a default run
/// needs is missing.
pub fn run_doctor(args: DoctorArgs) -> Result<()> {
    let config = match &args.config {
        Some(path) => Config::load(path)?,
        None => Config::default(),
    };
    let data = DataDir::locate();
    let cwd = std::env::current_dir().unwrap_or_default();
    println!(
        "data directory: {} ({})",
        shown(&data.path).display(),
        data.origin
    );
    print_search_order(&cwd);
    let (needed, library) = needed_files(&config);
    let (missing, broken) = check_files(&needed, &library);
    println!(
        "stereo dense map (OpenCV SGBM): {}",
        if cfg!(feature = "opencv") {
            "built in"
        } else {
            "not built (no opencv feature: install libopencv-dev clang libclang-dev and rebuild)"
        }
    );
    if missing.is_empty() && broken.is_empty() {
        println!("everything a default run needs is in place and loads");
        return Ok(());
    }
    if missing.is_empty() {
        anyhow::bail!(
            "{} cannot be loaded: {}; {}",
            if broken.len() == 1 {
                "one file"
            } else {
                "files"
            },
            broken.join("; "),
            data_dir::INSTALL_HINT
        );
    }
    if data.origin == DataOrigin::WorkingDirectory && !data.path.is_dir() {
        println!(
            "no data directory was found: dopslam looked at ./data of {}",
            cwd.display()
        );
    }
    anyhow::bail!(
        "{} missing ({}): {}",
        if missing.len() == 1 {
            "one file is"
        } else {
            "files are"
        },
        missing.join(", "),
        data_dir::INSTALL_HINT
    )
}
/// `path` made absolute, as the doctor shows it.
fn shown(path: &Path) -> PathBuf {
    std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf())
}

/// Loads each needed file as a run loads it and prints its line; returns the required
/// files missing, and those broken with why.
fn check_files(needed: &[Needed], library: &Path) -> (Vec<String>, Vec<String>) {
    println!("files (each loaded as a run loads it):");
    let (mut missing, mut broken) = (Vec::new(), Vec::new());
    for n in needed {
        let checked = load_check(n, library);
        let status = match &checked {
            None => "MISSING",
            Some(Ok(())) => "ok",
            Some(Err(_)) => "BROKEN",
        };
        println!(
            "  {:<8} {:<44} {}",
            status,
            n.what,
            shown(&n.path).display()
        );
        match checked {
            None if n.required => missing.push(shown(&n.path).display().to_string()),
            Some(Err(why)) => {
                println!("           {why}");
                if n.required {
                    broken.push(format!("{} ({why})", shown(&n.path).display()));
                }
            }
            _ => {}
        }
    }
    (missing, broken)
}

/// The places runtime files are looked for, in order, as `run` looks.
fn print_search_order(cwd: &Path) {
    println!("looked for, in this order:");
    println!("  1. explicit paths in the config: [detector] model_path / ort_library, [global] vocabulary; ORT_DYLIB_PATH for the runtime");
    match std::env::var_os(data_dir::ENV) {
        Some(v) => {
            let path = Path::new(&v);
            let problem = if path.is_dir() {
                ""
            } else if path.exists() {
                " (it names a file, not a folder: nothing is found there)"
            } else {
                " (no such folder: nothing is found there)"
            };
            println!(
                "  2. {}={} (when set, the only place looked at){problem}",
                data_dir::ENV,
                v.to_string_lossy()
            )
        }
        None => println!("  2. {} (unset)", data_dir::ENV),
    }
    match data_dir::install_record() {
        Some(record) => println!("  3. the install record {}", record_line(&record)),
        None => println!("  3. the install record (no XDG_DATA_HOME or HOME)"),
    }
    println!(
        "  4. ./data under the working directory ({})",
        cwd.join("data").display()
    );
}

/// The install record and what it says: the folder it names, or why it is skipped.
fn record_line(record: &Path) -> String {
    let shown = record.display();
    if record.is_dir() {
        return format!("{shown} (skipped: a folder, not the file tools/setup.sh writes)");
    }
    if !record.exists() {
        return format!("{shown} (none: tools/setup.sh writes it)");
    }
    let named = match std::fs::read_to_string(record) {
        Ok(text) => text.trim().to_string(),
        Err(e) => return format!("{shown} (skipped: it cannot be read: {e})"),
    };
    let skipped = match Path::new(&named) {
        p if !p.is_absolute() => " (skipped: not an absolute path)",
        p if !p.is_dir() => " (skipped: no such directory; run tools/setup.sh again)",
        _ => "",
    };
    format!("{shown} -> {named}{skipped}")
}

/// The files a run with `config` loads (the optional detector models besides), with
/// the ONNX Runtime library's path.
fn needed_files(config: &Config) -> (Vec<Needed>, std::path::PathBuf) {
    let library = dopslam::detect::onnx::runtime_library(config.detector.ort_library.as_deref());
    let mut needed = vec![Needed {
        what: "ONNX Runtime library (keyframe detector)",
        path: library.clone(),
        required: true,
        load: Load::Runtime,
    }];
    needed.extend(
        config
            .detector
            .pool_models()
            .into_iter()
            .map(|model| Needed {
                what: "detector model (the config's)",
                path: model.path,
                required: true,
                load: Load::Model(model.layout),
            }),
    );
    for (model, what) in [
        (Model::YoloxNano, "detector model yolox-nano (optional)"),
        (Model::Deimv2Femto, "detector model deimv2-femto (optional)"),
    ] {
        if config.detector.models.model().is_some_and(|m| m != model) {
            needed.extend(model.default_paths().into_iter().map(|path| Needed {
                what,
                path,
                required: false,
                load: Load::Model(model.layout()),
            }));
        }
    }
    needed.push(Needed {
        what: "place-recognition vocabulary (loop closing)",
        path: config.global.vocabulary_file(),
        required: true,
        load: Load::Vocabulary,
    });
    (needed, library)
}
