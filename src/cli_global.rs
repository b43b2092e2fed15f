//! The global pass's tools on the command line: `dopslam vocab` (train and inspect a
//! place-recognition vocabulary) and `dopslam graph` (make and optimise g2o pose graphs).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};

use dopslam::bow::{TrainOptions, Vocabulary};
use dopslam::io::g2o::G2oGraph;
use dopslam::optim::pose_graph::{GraphOptions, PoseGraph};
use dopslam::synth::pose_graphs::{sphere, SphereSpec};

#[derive(Args)]
pub struct VocabArgs {
    #[command(subcommand)]
    command: VocabCommand,
}

#[derive(Subcommand)]
enum VocabCommand {
    /// Train a vocabulary on the ORB descriptors of images (PNG/JPEG files, or folders searched recursively).
    Train {
        /// Images or folders of images (e.g. generated sequences' rgb/ folders).
        inputs: Vec<PathBuf>,
        #[arg(short, long, default_value = "data/vocabulary.dbow")]
        out: PathBuf,
        /// Branching factor k (at least 2).
        #[arg(long, default_value_t = 10, value_parser = crate::cli_values::at_least_two)]
        branching: usize,
        /// Depth L (up to k^L words; at least 1).
        #[arg(long, default_value_t = 4, value_parser = crate::cli_values::at_least_one)]
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

#[derive(Args)]
pub struct GraphArgs {
    #[command(subcommand)]
    command: GraphCommand,
}

#[derive(Subcommand)]
enum GraphCommand {
    /// Write a seeded synthetic sphere graph (like sphere2500) and its ground truth as g2o files.
    Sphere {
        out: PathBuf,
        #[arg(long, default_value_t = 50, value_parser = crate::cli_values::at_least_two)]
        rings: usize,
        #[arg(long, default_value_t = 50, value_parser = crate::cli_values::at_least_one)]
        per_ring: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// Optimise a g2o 3-D pose graph (VERTEX_SE3:QUAT / EDGE_SE3:QUAT) and write the result.
    Optimise {
        input: PathBuf,
        #[arg(short, long)]
        out: Option<PathBuf>,
        #[arg(long, default_value_t = 50)]
        iterations: usize,
        /// Print the report as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// The PNG and JPEG images below `inputs` (depth maps and masks left out). Each folder
/// is listed once, by its real path: a symbolic link back to a folder above (a loop)
/// adds nothing; a link that leads nowhere inside a folder is skipped with a warning.
fn image_files(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
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

fn train(inputs: &[PathBuf], out: &Path, options: TrainOptions, max_images: usize) -> Result<()> {
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

pub fn run_graph(args: GraphArgs) -> Result<()> {
    match args.command {
        GraphCommand::Sphere {
            out,
            rings,
            per_ring,
            seed,
        } => {
            let spec = SphereSpec {
                rings,
                per_ring,
                ..SphereSpec::default()
            };
            let (graph, truth) = sphere(&spec, seed);
            let ids: Vec<u64> = (0..graph.poses.len() as u64).collect();
            graph.to_g2o(&ids).write(&out)?;
            let truth_path = out.with_extension("truth.g2o");
            PoseGraph {
                poses: truth,
                ..graph.clone()
            }
            .to_g2o(&ids)
            .write(&truth_path)?;
            println!(
                "wrote {} ({} poses, {} edges) and {}",
                out.display(),
                graph.poses.len(),
                graph.edges.len(),
                truth_path.display()
            );
            Ok(())
        }
        GraphCommand::Optimise {
            input,
            out,
            iterations,
            json,
        } => {
            let file = G2oGraph::read(&input)?;
            let (mut graph, ids) = PoseGraph::from_g2o(&file);
            let start = Instant::now();
            let report = graph.optimise(&GraphOptions {
                max_iterations: iterations,
                ..GraphOptions::default()
            });
            let ms = start.elapsed().as_secs_f64() * 1e3;
            if let Some(out) = &out {
                graph.to_g2o(&ids).write(out)?;
            }
            if json {
                let mut value = serde_json::to_value(report)?;
                value["milliseconds"] = serde_json::json!(ms);
                value["poses"] = serde_json::json!(graph.poses.len());
                value["edges"] = serde_json::json!(graph.edges.len());
                println!("{value}");
            } else {
                println!(
                    "{}: {} poses, {} edges; chi2 {:.6e} -> {:.6e} in {} iterations, {:.1} ms{}",
                    input.display(),
                    graph.poses.len(),
                    graph.edges.len(),
                    report.initial_cost,
                    report.final_cost,
                    report.iterations,
                    ms,
                    if report.converged {
                        ""
                    } else {
                        " (not converged)"
                    }
                );
            }
            Ok(())
        }
    }
}

/// Prints the global pass's summary.
pub fn print_global(global: &dopslam::global::GlobalReport) {
    let rejected = global.candidates.iter().filter(|c| !c.accepted).count();
    println!(
        "global pass: {} loop(s) closed, {} candidate(s) rejected (report.json lists why), {:.0} ms (place recognition beside tracking: {:.0} ms)",
        global.loops.len(),
        rejected,
        global.total_ms,
        global.loop_detection_ms
    );
    for l in &global.loops {
        println!(
            "  loop: keyframe {} (t {:.2}) -> {} (t {:.2}), {} inliers, {} guided matches, moved {:.3} m / {:.2} deg, {} points fused",
            l.pair.keyframe, l.pair.keyframe_time, l.pair.matched, l.pair.matched_time, l.inliers, l.guided_matches, l.correction_m, l.correction_deg, l.fused_points
        );
        if let Some(m) = l.merged {
            println!(
                "    merged map segment {} into segment {}",
                m.segment, m.into
            );
        }
    }
    if let Some(ba) = &global.full_ba {
        println!(
            "  full BA: {} keyframes, {} points, cost {:.4e} -> {:.4e}, {} outliers removed, {:.0} ms",
            ba.keyframes, ba.points, ba.initial_cost, ba.final_cost, ba.outliers_removed, ba.milliseconds
        );
    }
    if let Some(offset) = &global.disparity_offset {
        println!("  {}", offset.summary());
    }
    if let Some(note) = &global.note {
        println!("  {note}");
    }
}
