//! A truncated signed distance field on sparse voxel hashing (Nießner et al. 2013):
//! blocks of \(8^3\) voxels allocated where depth is seen, found by their integer
//! block coordinate in a hash map.
//!
//! A voxel at world point \(p_w\) seen by a camera at `camera_from_world` \(T_{cw}\)
//! projects to pixel \(\pi(T_{cw} p_w)\) with depth \(z\); with measured depth \(d\)
//! there, its projective signed distance is \(\eta = d - z\) (positive in front of
//! the surface). Where \(\eta \ge -\tau\) (\(\tau\): truncation) the voxel takes
//! \(\phi = \min(1, \eta/\tau)\) into its running weighted mean:
//! \[ F \leftarrow \frac{W F + \phi}{W + 1}, \qquad W \leftarrow \min(W + 1, W_{max}) \]
//! and the colour likewise. Capping \(W\) lets newer observations win: a surface
//! that later proves to be free space (a person who sat and then left) is carved
//! away by the \(\phi = 1\) observations of the rays that now pass through it.
//! A pixel a mask marks dynamic fuses nothing at or behind its depth (\(\eta \le \tau\)),
//! but the free space in front of the mover (\(\eta > \tau\)) still carves.
//!
//! Integration is rayon-parallel over the blocks a frame touches: those within
//! \(\tau\) of its depth (allocated) and, for carving, existing blocks that rays
//! pass through in front of the surface.

use std::collections::HashMap;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::camera::PinholeCamera;
use crate::geometry::se3::Se3;
use crate::io::image_files::DepthImage;

/// A fast hasher for integer keys (the Fx hash of rustc): block lookups dominate
/// integration and meshing, and SipHash's resistance to flooding is not needed here.
#[derive(Default, Clone, Copy)]
pub struct FxHasher(u64);

impl std::hash::Hasher for FxHasher {
    fn write(&mut self, bytes: &[u8]) {
        for chunk in bytes.chunks(4) {
            let mut word = [0u8; 4];
            word[..chunk.len()].copy_from_slice(chunk);
            self.write_u32(u32::from_le_bytes(word));
        }
    }
    fn write_u32(&mut self, v: u32) {
        self.0 = (self.0.rotate_left(5) ^ v as u64).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_usize(&mut self, v: usize) {
        self.0 = (self.0.rotate_left(5) ^ v as u64).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn finish(&self) -> u64 {
        self.0
    }
}

/// A hash map with [`FxHasher`].
pub type FxMap<K, V> = HashMap<K, V, std::hash::BuildHasherDefault<FxHasher>>;

/// Voxels along one side of a block.
pub const BLOCK: usize = 8;
const BLOCK_VOXELS: usize = BLOCK * BLOCK * BLOCK;

/// Settings of a volume.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TsdfSettings {
    /// Voxel edge, metres.
    pub voxel: f64,
    /// Truncation distance \(\tau\), metres.
    pub truncation: f64,
    /// Depths beyond this are not fused, metres.
    pub max_depth: f64,
    /// Weight cap \(W_{max}\).
    pub max_weight: f32,
    /// Walk rays through free space to carve existing blocks in front of the surface.
    pub carve: bool,
}

impl Default for TsdfSettings {
    fn default() -> Self {
        Self {
            voxel: 0.01,
            truncation: 0.04,
            max_depth: 4.0,
            max_weight: 64.0,
            carve: true,
        }
    }
}

/// One block of voxels, x fastest.
#[derive(Debug, Clone)]
pub struct Block {
    pub sdf: Vec<f32>,
    pub weight: Vec<f32>,
    pub colour: Vec<[u8; 3]>,
    /// Observations within the truncation band (those that set the colour).
    pub colour_weight: Vec<u16>,
    /// Whether some observed voxel is behind a surface (\(F < 0\)): only such blocks
    /// hold something that carving could erase.
    surface: bool,
    /// The last integration that touched this block.
    stamp: u32,
}

impl Block {
    fn new() -> Self {
        Self {
            sdf: vec![1.0; BLOCK_VOXELS],
            weight: vec![0.0; BLOCK_VOXELS],
            colour: vec![[0; 3]; BLOCK_VOXELS],
            colour_weight: vec![0; BLOCK_VOXELS],
            surface: false,
            stamp: 0,
        }
    }
}

/// The index of voxel `(x, y, z)` inside a block.
pub fn voxel_index(x: usize, y: usize, z: usize) -> usize {
    (z * BLOCK + y) * BLOCK + x
}

/// One frame to fuse: depth in metres, colour, and an optional mask (`true`: dynamic,
/// not fused), all of the camera's size.
pub struct FrameInput<'a> {
    pub depth: &'a DepthImage,
    pub colour: &'a image::RgbImage,
    pub dynamic: Option<&'a [bool]>,
    pub camera_from_world: &'a Se3,
}

