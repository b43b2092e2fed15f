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

use super::scene::{Cuboid, Scene};
use super::texture::texel;
use crate::geometry::camera::PinholeCamera;
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
        }
    }
}

/// The standard deviation of Kinect depth noise at depth `z` metres.
pub fn kinect_depth_sigma(z: f64) -> f64 {
    0.0012 + 0.0019 * (z - 0.4) * (z - 0.4)
}

/// One rendered image row: colours, exact depths, instance ids.
type RenderedRow = (Vec<[u8; 3]>, Vec<f32>, Vec<u16>);

/// One rendered frame: colour, noisy sensor depth, the exact depth, and the instance
/// mask (row-major; 0 = static scene, else the mover's instance id).
pub struct Rendered {
    pub rgb: RgbImage,
    pub depth: DepthImage,
    pub exact_depth: DepthImage,
    pub mask: Vec<u16>,
}

/// Renders the scene seen by a camera at `world_from_camera`. `noise_seed` makes the
/// sensor noise repeatable (each row draws from its own generator, so the parallel
/// order does not matter).
pub fn render(
    scene: &Scene,
    movers: &[(Cuboid, u16)],
    camera: &PinholeCamera,
    world_from_camera: &Se3,
    sensor: &SensorConfig,
    noise_seed: u64,
) -> Rendered {
    let mover_boxes: Vec<Cuboid> = movers.iter().map(|m| m.0).collect();
    let (width, height) = (camera.width as usize, camera.height as usize);
    let rotation = world_from_camera.rotation.matrix();
    let origin = world_from_camera.translation.vector;
    let light = Vector3::new(0.3, -0.8, 0.5).normalize();
    let rows: Vec<RenderedRow> = (0..height)
        .into_par_iter()
        .map(|v| {
            let mut rng = Rng::new(noise_seed.wrapping_mul(0x9E37_79B9).wrapping_add(v as u64));
            let mut colours = Vec::with_capacity(width);
            let mut depths = Vec::with_capacity(width);
            let mut instances = Vec::with_capacity(width);
            for u in 0..width {
                let ray_camera = Vector3::new(
                    (u as f64 - camera.cx) / camera.fx,
                    (v as f64 - camera.cy) / camera.fy,
                    1.0,
                );
                let direction = rotation * ray_camera;
                let (colour, depth, instance) =
                    match scene.cast_with_movers(&mover_boxes, &origin, &direction) {
                        Some((hit, mover)) => {
                            let base = texel(hit.texture, hit.uv.0, hit.uv.1);
                            let shade = 0.55 + 0.45 * hit.normal.dot(&light).abs();
                            (
                                base.map(|c| c * shade),
                                hit.t,
                                mover.map_or(0, |i| movers[i].1),
                            )
                        }
                        None => ([0.0; 3], 0.0, 0),
                    };
                instances.push(instance);
                let noisy = colour.map(|c| {
                    (c * 255.0 + sensor.rgb_noise * rng.normal())
                        .round()
                        .clamp(0.0, 255.0) as u8
                });
                colours.push(noisy);
                depths.push(depth as f32);
            }
            (colours, depths, instances)
        })
        .collect();
    let mut rgb = RgbImage::new(camera.width, camera.height);
    let mut exact_depth = DepthImage::new(camera.width, camera.height);
    let mut mask = Vec::with_capacity(width * height);
    for (v, (colours, depths, instances)) in rows.into_iter().enumerate() {
        mask.extend(instances);
        for (u, colour) in colours.into_iter().enumerate() {
            rgb.put_pixel(u as u32, v as u32, image::Rgb(colour));
        }
        exact_depth.metres[v * width..(v + 1) * width].copy_from_slice(&depths);
    }
    let depth = sensor_depth(&exact_depth, sensor, noise_seed);
    Rendered {
        rgb,
        depth,
        exact_depth,
        mask,
    }
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
            room: Cuboid {
                min: Vector3::repeat(-4.0),
                max: Vector3::new(4.0, 4.0, 2.0),
                texture: 1,
            },
            furniture: vec![],
        };
        let mut camera = PinholeCamera::tum_fr3();
        camera.width = 64;
        camera.height = 48;
        camera.cx = 32.0;
        camera.cy = 24.0;
        let rendered = render(
            &scene,
            &[],
            &camera,
            &Se3::identity(),
            &SensorConfig::default(),
            1,
        );
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
