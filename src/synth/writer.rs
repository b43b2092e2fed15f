//! Writing a generated sequence in the TUM RGB-D layout: `rgb/`, `depth/` (16-bit,
//! 5000 per metre), `rgb.txt`, `depth.txt`, `groundtruth.txt`, `associations.txt`
//! (ORB-SLAM style), `calibration.yaml` (ORB-SLAM2 settings) and `scene.toml` (the
//! config as used, enough to regenerate the sequence); with stereo on, also the KITTI
//! odometry layout under `kitti/` (`sequences/00/{image_0,image_1,calib.txt,times.txt}`,
//! `poses/00.txt`).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use nalgebra::Vector3;
use thiserror::Error;

use super::config::SynthConfig;
use super::motion::poses_at;
use super::movers::{place_objects, place_people, place_seated, place_table, Appearance, Mover};
use super::oracle::OracleConfig;
use super::render::{render, render_colour, render_depth, Exposure, Rendered, View};
use super::scene::Scene;
use super::sprite::Sprite;
use crate::detect::{Detection, FrameDetections};
use crate::geometry::camera::PinholeCamera;
use crate::geometry::mesh::Mesh;
use crate::geometry::se3::Se3;
use crate::io::atomic::write_atomic;
use crate::io::file_list::read_file_list;
use crate::io::image_files::{depth_to_png16, DepthImage};
use crate::io::orbslam_settings::{Calibration, OrbSettings, OrbSlamSettings};
use crate::io::ply::{write_ply, PlyEncoding};
use crate::io::trajectory::TrajectoryFormat;
use crate::io::{IoError, Trajectory};
use crate::random::Rng;
use rayon::prelude::*;

/// The depth PNG scale of generated sequences (TUM's).
pub const DEPTH_SCALE: f64 = 5000.0;

