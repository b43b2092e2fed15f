//! The highway look (`[street] layout = "highway"`): what a real road scene is made of
//! and our other renders lack. A bright, smooth sky; a treeline on the horizon; belts
//! of trees beside the road; asphalt that is smooth at every scale a pixel covers, with
//! painted lane lines (dashed between lanes, solid at the edges: long, repetitive
//! edges, few corners). Only the cars keep the multi-scale blocks of
//! [`super::texture::texel`].
//!
//! Every texture averages its detail over the pixel's footprint on the surface (a
//! pattern finer than a pixel fades to its mean, as a lens integrates it), so far
//! asphalt and far leaves do not turn into pixel noise full of false corners.

use std::sync::Arc;

use nalgebra::Vector3;

use super::texture::{coverage, value_noise};

/// Texture ids of the road slabs start here (slab `k` is `ROAD + k`).
pub const ROAD: u32 = 1 << 20;
/// Texture ids of the roadside trees start here.
pub const TREES: u32 = 1 << 21;

/// The part of a ray's hit a texture needs: the face's texture id (the box's times
/// 8, plus the face), its outward normal and the two world coordinates along it.
#[derive(Debug, Clone, Copy)]
pub struct Surface<'a> {
    /// The face's texture id.
    pub texture: u32,
    /// Its outward normal.
    pub normal: &'a Vector3<f64>,
    /// The hit's world coordinates along the face's axes `(axis + 1) % 3` and
    /// `(axis + 2) % 3`.
    pub uv: (f64, f64),
}

/// Where the lanes of one road slab run: the path point it was laid under.
#[derive(Debug, Clone, PartialEq)]
pub struct LaneFrame {
    /// The path point (the camera's centre there).
    pub origin: Vector3<f64>,
    /// The horizontal heading of the path there.
    pub heading: Vector3<f64>,
    /// The horizontal left.
    pub left: Vector3<f64>,
    /// Path length from the first path point to this one (m): the dashes' phase.
    pub along: f64,
}

/// The lane lines, as lateral offsets from the path (m, left positive): the camera
/// drives in the right lane of a two-lane carriageway; across a median, the oncoming
/// carriageway's two lanes.
const SOLID_LINES: [f64; 4] = [-1.9, 5.6, 8.6, 16.1];
const DASHED_LINES: [f64; 2] = [1.85, 12.35];
/// The two carriageways' paved extent, shoulders included (m, left positive).
const CARRIAGEWAYS: [(f64, f64); 2] = [(-4.4, 6.1), (8.1, 16.6)];
/// Lateral centres of the lanes beside the camera's (m, left positive).
pub const FOLLOWING_LANE: f64 = 3.75;
/// The two oncoming lanes.
pub const ONCOMING_LANES: [f64; 2] = [10.5, 14.2];
/// Painted lines are this wide (m); dashes 6 m long every 18 m.
const LINE_WIDTH: f64 = 0.15;
const DASH: (f64, f64) = (6.0, 18.0);

/// The highway's look: the up axis and sign, the road's mean level (along up) and the
/// lane frames of the road slabs.
#[derive(Debug, Clone, PartialEq)]
pub struct HighwayLook {
    /// The world's up axis and its sign.
    pub up: (usize, f64),
    /// The road's mean height along `up` (signed: larger is higher).
    pub road_level: f64,
    /// One frame per road slab, in the slabs' order.
    pub lanes: Arc<Vec<LaneFrame>>,
}

/// Detail of amplitude `amplitude` at `cell` metres, faded to nothing as the pixel's
/// `footprint` outgrows the cell.
fn detail(id: u32, u: f64, v: f64, cell: f64, amplitude: f64, footprint: f64) -> f64 {
    let fade = (cell / footprint.max(1e-9)).min(1.0);
    amplitude * fade * (value_noise(id, u / cell, v / cell) - 0.5)
}

/// The height of the horizon's treeline above the road (m) at `across` metres along
/// a far wall: 8-20 m.
fn treeline(across: f64) -> f64 {
    8.0 + 12.0 * value_noise(52, across / 15.0, 0.0)
}

