//! `dopslam convert REC --to tum OUT`: an RGB-D sequence (a recording, usually) written
//! as the TUM folder every other tool reads: `rgb/` PNGs, `depth/` 16-bit PNGs at 5000
//! per metre, `rgb.txt`, `depth.txt` and an ORB-SLAM2 `calibration.yaml`.
//!
//! The folder is written under a temporary name beside `OUT` and renamed when complete,
//! so an interrupted conversion leaves no half folder that looks whole; `OUT` must not
//! exist (or be an empty folder): nothing is overwritten.

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use rayon::prelude::*;

use crate::io::image_files::depth_to_png16;
use crate::io::orbslam_settings::{OrbSettings, OrbSlamSettings};
use crate::io::sequence::{FrameImages, Sequence};
use crate::io::IoError;

/// The depth scale of the TUM layout: raw units per metre.
const TUM_DEPTH_SCALE: f64 = 5000.0;

/// Checks that `out` can be written: absent or an empty folder, its parent writable.
/// Returns the temporary folder the conversion writes into.
pub fn prepare(out: &Path) -> Result<PathBuf, IoError> {
    if out.exists() {
        let empty = out.is_dir()
            && std::fs::read_dir(out)
                .map(|mut d| d.next().is_none())
                .unwrap_or(false);
        if !empty {
            return Err(IoError::invalid(
                out,
                "exists and is not an empty folder: give a new output folder",
            ));
        }
    }
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "tum".into());
    let parent = out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    let partial = parent.join(format!(".{name}.partial-{}", std::process::id()));
    for dir in [partial.join("rgb"), partial.join("depth")] {
        std::fs::create_dir_all(&dir).map_err(|source| IoError::Write { path: dir, source })?;
    }
    Ok(partial)
}

/// Writes frames `0..frames` of `sequence` as a TUM folder at `out` (see the module
/// doc); returns the number of frames written.
pub fn to_tum(
    sequence: &dyn Sequence,
    out: &Path,
    frames: usize,
    progress: bool,
) -> Result<usize, IoError> {
    let partial = prepare(out)?;
    let result = write_frames(sequence, &partial, frames, progress).and_then(|names| {
        write_lists(sequence, &partial, &names)?;
        if out.exists() {
            std::fs::remove_dir(out).map_err(|source| IoError::Write {
                path: out.to_path_buf(),
                source,
            })?;
        }
        std::fs::rename(&partial, out).map_err(|source| IoError::Write {
            path: out.to_path_buf(),
            source,
        })?;
        Ok(names.len())
    });
    if result.is_err() {
        // Only the temporary folder this conversion made goes.
        let _ = std::fs::remove_dir_all(&partial);
    }
    result
}

/// Decodes and writes the frames in parallel; the stamps' file names in frame order.
fn write_frames(
    sequence: &dyn Sequence,
    dir: &Path,
    frames: usize,
    progress: bool,
) -> Result<Vec<String>, IoError> {
    let bar = if progress {
        ProgressBar::new(frames as u64)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("convert {bar:40} {pos}/{len} frames ({eta} left)")
            .expect("valid template"),
    );
    let names = (0..frames)
        .into_par_iter()
        .map(|index| {
            let frame = sequence.load(index)?;
            let FrameImages::Rgbd { rgb, depth } = frame.images else {
                return Err(IoError::invalid(
                    dir,
                    "a stereo sequence: --to tum takes RGB-D",
                ));
            };
            let name = format!("{:.6}.png", frame.timestamp);
            let save = |path: PathBuf, result: image::ImageResult<()>| {
                result.map_err(|e| IoError::Write {
                    path,
                    source: std::io::Error::other(e),
                })
            };
            let path = dir.join("rgb").join(&name);
            save(path.clone(), rgb.save(&path))?;
            let path = dir.join("depth").join(&name);
            save(
                path.clone(),
                depth_to_png16(&depth, TUM_DEPTH_SCALE).save(&path),
            )?;
            bar.inc(1);
            Ok(name)
        })
        .collect::<Result<Vec<_>, IoError>>();
    bar.finish_and_clear();
    names
}

/// `rgb.txt`, `depth.txt` (one stamp for both: the pair's colour stamp) and the
/// calibration.
fn write_lists(sequence: &dyn Sequence, dir: &Path, names: &[String]) -> Result<(), IoError> {
    let mut rgb = String::from("# color images\n# timestamp filename\n");
    let mut depth = String::from("# depth maps\n# timestamp filename\n");
    for name in names {
        let stamp = name.trim_end_matches(".png");
        rgb += &format!("{stamp} rgb/{name}\n");
        depth += &format!("{stamp} depth/{name}\n");
    }
    let write = |name: &str, text: &str| {
        let path = dir.join(name);
        std::fs::write(&path, text).map_err(|source| IoError::Write { path, source })
    };
    write("rgb.txt", &rgb)?;
    write("depth.txt", &depth)?;
    if let Some(calibration) = sequence.calibration() {
        let mut calibration = calibration.clone();
        calibration.depth_scale = Some(TUM_DEPTH_SCALE);
        write(
            "calibration.yaml",
            &OrbSlamSettings::to_yaml(&calibration, &OrbSettings::default()),
        )?;
    }
    Ok(())
}