/// Why a sequence cannot be generated.
#[derive(Debug, Error)]
pub enum SynthError {
    #[error("output folder {0} is not empty; choose another or pass --force to overwrite")]
    /// The output folder is not empty.
    NotEmpty(PathBuf),
    #[error("{0}")]
    /// The config cannot be written or read back.
    Config(String),
    #[error(transparent)]
    /// A value out of its range.
    Value(#[from] crate::checks::BadValue),
    #[error(transparent)]
    /// A file that cannot be read or written.
    Io(#[from] IoError),
}

/// What `generate` wrote.
#[derive(Debug, Clone)]
pub struct SynthSummary {
    /// Frames written.
    pub frames: usize,
    /// The folder.
    pub out: PathBuf,
    /// The time it took.
    pub seconds: f64,
}

/// Frame times in seconds from the start and the absolute timestamp of the first frame.
pub fn frame_times(config: &SynthConfig) -> Result<(Vec<f64>, f64), SynthError> {
    let n = config.sequence.frames;
    match &config.sequence.timing {
        Some(path) => {
            let entries = read_file_list(path, 1)?;
            if entries.len() < n {
                return Err(IoError::invalid(
                    path,
                    format!(
                        "has {} frame times but {n} frames were asked for",
                        entries.len()
                    ),
                )
                .into());
            }
            let t0 = entries[0].timestamp;
            Ok((entries[..n].iter().map(|e| e.timestamp - t0).collect(), t0))
        }
        None => Ok((
            (0..n).map(|i| i as f64 / config.sequence.fps).collect(),
            1_700_000_000.0,
        )),
    }
}

fn check_output_folder(out: &Path, force: bool) -> Result<(), SynthError> {
    if out.exists() {
        let empty = std::fs::read_dir(out)
            .map_err(|source| IoError::Read {
                path: out.to_path_buf(),
                source,
            })?
            .next()
            .is_none();
        if !empty && !force {
            return Err(SynthError::NotEmpty(out.to_path_buf()));
        }
    }
    for sub in ["rgb", "depth", "masks", "detections_oracle"] {
        std::fs::create_dir_all(out.join(sub)).map_err(|source| IoError::Write {
            path: out.join(sub),
            source,
        })?;
    }
    Ok(())
}

/// Exact boxes of the movers seen in a frame (before [`OracleConfig::apply`]), from its instance mask (x2, y2
/// exclusive); instances covering fewer than 20 pixels, and movers of no COCO class
/// (which no detector knows), are left out.
pub fn oracle_detections(mask: &[u16], width: u32, movers: &[Mover]) -> Vec<Detection> {
    // One pass over the mask: per instance id, the bounding box and pixel count.
    let mut boxes: std::collections::HashMap<u16, (u32, u32, u32, u32, usize)> =
        std::collections::HashMap::new();
    for (index, &id) in mask.iter().enumerate().filter(|(_, &id)| id > 0) {
        let (x, y) = (index as u32 % width, index as u32 / width);
        let b = boxes.entry(id).or_insert((u32::MAX, u32::MAX, 0, 0, 0));
        *b = (
            b.0.min(x),
            b.1.min(y),
            b.2.max(x + 1),
            b.3.max(y + 1),
            b.4 + 1,
        );
    }
    movers
        .iter()
        .filter_map(|mover| {
            let &(x1, y1, x2, y2, count) = boxes.get(&mover.instance)?;
            let class_id = mover.class_id?;
            (count >= 20).then(|| Detection {
                class: mover.class.to_string(),
                class_id,
                score: 1.0,
                bbox: [x1 as f32, y1 as f32, x2 as f32, y2 as f32],
                instance: Some(mover.instance),
            })
        })
        .collect()
}

/// What a frame's ground truth is made from besides its rendering: the camera, the
/// movers (instance ids and classes) and the oracle's imperfections.
#[derive(Clone, Copy)]
struct TruthSources<'a> {
    camera: &'a PinholeCamera,
    movers: &'a [Mover],
    oracle: &'a OracleConfig,
}

/// The error of saving the image `name` under `out`.
fn save_error(out: &Path, name: &str) -> impl Fn(image::ImageError) -> IoError {
    let path = out.join(name);
    move |e| IoError::Write {
        path: path.clone(),
        source: std::io::Error::other(e),
    }
}

/// Writes one frame's colour and depth PNGs.
fn write_images(out: &Path, stamp: f64, rendered: &Rendered) -> Result<(), SynthError> {
    let rgb_name = format!("rgb/{stamp:.6}.png");
    rendered
        .rgb
        .save(out.join(&rgb_name))
        .map_err(save_error(out, &rgb_name))?;
    let depth_name = format!("depth/{stamp:.6}.png");
    depth_to_png16(&rendered.depth, DEPTH_SCALE)
        .save(out.join(&depth_name))
        .map_err(save_error(out, &depth_name))?;
    Ok(())
}

/// Writes a frame's instance mask (`masks/`) and oracle detections
/// (`detections_oracle/`) into each target folder, named by that folder's timestamp
/// (the TUM layout's and the KITTI layout's); both are made once.
fn write_truth(
    targets: &[(&Path, f64)],
    rendered: &Rendered,
    TruthSources {
        camera,
        movers,
        oracle,
    }: TruthSources,
    seed: u64,
) -> Result<(), SynthError> {
    let mask = image::GrayImage::from_raw(
        camera.width,
        camera.height,
        rendered.mask.iter().map(|&i| i.min(255) as u8).collect(),
    )
    .expect("mask size matches");
    let mut detections = FrameDetections {
        timestamp: 0.0,
        detections: oracle.apply(
            &oracle_detections(&rendered.mask, camera.width, movers),
            camera.width,
            camera.height,
            &mut Rng::new(seed),
        ),
    };
    for &(out, stamp) in targets {
        let mask_name = format!("masks/{stamp:.6}.png");
        mask.save(out.join(&mask_name))
            .map_err(save_error(out, &mask_name))?;
        detections.timestamp = stamp;
        let json = serde_json::to_string_pretty(&detections)
            .map_err(|e| SynthError::Config(e.to_string()))?;
        write_atomic(
            &out.join(format!("detections_oracle/{stamp:.6}.json")),
            json.as_bytes(),
        )?;
    }
    Ok(())
}

/// Voxel edge of `movers.ply`, metres.
const MOVER_VOXEL: f64 = 0.02;

/// The voxels that a frame's mover pixels (exact depth, every other pixel) fall in,
/// in the world frame: the ground truth of where movers were, for judging dense maps.
fn mover_voxels(
    rendered: &Rendered,
    camera: &PinholeCamera,
    world_from_camera: &Se3,
) -> Vec<[i32; 3]> {
    let w = camera.width as usize;
    let mut voxels = Vec::new();
    for (i, &id) in rendered.mask.iter().enumerate() {
        let (u, v) = (i % w, i / w);
        if id == 0 || u % 2 == 1 || v % 2 == 1 {
            continue;
        }
        let z = rendered.exact_depth.metres[i] as f64;
        if z <= 0.0 {
            continue;
        }
        let p = camera.unproject(&nalgebra::Vector2::new(u as f64, v as f64), z);
        let p = world_from_camera * nalgebra::Point3::from(p);
        voxels.push([0, 1, 2].map(|k| (p[k] / MOVER_VOXEL).floor() as i32));
    }
    voxels.sort_unstable();
    voxels.dedup();
    voxels
}

/// Everything needed to render any frame of a config: frame times, camera poses, the
/// static scene and the movers.
pub struct World {
    /// The config.
    pub config: SynthConfig,
    /// The camera.
    pub camera: PinholeCamera,
    /// Frame times in seconds from the first frame, and the first frame's timestamp.
    pub times: Vec<f64>,
    /// The first frame's timestamp.
    pub t0: f64,
    /// `world_from_camera` of each frame (the ground truth).
    pub poses: Vec<Se3>,
    /// The static scene.
    pub scene: Scene,
    /// The movers.
    pub movers: Vec<Mover>,
    /// Per frame, the instants and poses sampled over the exposure (empty without blur).
    exposure: Vec<Vec<(f64, Se3)>>,
}

impl World {
    /// Builds the world of a config: reads timing, trajectory and cut-out files.
    pub fn new(config: &SynthConfig) -> Result<Self, SynthError> {
        config.validate()?;
        let (times, t0) = frame_times(config)?;
        let poses = poses_at(&config.motion, &times)?;
        let (scene, movers) = build_world(config, &poses)?;
        let mut exposure = vec![Vec::new(); times.len()];
        if config.sensor.exposure_instants(0.0).len() > 1 {
            let (first, last) = (times[0], times[times.len() - 1]);
            let instants: Vec<Vec<f64>> = times
                .iter()
                .map(|&t| {
                    config
                        .sensor
                        .exposure_instants(t)
                        .into_iter()
                        .map(|s| s.clamp(first, last))
                        .collect()
                })
                .collect();
            let flat: Vec<f64> = instants.iter().flatten().copied().collect();
            let mut flat_poses = poses_at(&config.motion, &flat)?.into_iter();
            for (frame, instants) in exposure.iter_mut().zip(instants) {
                *frame = instants
                    .into_iter()
                    .map(|s| (s, flat_poses.next().expect("one pose per instant")))
                    .collect();
            }
        }
        Ok(Self {
            config: config.clone(),
            camera: config.camera(),
            times,
            t0,
            poses,
            scene,
            movers,
            exposure,
        })
    }

