//! A coloured point cloud from masked depth: pixels back-projected with the frame's
//! final pose, \(p_w = T_{wc}\, d\, K^{-1}(u, v, 1)^T\), averaged per voxel (position,
//! colour), then optionally cleaned by statistical outlier removal (a point whose mean
//! distance \(\bar d_i\) to its k nearest neighbours exceeds
//! \(\mu + s\,\sigma\) of all \(\bar d\) goes, as PCL's and Open3D's filters do) and
//! given normals (the least-variance axis of its k neighbours, turned towards the
//! cameras that saw it). The sums are kept in chunks under a memory budget
//! ([`CloudBuilder::spill_to`]), and the cloud is written chunk by chunk
//! ([`Carved::write`]): no step holds the whole cloud but its positions (the neighbour
//! searches').

use std::path::Path;

use nalgebra::{Matrix3, Point3, Vector2, Vector3};
use rayon::prelude::*;

use super::cloud_voxels::{CloudSpillCounts, CloudVoxels, KeptCloud, Voxel};
use super::neighbours::PointIndex;
use super::tsdf::FrameInput;
use crate::geometry::camera::PinholeCamera;
use crate::geometry::mesh::Mesh;
use crate::io::ply::PlyEncoding;
use crate::io::ply_stream::{PlyPointStream, PointRows};
use crate::io::IoError;

/// Settings of the point cloud.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CloudSettings {
    /// Voxel edge of the downsampling, metres.
    pub voxel: f64,
    /// Use every `stride`-th pixel in each direction.
    pub stride: usize,
    /// Depths beyond this are left out, metres.
    pub max_depth: f64,
    /// Neighbours for outlier removal (0: off) and its threshold in standard deviations.
    pub outlier_neighbours: usize,
    /// The outlier threshold, standard deviations.
    pub outlier_std: f64,
    /// Neighbours for normals (0: no normals).
    pub normal_neighbours: usize,
    /// Pixels this close to the image border are left out (`[dense] image_margin`: a
    /// person cut by the border to a sliver is found by no detector).
    pub margin: u32,
}

/// Accumulates frames into voxels.
pub struct CloudBuilder {
    settings: CloudSettings,
    camera: PinholeCamera,
    voxels: CloudVoxels,
}

impl CloudBuilder {
    /// A cloud of `camera`'s frames with `settings`.
    pub fn new(settings: CloudSettings, camera: PinholeCamera) -> Self {
        Self {
            settings,
            camera,
            voxels: CloudVoxels::default(),
        }
    }

    /// Keeps at most `budget_bytes` of voxel sums in memory while frames are added:
    /// beyond it the chunks the camera left longest ago go to a spill file in `dir`
    /// (removed with the cloud) and come back when a frame adds to them.
    pub fn spill_to(&mut self, dir: &Path, budget_bytes: usize) -> Result<(), IoError> {
        self.voxels.spill_to(dir, budget_bytes)
    }

    /// With a budget: every chunk of sums in memory goes to the spill file (the mesh
    /// is made meanwhile); they come back as the cloud is carved.
    pub fn spill_everything(&mut self) -> Result<(), IoError> {
        self.voxels.spill_everything()
    }

    /// Keeps the sums in `dir` (see [`CloudVoxels::keep`]).
    pub fn keep(&self, dir: &Path) -> Result<KeptCloud, IoError> {
        self.voxels.keep(dir)
    }

    /// The cloud of `camera`'s frames with `settings` whose sums [`CloudBuilder::keep`]
    /// left in `dir` (see [`CloudVoxels::from_kept`]).
    pub fn from_kept(
        settings: CloudSettings,
        camera: PinholeCamera,
        dir: &Path,
        kept: &KeptCloud,
        spill_dir: &Path,
        budget_bytes: usize,
    ) -> Result<Self, IoError> {
        Ok(Self {
            settings,
            camera,
            voxels: CloudVoxels::from_kept(dir, kept, spill_dir, budget_bytes)?,
        })
    }

