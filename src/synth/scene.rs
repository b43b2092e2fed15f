//! The static scene: a room (an axis-aligned box seen from inside) and furniture
//! (axis-aligned boxes), each surface with a procedural texture.
//!
//! Ray casting against boxes uses the slab test: for a ray \(o + t d\), each axis gives
//! the interval \([(b_{min} - o)/d, (b_{max} - o)/d]\); the ray is inside the box over the
//! intersection of the three intervals.

use crate::geometry::mesh::Mesh;
use nalgebra::Vector3;

use super::sprite::Billboard;
use crate::random::Rng;

/// A mover's geometry in one frame.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A box.
    Box(Cuboid),
    /// A cut-out.
    Billboard(Billboard),
}

/// An axis-aligned box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cuboid {
    /// The lower corner.
    pub min: Vector3<f64>,
    /// The upper corner.
    pub max: Vector3<f64>,
    /// The texture's id.
    pub texture: u32,
}

/// What a ray hits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// The ray parameter: with a direction whose camera-frame z is 1, this is the depth.
    pub t: f64,
    /// The surface normal, facing the ray.
    pub normal: Vector3<f64>,
    /// The texture's id.
    pub texture: u32,
    /// Surface coordinates in metres (the two world coordinates along the face).
    pub uv: (f64, f64),
    /// A fixed colour (a cut-out's pixel) instead of the procedural texture.
    pub colour: Option<[f64; 3]>,
}

impl Hit {
    /// What a texture needs of the hit.
    pub fn surface(&self) -> super::outdoor::Surface<'_> {
        super::outdoor::Surface {
            texture: self.texture,
            normal: &self.normal,
            uv: self.uv,
        }
    }
}

/// How the scene's surfaces look.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum Look {
    /// Every face its own multi-scale texture (noise and coloured blocks).
    #[default]
    Blocks,
    /// A furnished room: a wooden floor, plaster walls with framed pictures, a tiled
    /// ceiling ([`super::texture::room_texel`]); `up` is the world's up axis and sign.
    Room {
        /// The up axis and its sign.
        up: (usize, f64),
    },
    /// A highway: sky, treelines, trees, asphalt with lane lines
    /// ([`super::outdoor::HighwayLook`]).
    Highway(std::sync::Arc<super::outdoor::HighwayLook>),
}

/// A room with furniture.
#[derive(Debug, Clone, PartialEq)]
pub struct Scene {
    /// The room's walls.
    pub room: Cuboid,
    /// The furniture.
    pub furniture: Vec<Cuboid>,
    /// How the surfaces look.
    pub look: Look,
}

/// The slab interval \([t_{enter}, t_{exit}]\) of a ray through a box, with the entry and
/// exit axes.
fn slab(
    cuboid: &Cuboid,
    origin: &Vector3<f64>,
    direction: &Vector3<f64>,
) -> (f64, usize, f64, usize) {
    let (mut t_enter, mut enter_axis, mut t_exit, mut exit_axis) =
        (f64::NEG_INFINITY, 0, f64::INFINITY, 0);
    let inverse_direction = direction.map(|d| 1.0 / d);
    for axis in 0..3 {
        let inverse = inverse_direction[axis];
        let (mut a, mut b) = (
            (cuboid.min[axis] - origin[axis]) * inverse,
            (cuboid.max[axis] - origin[axis]) * inverse,
        );
        if a > b {
            std::mem::swap(&mut a, &mut b);
        }
        if a > t_enter {
            t_enter = a;
            enter_axis = axis;
        }
        if b < t_exit {
            t_exit = b;
            exit_axis = axis;
        }
    }
    (t_enter, enter_axis, t_exit, exit_axis)
}

fn face_hit(
    cuboid: &Cuboid,
    point: Vector3<f64>,
    axis: usize,
    direction: &Vector3<f64>,
    t: f64,
) -> Hit {
    let mut normal = Vector3::zeros();
    normal[axis] = -direction[axis].signum();
    let (a, b) = ((axis + 1) % 3, (axis + 2) % 3);
    Hit {
        t,
        normal,
        texture: cuboid.texture * 8 + axis as u32 * 2 + (normal[axis] > 0.0) as u32,
        uv: (point[a], point[b]),
        colour: None,
    }
}