    /// The timestamp of frame `index` (as written in rgb.txt).
    pub fn stamp(&self, index: usize) -> f64 {
        self.t0 + self.times[index]
    }

    /// The view at time `t` from a camera at `world_from_camera`.
    pub fn view(&self, t: f64, world_from_camera: Se3) -> View {
        let centre = world_from_camera.translation.vector;
        let range = self.render_range();
        View {
            world_from_camera,
            movers: self
                .movers
                .iter()
                .filter(|m| m.cuboid_at(t).distance_to(&centre) <= range)
                .map(|m| (m.shape_at(t, &centre), m.instance))
                .collect(),
        }
    }

    /// How far the renderer looks: the street's render range, else everywhere.
    fn render_range(&self) -> f64 {
        if self.config.street.enabled {
            self.config.street.render_range
        } else {
            f64::INFINITY
        }
    }

    /// The scene that a camera at `world_from_camera` can see (all of a room).
    fn visible_scene(&self, world_from_camera: &Se3) -> std::borrow::Cow<'_, Scene> {
        if self.config.street.enabled {
            let centre = world_from_camera.translation.vector;
            std::borrow::Cow::Owned(self.scene.near(&centre, self.render_range()))
        } else {
            std::borrow::Cow::Borrowed(&self.scene)
        }
    }