    /// What the budget made the cloud do.
    pub fn spill_counts(&self) -> CloudSpillCounts {
        self.voxels.spill_counts()
    }

    /// Adds the unmasked pixels of one frame; an error only from the spill file.
    pub fn add(&mut self, frame: &FrameInput) -> Result<(), IoError> {
        let (w, h) = (frame.depth.width as usize, frame.depth.height as usize);
        let world_from_camera = frame.camera_from_world.inverse();
        let centre = world_from_camera.translation.vector;
        let (s, camera) = (self.settings, self.camera);
        let m = s.margin as usize;
        let inside = move |u: usize, v: usize| u >= m && v >= m && u + m < w && v + m < h;
        let points: Vec<(Vector3<f64>, [u8; 3])> = (0..h)
            .into_par_iter()
            .step_by(s.stride)
            .flat_map_iter(|v| {
                let world_from_camera = &world_from_camera;
                (0..w).step_by(s.stride).filter_map(move |u| {
                    let i = v * w + u;
                    let d = frame.depth.metres[i] as f64;
                    let masked = frame.dynamic.is_some_and(|mask| mask[i]);
                    if d <= 0.0 || d > s.max_depth || masked || !inside(u, v) {
                        return None;
                    }
                    let p = camera.unproject(&Vector2::new(u as f64, v as f64), d);
                    let p = (world_from_camera * Point3::from(p)).coords;
                    Some((p, frame.colour.get_pixel(u as u32, v as u32).0))
                })
            })
            .collect();
        for (p, c) in points {
            let key = [0, 1, 2].map(|k| (p[k] / s.voxel).floor() as i32);
            let voxel = self.voxels.voxel_mut(key)?;
            let view = (centre - p).normalize();
            for k in 0..3 {
                voxel.sum[k] += p[k];
                voxel.colour[k] += c[k] as u32;
                voxel.view[k] += view[k];
            }
            voxel.count += 1;
        }
        self.voxels.end_step()
    }

    /// The voxels whose means `drop` names removed (it answers for a chunk of
    /// neighbouring means at a time), and how many it removed. [`Carved::write`]
    /// makes the cloud of the rest (after the volume that `drop` reads is gone).
    pub fn carve(
        mut self,
        drop: impl Fn(&[Vector3<f64>]) -> Vec<bool>,
    ) -> Result<(Carved, usize), IoError> {
        let before = self.voxels.len();
        for at in self.voxels.chunk_keys() {
            let voxels = self.voxels.sorted(at)?;
            let means: Vec<Vector3<f64>> = (voxels.iter())
                .map(|(_, v)| Vector3::from(v.sum) / v.count as f64)
                .collect();
            let keep: Vec<bool> = drop(&means).into_iter().map(|d| !d).collect();
            self.voxels.retain(at, &keep)?;
            self.voxels.end_step()?;
        }
        let dropped = before - self.voxels.len();
        let carved = Carved {
            settings: self.settings,
            voxels: self.voxels,
        };
        Ok((carved, dropped))
    }
}

/// The cloud's voxels before outliers and normals ([`CloudBuilder::carve`]).
pub struct Carved {
    settings: CloudSettings,
    voxels: CloudVoxels,
}

/// The cloud as written ([`Carved::write`]).
pub struct WrittenCloud {
    /// The file's rows, to be finished ([`PlyPointStream::finish`]).
    pub stream: PlyPointStream,
    /// At most the asked number of its points, evenly spread over the file's order
    /// (pictures).
    pub sample: Mesh,
    /// What the memory budget made the voxel sums do.
    pub spill: CloudSpillCounts,
}

