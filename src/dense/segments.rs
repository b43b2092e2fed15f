//! Depth segments grown from dynamic keypoints: the masks of movers no detector knows.
//!
//! A mover of no COCO class (a box pushed across the floor, a balloon) has no box;
//! only its keypoints that the geometric check found moving mark it, and a disc around
//! each covers a few per cent of it. Here each such keypoint seeds a region grown over
//! its depth segment: 4-neighbours \(q\) of a region pixel \(p\) join while
//! \(|d_q - d_p| \le s\,d_p + 5\,\mathrm{mm}\) (no depth edge between them, step share
//! \(s\)), \(|d_q - z_0| \le b\) (within the band \(b\) around the seed's depth
//! \(z_0\)), and \(q\) lies within \(r = \max(r_{px}, f R / z_0)\) pixels of the seed
//! (each axis): at least `radius` pixels \(r_{px}\), and as far as a mover's half
//! extent `radius_metres` \(R\) reaches at the seed's depth with focal length \(f\). A
//! mover close to the camera fills much of the image (a box carried 1.3 m away is
//! some 400 pixels wide); a fixed pixel radius wide enough for it lets the regions
//! of false alarms on far walls grow over metres of static surface.
//!
//! A keypoint is found where texture is, often on a mover's outline, and its pixel may
//! then be the background's: the seed is the nearest depth within `snap` pixels of it
//! (a keypoint held moving at a depth edge belongs to what is in front).
//!
//! A mover stands in front of what it hides: most of its segment's border is a depth
//! edge to something farther. A wall around a keypoint wrongly held moving is not: its
//! region ends at the band, the radius or something nearer. So a region is kept when
//! the share of its border steps that are such edges is at least `edge_share`, and it
//! holds at least `support` keypoint seeds (or a followed one, see [`Seed`]). Depth
//! sensors lose the pixels along a depth edge: across such a hole the first depth
//! within `hole` pixels decides. Borders at the image edge, and concave creases (where
//! a box stands on the floor: the depth profile bends towards the camera), count
//! neither way and stop the growth.

use crate::io::image_files::DepthImage;

/// How segments are grown and kept.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentSettings {
    /// Half side of the square a region may grow in, pixels: the least, see
    /// `radius_metres`.
    pub radius: u32,
    /// Half side of that square in metres at the seed's depth (0: `radius` only).
    pub radius_metres: f32,
    /// Depth step share \(s\) that still joins two neighbours.
    pub step: f32,
    /// Depth band \(b\) around the seed's depth, metres.
    pub band: f32,
    /// Share of the border that must be a depth edge to something farther.
    pub edge_share: f32,
    /// Seeds a region must hold.
    pub support: usize,
    /// Half side of the square around a keypoint searched for its seed pixel.
    pub snap: u32,
    /// Pixels looked across a hole in the depth for what lies beyond it.
    pub hole: u32,
    /// Bend (share of the depth over 4 pixels each way) that makes a concave crease,
    /// where growth stops.
    pub crease: f32,
    /// Share of a region's pixels seen moving by the free-space evidence that keeps
    /// it whatever its border.
    pub moving_share: f32,
}

impl Default for SegmentSettings {
    fn default() -> Self {
        Self {
            radius: 160,
            radius_metres: 0.6,
            step: 0.02,
            band: 0.4,
            edge_share: 0.9,
            support: 1,
            snap: 3,
            hole: 8,
            crease: 0.008,
            moving_share: 0.1,
        }
    }
}

impl SegmentSettings {
    /// \(r = \max(r_{px}, f R / z_0)\): the half side in pixels of the square a region
    /// grown from a seed at depth `z0` (metres) may fill, with focal length `focal`.
    fn radius_at(&self, z0: f32, focal: f32) -> i64 {
        let metric = if z0 > 0.0 {
            focal * self.radius_metres / z0
        } else {
            0.0
        };
        (self.radius as f32).max(metric) as i64
    }
}

/// One grown region: its pixels and how its border ended.
struct Region {
    pixels: Vec<usize>,
    /// Border steps to something farther or without depth, and those that ended at
    /// the band, the radius, something nearer or another region.
    edges: usize,
    limits: usize,
}

/// Where a region is grown from: a dynamic keypoint of the frame (`since` is the
/// frame's time), or a segment kept earlier, projected into the frame (`since`: when a
/// keypoint last supported it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Seed {
    /// Column, pixels.
    pub x: f32,
    /// Row, pixels.
    pub y: f32,
    /// Whether it is a segment followed from earlier frames.
    pub followed: bool,
    /// When a keypoint last supported it.
    pub since: f64,
}