/// The sky: bright and even (a shading that changed across the far walls would draw
/// their seams).
const SKY: [f64; 3] = [0.90, 0.93, 0.97];

/// Grass: mid greens with tufts at 5 cm and patches at 1 m, faded with distance.
fn grass(u: f64, v: f64, footprint: f64) -> [f64; 3] {
    let light =
        0.9 + detail(54, u, v, 1.0, 0.4, footprint) + detail(55, u, v, 0.05, 0.6, footprint);
    [0.46, 0.54, 0.32].map(|c| (c * light).clamp(0.0, 1.0))
}

/// Leaves: greens with clusters at 0.3 m, leaves at 8 cm and 3 cm, faded with
/// distance.
fn foliage(id: u32, u: f64, v: f64, footprint: f64) -> [f64; 3] {
    let light = 0.9
        + detail(id, u, v, 2.0, 0.5, footprint)
        + detail(id ^ 1, u, v, 0.3, 0.8, footprint)
        + detail(id ^ 2, u, v, 0.08, 0.8, footprint)
        + detail(id ^ 3, u, v, 0.03, 0.6, footprint);
    [0.30, 0.36, 0.20].map(|c| (c * light.max(0.05)).clamp(0.0, 1.0))
}

/// The road at (lateral, along) metres of the lane frame, (u, v) in the world:
/// asphalt (grey with faint patches and grain, white lines) from the shoulder to the
/// far edge, grass on the verges and the median.
fn road((lateral, along): (f64, f64), (u, v): (f64, f64), footprint: f64) -> [f64; 3] {
    let on_asphalt = |(from, to): (f64, f64)| coverage(lateral - from, to - from, footprint);
    let paved = on_asphalt(CARRIAGEWAYS[0]).max(on_asphalt(CARRIAGEWAYS[1]));
    if paved <= 0.0 {
        return grass(u, v, footprint);
    }
    let tarmac = asphalt(lateral, along, footprint);
    if paved >= 1.0 {
        return tarmac;
    }
    let green = grass(u, v, footprint);
    std::array::from_fn(|k| tarmac[k] * paved + green[k] * (1.0 - paved))
}

/// Asphalt at (lateral, along) metres of the lane frame: grey with faint patches and
/// grain, white lines.
fn asphalt(lateral: f64, along: f64, footprint: f64) -> [f64; 3] {
    let grey = 0.33
        + detail(41, lateral, along, 3.0, 0.08, footprint)
        + detail(42, lateral, along, 0.05, 0.08, footprint);
    let line = |centre: f64| coverage(lateral - centre + LINE_WIDTH / 2.0, LINE_WIDTH, footprint);
    let solid = SOLID_LINES.iter().map(|&c| line(c)).fold(0.0, f64::max);
    let in_dash = coverage(along.rem_euclid(DASH.1), DASH.0, footprint);
    let dashed = DASHED_LINES
        .iter()
        .map(|&c| line(c) * in_dash)
        .fold(0.0, f64::max);
    let paint = solid.max(dashed);
    let g = grey * (1.0 - paint) + 0.82 * paint;
    [g, g, g * 0.98]
}

impl HighwayLook {
    /// The lane frame nearest to `point` (horizontally), searched from frame `start`
    /// along the path: overlapping slabs hide one another, so the slab hit may have
    /// been laid under a path point some metres away, whose lanes drift from the
    /// nearest one's on a curve.
    fn nearest_frame(&self, start: usize, point: &Vector3<f64>) -> &LaneFrame {
        let distance = |k: usize| {
            let mut offset = point - self.lanes[k].origin;
            offset[self.up.0] = 0.0;
            offset.norm_squared()
        };
        let mut best = start;
        for step in [1isize, -1] {
            let mut k = start as isize + step;
            while k >= 0 && (k as usize) < self.lanes.len() && distance(k as usize) < distance(best)
            {
                best = k as usize;
                k += step;
            }
        }
        &self.lanes[best]
    }