impl Carved {
    /// The cloud written chunk by chunk into `path` (as a stream, finished later):
    /// outliers removed and normals estimated over the whole cloud's positions (the
    /// only per-point data held whole), colours and view directions read chunk by
    /// chunk; a sample of at most `sample` points.
    pub fn write(
        mut self,
        path: &Path,
        encoding: PlyEncoding,
        comment: &str,
        sample: usize,
    ) -> Result<WrittenCloud, IoError> {
        let s = self.settings;
        let chunks = self.voxels.chunk_keys();
        let Positions {
            mut keys,
            mut positions,
        } = self.positions(&chunks)?;
        let keep = match s.outlier_neighbours > 0 && positions.len() > s.outlier_neighbours {
            true => inliers(&positions, s.outlier_neighbours, s.outlier_std),
            false => vec![true; positions.len()],
        };
        let mut kept = keep.iter();
        positions.retain(|_| *kept.next().expect("one flag a point"));
        let mut kept = keep.iter();
        keys.retain(|_| *kept.next().expect("one flag a point"));
        drop(keep);
        let normals = s.normal_neighbours >= 3 && positions.len() > s.normal_neighbours;
        let rows = PointRows {
            normals,
            colours: !positions.is_empty(),
        };
        let index = normals.then(|| PointIndex::new(&positions));
        let mut stream = PlyPointStream::create(path, rows, encoding, comment)?;
        let mut picked = Sample::new(sample);
        for &at in &chunks {
            // The chunk's kept points, and where they are in `positions`.
            let (own, points): (Vec<usize>, Vec<Point>) = (self.voxels.sorted(at)?.iter())
                .filter_map(|(key, v)| Some((keys.binary_search(key).ok()?, Point::of(v))))
                .unzip();
            let mut piece = Mesh::points(own.iter().map(|&i| positions[i]).collect());
            piece.colours = points.iter().map(|p| p.colour).collect();
            if let Some(index) = &index {
                piece.normals = (own.par_iter().zip(points.par_iter()))
                    .map(|(&i, p)| {
                        normal(index, &positions, i, &p.view.into(), s.normal_neighbours)
                    })
                    .collect();
            }
            stream.push(&piece)?;
            picked.add(&piece);
            self.voxels.end_step()?;
        }
        Ok(WrittenCloud {
            stream,
            sample: picked.mesh,
            spill: self.voxels.spill_counts(),
        })
    }

    /// Every point's voxel key and position, in the keys' order (the neighbour
    /// searches' ties are then broken as they always were).
    fn positions(&mut self, chunks: &[[i32; 3]]) -> Result<Positions, IoError> {
        let mut keyed = Vec::with_capacity(self.voxels.len());
        for &at in chunks {
            let voxels = self.voxels.sorted(at)?;
            keyed.extend(voxels.iter().map(|(k, v)| (*k, Point::of(v).position)));
            self.voxels.end_step()?;
        }
        keyed.par_sort_unstable_by_key(|(k, _)| *k);
        let (keys, positions) = keyed.into_iter().unzip();
        Ok(Positions { keys, positions })
    }
}

/// The cloud's points' voxel keys and positions, in the keys' order.
struct Positions {
    keys: Vec<[i32; 3]>,
    positions: Vec<[f32; 3]>,
}

/// Statistical outlier removal: which points to keep.
pub fn inliers(points: &[[f32; 3]], k: usize, std_ratio: f64) -> Vec<bool> {
    let index = PointIndex::new(points);
    let mean_distances: Vec<f64> = points
        .par_iter()
        .map(|p| {
            let near = index.nearest(p, k + 1);
            let d: f64 = near.iter().skip(1).map(|&(_, d)| d as f64).sum();
            d / (near.len().saturating_sub(1)).max(1) as f64
        })
        .collect();
    let n = mean_distances.len() as f64;
    let mean = mean_distances.iter().sum::<f64>() / n;
    let var = mean_distances
        .iter()
        .map(|d| (d - mean).powi(2))
        .sum::<f64>()
        / n;
    let limit = mean + std_ratio * var.sqrt();
    mean_distances.iter().map(|&d| d <= limit).collect()
}

