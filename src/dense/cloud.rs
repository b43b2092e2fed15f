//! A coloured point cloud from masked depth: pixels back-projected with the frame's
//! final pose, \(p_w = T_{wc}\, d\, K^{-1}(u, v, 1)^T\), averaged per voxel (position,
//! colour), then optionally cleaned by statistical outlier removal (a point whose mean
//! distance \(\bar d_i\) to its k nearest neighbours exceeds
//! \(\mu + s\,\sigma\) of all \(\bar d\) goes, as PCL's and Open3D's filters do) and
//! given normals (the least-variance axis of its k neighbours, turned towards the
//! cameras that saw it).

use std::path::Path;

use nalgebra::{Matrix3, Point3, Vector2, Vector3};
use rayon::prelude::*;

use super::cloud_voxels::{CloudSpillCounts, CloudVoxels, Voxel};
use super::neighbours::PointIndex;
use super::tsdf::FrameInput;
use crate::geometry::camera::PinholeCamera;
use crate::geometry::mesh::Mesh;
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
        self.voxels.end_frame()
    }

    /// The voxel means, those `drop` names removed (it answers for a chunk of
    /// neighbouring means at a time), in voxel order so that the output does not
    /// depend on hash order or on the budget; and how many `drop` removed.
    /// [`Carved::finish`] makes the cloud of them (after the volume that `drop` reads
    /// is gone).
    pub fn carve(
        self,
        drop: impl Fn(&[Vector3<f64>]) -> Vec<bool>,
    ) -> Result<(Carved, usize), IoError> {
        let mut kept: Vec<([i32; 3], Point)> = Vec::with_capacity(self.voxels.len());
        let mut dropped = 0;
        self.voxels.drain_sorted(|voxels| {
            let means: Vec<Vector3<f64>> = (voxels.iter())
                .map(|(_, v)| Vector3::from(v.sum) / v.count as f64)
                .collect();
            let gone = drop(&means);
            dropped += gone.iter().filter(|&&d| d).count();
            let points = voxels.iter().zip(gone).filter(|(_, d)| !d);
            kept.extend(points.map(|((k, v), _)| (*k, Point::of(v))));
        })?;
        // Chunk by chunk is not the voxels' order: sorted once more.
        kept.par_sort_unstable_by_key(|(k, _)| *k);
        let settings = self.settings;
        let carved = Carved {
            settings,
            points: kept,
        };
        Ok((carved, dropped))
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

/// The cloud's points before outliers and normals ([`CloudBuilder::carve`]).
pub struct Carved {
    settings: CloudSettings,
    /// The points in voxel order.
    points: Vec<([i32; 3], Point)>,
}

impl Carved {
    /// The cloud: outliers removed, normals estimated.
    pub fn finish(self) -> Mesh {
        let s = self.settings;
        let n = self.points.len();
        let mut cloud = Mesh::default();
        (cloud.vertices, cloud.colours) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let mut views = Vec::with_capacity(n);
        for (_, point) in self.points {
            cloud.vertices.push(point.position);
            cloud.colours.push(point.colour);
            views.push(Vector3::from(point.view));
        }
        if s.outlier_neighbours > 0 && cloud.len() > s.outlier_neighbours {
            let keep = inliers(&cloud.vertices, s.outlier_neighbours, s.outlier_std);
            let kept: Vec<usize> = (0..keep.len()).filter(|&i| keep[i]).collect();
            cloud.vertices = kept.iter().map(|&i| cloud.vertices[i]).collect();
            cloud.colours = kept.iter().map(|&i| cloud.colours[i]).collect();
            views = kept.iter().map(|&i| views[i]).collect();
        }
        if s.normal_neighbours >= 3 && cloud.len() > s.normal_neighbours {
            cloud.normals = normals(&cloud.vertices, &views, s.normal_neighbours);
        }
        cloud
    }
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

/// Unit normals: least-variance axis of the `k` nearest points, towards `views`.
pub fn normals(points: &[[f32; 3]], views: &[Vector3<f64>], k: usize) -> Vec<[f32; 3]> {
    let index = PointIndex::new(points);
    points
        .par_iter()
        .zip(views.par_iter())
        .map(|(p, view)| {
            let near = index.nearest(p, k);
            let pts: Vec<Vector3<f64>> = near
                .iter()
                .map(|&(i, _)| Vector3::from(points[i as usize].map(f64::from)))
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
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::image_files::DepthImage;

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
        let cloud = (builder.carve(|means| vec![false; means.len()]))
            .unwrap()
            .0
            .finish();
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
            (carved.finish(), dropped, counts)
        };
        let (whole, whole_dropped, all) = built(None);
        let (spilled, dropped, counts) = built(Some(1_000_000));
        assert!(
            counts.chunks_written > 0 && counts.chunks_reloaded > 0,
            "{counts:?}"
        );
        assert!(
            counts.peak_resident_mb < 0.7 * all.peak_resident_mb,
            "{counts:?} {all:?}"
        );
        assert!(whole_dropped > 0 && dropped == whole_dropped);
        assert!(whole.len() > 10_000);
        assert_eq!(spilled.vertices, whole.vertices);
        assert_eq!(spilled.colours, whole.colours);
        assert_eq!(spilled.normals, whole.normals);
        // The spill file went with the cloud.
        std::fs::remove_dir(&dir).unwrap();
    }
}