/// The nearest entry into any of `boxes` along a ray, with the box's index.
fn nearest_entry<'a>(
    boxes: impl Iterator<Item = &'a Cuboid>,
    origin: &Vector3<f64>,
    direction: &Vector3<f64>,
) -> Option<(Hit, usize)> {
    let mut best: Option<(Hit, usize)> = None;
    for (index, cuboid) in boxes.enumerate() {
        let (t_enter, axis, t_exit, _) = slab(cuboid, origin, direction);
        if t_enter > 1e-6 && t_enter <= t_exit && best.is_none_or(|(h, _)| t_enter < h.t) {
            let hit = face_hit(
                cuboid,
                origin + direction * t_enter,
                axis,
                direction,
                t_enter,
            );
            best = Some((hit, index));
        }
    }
    best
}

impl Cuboid {
    /// The distance from `p` to the box (0 inside): to its nearest point
    /// \(\min(\max(p, b_{min}), b_{max})\).
    pub fn distance_to(&self, p: &Vector3<f64>) -> f64 {
        (p.sup(&self.min).inf(&self.max) - p).norm()
    }

    /// Whether every camera position keeps more than `clearance` metres from the box.
    pub fn clear_of(&self, cameras: &[Vector3<f64>], clearance: f64) -> bool {
        cameras.iter().all(|c| self.distance_to(c) > clearance)
    }

    /// The eight corners.
    pub fn corners(&self) -> [Vector3<f64>; 8] {
        std::array::from_fn(|i| {
            Vector3::new(
                if i & 1 == 1 { self.max.x } else { self.min.x },
                if i & 2 == 2 { self.max.y } else { self.min.y },
                if i & 4 == 4 { self.max.z } else { self.min.z },
            )
        })
    }
}

impl Scene {
    /// The colour of a hit surface (see [`Look`]); `footprint` is the pixel's size on
    /// it in metres.
    pub fn colour(&self, hit: &Hit, footprint: f64) -> [f64; 3] {
        use super::texture::{room_texel, texel, Surface};
        let up = match &self.look {
            Look::Room { up } => *up,
            Look::Highway(look) => {
                return look.colour(self.room.texture, &hit.surface(), footprint)
            }
            Look::Blocks => return texel(hit.texture, hit.uv.0, hit.uv.1, footprint),
        };
        let (cuboid, axis) = (hit.texture / 8, (hit.texture % 8 / 2) as usize);
        let surface = if cuboid != self.room.texture {
            Surface::Furniture(hit.texture)
        } else if axis != up.0 {
            Surface::Wall
        } else if hit.normal[axis] * up.1 > 0.0 {
            Surface::Floor
        } else {
            Surface::Ceiling
        };
        room_texel(surface, hit.uv.0, hit.uv.1, footprint)
    }

    /// Whether `hit` emits its colour (a highway's sky) rather than being lit.
    pub fn is_emissive(&self, hit: &Hit) -> bool {
        matches!(&self.look, Look::Highway(look) if look.is_sky(self.room.texture, &hit.surface()))
    }

    /// The nearest static surface along the ray `origin + t * direction`, `t > 0`.
    pub fn cast(&self, origin: &Vector3<f64>, direction: &Vector3<f64>) -> Option<Hit> {
        self.cast_among(self.furniture.iter(), origin, direction)
    }

