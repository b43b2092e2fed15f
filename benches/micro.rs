//! `cargo bench --bench micro`: the per-frame building blocks, timed on seeded
//! synthetic frames (not a test; `tools/bench.sh` puts the figures in its report):
//! ORB extraction at 640x480 (TUM) and 1241x376 (KITTI), TSDF integration of a
//! 640x480 depth frame, the registration of an Azure Kinect depth frame (640x576) into
//! the colour camera, trajectory evaluation (ATE + RPE) of a 30 s trajectory, and
//! what a frame writes to the run's spill files (its report line and its record).
//! Prints one `name: median ms (...)` line each. `RAYON_NUM_THREADS` sets the threads.

use std::time::Instant;

use dopslam::config::Config;
use dopslam::dense::tsdf::{FrameInput, TsdfVolume};
use dopslam::eval::report::{evaluate, EvalOptions, RpeSpec};
use dopslam::eval::rpe::DeltaUnit;
use dopslam::features::OrbExtractor;
use dopslam::synth::writer::World;
use dopslam::synth::SynthConfig;

const FRAMES: usize = 12;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Runs `work` on each input `rounds` times; the median milliseconds.
fn time<T>(inputs: &[T], rounds: usize, mut work: impl FnMut(&T)) -> f64 {
    let mut times = Vec::new();
    for _ in 0..rounds {
        for input in inputs {
            let start = Instant::now();
            work(input);
            times.push(start.elapsed().as_secs_f64() * 1e3);
        }
    }
    median(times)
}

fn main() {
    println!("threads: {}", rayon::current_num_threads());
    let preset =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/synth/walking_xyz.toml");
    let synth = SynthConfig::load(&preset).expect("the walking_xyz preset");
    let world = World::new(&synth).expect("the walking_xyz world");
    let rendered: Vec<_> = (0..FRAMES).map(|i| world.render(i * 20)).collect();
    let config = Config::default();
    let extractor = OrbExtractor::new(&config.orb);

    let grey: Vec<image::GrayImage> = rendered
        .iter()
        .map(|r| image::imageops::grayscale(&r.rgb))
        .collect();
    let mut keypoints = 0;
    let ms = time(&grey, 3, |g| keypoints = extractor.extract(g).len());
    println!(
        "ORB extraction 640x480 ({} features, {} levels): {ms:.2} ms median ({keypoints} keypoints)",
        config.orb.n_features, config.orb.n_levels
    );
    let wide: Vec<image::GrayImage> = grey
        .iter()
        .map(|g| image::imageops::resize(g, 1241, 376, image::imageops::FilterType::Triangle))
        .collect();
    let kitti = OrbExtractor::new(&dopslam::features::orb::OrbConfig {
        n_features: 2000,
        ..config.orb.clone()
    });
    let ms = time(&wide, 3, |g| keypoints = kitti.extract(g).len());
    println!("ORB extraction 1241x376 (2000 features, as ORB-SLAM2 on KITTI): {ms:.2} ms median ({keypoints} keypoints)");

    let mut volume = TsdfVolume::new(config.dense.tsdf(), world.camera);
    let frames: Vec<usize> = (0..FRAMES).collect();
    let ms = time(&frames, 1, |&i| {
        let camera_from_world = world.poses[i * 20].inverse();
        volume
            .integrate(&FrameInput {
                depth: &rendered[i].depth,
                colour: &rendered[i].rgb,
                dynamic: None,
                camera_from_world: &camera_from_world,
                weight: 1.0,
            })
            .expect("no spill file");
    });
    println!(
        "TSDF integration 640x480 (voxel {} m): {ms:.2} ms median per frame ({} blocks)",
        config.dense.tsdf.voxel,
        volume.blocks.len()
    );

    registration(&rendered);
    spills();

    let (reference, estimate) = dopslam::demo::demo_trajectories(1, 30.0, 0.004);
    let options = EvalOptions {
        rpe: vec![RpeSpec {
            delta: 1.0,
            unit: DeltaUnit::Seconds,
        }],
        ..EvalOptions::default()
    };
    let mut rmse = 0.0;
    let ms = time(&[()], 20, |_| {
        rmse = evaluate(&reference, &estimate, &options)
            .expect("evaluation")
            .ape
            .statistics
            .rmse;
    });
    println!(
        "evaluation (ATE + RPE 1 s) of {} poses against {}: {ms:.2} ms median (APE RMSE {rmse:.4} m)",
        estimate.len(),
        reference.len()
    );
}