    fn frame_seed(&self, index: usize) -> u64 {
        self.config
            .sequence
            .seed
            .wrapping_mul(1_000_003)
            .wrapping_add(index as u64)
    }

    /// The views over frame `index`'s exposure, each camera moved by `camera_offset`.
    fn exposure_views(&self, index: usize, camera_offset: &Se3) -> Vec<View> {
        self.exposure[index]
            .iter()
            .map(|(t, pose)| self.view(*t, pose * camera_offset))
            .collect()
    }

    /// Renders frame `index` (the colour, or left, camera).
    pub fn render(&self, index: usize) -> Rendered {
        let t = self.times[index];
        let views = self.exposure_views(index, &Se3::identity());
        let exposure = Exposure {
            views: &views,
            gain: self.config.sensor.gain(t),
            noise_seed: self.frame_seed(index),
        };
        render(
            &self.visible_scene(&self.poses[index]),
            &self.view(t, self.poses[index]),
            &self.camera,
            &self.config.sensor,
            &exposure,
        )
    }

    /// The right camera's image of frame `index`: the left camera moved by the stereo
    /// baseline along its x axis.
    pub fn render_right(&self, index: usize) -> image::RgbImage {
        let t = self.times[index];
        let offset = Se3::from_parts(
            nalgebra::Translation3::new(self.config.stereo.baseline, 0.0, 0.0),
            nalgebra::Rotation3::identity(),
        );
        let views = self.exposure_views(index, &offset);
        let exposure = Exposure {
            views: &views,
            gain: self.config.sensor.gain(t),
            noise_seed: self.frame_seed(index) ^ 0x5EC0_4D00,
        };
        // The rig's rectification error: the right camera's true principal point and
        // focal lengths.
        let mut camera = self.camera;
        camera.cx += self.config.stereo.rectification_error_px;
        camera.fx *= 1.0 + self.config.stereo.rectification_scale_error;
        camera.fy *= 1.0 + self.config.stereo.rectification_scale_error;
        render_colour(
            &self.visible_scene(&self.poses[index]),
            &self.view(t, self.poses[index] * offset),
            &camera,
            &self.config.sensor,
            &exposure,
        )
    }
}

impl World {
    /// The depth camera's own depth of frame `index`, when the config has one.
    pub fn render_depth_camera(&self, index: usize) -> Option<DepthImage> {
        let depth = self.config.depth_camera.as_ref()?;
        let [x, y, z] = depth.offset;
        let offset = Se3::from_parts(
            nalgebra::Translation3::new(x, y, z),
            nalgebra::Rotation3::identity(),
        );
        let pose = self.poses[index] * offset;
        let seed = self.frame_seed(index) ^ 0xDE_D7_CA;
        let view = self.view(self.times[index], pose);
        Some(render_depth(
            &self.visible_scene(&pose),
            &view,
            &depth.camera,
            &self.config.sensor,
            seed,
        ))
    }
}

/// Writes `depth_camera.yaml`: the depth camera's intrinsics as an ORB-SLAM2 settings
/// file, and its offset as `ColourFromDepth.tx/ty/tz`.
fn write_depth_camera_file(config: &SynthConfig, out: &Path) -> Result<(), SynthError> {
    let Some(depth) = &config.depth_camera else {
        return Ok(());
    };
    let calibration = Calibration {
        camera: depth.camera,
        bf: None,
        depth_scale: Some(5000.0),
        th_depth: None,
        fps: Some(config.sequence.fps),
    };
    let mut text = OrbSlamSettings::to_yaml(&calibration, &Default::default());
    for (axis, value) in ["tx", "ty", "tz"].iter().zip(depth.offset) {
        text += &format!("ColourFromDepth.{axis}: {value:?}\n");
    }
    Ok(write_atomic(
        &out.join("depth_camera.yaml"),
        text.as_bytes(),
    )?)
}