    /// [`Scene::cast`] trying only the furniture boxes `furniture` yields (a renderer
    /// that knows which boxes a ray can meet passes only those).
    pub fn cast_among<'a>(
        &self,
        furniture: impl Iterator<Item = &'a Cuboid>,
        origin: &Vector3<f64>,
        direction: &Vector3<f64>,
    ) -> Option<Hit> {
        if let Some((hit, _)) = nearest_entry(furniture, origin, direction) {
            return Some(hit);
        }
        let (_, _, t_exit, axis) = slab(&self.room, origin, direction);
        (t_exit > 1e-6 && t_exit.is_finite()).then(|| {
            face_hit(
                &self.room,
                origin + direction * t_exit,
                axis,
                direction,
                t_exit,
            )
        })
    }

    /// The nearest surface among the static room, the given furniture and the given
    /// movers (with their indices, at their current place): the hit and the index of
    /// the mover hit, `None` for a static surface. A renderer passes only what a ray
    /// can meet.
    pub fn cast_with_movers_among<'a>(
        &self,
        furniture: impl Iterator<Item = &'a Cuboid>,
        movers: impl Iterator<Item = (usize, &'a Shape)>,
        origin: &Vector3<f64>,
        direction: &Vector3<f64>,
    ) -> Option<(Hit, Option<usize>)> {
        let mut best = self
            .cast_among(furniture, origin, direction)
            .map(|hit| (hit, None));
        for (index, shape) in movers {
            let hit = match shape {
                Shape::Box(cuboid) => {
                    nearest_entry(std::iter::once(cuboid), origin, direction).map(|(hit, _)| hit)
                }
                Shape::Billboard(board) => {
                    board.intersect(origin, direction).map(|(t, colour)| Hit {
                        t,
                        normal: board.normal,
                        texture: 0,
                        uv: (0.0, 0.0),
                        colour: Some(colour),
                    })
                }
            };
            if let Some(hit) = hit {
                if best.as_ref().is_none_or(|(b, _)| hit.t < b.t) {
                    best = Some((hit, Some(index)));
                }
            }
        }
        best
    }

    /// Makes way for movers: the walls move out to keep `margin` metres from every box
    /// in `keep_clear` (floor and ceiling, along axis `up`, stay), and furniture that
    /// overlaps one of them goes.
    pub fn make_room_for(&mut self, keep_clear: &[Cuboid], up: usize, margin: f64) {
        let overlaps = |a: &Cuboid, b: &Cuboid| {
            (0..3).all(|axis| a.min[axis] < b.max[axis] && b.min[axis] < a.max[axis])
        };
        self.furniture
            .retain(|f| !keep_clear.iter().any(|c| overlaps(f, c)));
        for c in keep_clear {
            for axis in (0..3).filter(|&a| a != up) {
                self.room.min[axis] = self.room.min[axis].min(c.min[axis] - margin);
                self.room.max[axis] = self.room.max[axis].max(c.max[axis] + margin);
            }
        }
    }

    /// The scene with only the furniture within `range` metres of `centre` (what a
    /// camera there can see in a street of many buildings; the room stays).
    pub fn near(&self, centre: &Vector3<f64>, range: f64) -> Scene {
        Scene {
            room: self.room,
            furniture: self
                .furniture
                .iter()
                .filter(|c| c.distance_to(centre) <= range)
                .copied()
                .collect(),
            look: self.look.clone(),
        }
    }

    /// The distance from a point to the nearest surface of the scene (walls and furniture).
    pub fn distance_to_surface(&self, p: &Vector3<f64>) -> f64 {
        let box_distance = |c: &Cuboid, inside_room: bool| {
            let mut outside = Vector3::zeros();
            let mut inside = f64::INFINITY;
            for axis in 0..3 {
                let below = c.min[axis] - p[axis];
                let above = p[axis] - c.max[axis];
                outside[axis] = below.max(above).max(0.0);
                inside = inside.min((-below).min(-above));
            }
            let outside_norm = outside.norm();
            if inside_room || outside_norm == 0.0 {
                if outside_norm > 0.0 {
                    outside_norm
                } else {
                    inside.abs()
                }
            } else {
                outside_norm
            }
        };
        self.furniture
            .iter()
            .map(|c| box_distance(c, false))
            .fold(box_distance(&self.room, true), f64::min)
    }

    /// The exact static geometry as a triangle mesh (the room's six walls and every
    /// furniture box; 8 vertices and 12 triangles a box), for judging dense maps.
    pub fn to_mesh(&self) -> Mesh {
        let boxes: Vec<&Cuboid> = std::iter::once(&self.room).chain(&self.furniture).collect();
        let mut mesh = Mesh::default();
        for c in &boxes {
            for corner in 0..8 {
                let pick = |axis: usize| {
                    if corner >> axis & 1 == 1 {
                        c.max[axis]
                    } else {
                        c.min[axis]
                    }
                };
                mesh.vertices
                    .push([pick(0) as f32, pick(1) as f32, pick(2) as f32]);
            }
        }
        // Corner index bits: x = 1, y = 2, z = 4. Two triangles per face.
        const FACES: [[u32; 4]; 6] = [
            [0, 2, 6, 4],
            [1, 5, 7, 3],
            [0, 4, 5, 1],
            [2, 3, 7, 6],
            [0, 1, 3, 2],
            [4, 6, 7, 5],
        ];
        for b in 0..boxes.len() as u32 {
            for f in FACES {
                let v = f.map(|i| i + 8 * b);
                mesh.triangles.push([v[0], v[1], v[2]]);
                mesh.triangles.push([v[0], v[2], v[3]]);
            }
        }
        mesh
    }

    /// A room around the camera positions, `margin` metres beyond them on every side,
    /// with `count` furniture boxes that keep `clearance` metres from every camera
    /// position (tables, shelves, boxes of assorted sizes standing on the floor or
    /// hanging on walls).
    pub fn around(
        cameras: &[Vector3<f64>],
        margin: f64,
        count: usize,
        clearance: f64,
        seed: u64,
    ) -> Scene {
        let mut lo = Vector3::repeat(f64::INFINITY);
        let mut hi = Vector3::repeat(f64::NEG_INFINITY);
        for c in cameras {
            lo = lo.inf(c);
            hi = hi.sup(c);
        }
        let room = Cuboid {
            min: lo.add_scalar(-margin),
            max: hi.add_scalar(margin),
            texture: 1,
        };
        let mut rng = Rng::new(seed);
        let mut furniture = Vec::new();
        let mut attempts = 0;
        while furniture.len() < count && attempts < 100 * count.max(1) {
            attempts += 1;
            let size = Vector3::new(
                rng.range(0.2, 1.2),
                rng.range(0.2, 1.2),
                rng.range(0.2, 1.2),
            );
            let mut min = Vector3::zeros();
            for axis in 0..3 {
                min[axis] = rng.range(room.min[axis], room.max[axis] - size[axis]);
            }
            // Push each box against the nearest wall along a random axis, as furniture stands.
            let axis = (rng.next_u64() % 3) as usize;
            if rng.uniform() < 0.5 {
                min[axis] = room.min[axis];
            } else {
                min[axis] = room.max[axis] - size[axis];
            }
            let candidate = Cuboid {
                min,
                max: min + size,
                texture: 2 + furniture.len() as u32,
            };
            if candidate.clear_of(cameras, clearance) {
                furniture.push(candidate);
            }
        }
        Scene {
            room,
            furniture,
            look: Look::Blocks,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rays_hit_the_nearest_surface() {
        let scene = Scene {
            room: Cuboid {
                min: Vector3::repeat(-3.0),
                max: Vector3::repeat(3.0),
                texture: 1,
            },
            furniture: vec![Cuboid {
                min: Vector3::new(-0.5, -0.5, 1.0),
                max: Vector3::new(0.5, 0.5, 2.0),
                texture: 2,
            }],
            look: Look::Blocks,
        };
        let hit = scene
            .cast(&Vector3::zeros(), &Vector3::new(0.0, 0.0, 1.0))
            .unwrap();
        assert!((hit.t - 1.0).abs() < 1e-12 && hit.normal == Vector3::new(0.0, 0.0, -1.0));
        let wall = scene
            .cast(&Vector3::zeros(), &Vector3::new(1.0, 0.0, 0.0))
            .unwrap();
        assert!((wall.t - 3.0).abs() < 1e-12 && wall.normal == Vector3::new(-1.0, 0.0, 0.0));
        let p = Vector3::new(0.0, 0.0, 0.9);
        assert!((scene.distance_to_surface(&p) - 0.1).abs() < 1e-12);
        assert!((scene.distance_to_surface(&Vector3::new(2.5, 0.0, -2.0)) - 0.5).abs() < 1e-12);
    }

    #[test]
    fn the_mesh_holds_every_box() {
        let scene = Scene::around(&[Vector3::zeros()], 2.0, 3, 0.5, 1);
        let mesh = scene.to_mesh();
        assert_eq!((mesh.vertices.len(), mesh.triangles.len()), (32, 48));
        assert!(mesh.validate().is_ok());
    }

    #[test]
    fn furniture_keeps_clear_of_the_cameras() {
        let cameras = vec![Vector3::zeros(), Vector3::new(0.3, 0.0, 0.0)];
        let scene = Scene::around(&cameras, 2.5, 10, 0.8, 4);
        assert_eq!(scene.furniture.len(), 10);
        for c in &cameras {
            for f in &scene.furniture {
                let nearest = c.sup(&f.min).inf(&f.max);
                assert!((nearest - c).norm() > 0.8);
            }
        }
    }

    #[test]
    fn the_room_look_tells_floor_walls_and_ceiling_apart() {
        use crate::synth::texture::{room_texel, Surface};
        let room = Cuboid {
            min: Vector3::repeat(-3.0),
            max: Vector3::repeat(3.0),
            texture: 1,
        };
        // Camera convention: y points down, so up is -y.
        let scene = Scene {
            room,
            furniture: vec![],
            look: Look::Room { up: (1, -1.0) },
        };
        let colour_of = |direction: Vector3<f64>| {
            let hit = scene.cast(&Vector3::zeros(), &direction).unwrap();
            (scene.colour(&hit, 0.001), hit.uv)
        };
        let (floor, uv) = colour_of(Vector3::new(0.1, 1.0, 0.2));
        assert_eq!(floor, room_texel(Surface::Floor, uv.0, uv.1, 0.001));
        let (ceiling, uv) = colour_of(Vector3::new(0.1, -1.0, 0.2));
        assert_eq!(ceiling, room_texel(Surface::Ceiling, uv.0, uv.1, 0.001));
        let (wall, uv) = colour_of(Vector3::new(0.1, 0.2, 1.0));
        assert_eq!(wall, room_texel(Surface::Wall, uv.0, uv.1, 0.001));
    }
}
