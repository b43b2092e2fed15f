//! A frame ready for tracking (ORB-SLAM2 §III-A): ORB keypoints (undistorted), their
//! descriptors, a depth per keypoint (RGB-D: read from the depth map; stereo: from row
//! matches in the right image) and the virtual right coordinate
//! \(u_R = u - bf / z\) so that one stereo reprojection model serves RGB-D and stereo,
//! and a grid over the image for fast radius searches.

use image::GrayImage;

use nalgebra::Vector2;

use crate::features::{Descriptor, KeyPoint, OrbExtractor};
use crate::geometry::camera::{ImageSize, PinholeCamera};
use crate::geometry::stereo_camera::StereoCamera;
use crate::io::image_files::DepthImage;

use stereo::{add_disparity_offset, bearings_beyond, extract_and_match, DepthSettings, StereoPair};

pub mod matching;
pub mod stereo;

/// Grid cells over the image, for keypoint lookups by position.
const GRID_COLUMNS: usize = 64;
const GRID_ROWS: usize = 48;

/// One frame's features and depth.
#[derive(Debug, Clone)]
pub struct Frame {
    /// The frame's index in the sequence.
    pub index: usize,
    /// Seconds (the sequence's clock).
    pub timestamp: f64,
    /// Undistorted keypoints (level-0 pixels).
    pub keypoints: Vec<KeyPoint>,
    /// One descriptor per keypoint.
    pub descriptors: Vec<Descriptor>,
    /// Depth in metres per keypoint; 0 when unknown.
    pub depth: Vec<f32>,
    /// Virtual right-image coordinate per keypoint; negative when unknown.
    pub right_u: Vec<f32>,
    /// Moving probability per keypoint (the DOP model; 0.5, unknown, until set).
    pub moving: Vec<f32>,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    grid: Grid,
}

/// The keypoints by grid cell, in one array: cell \(c\)'s keypoint indices are
/// `items[start[c]..start[c + 1]]`, in index order. A vector per cell cost a keyframe
/// 3072 vector headers and an allocation per occupied cell (about 130 kB for 2000
/// keypoints, as much as its features); this costs 12 kB and 4 bytes a keypoint.
#[derive(Debug, Clone, Default)]
struct Grid {
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Grid {
    /// The keypoint indices of cell `c`.
    fn cell(&self, c: usize) -> &[u32] {
        &self.items[self.start[c] as usize..self.start[c + 1] as usize]
    }
}

impl Frame {
    /// The bytes its arrays hold (their capacity), for the memory report.
    pub fn heap_bytes(&self) -> usize {
        use std::mem::size_of;
        self.keypoints.capacity() * size_of::<KeyPoint>()
            + self.descriptors.capacity() * size_of::<Descriptor>()
            + (self.depth.capacity() + self.right_u.capacity() + self.moving.capacity())
                * size_of::<f32>()
            + (self.grid.start.capacity() + self.grid.items.capacity()) * size_of::<u32>()
    }

    /// Its keypoints as the DOP model sees them: undistorted position and depth.
    pub fn dop_keypoints(&self) -> Vec<crate::dop::boxes::Keypoint> {
        self.keypoints
            .iter()
            .zip(&self.depth)
            .map(|(k, z)| crate::dop::boxes::Keypoint {
                x: k.x,
                y: k.y,
                depth: *z,
            })
            .collect()
    }

    /// Extracts features from a grey image, reads each keypoint's depth at its
    /// (rounded, distorted) pixel, then undistorts the keypoints with `lens`.
    pub fn from_rgbd(
        index: usize,
        timestamp: f64,
        grey: &GrayImage,
        depth: &DepthImage,
        extractor: &OrbExtractor,
        camera: &StereoCamera,
        lens: &PinholeCamera,
    ) -> Self {
        let mut features = extractor.extract(grey);
        let depths: Vec<f32> = features
            .keypoints
            .iter()
            .map(|k| {
                let (u, v) = (k.x.round() as u32, k.y.round() as u32);
                let z = if u < depth.width && v < depth.height {
                    depth.at(u, v)
                } else {
                    0.0
                };
                z.max(0.0)
            })
            .collect();
        if !lens.is_undistorted() {
            for k in &mut features.keypoints {
                let ideal = lens.undistort(&Vector2::new(k.x as f64, k.y as f64));
                (k.x, k.y) = (ideal.x as f32, ideal.y as f32);
            }
        }
        let right_u = features
            .keypoints
            .iter()
            .zip(&depths)
            .map(|(k, &z)| {
                if z > 0.0 {
                    k.x - (camera.bf / z as f64) as f32
                } else {
                    -1.0
                }
            })
            .collect();
        Self::from_parts(
            index,
            timestamp,
            features.keypoints,
            features.descriptors,
            depths,
            right_u,
            (grey.width(), grey.height()),
        )
    }