/// A bounded sample of the points pushed: every `step`-th, the step doubled (and every
/// other point kept dropped) whenever more than `max` are kept.
pub(super) struct Sample {
    pub(super) mesh: Mesh,
    step: usize,
    seen: usize,
    max: usize,
}

impl Sample {
    pub(super) fn new(max: usize) -> Self {
        Self {
            mesh: Mesh::default(),
            step: 1,
            seen: 0,
            max: max.max(1),
        }
    }

    pub(super) fn add(&mut self, piece: &Mesh) {
        for i in 0..piece.len() {
            if self.seen.is_multiple_of(self.step) {
                self.mesh.vertices.push(piece.vertices[i]);
                self.mesh.colours.extend(piece.colours.get(i));
            }
            self.seen += 1;
            if self.mesh.len() > self.max {
                let mesh = &mut self.mesh;
                mesh.vertices = mesh.vertices.iter().copied().step_by(2).collect();
                mesh.colours = mesh.colours.iter().copied().step_by(2).collect();
                self.step *= 2;
            }
        }
    }
}

/// A voxel's point: its mean position and colour, and its summed view directions.
struct Point {
    position: [f32; 3],
    colour: [u8; 3],
    view: [f64; 3],
}

impl Point {
    fn of(voxel: &Voxel) -> Self {
        let n = voxel.count as f64;
        Self {
            position: voxel.sum.map(|c| (c / n) as f32),
            colour: voxel.colour.map(|c| (c as f64 / n).round() as u8),
            view: voxel.view,
        }
    }
}

