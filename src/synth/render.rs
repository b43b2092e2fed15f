//! Ray-cast rendering of colour and depth, parallel over rows with rayon, and the
//! sensor models.
//!
//! Depth noise follows the Kinect model of Nguyen, Izadi and Lovell (2012):
//! \(\sigma_z(z) = 0.0012 + 0.0019\,(z - 0.4)^2\) metres, then quantised to the depth
//! PNG's 1/`depth_scale` steps; pixels beyond `max_depth` and at depth discontinuities
//! read 0 (no depth), as a structured-light sensor gives them.

use image::RgbImage;
use nalgebra::Vector3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::scene::Shape;
use super::scene::{Cuboid, Hit, Scene};
use crate::checks::{self, BadValue};
use crate::geometry::camera::PinholeCamera;
use crate::geometry::depth_noise::kinect_depth_sigma;
use crate::geometry::se3::Se3;
use crate::io::image_files::DepthImage;
use crate::random::Rng;

/// The sensor section of a synth config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SensorConfig {
    /// Add Kinect-like depth noise.
    pub depth_noise: bool,
    /// Beyond this range (metres) depth reads 0.
    pub max_depth: f64,
    /// Invalidate pixels whose 4-neighbours differ in depth by more than this fraction.
    pub discontinuity_fraction: f64,
    /// Standard deviation of the colour noise, in 8-bit grey levels.
    pub rgb_noise: f64,
    /// Disparity quantisation step in pixels (Kinect: 1/8); 0 turns it off.
    pub disparity_step: f64,
    /// Baseline times focal length of the depth sensor (pixel·metres; Kinect about 40).
    pub bf: f64,
    /// Exposure time in seconds for motion blur (colour averaged over the camera's and
    /// the movers' motion during the exposure); 0 turns it off.
    pub exposure_time: f64,
    /// How many instants the exposure is sampled at.
    pub blur_samples: usize,
    /// Relative amplitude of slow brightness changes (auto exposure); 0 turns it off.
    pub exposure_variation: f64,
}

impl Default for SensorConfig {
    fn default() -> Self {
        Self {
            depth_noise: true,
            max_depth: 4.5,
            discontinuity_fraction: 0.05,
            rgb_noise: 2.0,
            disparity_step: 0.125,
            bf: 40.0,
            exposure_time: 0.0,
            blur_samples: 4,
            exposure_variation: 0.0,
        }
    }
}

impl SensorConfig {
    /// The brightness gain at time `t` seconds: \(1 + a \sin(2\pi t / 7.3)\sin(2\pi t / 2.9 + 1)\),
    /// a slow, irregular drift like a camera's auto exposure.
    pub fn gain(&self, t: f64) -> f64 {
        use std::f64::consts::TAU;
        1.0 + self.exposure_variation * (TAU * t / 7.3).sin() * (TAU * t / 2.9 + 1.0).sin()
    }

    /// The instants (seconds) at which a frame at `t` is sampled: `t` alone, or
    /// `blur_samples` instants spread over the exposure centred on `t`.
    pub fn exposure_instants(&self, t: f64) -> Vec<f64> {
        if self.exposure_time <= 0.0 || self.blur_samples < 2 {
            return vec![t];
        }
        let n = self.blur_samples;
        (0..n)
            .map(|k| t + self.exposure_time * (k as f64 / (n - 1) as f64 - 0.5))
            .collect()
    }

    /// Checks each value's range; the error names the key.
    pub fn validate(&self) -> Result<(), BadValue> {
        checks::positive("sensor.max_depth", self.max_depth)?;
        if !(0.0..1.0).contains(&self.exposure_variation) {
            return Err(BadValue::new(
                "sensor.exposure_variation",
                format!("must be in [0, 1), got {}", self.exposure_variation),
            ));
        }
        if !(0.0..=0.2).contains(&self.exposure_time) {
            return Err(BadValue::new(
                "sensor.exposure_time",
                format!("must be 0 to 0.2 s, got {}", self.exposure_time),
            ));
        }
        if self.blur_samples == 0 || self.blur_samples > 32 {
            return Err(BadValue::new(
                "sensor.blur_samples",
                format!("must be 1 to 32, got {}", self.blur_samples),
            ));
        }
        Ok(())
    }
}

/// What the camera sees at one instant: its pose and the movers' shapes with their
/// instance ids.
#[derive(Debug, Clone)]
pub struct View {
    /// The camera's pose.
    pub world_from_camera: Se3,
    /// The movers' shapes and instance ids.
    pub movers: Vec<(Shape, u16)>,
}