/// The room (walls and furniture) the synth config at `path` renders.
fn room_of(path: &Path) -> Result<Scene, SynthError> {
    let other =
        SynthConfig::load(path).map_err(|e| SynthError::Config(format!("[scene] room_of: {e}")))?;
    if other.scene.room_of.is_some() {
        return Err(SynthError::Config(format!(
            "[scene] room_of: {} names a room of its own; name that config instead",
            path.display()
        )));
    }
    let (times, _) = frame_times(&other)?;
    let poses = poses_at(&other.motion, &times)?;
    Ok(scene_and_movers(&other, &poses)?.0)
}

/// Loads a cut-out named by the config, if any.
fn load_sprite(path: &Option<PathBuf>) -> Result<Option<std::sync::Arc<Sprite>>, SynthError> {
    path.as_deref()
        .map(Sprite::load)
        .transpose()
        .map_err(SynthError::from)
}

/// The static scene and the movers of a config along the given camera poses (no movers
/// with `without_movers`, in the same scene).
pub fn build_world(config: &SynthConfig, poses: &[Se3]) -> Result<(Scene, Vec<Mover>), SynthError> {
    let (mut scene, mut movers) = scene_and_movers(config, poses)?;
    if let Some(other) = &config.scene.room_of {
        scene = room_of(other)?;
    }
    if config.sequence.without_movers {
        movers.clear();
    }
    Ok((scene, movers))
}

fn scene_and_movers(
    config: &SynthConfig,
    poses: &[Se3],
) -> Result<(Scene, Vec<Mover>), SynthError> {
    if config.street.enabled {
        let appearance = match load_sprite(&config.people.sprite)? {
            Some(sprite) => Appearance::Sprite {
                standing: Some(sprite),
                seated: None,
            },
            None => Appearance::Box,
        };
        return Ok(super::street::build_street(
            &config.street,
            poses,
            &appearance,
            config.sequence.seed,
            config.sequence.fps,
        ));
    }
    let positions: Vec<Vector3<f64>> = poses.iter().map(|p| p.translation.vector).collect();
    let mut scene = Scene::around(
        &positions,
        config.scene.room_margin,
        config.scene.furniture,
        config.scene.clearance,
        config.sequence.seed,
    );
    if config.scene.look == super::config::SceneLook::Room {
        scene.look = super::scene::Look::Room {
            up: super::movers::up_axis(poses),
        };
    }
    let standing = load_sprite(&config.people.sprite)?;
    let seated = load_sprite(&config.seated.sprite)?;
    let appearance = |seated: Option<_>| {
        if standing.is_none() && seated.is_none() {
            Appearance::Box
        } else {
            Appearance::Sprite {
                standing: standing.clone(),
                seated,
            }
        }
    };
    let mut movers = place_people(&config.people, &appearance(None), poses, &mut scene);
    if let Some(table) = config.scene.table {
        place_table(table, poses, &mut scene);
    }
    movers.extend(place_seated(
        &config.seated,
        &appearance(seated.clone()),
        config.people.height,
        poses,
        &scene,
        movers.len() as u16 + 1,
    ));
    for objects in std::iter::once(&config.objects).chain(&config.unknown) {
        movers.extend(place_objects(
            objects,
            poses,
            &scene,
            movers.len() as u16 + 1,
        ));
    }
    if let Some(first) = movers.first() {
        let swept: Vec<_> = movers.iter().map(Mover::swept_box).collect();
        scene.make_room_for(&swept, first.up.0, 0.6);
    }
    Ok((scene, movers))
}