    /// Extracts features from both images of a rectified stereo pair (in parallel) and
    /// gives each left keypoint the depth of its row match in the right image
    /// ([`extract_and_match`]) with the rig's disparity offset added
    /// ([`add_disparity_offset`]); keypoints farther than `bearing_depth` metres keep
    /// their depth but lose their right column ([`bearings_beyond`]; 0: none do).
    pub fn from_stereo(
        index: usize,
        timestamp: f64,
        pair: StereoPair,
        extractor: &OrbExtractor,
        camera: &StereoCamera,
        settings: DepthSettings,
    ) -> Self {
        let (left_features, mut matches) = extract_and_match(pair, extractor, camera.bf, camera.fx);
        add_disparity_offset(
            &mut matches,
            &left_features.keypoints,
            camera.bf,
            settings.disparity_offset,
        );
        bearings_beyond(&mut matches, settings.bearing_depth);
        Self::from_parts(
            index,
            timestamp,
            left_features.keypoints,
            left_features.descriptors,
            matches.depth,
            matches.right_u,
            pair.left.dimensions(),
        )
    }

    /// A frame from already extracted features (keypoints undistorted).
    pub fn from_parts(
        index: usize,
        timestamp: f64,
        keypoints: Vec<KeyPoint>,
        descriptors: Vec<Descriptor>,
        depth: Vec<f32>,
        right_u: Vec<f32>,
        size: impl Into<ImageSize>,
    ) -> Self {
        let ImageSize { width, height } = size.into();
        let n = keypoints.len();
        let mut frame = Self {
            index,
            timestamp,
            keypoints,
            descriptors,
            depth,
            moving: vec![0.5; n],
            right_u,
            width,
            height,
            grid: Grid::default(),
        };
        frame.build_grid();
        frame
    }

    fn cell(&self, x: f32, y: f32) -> Option<(usize, usize)> {
        let cx = (x / self.width as f32 * GRID_COLUMNS as f32).floor();
        let cy = (y / self.height as f32 * GRID_ROWS as f32).floor();
        (cx >= 0.0 && cy >= 0.0 && (cx as usize) < GRID_COLUMNS && (cy as usize) < GRID_ROWS)
            .then_some((cx as usize, cy as usize))
    }

    /// A counting sort of the keypoints by cell (stable: index order within a cell):
    /// counts, their running sums (each cell's end), then the keypoints placed from
    /// the last back, each cell's end moving down to its start.
    fn build_grid(&mut self) {
        let cells = GRID_COLUMNS * GRID_ROWS;
        let cell_of = |k: &KeyPoint| self.cell(k.x, k.y).map(|(cx, cy)| cy * GRID_COLUMNS + cx);
        let mut start = vec![0u32; cells + 1];
        for c in self.keypoints.iter().filter_map(cell_of) {
            start[c] += 1;
        }
        for c in 1..=cells {
            start[c] += start[c - 1];
        }
        let mut items = vec![0u32; start[cells] as usize];
        for (i, k) in self.keypoints.iter().enumerate().rev() {
            if let Some(c) = cell_of(k) {
                start[c] -= 1;
                items[start[c] as usize] = i as u32;
            }
        }
        self.grid = Grid { start, items };
    }

    /// The number of keypoints.
    pub fn len(&self) -> usize {
        self.keypoints.len()
    }

    /// Whether the frame has no keypoint.
    pub fn is_empty(&self) -> bool {
        self.keypoints.is_empty()
    }

    /// Keypoints within `radius` pixels of `(x, y)` on levels `min_level..=max_level`.
    pub fn features_in_area(
        &self,
        x: f32,
        y: f32,
        radius: f32,
        min_level: u8,
        max_level: u8,
    ) -> Vec<usize> {
        let mut found = Vec::new();
        self.for_features_in_area(
            Area {
                x,
                y,
                radius,
                min_level,
                max_level,
            },
            |i| found.push(i),
        );
        found
    }