/// One rendered frame: colour, noisy sensor depth, the exact depth, and the instance
/// mask (row-major; 0 = static scene, else the mover's instance id).
pub struct Rendered {
    /// Colour.
    pub rgb: RgbImage,
    /// Sensor depth with noise.
    pub depth: DepthImage,
    /// Exact depth.
    pub exact_depth: DepthImage,
    /// Instance mask, row-major.
    pub mask: Vec<u16>,
}

/// Traced rays of one image: linear colours (0..1), exact depths, instance ids.
struct Traced {
    colour: Vec<[f32; 3]>,
    depth: Vec<f32>,
    mask: Vec<u16>,
}

/// The pixel rectangle `[u0, u1] x [v0, v1]` (one pixel wider each side) that holds the
/// projection of a convex object with these corners; unbounded when a corner is not in
/// front of the camera.
fn screen_bounds(
    corners: &[Vector3<f64>],
    camera: &PinholeCamera,
    camera_from_world: &Se3,
) -> [f64; 4] {
    let mut bounds = [
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    ];
    for corner in corners {
        let p = camera_from_world * nalgebra::Point3::from(*corner);
        if p.z <= 1e-3 {
            return [
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
            ];
        }
        let pixel = camera.project(&p.coords);
        bounds = [
            bounds[0].min(pixel.x - 1.0),
            bounds[1].max(pixel.x + 1.0),
            bounds[2].min(pixel.y - 1.0),
            bounds[3].max(pixel.y + 1.0),
        ];
    }
    bounds
}

/// The corners of a mover's shape.
fn shape_corners(shape: &Shape) -> Vec<Vector3<f64>> {
    match shape {
        Shape::Box(cuboid) => cuboid.corners().to_vec(),
        Shape::Billboard(board) => {
            let half = board.right * (board.width * 0.5);
            let top = board.up * board.height;
            vec![
                board.base - half,
                board.base + half,
                board.base - half + top,
                board.base + half + top,
            ]
        }
    }
}

/// Casts one ray per pixel (rows in parallel). Each ray tries only the furniture and
/// movers whose screen rectangle holds its pixel.
fn trace(scene: &Scene, view: &View, camera: &PinholeCamera, with_depth: bool) -> Traced {
    let (width, height) = (camera.width as usize, camera.height as usize);
    let camera_from_world = view.world_from_camera.inverse();
    let furniture: Vec<(&Cuboid, [f64; 4])> = scene
        .furniture
        .iter()
        .map(|c| (c, screen_bounds(&c.corners(), camera, &camera_from_world)))
        .filter(|(_, b)| b[0] <= b[1])
        .collect();
    let movers: Vec<(usize, &Shape, [f64; 4])> = view
        .movers
        .iter()
        .enumerate()
        .map(|(i, (shape, _))| {
            let bounds = screen_bounds(&shape_corners(shape), camera, &camera_from_world);
            (i, shape, bounds)
        })
        .collect();
    let rotation = view.world_from_camera.rotation.matrix();
    let origin = view.world_from_camera.translation.vector;
    let light = Vector3::new(0.3, -0.8, 0.5).normalize();
    let rows: Vec<Traced> = (0..height)
        .into_par_iter()
        .map(|v| {
            let mut row = Traced {
                colour: Vec::with_capacity(width),
                depth: Vec::with_capacity(if with_depth { width } else { 0 }),
                mask: Vec::with_capacity(if with_depth { width } else { 0 }),
            };
            let vf = v as f64;
            let row_furniture: Vec<(&Cuboid, f64, f64)> = furniture
                .iter()
                .filter(|(_, b)| b[2] <= vf && vf <= b[3])
                .map(|(c, b)| (*c, b[0], b[1]))
                .collect();
            let row_movers: Vec<(usize, &Shape, f64, f64)> = movers
                .iter()
                .filter(|(_, _, b)| b[2] <= vf && vf <= b[3])
                .map(|(i, s, b)| (*i, *s, b[0], b[1]))
                .collect();
            let y = (vf - camera.cy) / camera.fy;
            for u in 0..width {
                let uf = u as f64;
                let ray_camera = Vector3::new((uf - camera.cx) / camera.fx, y, 1.0);
                let direction = rotation * ray_camera;
                let hit = scene.cast_with_movers_among(
                    row_furniture
                        .iter()
                        .filter(|(_, u0, u1)| *u0 <= uf && uf <= *u1)
                        .map(|(c, _, _)| *c),
                    row_movers
                        .iter()
                        .filter(|(_, _, u0, u1)| *u0 <= uf && uf <= *u1)
                        .map(|(i, s, _, _)| (*i, *s)),
                    &origin,
                    &direction,
                );
                let (colour, depth, instance) = match hit {
                    Some((hit, mover)) => {
                        let colour = hit
                            .colour
                            .unwrap_or_else(|| shaded(scene, &hit, &direction, &light, camera.fx));
                        (colour, hit.t, mover.map_or(0, |i| view.movers[i].1))
                    }
                    None => ([0.0; 3], 0.0, 0),
                };
                row.colour.push(colour.map(|c| c as f32));
                if with_depth {
                    row.depth.push(depth as f32);
                    row.mask.push(instance);
                }
            }
            row
        })
        .collect();
    Traced::joined(rows, width * height)
}

