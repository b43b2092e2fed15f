//! `dopslam info`: what a sequence folder or a recording holds.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;
use dopslam::config::Config;
use dopslam::io::kitti::KittiSequence;
use dopslam::io::recording::RecordingSequence;
use dopslam::io::sequence::Sequence;
use dopslam::io::tum::TumSequence;

use super::load_config;

#[derive(Args)]
pub struct InfoArgs {
    /// The sequence folder, or a recording (ROS 1 .bag, ROS 2 bag folder, .mcap, .db3).
    sequence: PathBuf,
    /// A TOML config ([dataset] section: depth scale, association tolerance or file).
    #[arg(long)]
    config: Option<PathBuf>,
    #[command(flatten)]
    topics: super::topics::TopicArgs,
    /// Also decode every frame, one core, and say how fast (frames/s) and at what peak
    /// memory: checks that a recording or folder reads whole, and that reading is no
    /// bottleneck.
    #[arg(long)]
    read_frames: bool,
}

pub fn run_info(args: InfoArgs) -> Result<()> {
    let mut config = load_config(args.config.as_deref())?;
    let root = &args.sequence;
    if dopslam::io::recording::is_recording(root) {
        args.topics.apply(&mut config);
        print_recording_info(root, &config)?;
    } else {
        describe_folder(root, &config)?;
    }
    if args.read_frames {
        read_all_frames(root, &config)?;
    }
    Ok(())
}

/// `dopslam info` on a TUM/Bonn or KITTI folder.
pub fn describe_folder(root: &Path, config: &Config) -> Result<()> {
    dopslam::run::check_sequence_folder(root)?;
    let sequence: Box<dyn Sequence> = if root.join("image_0").is_dir() {
        Box::new(KittiSequence::open(root, None)?)
    } else {
        let options = config.dataset.tum_options();
        let tum = TumSequence::open(root, &options)?;
        println!(
            "rgb.txt / depth.txt entries: {} / {}, paired: {} (tolerance {} s)",
            tum.listed.0,
            tum.listed.1,
            tum.len(),
            options.max_difference
        );
        Box::new(tum)
    };
    println!(
        "sequence {} ({:?}): {} frames",
        sequence.name(),
        sequence.sensor(),
        sequence.len()
    );
    if !sequence.is_empty() {
        let (first, last) = (
            sequence.timestamp(0),
            sequence.timestamp(sequence.len() - 1),
        );
        println!("time span {:.3} s ({first:.6} .. {last:.6})", last - first);
    }
    match sequence.calibration() {
        Some(c) => println!(
            "calibration: {:?}, bf {:?}, depth scale {:?}",
            c.camera, c.bf, c.depth_scale
        ),
        None => {
            println!("calibration: none found (give one with [dataset] settings = \"camera.yaml\")")
        }
    }
    match sequence.ground_truth() {
        Some(gt) => println!(
            "ground truth: {} poses, path length {:.3} m",
            gt.len(),
            gt.path_length()
        ),
        None => println!("ground truth: none"),
    }
    Ok(())
}

/// `dopslam info` on a recording: its topics with rates, the ones chosen, the frames
/// paired, the calibration found and what the scan warned about.
pub fn print_recording_info(path: &Path, config: &Config) -> Result<()> {
    let recording = RecordingSequence::open(path, &config.dataset.recording_options())?;
    let d = &recording.description;
    println!("recording {}: {} topics", path.display(), d.topics.len());
    print_streams(d);
    println!(
        "frames: {} {} pairs (tolerance {} s)",
        d.frames,
        if d.stereo {
            "left/right"
        } else {
            "colour/depth"
        },
        config.dataset.max_difference
    );
    if !recording.is_empty() {
        let (first, last) = (
            recording.timestamp(0),
            recording.timestamp(recording.len() - 1),
        );
        println!("time span {:.3} s ({first:.6} .. {last:.6})", last - first);
    }
    if let Some(c) = recording.calibration() {
        print_calibration(c);
    }
    if let Some(truth) = recording.ground_truth() {
        println!(
            "ground truth: {} poses, path length {:.3} m",
            truth.len(),
            truth.path_length()
        );
    }
    for warning in &d.warnings {
        println!("warning: {warning}");
    }
    Ok(())
}

/// The topics of a recording's description, the streams chosen and the camera info.
fn print_streams(d: &dopslam::io::recording::frames::Description) {
    for (name, msg_type, count, rate) in &d.topics {
        println!("  {name:<40} {msg_type:<28} {count:>7} messages  {rate:>6.1} Hz");
    }
    if d.stereo {
        println!(
            "stereo pair: left {}, right {} (rectified)",
            d.colour, d.depth
        );
    } else {
        let registration = if d.registered {
            "recorded in the colour camera".to_owned()
        } else {
            format!(
                "in its own camera: registered into the colour camera by {}",
                d.registered_by.as_deref().unwrap_or("?")
            )
        };
        println!(
            "colour: {}\ndepth: {} ({registration}), {} units per metre",
            d.colour, d.depth, d.depth_scale
        );
    }
    for note in &d.notes {
        println!("  {note}");
    }
    match (&d.camera_info, &d.cameras_from) {
        (Some(topic), _) => println!("camera info: {topic}"),
        (None, Some(from)) => println!("cameras: from {from}"),
        (None, None) => {
            println!("camera info: none (give the calibration with --settings or --camera)")
        }
    }
}

/// A recording's calibration, one line.
fn print_calibration(c: &dopslam::io::orbslam_settings::Calibration) {
    let k = &c.camera;
    println!(
        "calibration: fx {:.3} fy {:.3} cx {:.3} cy {:.3}, {}x{}, distortion {:?}{}, {:.1} Hz{}",
        k.fx,
        k.fy,
        k.cx,
        k.cy,
        k.width,
        k.height,
        k.distortion,
        if k.rational.iter().any(|&v| v != 0.0) {
            format!(" rational {:?}", k.rational)
        } else {
            String::new()
        },
        c.fps.unwrap_or(0.0),
        c.bf.map_or(String::new(), |bf| format!(
            ", bf {bf:.3} (baseline {:.4} m)",
            bf / k.fx
        ))
    );
}

/// `dopslam info --read-frames`: decodes every frame on this thread and prints the rate
/// and the process's peak memory.
pub fn read_all_frames(path: &Path, config: &Config) -> Result<()> {
    let sequence = dopslam::run::open_sequence(path, config)?;
    let start = std::time::Instant::now();
    for index in 0..sequence.len() {
        std::hint::black_box(sequence.load(index)?);
    }
    let seconds = start.elapsed().as_secs_f64();
    let peak = dopslam::memory::peak_resident_mib().map_or("?".into(), |m| format!("{m:.0}"));
    println!(
        "read {} frames in {seconds:.2} s ({:.1} frames/s, one core), peak memory {peak} MiB",
        sequence.len(),
        sequence.len() as f64 / seconds.max(1e-9)
    );
    Ok(())
}