    /// A far wall's point at `uv` on a face across `axis`: its height above the road
    /// and its coordinate along the wall.
    fn on_wall(&self, axis: usize, uv: (f64, f64)) -> (f64, f64) {
        let (up, sign) = self.up;
        let (height, across) = if (axis + 1) % 3 == up {
            uv
        } else {
            (uv.1, uv.0)
        };
        (height * sign - self.road_level, across)
    }

    /// Whether `hit` is the sky, which emits its colour rather than reflecting the
    /// scene's light (the renderer leaves it unshaded); `room` is the room's texture.
    pub fn is_sky(&self, room: u32, hit: &Surface) -> bool {
        let axis = (hit.texture % 8 / 2) as usize;
        if hit.texture / 8 != room {
            return false;
        }
        if axis == self.up.0 {
            return hit.normal[axis] * self.up.1 < 0.0;
        }
        let (height, across) = self.on_wall(axis, hit.uv);
        height >= treeline(across)
    }

    /// The colour of `hit` (`Scene::colour` for this look); `room` is the room's
    /// texture.
    pub fn colour(&self, room: u32, hit: &Surface, footprint: f64) -> [f64; 3] {
        let (cuboid, axis) = (hit.texture / 8, (hit.texture % 8 / 2) as usize);
        let (up, sign) = self.up;
        let facing_up = axis == up && hit.normal[axis] * sign > 0.0;
        if cuboid == room {
            if self.is_sky(room, hit) {
                return SKY;
            }
            if facing_up {
                return grass(hit.uv.0, hit.uv.1, footprint);
            }
            // A far wall below its treeline (8-20 m above the road).
            let (height, across) = self.on_wall(axis, hit.uv);
            return foliage(53, across, height, footprint.max(0.3));
        }
        if (ROAD..TREES).contains(&cuboid) {
            if !facing_up {
                // A slab's side shows only where a climbing road steps up by a few
                // centimetres: asphalt, a quarter brighter for the renderer's
                // shading of a vertical face.
                return [0.41; 3];
            }
            let Some(slab) = self.lanes.get((cuboid - ROAD) as usize) else {
                return [0.3; 3];
            };
            let mut point = slab.origin;
            point[(axis + 1) % 3] = hit.uv.0;
            point[(axis + 2) % 3] = hit.uv.1;
            let frame = self.nearest_frame((cuboid - ROAD) as usize, &point);
            let offset = point - frame.origin;
            let lane = (
                offset.dot(&frame.left),
                frame.along + offset.dot(&frame.heading),
            );
            return road(lane, hit.uv, footprint);
        }
        if cuboid >= TREES {
            return foliage(cuboid, hit.uv.0, hit.uv.1, footprint);
        }
        super::texture::texel(hit.texture, hit.uv.0, hit.uv.1, footprint)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spread(samples: &[f64]) -> f64 {
        let mean = samples.iter().sum::<f64>() / samples.len() as f64;
        (samples.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / samples.len() as f64).sqrt()
    }

    #[test]
    fn detail_finer_than_a_pixel_fades_to_its_mean() {
        let at = |footprint: f64| -> Vec<f64> {
            (0..400)
                .map(|i| {
                    let (u, v) = (i as f64 * 0.137, i as f64 * 0.071);
                    foliage(TREES + 3, u, v, footprint)[1] + grass(u, v + 0.5, footprint)[1]
                })
                .collect()
        };
        let (near, far) = (spread(&at(0.002)), spread(&at(50.0)));
        assert!(far < 0.25 * near, "near {near}, far {far}");
    }

    #[test]
    fn lane_lines_are_dashed_between_lanes_and_solid_at_the_edges() {
        let paint = |lateral: f64, along: f64| road((lateral, along), (0.0, 0.0), 0.002)[0] > 0.7;
        for along in [1.0, 7.0, 13.0] {
            assert!(paint(SOLID_LINES[0], along) && paint(SOLID_LINES[1], along));
            assert!(!paint(0.0, along) && !paint(FOLLOWING_LANE, along));
        }
        assert!(paint(DASHED_LINES[0], 3.0) && !paint(DASHED_LINES[0], 12.0));
    }
}