impl Traced {
    /// The image whose rows are `rows`, in order (`pixels` in all).
    fn joined(rows: Vec<Traced>, pixels: usize) -> Traced {
        let mut traced = Traced {
            colour: Vec::with_capacity(pixels),
            depth: Vec::with_capacity(pixels),
            mask: Vec::with_capacity(pixels),
        };
        for row in rows {
            traced.colour.extend(row.colour);
            traced.depth.extend(row.depth);
            traced.mask.extend(row.mask);
        }
        traced
    }
}

/// The colour of a surface without its own: the scene's colour at the pixel's
/// footprint (its angular size \(1/f_x\) times the distance, stretched by the
/// incidence), shaded by `light` unless the surface is emissive.
fn shaded(
    scene: &Scene,
    hit: &Hit,
    direction: &Vector3<f64>,
    light: &Vector3<f64>,
    fx: f64,
) -> [f64; 3] {
    let shade = if scene.is_emissive(hit) {
        1.0
    } else {
        0.55 + 0.45 * hit.normal.dot(light).abs()
    };
    let length = direction.norm();
    let incidence = (hit.normal.dot(direction).abs() / length).max(0.2);
    let footprint = hit.t * length / fx / incidence;
    scene.colour(hit, footprint).map(|c| c * shade)
}

/// How a frame is exposed: the views sampled during the exposure (empty: just the
/// frame's own view), the brightness gain, and the seed of the sensor noise (each row
/// draws from its own generator, so the parallel order does not matter).
#[derive(Debug, Clone, Copy)]
pub struct Exposure<'a> {
    /// Views sampled during the exposure.
    pub views: &'a [View],
    /// Brightness gain.
    pub gain: f64,
    /// The seed of the sensor noise.
    pub noise_seed: u64,
}

/// Renders a frame: depth and mask from `view`, colour as `exposure` says.
pub fn render(
    scene: &Scene,
    view: &View,
    camera: &PinholeCamera,
    sensor: &SensorConfig,
    exposure: &Exposure,
) -> Rendered {
    let Traced {
        colour,
        depth: metres,
        mask,
    } = trace(scene, view, camera, true);
    let rgb = expose(scene, colour, camera, sensor, exposure);
    let exact_depth = DepthImage {
        width: camera.width,
        height: camera.height,
        metres,
    };
    let depth = sensor_depth(&exact_depth, sensor, exposure.noise_seed);
    Rendered {
        rgb,
        depth,
        exact_depth,
        mask,
    }
}

/// Renders only the sensor depth seen from `view` (a depth camera of its own).
pub fn render_depth(
    scene: &Scene,
    view: &View,
    camera: &PinholeCamera,
    sensor: &SensorConfig,
    noise_seed: u64,
) -> DepthImage {
    let exact = DepthImage {
        width: camera.width,
        height: camera.height,
        metres: trace(scene, view, camera, true).depth,
    };
    sensor_depth(&exact, sensor, noise_seed)
}

/// Renders only the colour image seen from `view` (the right camera of a stereo pair).
pub fn render_colour(
    scene: &Scene,
    view: &View,
    camera: &PinholeCamera,
    sensor: &SensorConfig,
    exposure: &Exposure,
) -> RgbImage {
    let colour = trace(scene, view, camera, false).colour;
    expose(scene, colour, camera, sensor, exposure)
}

/// Replaces the traced colours by the exposure's average (when blurred), applies the
/// gain and noise, and quantises to 8 bits.
fn expose(
    scene: &Scene,
    mut colour: Vec<[f32; 3]>,
    camera: &PinholeCamera,
    sensor: &SensorConfig,
    exposure: &Exposure,
) -> RgbImage {
    let (gain, noise_seed) = (exposure.gain, exposure.noise_seed);
    let exposure = exposure.views;
    let width = camera.width as usize;
    if !exposure.is_empty() {
        colour.iter_mut().for_each(|c| *c = [0.0; 3]);
        for instant in exposure {
            let sample = trace(scene, instant, camera, false);
            for (sum, c) in colour.iter_mut().zip(&sample.colour) {
                for k in 0..3 {
                    sum[k] += c[k];
                }
            }
        }
        let n = exposure.len() as f32;
        colour.iter_mut().for_each(|c| *c = c.map(|v| v / n));
    }
    let gain = gain as f32;
    let bytes: Vec<u8> = colour
        .par_chunks(width)
        .enumerate()
        .flat_map_iter(|(v, row)| {
            let mut rng = Rng::new(noise_seed.wrapping_mul(0x9E37_79B9).wrapping_add(v as u64));
            let noise = sensor.rgb_noise as f32;
            row.iter()
                .flat_map(|c| {
                    c.map(|x| {
                        // Round half up; `as u8` saturates below 0 and above 255.
                        (x * gain * 255.0 + noise * rng.normal() as f32 + 0.5) as u8
                    })
                })
                .collect::<Vec<u8>>()
        })
        .collect();
    RgbImage::from_raw(camera.width, camera.height, bytes).expect("size matches")
}

