//! `dopslam vocab`: train or inspect the place-recognition vocabulary.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use dopslam::bow::{TrainOptions, Vocabulary};
use indicatif::{ProgressBar, ProgressStyle};

#[derive(Args)]
pub struct VocabArgs {
    #[command(subcommand)]
    command: VocabCommand,
}

#[derive(Subcommand)]
pub enum VocabCommand {
    /// Train a vocabulary on the ORB descriptors of images (PNG/JPEG files, or folders searched recursively).
    Train {
        /// Images or folders of images (e.g. generated sequences' rgb/ folders).
        inputs: Vec<PathBuf>,
        #[arg(short, long, default_value = "data/vocabulary.dbow")]
        out: PathBuf,
        /// Branching factor k (at least 2).
        #[arg(long, default_value_t = 10, value_parser = super::values::at_least_two)]
        branching: usize,
        /// Depth L (up to k^L words; at least 1).
        #[arg(long, default_value_t = 4, value_parser = super::values::at_least_one)]
        depth: usize,
        /// Use at most this many images (evenly spaced).
        #[arg(long, default_value_t = 2000)]
        max_images: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Load a vocabulary and print its size and load time.
    Info { path: PathBuf },
}

/// The PNG and JPEG images below `inputs` (depth maps and masks left out). Each folder
/// is listed once, by its real path: a symbolic link back to a folder above (a loop)
/// adds nothing; a link that leads nowhere inside a folder is skipped with a warning.
pub fn image_files(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut files = Vec::new();
    let mut listed = std::collections::HashSet::new();
    let mut stack: Vec<(PathBuf, bool)> = inputs.iter().map(|p| (p.clone(), true)).collect();
    while let Some((path, given)) = stack.pop() {
        if path.is_dir() {
            let real = path.canonicalize().unwrap_or_else(|_| path.clone());
            if !listed.insert(real) {
                continue;
            }
            for entry in std::fs::read_dir(&path)
                .with_context(|| format!("cannot list {}", path.display()))?
            {
                stack.push((entry?.path(), false));
            }
        } else if path.is_file() {
            let ext = path
                .extension()
                .and_then(|e| e.to_str())
                .unwrap_or("")
                .to_ascii_lowercase();
            // Depth maps and masks are 16-bit PNGs in folders named so: skip them.
            let skip = path
                .components()
                .any(|c| matches!(c.as_os_str().to_str(), Some("depth" | "masks")))
                || path
                    .file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.contains("depth"));
            if matches!(ext.as_str(), "png" | "jpg" | "jpeg") && !skip {
                files.push(path);
            }
        } else if given {
            bail!("{}: no such file or folder", path.display());
        } else {
            eprintln!(
                "warning: {}: a symbolic link that leads to no file or folder (a loop, or its target is gone): skipped",
                path.display()
            );
        }
    }
    files.sort();
    Ok(files)
}

pub fn train(
    inputs: &[PathBuf],
    out: &Path,
    options: TrainOptions,
    max_images: usize,
) -> Result<()> {
    // The output can be written (and replaces no input) before any training.
    let mut files = image_files(inputs)?;
    let input_refs: Vec<&Path> = files.iter().map(PathBuf::as_path).collect();
    dopslam::io::output::check_file(out, "vocabulary", &input_refs)?;
    if files.is_empty() {
        bail!("no PNG or JPEG images in {:?}", inputs);
    }
    if files.len() > max_images {
        let step = files.len() as f64 / max_images as f64;
        files = (0..max_images)
            .map(|i| files[(i as f64 * step) as usize].clone())
            .collect();
    }
    let extractor = dopslam::features::OrbExtractor::new(&dopslam::config::Config::default().orb);
    let bar = ProgressBar::new(files.len() as u64);
    bar.set_style(
        ProgressStyle::with_template("ORB {bar:40} {pos}/{len} images ({eta} left)")
            .expect("template"),
    );
    let mut images = Vec::with_capacity(files.len());
    for path in &files {
        let grey = dopslam::io::image_files::read_gray(path)?;
        images.push(extractor.extract(&grey).descriptors);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let descriptors: usize = images.iter().map(Vec::len).sum();
    if descriptors == 0 {
        bail!(
            "the {} images have no ORB keypoints (blank or black?): no vocabulary was written",
            images.len()
        );
    }
    eprintln!(
        "training on {descriptors} descriptors of {} images (k = {}, L = {})",
        images.len(),
        options.branching,
        options.depth
    );
    let start = Instant::now();
    let vocabulary = Vocabulary::train(&images, &options);
    if vocabulary.len() < 2 {
        bail!(
            "training gave {} word(s) from {descriptors} descriptors: too little texture to tell places apart; no vocabulary was written",
            vocabulary.len()
        );
    }
    vocabulary.write(out)?;
    println!(
        "wrote {} ({} words, trained in {:.1} s)",
        out.display(),
        vocabulary.len(),
        start.elapsed().as_secs_f64()
    );
    Ok(())
}

pub fn run_vocab(args: VocabArgs) -> Result<()> {
    match args.command {
        VocabCommand::Train {
            inputs,
            out,
            branching,
            depth,
            max_images,
            seed,
        } => train(
            &inputs,
            &out,
            TrainOptions {
                branching,
                depth,
                seed,
                ..TrainOptions::default()
            },
            max_images,
        ),
        VocabCommand::Info { path } => {
            let start = Instant::now();
            let vocabulary = Vocabulary::read(&path)?;
            println!(
                "{}: k = {}, L = {}, {} words, loaded in {:.1} ms",
                path.display(),
                vocabulary.branching,
                vocabulary.depth,
                vocabulary.len(),
                start.elapsed().as_secs_f64() * 1e3
            );
            Ok(())
        }
    }
}