/// A kept segment: its pixels, and when a dynamic keypoint last supported it.
#[derive(Debug, Clone, PartialEq)]
pub struct Segment {
    /// Pixel indices, row-major.
    pub pixels: Vec<usize>,
    /// When a keypoint last supported it.
    pub since: f64,
}

/// The depth segments grown from `seeds` that hold at least `support` keypoint seeds
/// or a followed one, and pass the border test or, with `moving` (pixels the
/// neighbour frames saw through, [`super::free_space`]), have at least
/// `moving_share` of their pixels seen moving: a mover's segment reaches beyond the
/// depth band (a box's top and sides) and then fails the border test, while a false
/// alarm on a wall holds a few moving pixels in thousands. `focal` (pixels) turns
/// `radius_metres` into pixels at each seed's depth.
pub fn grow_segments(
    depth: &DepthImage,
    seeds: &[Seed],
    moving: Option<&[bool]>,
    settings: &SegmentSettings,
    focal: f32,
) -> Vec<Segment> {
    if seeds.is_empty() {
        // Most frames: no full-frame bookkeeping.
        return Vec::new();
    }
    let (w, h) = (depth.width as usize, depth.height as usize);
    // The region (1, 2, …) each visited pixel belongs to; 0: none yet.
    let mut owner = vec![0u32; w * h];
    let seed_pixels: Vec<(usize, &Seed)> = seeds
        .iter()
        .filter_map(|seed| Some((nearest_depth(depth, seed.x, seed.y, settings.snap)?, seed)))
        .collect();
    let mut kept = Vec::new();
    let mut id = 0u32;
    for &(start, _) in &seed_pixels {
        if owner[start] != 0 {
            continue;
        }
        id += 1;
        let region = grow(&mut owner, depth, start, id, settings, focal);
        let inside: Vec<&Seed> = seed_pixels
            .iter()
            .filter(|(pixel, _)| owner[*pixel] == id)
            .map(|(_, seed)| *seed)
            .collect();
        let keypoints = inside.iter().filter(|s| !s.followed).count();
        let followed = inside.iter().any(|s| s.followed);
        let judged = region.edges + region.limits;
        let edge_share = region.edges as f32 / judged.max(1) as f32;
        // Counted only when the border test fails.
        let seen_moving = || {
            moving.is_some_and(|m| {
                let count = region.pixels.iter().filter(|&&i| m[i]).count();
                count as f32 >= settings.moving_share * region.pixels.len() as f32
            })
        };
        if (keypoints >= settings.support || followed)
            && ((judged > 0 && edge_share >= settings.edge_share) || seen_moving())
        {
            kept.push(Segment {
                pixels: region.pixels,
                since: inside.iter().map(|s| s.since).fold(f64::MIN, f64::max),
            });
        }
    }
    kept
}

/// The pixel with the nearest depth within `snap` pixels of `(x, y)` (each axis), or
/// `None` when none there has a depth.
fn nearest_depth(depth: &DepthImage, x: f32, y: f32, snap: u32) -> Option<usize> {
    let (w, h) = (depth.width as i64, depth.height as i64);
    let (u, v) = (x.round() as i64, y.round() as i64);
    let r = snap as i64;
    let mut best: Option<(f32, usize)> = None;
    for qv in (v - r).max(0)..=(v + r).min(h - 1) {
        for qu in (u - r).max(0)..=(u + r).min(w - 1) {
            let i = (qv * w + qu) as usize;
            let d = depth.metres[i];
            if d > 0.0 && best.is_none_or(|(b, _)| d < b) {
                best = Some((d, i));
            }
        }
    }
    best.map(|(_, i)| i)
}

/// Whether the depth profile through `(u, v)` along `(du, dv)` bends towards the
/// camera there (a concave crease: a box standing on the floor, seen from in front):
/// with \(k\) = 4 pixels, \((d_{+k} - d_0) - (d_0 - d_{-k}) < -c\,d_0\).
fn concave(depth: &DepthImage, (u, v): (i64, i64), (du, dv): (i64, i64), c: f32) -> bool {
    const K: i64 = 4;
    let (w, h) = (depth.width as i64, depth.height as i64);
    let at = |k: i64| {
        let (x, y) = (u + k * du, v + k * dv);
        (x >= 0 && y >= 0 && x < w && y < h)
            .then(|| depth.metres[(y * w + x) as usize])
            .filter(|&d| d > 0.0)
    };
    match (at(-K), at(0), at(K)) {
        (Some(before), Some(here), Some(after)) => (after - here) - (here - before) < -c * here,
        _ => false,
    }
}