/// Generates the sequence described by `config` into `out`.
pub fn generate(config: &SynthConfig, out: &Path, force: bool) -> Result<SynthSummary, SynthError> {
    let start = std::time::Instant::now();
    let world = World::new(config)?;
    check_output_folder(out, force)?;
    let stereo = config.stereo.baseline > 0.0;
    let kitti = out.join("kitti/sequences/00");
    if stereo {
        for sub in ["image_0", "image_1", "masks", "detections_oracle"] {
            std::fs::create_dir_all(kitti.join(sub)).map_err(|source| IoError::Write {
                path: kitti.join(sub),
                source,
            })?;
        }
    }
    if config.depth_camera.is_some() {
        let dir = out.join("depth_camera");
        std::fs::create_dir_all(&dir).map_err(|source| IoError::Write { path: dir, source })?;
        write_depth_camera_file(config, out)?;
    }
    let camera = world.camera;
    let times = &world.times;
    let progress = ProgressBar::new(times.len() as u64);
    progress.set_style(
        ProgressStyle::with_template("synth {bar:40} {pos}/{len} frames ({eta} left)")
            .expect("valid template"),
    );
    // The frames first; the index files afterwards.
    let mover_voxels = render_frames(
        &world,
        config,
        out,
        stereo.then_some(kitti.as_path()),
        &progress,
    )?;
    progress.finish_and_clear();
    write_index_files(&world, out)?;
    let calibration = Calibration {
        camera,
        bf: Some(40.0),
        depth_scale: Some(DEPTH_SCALE),
        th_depth: Some(40.0),
        fps: Some(config.sequence.fps),
    };
    write_atomic(
        &out.join("calibration.yaml"),
        OrbSlamSettings::to_yaml(&calibration, &OrbSettings::default()).as_bytes(),
    )?;
    write_ply(
        &out.join("static_scene.ply"),
        &world.scene.to_mesh(),
        None,
        PlyEncoding::Ascii,
        "dopslam synth static scene",
    )?;
    write_movers(out, mover_voxels)?;
    if stereo {
        write_kitti_files(&world, &out.join("kitti"))?;
    }
    write_instances(&out.join("masks"), &world.movers)?;
    let scene_toml = toml::to_string(config).map_err(|e| SynthError::Config(e.to_string()))?;
    write_atomic(
        &out.join("scene.toml"),
        format!("# dopslam synth: the config this sequence was generated with\n{scene_toml}")
            .as_bytes(),
    )?;
    Ok(SynthSummary {
        frames: world.times.len(),
        out: out.to_path_buf(),
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// Renders every frame of `world` and writes its images and truth (in parallel: each
/// frame's noise has its own seed, so the files do not depend on the order); returns
/// each frame's mover voxels.
fn render_frames(
    world: &World,
    config: &SynthConfig,
    out: &Path,
    kitti: Option<&Path>,
    progress: &ProgressBar,
) -> Result<Vec<Vec<[i32; 3]>>, SynthError> {
    let (camera, times) = (world.camera, &world.times);
    let stereo = kitti.is_some();
    let kitti = kitti.unwrap_or(out);
    (0..times.len())
        .into_par_iter()
        .map(|index| {
            let rendered = world.render(index);
            let voxels = mover_voxels(&rendered, &camera, &world.poses[index]);
            let truth = TruthSources {
                camera: &camera,
                movers: &world.movers,
                oracle: &config.oracle,
            };
            let truth_seed = world.frame_seed(index) ^ 0x0AC1_E5EE;
            write_images(out, world.stamp(index), &rendered)?;
            if let Some(depth) = world.render_depth_camera(index) {
                let name = format!("depth_camera/{:.6}.png", world.stamp(index));
                depth_to_png16(&depth, 5000.0)
                    .save(out.join(&name))
                    .map_err(save_error(out, &name))?;
            }
            let tum = (out, world.stamp(index));
            let targets: &[(&Path, f64)] = if stereo {
                &[tum, (kitti, world.times[index])]
            } else {
                &[tum]
            };
            write_truth(targets, &rendered, truth, truth_seed)?;
            if stereo {
                let left = image::DynamicImage::ImageRgb8(rendered.rgb).to_luma8();
                let right = image::DynamicImage::ImageRgb8(world.render_right(index)).to_luma8();
                for (sub, grey) in [("image_0", left), ("image_1", right)] {
                    let name = format!("{sub}/{index:06}.png");
                    grey.save(kitti.join(&name))
                        .map_err(save_error(kitti, &name))?;
                }
            }
            progress.inc(1);
            Ok::<_, SynthError>(voxels)
        })
        .collect()
}

/// `rgb.txt`, `depth.txt`, `associations.txt` and `groundtruth.txt` of `world`.
fn write_index_files(world: &World, out: &Path) -> Result<(), SynthError> {
    let times = &world.times;
    let (mut rgb_txt, mut depth_txt, mut associations) = (
        String::from("# color images\n# timestamp filename\n"),
        String::from("# depth maps\n# timestamp filename\n"),
        String::new(),
    );
    let poses = &world.poses;
    let t0 = world.t0;
    let mut ground_truth = Trajectory::default();
    for (t, pose) in times.iter().zip(poses) {
        let stamp = t0 + t;
        let (rgb_name, depth_name) = (
            format!("rgb/{stamp:.6}.png"),
            format!("depth/{stamp:.6}.png"),
        );
        let _ = writeln!(rgb_txt, "{stamp:.6} {rgb_name}");
        let _ = writeln!(depth_txt, "{stamp:.6} {depth_name}");
        let _ = writeln!(
            associations,
            "{stamp:.6} {rgb_name} {stamp:.6} {depth_name}"
        );
        ground_truth.push(stamp, *pose);
    }
    write_atomic(&out.join("rgb.txt"), rgb_txt.as_bytes())?;
    write_atomic(&out.join("depth.txt"), depth_txt.as_bytes())?;
    write_atomic(&out.join("associations.txt"), associations.as_bytes())?;
    ground_truth.write(&out.join("groundtruth.txt"), TrajectoryFormat::Tum)?;
    Ok(())
}

/// `movers.ply`: the mover voxels of every frame, merged.
fn write_movers(out: &Path, mover_voxels: Vec<Vec<[i32; 3]>>) -> Result<(), SynthError> {
    let mut movers: Vec<[i32; 3]> = mover_voxels.into_iter().flatten().collect();
    movers.sort_unstable();
    movers.dedup();
    let movers = Mesh::points(
        movers
            .iter()
            .map(|k| k.map(|c| ((c as f64 + 0.5) * MOVER_VOXEL) as f32))
            .collect(),
    );
    write_ply(
        &out.join("movers.ply"),
        &movers,
        None,
        PlyEncoding::Binary,
        "dopslam synth: where movers were (every frame's mover pixels at exact depth, 2 cm voxels)",
    )?;
    Ok(())
}

/// `masks/instances.txt`: each mover's instance id (its value in the masks) and class;
/// a class that is not a COCO name is a mover no detector knows.
fn write_instances(masks: &Path, movers: &[Mover]) -> Result<(), SynthError> {
    let mut text = String::from("# instance class\n");
    for mover in movers {
        text += &format!("{} {}\n", mover.instance, mover.class);
    }
    Ok(write_atomic(
        &masks.join(crate::io::image_files::INSTANCES),
        text.as_bytes(),
    )?)
}

/// The KITTI odometry side files: `calib.txt` (P0/P2 left, P1/P3 right with
/// \(P_1[0,3] = -f_x b\)), `times.txt` (seconds from the first frame) and
/// `poses/00.txt` (left camera poses relative to the first frame, 12 numbers a line).
fn write_kitti_files(world: &World, root: &Path) -> Result<(), SynthError> {
    let c = &world.camera;
    let projection = |tx: f64| {
        format!(
            "{:e} 0 {:e} {:e} 0 {:e} {:e} 0 0 0 1 0",
            c.fx, c.cx, tx, c.fy, c.cy
        )
    };
    let (left, right) = (
        projection(0.0),
        projection(-c.fx * world.config.stereo.baseline),
    );
    let calib = format!("P0: {left}\nP1: {right}\nP2: {left}\nP3: {right}\n");
    let sequence = root.join("sequences/00");
    write_atomic(&sequence.join("calib.txt"), calib.as_bytes())?;
    let times: String = world.times.iter().map(|t| format!("{t:e}\n")).collect();
    write_atomic(&sequence.join("times.txt"), times.as_bytes())?;
    let first_from_world = world.poses[0].inverse();
    let mut poses = Trajectory::default();
    for (t, pose) in world.times.iter().zip(&world.poses) {
        poses.push(*t, first_from_world * pose);
    }
    std::fs::create_dir_all(root.join("poses")).map_err(|source| IoError::Write {
        path: root.join("poses"),
        source,
    })?;
    poses.write(&root.join("poses/00.txt"), TrajectoryFormat::Kitti)?;
    Ok(())
}