/// Applies range limits, discontinuity holes and noise to an exact depth map.
pub fn sensor_depth(exact: &DepthImage, sensor: &SensorConfig, noise_seed: u64) -> DepthImage {
    let (w, h) = (exact.width as usize, exact.height as usize);
    let mut out = DepthImage::new(exact.width, exact.height);
    let mut rng = Rng::new(noise_seed ^ 0xD1B5_4A32_D192_ED03);
    for v in 0..h {
        for u in 0..w {
            let z = exact.metres[v * w + u] as f64;
            let noise = rng.normal();
            if z <= 0.0 || z > sensor.max_depth {
                continue;
            }
            let neighbours = [
                (u.wrapping_sub(1), v),
                (u + 1, v),
                (u, v.wrapping_sub(1)),
                (u, v + 1),
            ];
            let edge = neighbours.iter().any(|&(x, y)| {
                x < w && y < h && {
                    let n = exact.metres[y * w + x] as f64;
                    (n - z).abs() > sensor.discontinuity_fraction * z
                }
            });
            if edge {
                continue;
            }
            let noisy = if sensor.depth_noise {
                z + kinect_depth_sigma(z) * noise
            } else {
                z
            };
            out.metres[v * w + u] = quantise_disparity(noisy, sensor).max(0.0) as f32;
        }
    }
    out
}

/// Rounds a depth to the nearest disparity step: \(d = bf / z\),
/// \(z' = bf / (\mathrm{round}(d / \Delta d)\,\Delta d)\).
pub fn quantise_disparity(z: f64, sensor: &SensorConfig) -> f64 {
    if sensor.disparity_step <= 0.0 || z <= 0.0 {
        return z;
    }
    let steps = (sensor.bf / z / sensor.disparity_step).round().max(1.0);
    sensor.bf / (steps * sensor.disparity_step)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disparity_steps_grow_with_distance() {
        let sensor = SensorConfig::default();
        // At 4 m, d = 10 px; neighbouring steps 9.875 and 10.125 px are about 5 cm apart.
        assert!((quantise_disparity(4.0, &sensor) - 4.0).abs() < 1e-12);
        let step_far = 40.0 / 9.875 - 4.0;
        assert!((quantise_disparity(4.0 + 0.6 * step_far, &sensor) - 40.0 / 9.875).abs() < 1e-12);
        let near = quantise_disparity(1.0003, &sensor);
        assert!((near - 1.0003).abs() < 0.004, "{near}");
    }

    #[test]
    fn noise_grows_with_distance() {
        assert!(kinect_depth_sigma(1.0) < kinect_depth_sigma(3.0));
        assert!((kinect_depth_sigma(0.4) - 0.0012).abs() < 1e-15);
    }

    #[test]
    fn exact_depth_is_the_distance_along_the_optical_axis() {
        let scene = Scene {
            room: super::super::scene::Cuboid {
                min: Vector3::repeat(-4.0),
                max: Vector3::new(4.0, 4.0, 2.0),
                texture: 1,
            },
            furniture: vec![],
            look: Default::default(),
        };
        let mut camera = PinholeCamera::tum_fr3();
        camera.width = 64;
        camera.height = 48;
        camera.cx = 32.0;
        camera.cy = 24.0;
        let view = View {
            world_from_camera: Se3::identity(),
            movers: vec![],
        };
        let exposure = Exposure {
            views: &[],
            gain: 1.0,
            noise_seed: 1,
        };
        let rendered = render(&scene, &view, &camera, &SensorConfig::default(), &exposure);
        // The wall at z = 2 faces the camera: every pixel's depth is 2.
        assert!(rendered
            .exact_depth
            .metres
            .iter()
            .all(|&z| (z - 2.0).abs() < 1e-5));
        let valid = rendered.depth.valid_fraction();
        assert!(valid > 0.99, "{valid}");
    }
}