/// The first depth from `(u, v)` along `(du, dv)` within `hole` pixels past the
/// neighbour, if any.
fn across_hole(
    depth: &DepthImage,
    (u, v): (i64, i64),
    (du, dv): (i64, i64),
    hole: u32,
) -> Option<f32> {
    let (w, h) = (depth.width as i64, depth.height as i64);
    (2..=hole as i64 + 1)
        .map(|k| (u + k * du, v + k * dv))
        .take_while(|&(x, y)| x >= 0 && y >= 0 && x < w && y < h)
        .map(|(x, y)| depth.metres[(y * w + x) as usize])
        .find(|&d| d > 0.0)
}

/// Grows region `id` from pixel `start` (breadth first), marking `owner`.
fn grow(
    owner: &mut [u32],
    depth: &DepthImage,
    start: usize,
    id: u32,
    settings: &SegmentSettings,
    focal: f32,
) -> Region {
    let (w, h) = (depth.width as usize, depth.height as usize);
    let d = &depth.metres;
    let (su, sv) = ((start % w) as i64, (start / w) as i64);
    let z0 = d[start];
    let r = settings.radius_at(z0, focal);
    let mut region = Region {
        pixels: vec![start],
        edges: 0,
        limits: 0,
    };
    owner[start] = id;
    let mut next = 0;
    while next < region.pixels.len() {
        let p = region.pixels[next];
        next += 1;
        let (pu, pv) = ((p % w) as i64, (p / w) as i64);
        let dp = d[p];
        for (du, dv) in [(1i64, 0i64), (-1, 0), (0, 1), (0, -1)] {
            let (qu, qv) = (pu + du, pv + dv);
            if qu < 0 || qv < 0 || qu >= w as i64 || qv >= h as i64 {
                continue;
            }
            let q = qv as usize * w + qu as usize;
            if owner[q] == id {
                continue;
            }
            let dq = d[q];
            let step = settings.step * dp + 0.005;
            if dq <= 0.0 {
                // A hole: depth sensors lose the pixels along a depth edge. Judge the
                // border by the first depth across it.
                match across_hole(depth, (pu, pv), (du, dv), settings.hole) {
                    Some(beyond) if beyond > dp + step => region.edges += 1,
                    Some(beyond) if beyond < dp - step => region.limits += 1,
                    _ => {}
                }
                continue;
            }
            if dq > dp + step {
                region.edges += 1;
                continue;
            }
            let inside = (qu - su).abs() <= r && (qv - sv).abs() <= r;
            if owner[q] != 0 || !inside || dq < dp - step || (dq - z0).abs() > settings.band {
                region.limits += 1;
                continue;
            }
            if concave(depth, (pu, pv), (du, dv), settings.crease) {
                // Where the mover meets what it stands on: neither edge nor limit.
                continue;
            }
            owner[q] = id;
            region.pixels.push(q);
        }
    }
    region
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 200 x 150 wall at 3 m with a 40 x 30 block at 2 m (x 80..120, y 60..90)
    /// standing on nothing (a balloon).
    fn wall_with_block() -> DepthImage {
        let mut depth = DepthImage::new(200, 150);
        for v in 0..150 {
            for u in 0..200 {
                let block = (80..120).contains(&u) && (60..90).contains(&v);
                depth.metres[v * 200 + u] = if block { 2.0 } else { 3.0 };
            }
        }
        depth
    }

    fn grown(depth: &DepthImage, seeds: &[(f32, f32)]) -> Vec<bool> {
        let seeds: Vec<Seed> = seeds
            .iter()
            .map(|&(x, y)| Seed {
                x,
                y,
                followed: false,
                since: 0.0,
            })
            .collect();
        grown_from(depth, &seeds)
    }

    fn grown_from(depth: &DepthImage, seeds: &[Seed]) -> Vec<bool> {
        let mut mask = vec![false; depth.metres.len()];
        let settings = SegmentSettings {
            radius: 100,
            radius_metres: 0.0,
            support: 2,
            ..SegmentSettings::default()
        };
        for segment in grow_segments(depth, seeds, None, &settings, 500.0) {
            for i in segment.pixels {
                mask[i] = true;
            }
        }
        mask
    }

    #[test]
    fn two_seeds_on_a_block_in_front_of_a_wall_mask_the_whole_block_only() {
        let depth = wall_with_block();
        let mask = grown(&depth, &[(85.0, 65.0), (110.0, 80.0)]);
        let count = mask.iter().filter(|&&m| m).count();
        assert_eq!(count, 40 * 30, "the block, every pixel of it");
        assert!(mask[75 * 200 + 100] && !mask[75 * 200 + 60]);
    }

    #[test]
    fn seeds_on_the_wall_or_a_lone_seed_mask_nothing() {
        let depth = wall_with_block();
        let wall = grown(&depth, &[(20.0, 20.0), (30.0, 25.0), (170.0, 130.0)]);
        assert!(
            !wall.iter().any(|&m| m),
            "the wall ends at the floor's band and at the block, not at depth edges"
        );
        let lone = grown(&depth, &[(100.0, 75.0)]);
        assert!(!lone.iter().any(|&m| m), "one seed is too little support");
        // A segment followed from earlier frames needs no keypoint of its own.
        let followed = Seed {
            x: 100.0,
            y: 75.0,
            followed: true,
            since: 0.0,
        };
        assert_eq!(
            grown_from(&depth, &[followed])
                .iter()
                .filter(|&&m| m)
                .count(),
            1200
        );
    }

    /// A box carried close to the camera (1 m, 260 pixels wide at focal length 500) in
    /// front of a wall at 3 m: a 100-pixel radius stops its region short of its far
    /// side, which then fails the border test; 0.6 m reach 300 pixels at its depth and
    /// mask all of it. Seeds on the wall still grow nothing.
    #[test]
    fn a_close_box_wider_than_the_pixel_radius_is_masked_with_the_metric_radius() {
        let (w, h) = (400usize, 200usize);
        let mut depth = DepthImage::new(w as u32, h as u32);
        for v in 0..h {
            for u in 0..w {
                let close = (20..280).contains(&u) && (40..160).contains(&v);
                depth.metres[v * w + u] = if close { 1.0 } else { 3.0 };
            }
        }
        let seeds = [(30.0, 50.0), (40.0, 60.0), (380.0, 20.0), (390.0, 30.0)].map(|(x, y)| Seed {
            x,
            y,
            followed: false,
            since: 0.0,
        });
        let masked = |radius_metres: f32| {
            let settings = SegmentSettings {
                radius: 100,
                radius_metres,
                support: 2,
                ..SegmentSettings::default()
            };
            grow_segments(&depth, &seeds, None, &settings, 500.0)
                .iter()
                .map(|s| s.pixels.len())
                .sum::<usize>()
        };
        assert_eq!(
            masked(0.0),
            0,
            "cut at 100 pixels, the region fails the border test"
        );
        assert_eq!(masked(0.6), 260 * 120, "the whole box, nothing of the wall");
        assert_eq!(SegmentSettings::default().radius_at(1.3, 535.4), 247);
        assert_eq!(SegmentSettings::default().radius_at(4.0, 535.4), 160);
    }

    /// A block standing on a floor: the concave crease where it meets the floor stops
    /// the growth, so most of its border stays a depth edge and it is masked.
    #[test]
    fn a_block_on_a_sloping_floor_is_masked() {
        let mut depth = wall_with_block();
        // Rows 90.. are a floor coming towards the camera: 3 m at row 90 to 1.5 m.
        for v in 90..150 {
            for u in 0..200 {
                depth.metres[v * 200 + u] = 3.0 - 1.5 * (v - 90) as f32 / 60.0;
            }
        }
        // The block's front stands on the floor where it is 2 m away: row 130.
        for v in 60..130 {
            for u in 80..120 {
                depth.metres[v * 200 + u] = 2.0;
            }
        }
        let mask = grown(&depth, &[(85.0, 65.0), (110.0, 120.0)]);
        assert!(mask[70 * 200 + 100] && mask[125 * 200 + 100], "the block");
        assert!(
            !mask[70 * 200 + 60] && !mask[110 * 200 + 60],
            "the wall, the floor beside it"
        );
        // The floor in front of it joins within the band (0.4 m: 16 rows), no farther.
        assert!(!mask[147 * 200 + 100], "the floor beyond the band");
    }
}
