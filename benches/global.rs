//! `cargo bench --bench global`: the global pass's solvers on seeded synthetic problems,
//! timed (not a test; targets in the README): vocabulary load, the sphere pose graph
//! (2500 poses, like sphere2500), and full bundle adjustment on a 225-keyframe problem
//! (like TUM fr3 office in ORB-SLAM2) and a 500-keyframe / 50k-point one.
//! `RAYON_NUM_THREADS` sets the threads (2 on the project's machines).

use std::time::Instant;

use dopslam::bow::Vocabulary;
use dopslam::geometry::stereo_camera::StereoCamera;
use dopslam::optim::local_ba::bundle_adjust;
use dopslam::optim::pose_graph::GraphOptions;
use dopslam::synth::ba_problems::{centre_rmse, room_problem, BaSpec};
use dopslam::synth::pose_graphs::{position_rmse, sphere, SphereSpec};

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    println!("threads: {}", rayon::current_num_threads());
    let path = std::path::Path::new("data/vocabulary.dbow");
    if path.exists() {
        let times: Vec<f64> = (0..5)
            .map(|_| {
                let start = Instant::now();
                let v = Vocabulary::read(path).expect("vocabulary");
                assert!(!v.is_empty());
                start.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        println!(
            "vocabulary load ({}): {:.2} ms (median of 5)",
            path.display(),
            median(times)
        );
    }
    let times: Vec<(f64, f64, f64, usize)> = (0..3)
        .map(|_| {
            let (mut graph, truth) = sphere(&SphereSpec::default(), 1);
            let start = Instant::now();
            let report = graph.optimise(&GraphOptions::default());
            let ms = start.elapsed().as_secs_f64() * 1e3;
            (
                ms,
                report.final_cost,
                position_rmse(&graph.poses, &truth),
                report.iterations,
            )
        })
        .collect();
    // Every run solves the same seeded graph: cost, error and iterations agree.
    let (_, cost, rmse, iterations) = times[0];
    println!(
        "pose graph sphere 2500 poses: {:.0} ms (median of 3; {iterations} iterations), chi2 {cost:.1}, position RMSE {rmse:.3} m on a 50 m sphere",
        median(times.iter().map(|t| t.0).collect())
    );
    let camera = StereoCamera::new(&dopslam::geometry::camera::PinholeCamera::tum_fr3(), 40.0);
    for (keyframes, points) in [(225, 20_000), (500, 50_000)] {
        let (mut problem, poses, _) = room_problem(&BaSpec::new(keyframes, points), &camera, 1);
        let observations = problem.observations.len();
        let before = centre_rmse(&problem.poses, &poses);
        let start = Instant::now();
        let report = bundle_adjust(&mut problem, &camera, 10, 5);
        let ms = start.elapsed().as_secs_f64() * 1e3;
        println!(
            "full BA {keyframes} keyframes, {points} points, {observations} observations: {ms:.0} ms (10 robust + 5 inlier iterations), cost {:.4e} -> {:.4e}, centre RMSE {before:.4} -> {:.5} m",
            report.initial_cost,
            report.final_cost,
            centre_rmse(&problem.poses, &poses)
        );
    }
}
