//! `dopslam detect`: COCO detections on an image or a sequence, printed and drawn.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;
use dopslam::io::atomic::write_atomic;

use super::load_config;

#[derive(Args)]
pub struct DetectArgs {
    /// An image file, a sequence folder (TUM/Bonn RGB-D layout) or a recording (ROS bag, MCAP).
    input: PathBuf,
    /// A TOML config whose [detector] section picks the model (default: YOLOv4-tiny ONNX).
    #[arg(long)]
    config: Option<PathBuf>,
    /// The model: yolov4-tiny, yolox-nano or deimv2-femto, from its installed file
    /// unless --model-path names one (overrides the config's models).
    #[arg(long, value_enum)]
    model: Option<DetectModelArg>,
    /// The model file (overrides the config); repeat it to run several files of the
    /// model (the same weights at several input sizes) and merge their boxes.
    #[arg(long)]
    model_path: Vec<PathBuf>,
    /// Output folder: annotated PNGs and per-frame JSON (a detection cache).
    #[arg(long, default_value = "outputs/detect")]
    out: PathBuf,
    /// For a sequence: detect every Nth frame.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
    /// Also detect on N x N overlapping tiles of each image and merge the boxes
    /// (overrides the config's [detector] tiles; 1: the whole image only).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=4))]
    tiles: Option<u32>,
    /// Print the detections as JSON on stdout (one array: per image or frame its name,
    /// timestamp, milliseconds and detections) instead of the table.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    topics: super::topics::TopicArgs,
}

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum DetectModelArg {
    Yolov4Tiny,
    YoloxNano,
    Deimv2Femto,
}

/// Before any work: `detect` writes neither into an input sequence nor over an input
/// image (`NAME.png` and `NAME.json` in `--out`), and `--out` can be written.
pub fn check_detect_outputs(args: &DetectArgs) -> Result<()> {
    use dopslam::io::output::{check_file, prepare_dir};
    if args.input.is_dir() {
        prepare_dir(&args.out, "output", &[&args.input])?;
        return Ok(());
    }
    let name = args
        .input
        .file_stem()
        .map_or("image".into(), |s| s.to_string_lossy().into_owned());
    for ext in ["png", "json"] {
        check_file(
            &args.out.join(format!("{name}.{ext}")),
            "detection output",
            &[&args.input],
        )?;
    }
    prepare_dir(&args.out, "output", &[])?;
    Ok(())
}

pub fn run_detect(args: DetectArgs) -> Result<()> {
    use dopslam::detect::{Model, Models, Source};
    let config = load_config(args.config.as_deref())?;
    check_detect_outputs(&args)?;
    let mut detector_config = config.detector.clone();
    if matches!(detector_config.source, Source::None | Source::Auto) {
        detector_config.source = Source::Onnx;
    }
    if args.model.is_some() || !args.model_path.is_empty() {
        let model = match args.model {
            Some(DetectModelArg::Yolov4Tiny) => Model::Yolov4Tiny,
            Some(DetectModelArg::YoloxNano) => Model::YoloxNano,
            Some(DetectModelArg::Deimv2Femto) => Model::Deimv2Femto,
            None => detector_config.models.model().unwrap_or(Model::Yolov4Tiny),
        };
        detector_config.models = match args.model_path.len() {
            0 => Models::One { model, path: None },
            1 => Models::One {
                model,
                path: Some(args.model_path[0].clone()),
            },
            _ => Models::Sizes {
                model,
                paths: args.model_path.clone(),
            },
        };
    }
    if let Some(tiles) = args.tiles {
        detector_config.tiles = tiles;
    }
    let mut detector = detector_config
        .open(args.input.is_dir().then_some(args.input.as_path()))?
        .expect("a source other than none");
    let mut all = Vec::new();
    let mut detect_one = |name: String, timestamp: f64, image: image::RgbImage| -> Result<()> {
        let named = NamedImage {
            name,
            timestamp,
            image,
        };
        all.push(detect_and_write(detector.as_mut(), &args, named)?);
        Ok(())
    };
    if args.input.is_dir() || dopslam::io::recording::is_recording(&args.input) {
        let mut config = config.clone();
        args.topics.apply(&mut config);
        let sequence = dopslam::run::open_sequence(&args.input, &config)?;
        // One frame at a time: a long sequence is never held whole.
        for index in (0..sequence.len()).step_by(args.every as usize) {
            let frame = sequence.load(index)?;
            let image = match frame.images {
                dopslam::io::sequence::FrameImages::Rgbd { rgb, .. } => rgb,
                // The left image, in colour, as the tracking pass hands it to the detector.
                dopslam::io::sequence::FrameImages::Stereo { left, .. } => {
                    image::DynamicImage::ImageLuma8(left).to_rgb8()
                }
            };
            detect_one(format!("{:.6}", frame.timestamp), frame.timestamp, image)?;
        }
    } else {
        let image = image::open(&args.input)
            .with_context(|| format!("cannot read image {}", args.input.display()))?
            .to_rgb8();
        let name = args
            .input
            .file_stem()
            .map_or("image".into(), |s| s.to_string_lossy().into_owned());
        detect_one(name, 0.0, image)?;
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&all)?);
        eprintln!("wrote {}", args.out.display());
    } else {
        println!("wrote {}", args.out.display());
    }
    Ok(())
}

/// An image `dopslam detect` reads: its name in the outputs and its timestamp (0 for a
/// single image).
pub struct NamedImage {
    name: String,
    timestamp: f64,
    image: image::RgbImage,
}

/// Detects on one image of `dopslam detect`, prints its boxes (unless `--json`), writes
/// the image with its boxes drawn and the detections (a sequence's into its detection
/// cache), and returns the image's entry of the `--json` list.
pub fn detect_and_write(
    detector: &mut dyn dopslam::detect::Detector,
    args: &DetectArgs,
    named: NamedImage,
) -> Result<serde_json::Value> {
    let NamedImage {
        name,
        timestamp,
        mut image,
    } = named;
    use dopslam::detect::{draw::draw_detections, FrameDetections};
    let start = std::time::Instant::now();
    let detections = detector.detect(timestamp, &image)?;
    let ms = start.elapsed().as_secs_f64() * 1e3;
    if !args.json {
        println!("{name}: {} detections ({ms:.1} ms)", detections.len());
        for d in &detections {
            let [x1, y1, x2, y2] = d.bbox;
            println!(
                "  {} {:.2} [{x1:.0},{y1:.0},{x2:.0},{y2:.0}]",
                d.class, d.score
            );
        }
    }
    draw_detections(&mut image, &detections);
    let png = args.out.join(format!("{name}.png"));
    image
        .save(&png)
        .with_context(|| format!("cannot write {}", png.display()))?;
    let frame = FrameDetections {
        timestamp,
        detections,
    };
    if args.input.is_dir() {
        dopslam::detect::write_cache(&args.out.join("detections"), &frame)?;
    } else {
        // The same per-frame JSON as a sequence's detection cache.
        let json = serde_json::to_string_pretty(&frame)?;
        write_atomic(&args.out.join(format!("{name}.json")), json.as_bytes())?;
    }
    Ok(serde_json::json!({
        "name": name,
        "timestamp": timestamp,
        "milliseconds": ms,
        "detections": frame.detections,
    }))
}