/// A sparse TSDF volume.
#[derive(Debug, Clone)]
pub struct TsdfVolume {
    pub settings: TsdfSettings,
    camera: PinholeCamera,
    pub blocks: Vec<Block>,
    pub coords: Vec<[i32; 3]>,
    index: FxMap<[i32; 3], u32>,
    frames: u32,
}

impl TsdfVolume {
    pub fn new(settings: TsdfSettings, camera: PinholeCamera) -> Self {
        Self {
            settings,
            camera,
            blocks: Vec::new(),
            coords: Vec::new(),
            index: FxMap::default(),
            frames: 0,
        }
    }

    /// Edge of a block, metres.
    pub fn block_size(&self) -> f64 {
        self.settings.voxel * BLOCK as f64
    }

    /// The block holding world point `p`.
    fn block_of(&self, p: &Vector3<f64>) -> [i32; 3] {
        let s = self.block_size();
        [
            (p.x / s).floor() as i32,
            (p.y / s).floor() as i32,
            (p.z / s).floor() as i32,
        ]
    }

    /// The block at `coord`, if allocated.
    pub fn block(&self, coord: [i32; 3]) -> Option<&Block> {
        self.index.get(&coord).map(|&i| &self.blocks[i as usize])
    }

    /// The block at `coord`, allocated if it was not.
    pub fn block_mut(&mut self, coord: [i32; 3]) -> &mut Block {
        let next = self.blocks.len() as u32;
        let i = *self.index.entry(coord).or_insert(next);
        if i == next {
            self.blocks.push(Block::new());
            self.coords.push(coord);
        }
        &mut self.blocks[i as usize]
    }

    /// Bytes held by the voxel data.
    pub fn memory_bytes(&self) -> usize {
        self.blocks.len() * BLOCK_VOXELS * (4 + 4 + 3 + 2)
    }

    /// Fuses one frame (see the module doc).
    pub fn integrate(&mut self, frame: &FrameInput) {
        self.frames += 1;
        let stamp = self.frames;
        let (near, carved) = self.blocks_seen(frame);
        for coord in near {
            self.block_mut(coord).stamp = stamp;
        }
        for coord in carved {
            if let Some(&i) = self.index.get(&coord) {
                self.blocks[i as usize].stamp = stamp;
            }
        }
        let (settings, camera, block_size) = (self.settings, self.camera, self.block_size());
        self.blocks
            .par_iter_mut()
            .zip(self.coords.par_iter())
            .filter(|(b, _)| b.stamp == stamp)
            .for_each(|(block, coord)| {
                integrate_block(block, coord, block_size, &settings, &camera, frame)
            });
    }

    /// Block coordinates within \(\tau\) of the frame's depth, and blocks that rays
    /// cross in front of it (from every 4th pixel; rays from every 8th, only when carving).
    fn blocks_seen(&self, frame: &FrameInput) -> (Vec<[i32; 3]>, Vec<[i32; 3]>) {
        let (w, h) = (frame.depth.width as usize, frame.depth.height as usize);
        let world_from_camera = frame.camera_from_world.inverse();
        let tau = self.settings.truncation;
        let step = 4;
        type Blocks = Vec<[i32; 3]>;
        let rows: Vec<(Blocks, Blocks)> = (0..h)
            .into_par_iter()
            .step_by(step)
            .map(|v| {
                let mut near = Vec::new();
                let mut carved = Vec::new();
                for u in (0..w).step_by(step) {
                    let i = v * w + u;
                    let d = frame.depth.metres[i] as f64;
                    if d <= 0.0 || d > self.settings.max_depth {
                        continue;
                    }
                    let dynamic = frame.dynamic.is_some_and(|m| m[i]);
                    let ray = self
                        .camera
                        .unproject(&nalgebra::Vector2::new(u as f64, v as f64), 1.0);
                    let p = |z: f64| (world_from_camera * Point3::from(ray * z)).coords;
                    // Every block within tau of the surface point, in any direction
                    // (not for a mover's surface; the free space before it still counts).
                    let surface = p(d);
                    let (lo, hi) = if dynamic {
                        ([0; 3], [-1; 3])
                    } else {
                        (
                            self.block_of(&surface.add_scalar(-tau)),
                            self.block_of(&surface.add_scalar(tau)),
                        )
                    };
                    for bz in lo[2]..=hi[2] {
                        for by in lo[1]..=hi[1] {
                            for bx in lo[0]..=hi[0] {
                                // Neighbouring pixels mostly repeat the last few blocks.
                                let b = [bx, by, bz];
                                if !near[near.len().saturating_sub(16)..].contains(&b) {
                                    near.push(b);
                                }
                            }
                        }
                    }
                    if self.settings.carve && u % 8 == 0 && v % 8 == 0 {
                        // Steps of one block along the ray, up to the truncation band.
                        let dz = self.block_size() / ray.norm();
                        let mut z = dz;
                        while z < d - tau {
                            let coord = self.block_of(&p(z));
                            if let Some(&i) = self.index.get(&coord) {
                                if self.blocks[i as usize].surface {
                                    carved.push(coord);
                                }
                            }
                            z += dz;
                        }
                    }
                }
                near.sort_unstable();
                near.dedup();
                carved.sort_unstable();
                carved.dedup();
                (near, carved)
            })
            .collect();
        let mut near: Vec<[i32; 3]> = rows.iter().flat_map(|r| r.0.iter().copied()).collect();
        let mut carved: Vec<[i32; 3]> = rows.iter().flat_map(|r| r.1.iter().copied()).collect();
        near.sort_unstable();
        near.dedup();
        carved.sort_unstable();
        carved.dedup();
        (near, carved)
    }
}

