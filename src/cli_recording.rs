//! The command line's side of recordings (ROS bags, MCAP): the topic options shared by
//! `info`, `run` and `detect`, and what `dopslam info` prints about a recording.

use std::path::Path;

use anyhow::{Context, Result};
use clap::Args;
use dopslam::config::Config;
use dopslam::io::recording::convert::{self, Layout};
use dopslam::io::recording::{RecordingSequence, TopicChoice};
use dopslam::io::sequence::Sequence;

/// Which topics of a recording make the frames (override `[dataset]`'s keys).
#[derive(Args, Debug, Clone, Default)]
pub struct TopicArgs {
    /// A recording's colour topic (sensor_msgs/Image or CompressedImage); default: found
    /// from the messages' encodings.
    #[arg(long)]
    pub rgb_topic: Option<String>,
    /// A recording's depth topic, registered to the colour camera; default: found.
    #[arg(long)]
    pub depth_topic: Option<String>,
    /// A recording's sensor_msgs/CameraInfo topic; default: the colour topic's.
    #[arg(long)]
    pub camera_info_topic: Option<String>,
    /// A recording's pose topic (PoseStamped, Odometry, TransformStamped) to evaluate
    /// the trajectory against.
    #[arg(long)]
    pub ground_truth_topic: Option<String>,
    /// A TUM trajectory file to evaluate a recording's run against (a recording without
    /// a pose topic).
    #[arg(long, value_name = "FILE")]
    pub ground_truth: Option<std::path::PathBuf>,
}

impl TopicArgs {
    /// Writes the topics given into the config's `[dataset]`.
    pub fn apply(&self, config: &mut Config) {
        config.dataset.override_topics(&TopicChoice {
            rgb: self.rgb_topic.clone(),
            depth: self.depth_topic.clone(),
            camera_info: self.camera_info_topic.clone(),
            ground_truth: self.ground_truth_topic.clone(),
        });
        if self.ground_truth.is_some() {
            config
                .dataset
                .ground_truth_file
                .clone_from(&self.ground_truth);
        }
    }
}

/// `dopslam info` on a recording: its topics with rates, the ones chosen, the frames
/// paired, the calibration found and what the scan warned about.
pub fn print_recording_info(path: &Path, config: &Config) -> Result<()> {
    let recording = RecordingSequence::open(path, &config.dataset.recording_options())?;
    let d = &recording.description;
    println!("recording {}: {} topics", path.display(), d.topics.len());
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

/// The layouts `dopslam convert` writes.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum LayoutArg {
    /// TUM RGB-D (RGB-D recordings): rgb/ and depth/ PNGs (16-bit, 5000 per metre),
    /// rgb.txt, depth.txt, calibration.yaml.
    Tum,
    /// KITTI odometry (stereo recordings): image_0/, image_1/, times.txt, calib.txt.
    Kitti,
}

/// `dopslam convert`.
#[derive(Args, Debug)]
pub struct ConvertArgs {
    /// A recording (ROS 1 .bag, ROS 2 bag folder, .mcap, .db3) or any RGB-D sequence.
    input: std::path::PathBuf,
    /// The layout to write.
    #[arg(long, value_enum, default_value = "tum")]
    to: LayoutArg,
    /// The output folder: must not exist yet (or be empty).
    out: std::path::PathBuf,
    /// A TOML config ([dataset]: depth scale, tolerance, topics).
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Convert only the first N frames.
    #[arg(long)]
    frames: Option<usize>,
    #[command(flatten)]
    topics: TopicArgs,
}

/// Runs `dopslam convert`.
pub fn run_convert(args: ConvertArgs, mut config: Config) -> Result<()> {
    args.topics.apply(&mut config);
    let layout = match args.to {
        LayoutArg::Tum => Layout::Tum,
        LayoutArg::Kitti => Layout::Kitti,
    };
    // The output is checked before the recording is scanned (which can take a while).
    if dopslam::io::output::is_within(&args.out, &args.input) {
        anyhow::bail!(
            "{}: the output folder is inside the input {}: dopslam never writes into its inputs; choose a folder elsewhere",
            args.out.display(),
            args.input.display()
        );
    }
    let partial = convert::prepare(&args.out, layout)?;
    std::fs::remove_dir_all(&partial)?;
    let sequence = dopslam::run::open_sequence(&args.input, &config)?;
    let frames = args.frames.unwrap_or(usize::MAX).min(sequence.len());
    let written = convert::convert(sequence.as_ref(), &args.out, frames, layout, true)?;
    // What the reader found wrong and read past (a recording cut short, no index) stays
    // with the converted folder.
    if !sequence.warnings().is_empty() {
        let path = args.out.join("conversion_warnings.txt");
        std::fs::write(&path, sequence.warnings().join("\n") + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!(
            "what the reader found wrong with the recording is kept in {}",
            path.display()
        );
    }
    println!(
        "wrote {written} frames to {} ({layout:?} layout)",
        args.out.display()
    );
    Ok(())
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