/// The unit normal at `points[i]`: the least-variance axis of its `k` nearest, towards
/// `view`.
fn normal(
    index: &PointIndex,
    points: &[[f32; 3]],
    i: usize,
    view: &Vector3<f64>,
    k: usize,
) -> [f32; 3] {
    let near = index.nearest(&points[i], k);
    let pts: Vec<Vector3<f64>> = near
        .iter()
        .map(|&(j, _)| Vector3::from(points[j as usize].map(f64::from)))
        .collect();
    let mean = pts.iter().sum::<Vector3<f64>>() / pts.len() as f64;
    let cov: Matrix3<f64> = pts
        .iter()
        .map(|q| (q - mean) * (q - mean).transpose())
        .sum();
    let eigen = cov.symmetric_eigen();
    let smallest = eigen.eigenvalues.imin();
    let mut n: Vector3<f64> = eigen.eigenvectors.column(smallest).into_owned();
    if n.dot(view) < 0.0 {
        n = -n;
    }
    n.map(|c| c as f32).into()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::image_files::DepthImage;

    /// `carved` written to a file and read back, and its sample.
    fn written(carved: Carved, name: &str, sample: usize) -> (Mesh, Mesh) {
        let dir = std::env::temp_dir().join(format!("dopslam-cloud-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("points.ply");
        let cloud = (carved.write(&path, PlyEncoding::Binary, "test", sample)).unwrap();
        cloud.stream.finish().unwrap();
        let mesh = crate::io::ply::read_ply(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        (mesh, cloud.sample)
    }

    /// Outliers and normals of `points` held whole, in their own order.
    fn whole_cloud(points: &[[f32; 3]], views: &[Vector3<f64>], s: &CloudSettings) -> Mesh {
        let keep = inliers(points, s.outlier_neighbours, s.outlier_std);
        let kept: Vec<usize> = (0..points.len()).filter(|&i| keep[i]).collect();
        let mut cloud = Mesh::points(kept.iter().map(|&i| points[i]).collect());
        let index = PointIndex::new(&cloud.vertices);
        cloud.normals = (0..kept.len())
            .map(|i| {
                normal(
                    &index,
                    &cloud.vertices,
                    i,
                    &views[kept[i]],
                    s.normal_neighbours,
                )
            })
            .collect();
        cloud
    }

    /// A wall, a thin pole before it and stray points, written chunk by chunk (in
    /// chunk order) and finished whole in the points' own order: the same points go
    /// and the same normals come.
    #[test]
    fn a_cloud_written_in_chunks_is_the_cloud_finished_whole() {
        let s = CloudSettings {
            voxel: 0.02,
            stride: 1,
            max_depth: 10.0,
            outlier_neighbours: 16,
            outlier_std: 2.0,
            normal_neighbours: 16,
            margin: 0,
        };
        let mut rng = crate::random::Rng::new(5);
        let mut candidates: Vec<[f32; 3]> = Vec::new();
        for i in 0..150 {
            for j in 0..60 {
                let z = 2.01 + 0.002 * rng.uniform() as f32;
                candidates.push([0.02 * i as f32 + 0.01, 0.02 * j as f32 + 0.01, z]);
            }
        }
        for j in 0..60 {
            candidates.push([1.51, 0.02 * j as f32 + 0.01, 1.01]);
        }
        for _ in 0..40 {
            let r = [3.0, 1.2, 1.0].map(|size| size * rng.uniform() as f32);
            candidates.push([r[0], r[1], 0.5 + r[2]]);
        }
        // One point a voxel, as the voxel means are.
        let key = |p: &[f32; 3]| [0, 1, 2].map(|k| (p[k] as f64 / s.voxel).floor() as i32);
        let mut seen = std::collections::HashSet::new();
        let points: Vec<[f32; 3]> = candidates
            .into_iter()
            .filter(|p| seen.insert(key(p)))
            .collect();
        let mut builder = CloudBuilder::new(s, PinholeCamera::tum_fr3());
        for p in &points {
            let voxel = builder.voxels.voxel_mut(key(p)).unwrap();
            *voxel = Voxel {
                sum: p.map(f64::from),
                colour: [1, 2, 3],
                view: [0.0, 0.0, -1.0],
                count: 1,
            };
        }
        builder.voxels.end_step().unwrap();
        let (carved, _) = builder.carve(|m| vec![false; m.len()]).unwrap();
        let (chunked, sample) = written(carved, "whole", 500);
        let views = vec![Vector3::new(0.0, 0.0, -1.0); points.len()];
        let whole = whole_cloud(&points, &views, &s);
        let sorted = |m: &Mesh| {
            let mut rows: Vec<([u32; 3], [f32; 3])> = (0..m.len())
                .map(|i| (m.vertices[i].map(f32::to_bits), m.normals[i]))
                .collect();
            rows.sort_unstable_by_key(|r| r.0);
            rows
        };
        let (a, b) = (sorted(&chunked), sorted(&whole));
        assert!(
            whole.len() < points.len() && whole.len() > 8500,
            "{}",
            whole.len()
        );
        assert_eq!(a.len(), b.len());
        for ((pa, na), (pb, nb)) in a.iter().zip(&b) {
            assert_eq!(pa, pb);
            let dot: f32 = (0..3).map(|k| na[k] * nb[k]).sum();
            assert!(dot > 0.9999, "{na:?} {nb:?}");
        }
        assert!(
            sample.len() <= 500 && sample.len() > 250,
            "{}",
            sample.len()
        );
    }

    #[test]
    fn a_wall_becomes_a_flat_cloud_with_normals_to_the_camera_and_no_outliers() {
        let camera = PinholeCamera::tum_fr3();
        let mut depth = DepthImage::new(camera.width, camera.height);
        depth.metres.iter_mut().for_each(|d| *d = 2.0);
        // One stray pixel far in front of the wall.
        depth.metres[(100 * camera.width + 100) as usize] = 0.7;
        let colour =
            image::RgbImage::from_pixel(camera.width, camera.height, image::Rgb([200, 100, 50]));
        let pose = crate::geometry::se3::Se3::identity();
        let mut builder = CloudBuilder::new(
            CloudSettings {
                voxel: 0.02,
                stride: 2,
                max_depth: 4.0,
                outlier_neighbours: 8,
                outlier_std: 2.0,
                normal_neighbours: 10,
                margin: 0,
            },
            camera,
        );
        let mut mask = vec![false; (camera.width * camera.height) as usize];
        mask[..(camera.width * 10) as usize]
            .iter_mut()
            .for_each(|m| *m = true);
        builder
            .add(&FrameInput {
                depth: &depth,
                colour: &colour,
                dynamic: Some(&mask),
                camera_from_world: &pose,
                weight: 1.0,
            })
            .unwrap();
        let (carved, _) = (builder.carve(|means| vec![false; means.len()])).unwrap();
        let (cloud, _) = written(carved, "wall", 1000);
        assert!(cloud.len() > 1000);
        assert!(
            cloud.vertices.iter().all(|v| (v[2] - 2.0).abs() < 1e-4),
            "the stray point is gone"
        );
        assert!(cloud.colours.iter().all(|c| *c == [200, 100, 50]));
        assert!(
            cloud.normals.iter().all(|n| n[2] < -0.99),
            "normals face the camera"
        );
        // The masked top rows are not fused.
        let top = camera.unproject(&Vector2::new(0.0, 9.0), 2.0).y as f32;
        assert!(cloud.vertices.iter().all(|v| v[1] > top));
    }

    /// A camera pans 3 m along a wall and back: with a budget of a frame's voxels, the
    /// chunks it left go to the spill file and come back on the return; the same cloud.
    #[test]
    fn a_cloud_over_its_budget_spills_and_gives_the_same_points() {
        let camera = PinholeCamera::tum_fr3();
        let mut depth = DepthImage::new(camera.width, camera.height);
        depth.metres.iter_mut().for_each(|d| *d = 2.0);
        let colour = image::RgbImage::from_fn(camera.width, camera.height, |u, v| {
            image::Rgb([(u % 256) as u8, (v % 256) as u8, 7])
        });
        let settings = CloudSettings {
            voxel: 0.02,
            stride: 4,
            max_depth: 4.0,
            outlier_neighbours: 8,
            outlier_std: 2.0,
            normal_neighbours: 10,
            margin: 0,
        };
        let xs: Vec<f64> = (0..13)
            .chain((0..12).rev())
            .map(|k| 0.25 * k as f64)
            .collect();
        let dir = std::env::temp_dir().join(format!("dopslam-cloud-{}", std::process::id()));
        let built = |budget: Option<usize>| {
            let mut builder = CloudBuilder::new(settings, camera);
            if let Some(bytes) = budget {
                builder.spill_to(&dir, bytes).unwrap();
            }
            for x in &xs {
                let pose = crate::geometry::se3::Se3::translation(-x, 0.0, 0.0);
                (builder.add(&FrameInput {
                    depth: &depth,
                    colour: &colour,
                    dynamic: None,
                    camera_from_world: &pose,
                    weight: 1.0,
                }))
                .unwrap();
            }
            let counts = builder.spill_counts();
            let (carved, dropped) = (builder
                .carve(|means| means.iter().map(|p| (2.5..2.6).contains(&p.x)).collect()))
            .unwrap();
            let (cloud, _) = written(carved, &format!("{budget:?}"), 1000);
            (cloud, dropped, counts)
        };
        let (whole, whole_dropped, all) = built(None);
        let (spilled, dropped, counts) = built(Some(1_000_000));
        let within = counts.peak_resident_mb < 0.7 * all.peak_resident_mb;
        let spilled_back = counts.chunks_written > 0 && counts.chunks_reloaded > 0;
        assert!(within && spilled_back, "{counts:?} {all:?}");
        assert!(whole_dropped > 0 && dropped == whole_dropped);
        assert!(whole.len() > 10_000);
        assert_eq!(spilled.vertices, whole.vertices);
        assert_eq!(spilled.colours, whole.colours);
        assert_eq!(spilled.normals, whole.normals);
        // The spill file went with the cloud.
        std::fs::remove_dir(&dir).unwrap();
    }
}