/// Fuses one frame into one block.
fn integrate_block(
    block: &mut Block,
    coord: &[i32; 3],
    block_size: f64,
    settings: &TsdfSettings,
    camera: &PinholeCamera,
    frame: &FrameInput,
) {
    let (w, h) = (frame.depth.width as i32, frame.depth.height as i32);
    let tau = settings.truncation as f32;
    let inv_tau = 1.0 / tau;
    let far = (settings.max_depth + settings.truncation) as f32;
    let max_depth = settings.max_depth as f32;
    let (fx, fy, cx, cy) = (
        camera.fx as f32,
        camera.fy as f32,
        camera.cx as f32,
        camera.cy as f32,
    );
    // Voxel centres sit at integer multiples of the voxel size (a corner-aligned
    // lattice shared by neighbouring blocks); in the camera a voxel is
    // p = R c + t + x R e_x v + y R e_y v + z R e_z v, stepped incrementally in f32.
    let r = frame.camera_from_world.rotation.matrix();
    let corner = Vector3::new(coord[0] as f64, coord[1] as f64, coord[2] as f64) * block_size;
    let origin = (r * corner + frame.camera_from_world.translation.vector).cast::<f32>();
    let step = |k: usize| (r.column(k) * settings.voxel).into_owned().cast::<f32>();
    let (dx, dy, dz) = (step(0), step(1), step(2));
    let depth = &frame.depth.metres;
    let colour = frame.colour.as_raw();
    let mut i = 0;
    for z in 0..BLOCK {
        let pz = origin + dz * z as f32;
        for y in 0..BLOCK {
            let mut p = pz + dy * y as f32;
            for _ in 0..BLOCK {
                let here = p;
                p += dx;
                i += 1;
                if here.z <= 0.0 || here.z > far {
                    continue;
                }
                // Nearest pixel; `+ 0.5` then truncation (no libm round call).
                let inv = 1.0 / here.z;
                let (uf, vf) = (fx * here.x * inv + cx + 0.5, fy * here.y * inv + cy + 0.5);
                if uf < 0.0 || vf < 0.0 {
                    continue;
                }
                let (u, v) = (uf as i32, vf as i32);
                if u >= w || v >= h {
                    continue;
                }
                let pixel = (v * w + u) as usize;
                let d = depth[pixel];
                if d <= 0.0 || d > max_depth {
                    continue;
                }
                let eta = d - here.z;
                // A masked pixel's depth is a mover's: nothing at or behind it is
                // fused, but the free space in front of it still carves.
                let dynamic = frame.dynamic.is_some_and(|m| m[pixel]);
                if eta < -tau || (dynamic && eta <= tau) {
                    continue;
                }
                let k = i - 1;
                let weight = block.weight[k];
                let inv_total = 1.0 / (weight + 1.0);
                block.sdf[k] = (block.sdf[k] * weight + (eta * inv_tau).min(1.0)) * inv_total;
                block.weight[k] = (weight + 1.0).min(settings.max_weight);
                if eta <= tau {
                    let c = &colour[3 * pixel..3 * pixel + 3];
                    let seen = block.colour_weight[k].min(settings.max_weight as u16) as f32;
                    let inv_seen = 1.0 / (seen + 1.0);
                    let old = &mut block.colour[k];
                    for ch in 0..3 {
                        old[ch] = ((old[ch] as f32 * seen + c[ch] as f32) * inv_seen + 0.5) as u8;
                    }
                    block.colour_weight[k] = block.colour_weight[k].saturating_add(1);
                }
            }
        }
    }
    block.surface = block
        .sdf
        .iter()
        .zip(&block.weight)
        .any(|(&f, &w)| f < 0.0 && w > 0.0);
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::dense::marching_cubes::extract;
    use crate::geometry::se3;
    use nalgebra::Matrix3;
    use std::collections::HashMap;

    pub fn small_camera() -> PinholeCamera {
        PinholeCamera {
            fx: 140.0,
            fy: 140.0,
            cx: 80.0,
            cy: 60.0,
            width: 160,
            height: 120,
            distortion: [0.0; 5],
        }
    }

    /// `camera_from_world` of a camera at `eye` looking at `target` (world y down).
    pub fn looking_at(eye: Vector3<f64>, target: Vector3<f64>) -> Se3 {
        let z = (target - eye).normalize();
        let helper = if z.y.abs() > 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let x = helper.cross(&z).normalize();
        let y = z.cross(&x);
        se3::from_parts(eye, Matrix3::from_columns(&[x, y, z])).inverse()
    }

    /// Depth of the nearest hit among spheres `(centre, radius)` and the plane z = `wall`;
    /// without a hit, `backdrop` (a camera-fixed depth) or none.
    pub fn render_depth(
        camera: &PinholeCamera,
        camera_from_world: &Se3,
        spheres: &[(Vector3<f64>, f64)],
        wall: Option<f64>,
    ) -> DepthImage {
        render_with_backdrop(camera, camera_from_world, spheres, wall, None)
    }

    pub fn render_with_backdrop(
        camera: &PinholeCamera,
        camera_from_world: &Se3,
        spheres: &[(Vector3<f64>, f64)],
        wall: Option<f64>,
        backdrop: Option<f64>,
    ) -> DepthImage {
        let world_from_camera = camera_from_world.inverse();
        let origin = world_from_camera.translation.vector;
        let mut depth = DepthImage::new(camera.width, camera.height);
        for v in 0..camera.height {
            for u in 0..camera.width {
                let ray_c = camera.unproject(&nalgebra::Vector2::new(u as f64, v as f64), 1.0);
                let dir = world_from_camera.rotation * ray_c;
                let mut best = f64::INFINITY;
                for (c, r) in spheres {
                    // |o + t d - c|² = r², t along d (d has camera z = 1).
                    let oc = origin - c;
                    let (a, b, k) = (dir.dot(&dir), 2.0 * dir.dot(&oc), oc.dot(&oc) - r * r);
                    let disc = b * b - 4.0 * a * k;
                    if disc >= 0.0 {
                        let t = (-b - disc.sqrt()) / (2.0 * a);
                        if t > 0.0 {
                            best = best.min(t);
                        }
                    }
                }
                if let Some(z) = wall {
                    let t = (z - origin.z) / dir.z;
                    if t > 0.0 {
                        best = best.min(t);
                    }
                }
                if let Some(z) = backdrop.filter(|_| !best.is_finite()) {
                    best = z;
                }
                if best.is_finite() {
                    depth.metres[(v * camera.width + u) as usize] = best as f32;
                }
            }
        }
        depth
    }

    fn fuse_views(
        volume: &mut TsdfVolume,
        views: &[Se3],
        spheres: &[(Vector3<f64>, f64)],
        wall: Option<f64>,
    ) {
        let camera = small_camera();
        let colour =
            image::RgbImage::from_pixel(camera.width, camera.height, image::Rgb([90, 160, 40]));
        // A sphere alone gets a backdrop 2.5 m away, as a room would give.
        let backdrop = wall.is_none().then_some(2.5);
        for pose in views {
            let depth = render_with_backdrop(&camera, pose, spheres, wall, backdrop);
            volume.integrate(&FrameInput {
                depth: &depth,
                colour: &colour,
                dynamic: None,
                camera_from_world: pose,
            });
        }
    }

    fn ring(centre: Vector3<f64>, radius: f64, n: usize) -> Vec<Se3> {
        (0..n)
            .map(|k| {
                let a = k as f64 / n as f64 * std::f64::consts::TAU;
                let eye = centre
                    + Vector3::new(a.cos() * radius, 0.3 * (2.0 * a).sin(), a.sin() * radius);
                looking_at(eye, centre)
            })
            .collect()
    }

    #[test]
    fn a_sphere_seen_all_round_becomes_a_closed_outward_mesh_on_its_surface() {
        let centre = Vector3::new(0.1, -0.05, 0.2);
        let radius = 0.25;
        let settings = TsdfSettings {
            voxel: 0.02,
            truncation: 0.06,
            ..TsdfSettings::default()
        };
        let mut volume = TsdfVolume::new(settings, small_camera());
        let mut views = ring(centre, 1.0, 24);
        views.push(looking_at(centre + Vector3::new(0.0, -1.0, 0.01), centre));
        views.push(looking_at(centre + Vector3::new(0.0, 1.0, 0.01), centre));
        fuse_views(&mut volume, &views, &[(centre, radius)], None);
        let mesh = extract(&volume);
        // The sphere's part of the mesh (the backdrop lies 1.5 m from its centre).
        let near = |i: u32| (mesh.vertex(i as usize) - centre).norm() < 0.6;
        let triangles: Vec<[u32; 3]> = mesh
            .triangles
            .iter()
            .filter(|t| t.iter().all(|&i| near(i)))
            .copied()
            .collect();
        assert!(triangles.len() > 500, "{} triangles", triangles.len());
        let mut total = 0.0;
        let vertices: std::collections::BTreeSet<u32> =
            triangles.iter().flatten().copied().collect();
        for &i in &vertices {
            let error = ((mesh.vertex(i as usize) - centre).norm() - radius).abs();
            assert!(error < 0.75 * settings.voxel, "vertex {i} off by {error}");
            assert_eq!(mesh.colours[i as usize], [90, 160, 40]);
            total += error;
        }
        let mean = total / vertices.len() as f64;
        assert!(mean < 0.2 * settings.voxel, "mean error {mean}");
        // Closed and consistently oriented: each directed edge once, its reverse once.
        let mut directed: HashMap<(u32, u32), usize> = HashMap::new();
        for t in &triangles {
            for k in 0..3 {
                *directed.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
            }
            let [a, b, c] = t.map(|i| mesh.vertex(i as usize));
            let normal = (b - a).cross(&(c - a));
            assert!(
                normal.dot(&(a - centre)) > 0.0,
                "triangle {t:?} faces inwards"
            );
        }
        for (&(a, b), &n) in &directed {
            assert_eq!(n, 1, "edge ({a}, {b}) used {n} times one way");
            assert!(
                directed.contains_key(&(b, a)),
                "edge ({a}, {b}) at {:?} is a border",
                mesh.vertex(a as usize) - centre
            );
        }
    }

    #[test]
    fn a_ball_that_leaves_is_carved_away_and_masked_pixels_are_not_fused() {
        let settings = TsdfSettings {
            voxel: 0.02,
            truncation: 0.06,
            max_weight: 20.0,
            ..TsdfSettings::default()
        };
        let ball = (Vector3::new(0.0, 0.0, 1.2), 0.2);
        let views: Vec<Se3> = (0..10)
            .map(|k| {
                looking_at(
                    Vector3::new(-0.1 + 0.02 * k as f64, 0.0, 0.0),
                    Vector3::new(0.0, 0.0, 2.0),
                )
            })
            .collect();
        let near_ball = |volume: &TsdfVolume| {
            let mesh = extract(volume);
            (0..mesh.len())
                .filter(|&i| (mesh.vertex(i) - ball.0).norm() < ball.1 + 0.05)
                .count()
        };
        let mut volume = TsdfVolume::new(settings, small_camera());
        fuse_views(&mut volume, &views, &[ball], Some(2.0));
        assert!(
            near_ball(&volume) > 50,
            "the ball is in the map while it is there"
        );
        // It leaves: the wall behind is seen through where it was.
        for _ in 0..3 {
            fuse_views(&mut volume, &views, &[], Some(2.0));
        }
        assert_eq!(near_ball(&volume), 0, "the ball is carved away");
        // Masked as dynamic, it never enters.
        let camera = small_camera();
        let mut clean = TsdfVolume::new(settings, camera);
        let colour = image::RgbImage::new(camera.width, camera.height);
        for pose in &views {
            let depth = render_depth(&camera, pose, &[ball], Some(2.0));
            let mask: Vec<bool> = depth.metres.iter().map(|&d| d < 1.9).collect();
            clean.integrate(&FrameInput {
                depth: &depth,
                colour: &colour,
                dynamic: Some(&mask),
                camera_from_world: pose,
            });
        }
        assert_eq!(near_ball(&clean), 0);
        assert!(extract(&clean).len() > 100, "the wall is there");
    }
}