/// The rendered depths seen by an Azure Kinect's depth camera (640x576, rows repeated to
/// its height), registered into a 640x480 colour camera 32 mm beside it, both lenses
/// with the rational model's distortion of a real unit.
fn registration(rendered: &[dopslam::synth::render::Rendered]) {
    use dopslam::geometry::camera::PinholeCamera;
    use dopslam::io::image_files::DepthImage;
    use dopslam::io::recording::register::Registration;
    let lens = |f: f64, (w, h): (u32, u32), distortion, rational| {
        let mut lens = PinholeCamera::tum_fr3();
        (lens.fx, lens.fy, lens.width, lens.height) = (f, f, w, h);
        (lens.cx, lens.cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        (lens.distortion, lens.rational) = (distortion, rational);
        lens
    };
    let depth_camera = lens(
        504.0,
        (640, 576),
        [0.6, 0.1, 0.0, 0.0, 0.002],
        [0.9, 0.25, 0.01],
    );
    let colour = lens(
        525.0,
        (640, 480),
        [0.5, -2.6, 0.0006, -0.0002, 1.5],
        [0.4, -2.4, 1.4],
    );
    let offset = nalgebra::Isometry3::translation(-0.032, 0.002, 0.004);
    let registration = Registration::new(&depth_camera, &colour, offset);
    let depths: Vec<DepthImage> = rendered
        .iter()
        .map(|r| DepthImage {
            width: 640,
            height: 576,
            metres: (0..576)
                .flat_map(|v| &r.depth.metres[v * 480 / 576 * 640..][..640])
                .copied()
                .collect(),
        })
        .collect();
    let mut valid = 0;
    let ms = time(&depths, 3, |d| {
        let out = registration.apply(d).expect("the depth camera's size");
        valid = out.metres.iter().filter(|&&z| z > 0.0).count();
    });
    println!("depth registration 640x576 into 640x480 (rational lenses): {ms:.2} ms median ({valid} colour pixels with depth)");
}

/// A street frame's report line and its record with 370 observations (the street's
/// median) pushed to spill files, as the tracking pass does each frame.
fn spills() {
    use dopslam::geometry::se3::Se3;
    use dopslam::map::record::{FrameObservation, FrameRecord, FrameRecords};
    use dopslam::records::{FrameLine, FrameLines};
    let dir = std::env::temp_dir().join(format!("dopslam-bench-spills-{}", std::process::id()));
    let line: FrameLine = serde_json::from_str(
        r#"{"index": 100, "timestamp": 10.0, "state": "ok", "segment": 0, "keypoints": 2001,
        "matches": 409, "inliers": 408, "keyframe": false, "dynamic_keypoints": 1,
        "dynamic_map_points": 6, "geometric_raised": 4, "geometric_lowered": 82,
        "rigidity_outliers": 1, "matching_ms": 0.883, "optimisation_ms": 0.524,
        "dop_ms": 0.951, "extraction_ms": 18.44, "tracking_ms": 21.42}"#,
    )
    .expect("a frame line");
    let mut points: slotmap::SlotMap<dopslam::map::MapPointKey, ()> = slotmap::SlotMap::with_key();
    let observations: Vec<FrameObservation> = (0..370)
        .map(|i| FrameObservation {
            point: points.insert(()),
            keypoint: i,
            x: i as f32,
            y: 2.0 * i as f32,
            right_u: i as f32 - 3.0,
            level: (i % 8) as u8,
        })
        .collect();
    let record = FrameRecord {
        camera_from_world: Some(Se3::identity()),
        observations,
        ..FrameRecord::start(10.0, 0)
    };
    let mut lines = FrameLines::spilling_into(&dir).expect("a spill file");
    let mut records = FrameRecords::spilling_into(&dir).expect("spill files");
    let frames: Vec<usize> = (0..2000).collect();
    let ms = time(&frames, 1, |_| {
        lines.push(line.clone()).expect("a line written");
        records.push(record.clone()).expect("a record written");
    });
    drop((lines, records));
    let _ = std::fs::remove_dir(&dir);
    println!(
        "a frame's report line and record (370 observations) to the spill files: {ms:.4} ms median"
    );
}