    /// Calls `visit` with each keypoint in `area`, in the order of
    /// [`Frame::features_in_area`], allocating nothing (the projection searches ask
    /// this of every map point they project).
    pub fn for_features_in_area(&self, area: Area, mut visit: impl FnMut(usize)) {
        let Area {
            x,
            y,
            radius,
            min_level,
            max_level,
        } = area;
        let cell_w = self.width as f32 / GRID_COLUMNS as f32;
        let cell_h = self.height as f32 / GRID_ROWS as f32;
        let x0 = ((x - radius) / cell_w).floor().max(0.0) as usize;
        let x1 = (((x + radius) / cell_w).floor() as isize).min(GRID_COLUMNS as isize - 1);
        let y0 = ((y - radius) / cell_h).floor().max(0.0) as usize;
        let y1 = (((y + radius) / cell_h).floor() as isize).min(GRID_ROWS as isize - 1);
        if x1 < 0 || y1 < 0 {
            return;
        }
        for cy in y0..=y1 as usize {
            for cx in x0..=x1 as usize {
                for &i in self.grid.cell(cy * GRID_COLUMNS + cx) {
                    let k = &self.keypoints[i as usize];
                    if k.level < min_level || k.level > max_level {
                        continue;
                    }
                    let (dx, dy) = (k.x - x, k.y - y);
                    if dx.abs() < radius && dy.abs() < radius {
                        visit(i as usize);
                    }
                }
            }
        }
    }
}

/// A window of the image: keypoints within `radius` pixels of `(x, y)` (along each
/// axis) on levels `min_level..=max_level`.
#[derive(Debug, Clone, Copy)]
pub struct Area {
    /// Centre column, level-0 pixels.
    pub x: f32,
    /// Centre row.
    pub y: f32,
    /// Half the window's side, level-0 pixels.
    pub radius: f32,
    /// The lowest pyramid level.
    pub min_level: u8,
    /// The highest pyramid level.
    pub max_level: u8,
}

#[cfg(test)]
impl Frame {
    /// A frame of `n` keypoints at the origin, without depth or descriptors, for tests
    /// of the map's and the tracker's bookkeeping.
    pub fn blank(n: usize, size: (u32, u32)) -> Self {
        Self::from_parts(
            0,
            0.0,
            vec![KeyPoint::default(); n],
            vec![[0; 4]; n],
            vec![0.0; n],
            vec![-1.0; n],
            size,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_finds_what_a_scan_of_every_keypoint_finds() {
        let mut rng = crate::random::Rng::new(3);
        let keypoints: Vec<KeyPoint> = (0..2000)
            .map(|_| KeyPoint {
                // Some outside the image: no cell holds them.
                x: rng.range(-5.0, 645.0) as f32,
                y: rng.range(-5.0, 485.0) as f32,
                level: (rng.uniform() * 8.0) as u8,
                ..KeyPoint::default()
            })
            .collect();
        let n = keypoints.len();
        let frame = Frame::from_parts(
            0,
            0.0,
            keypoints.clone(),
            vec![[0; 4]; n],
            vec![0.0; n],
            vec![-1.0; n],
            (640, 480),
        );
        for _ in 0..200 {
            let (x, y) = (
                rng.range(-20.0, 660.0) as f32,
                rng.range(-20.0, 500.0) as f32,
            );
            let radius = rng.range(1.0, 60.0) as f32;
            let (min_level, max_level) = (1, 5);
            let mut found = frame.features_in_area(x, y, radius, min_level, max_level);
            let in_image = |k: &KeyPoint| frame.cell(k.x, k.y).is_some();
            let expected: Vec<usize> = (0..n)
                .filter(|&i| {
                    let k = &keypoints[i];
                    in_image(k)
                        && (min_level..=max_level).contains(&k.level)
                        && (k.x - x).abs() < radius
                        && (k.y - y).abs() < radius
                })
                .collect();
            // Within a cell in index order, cells row by row.
            let cell = |i: &usize| {
                let (cx, cy) = frame.cell(keypoints[*i].x, keypoints[*i].y).unwrap();
                cy * GRID_COLUMNS + cx
            };
            assert!(found
                .windows(2)
                .all(|w| (cell(&w[0]), w[0]) < (cell(&w[1]), w[1])));
            found.sort_unstable();
            assert_eq!(found, expected);
        }
        assert_eq!(
            frame.grid.items.len(),
            frame
                .keypoints
                .iter()
                .filter(|k| frame.cell(k.x, k.y).is_some())
                .count()
        );
    }
}
