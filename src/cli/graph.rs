//! `dopslam graph`: 3-D pose graphs in g2o's format, made and optimised.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::Result;
use clap::{Args, Subcommand};
use dopslam::io::g2o::G2oGraph;
use dopslam::optim::pose_graph::{GraphOptions, PoseGraph};
use dopslam::synth::pose_graphs::{sphere, SphereSpec};

#[derive(Args)]
pub struct GraphArgs {
    #[command(subcommand)]
    command: GraphCommand,
}

#[derive(Subcommand)]
pub enum GraphCommand {
    /// Write a seeded synthetic sphere graph (like sphere2500) and its ground truth as g2o files.
    Sphere {
        out: PathBuf,
        #[arg(long, default_value_t = 50, value_parser = super::values::at_least_two)]
        rings: usize,
        #[arg(long, default_value_t = 50, value_parser = super::values::at_least_one)]
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
