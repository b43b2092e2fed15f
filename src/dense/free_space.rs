//! Movers seen by the free space they leave behind, and static pixels seen still: the
//! dense pass runs after tracking, so every frame's depth and final pose are known, and
//! each pixel of a frame can be checked against the frames a moment before and after.
//!
//! A pixel \((u, v)\) of frame \(t\) with depth \(z\) is the point
//! \(X = T_{wc}(t)\, z K^{-1} (u, v, 1)^\top\). Moved into a neighbour frame \(j\),
//! \(p = T_{cw}(j) X\), it projects to \((u_j, v_j)\), where \(j\) measured depth \(d_j\).
//! With the tolerance \(\tau(z) = \tau_0 + \tau_2 z^2\) (depth sensors' error grows with
//! the square of the depth):
//! - *seen through*: every valid depth of \(j\) within `reach` pixels of \((u_j, v_j)\)
//!   lies beyond \(p_z + \tau(p_z)\). Frame \(j\) looked through the place where \(X\)
//!   was: at time \(j\) nothing was there, so \(X\) belongs to something that moves
//!   (a walker, a pushed box, a person no detector found). Looking at the nearest
//!   depth around \((u_j, v_j)\) keeps a static depth edge, which a pose or pixel error
//!   puts on the far side, from counting.
//! - *still*: \(|d_j - p_z| \le \tau(p_z)\) at \((u_j, v_j)\): the same surface, in the
//!   same place.
//! - *no return* (when `no_return` is set): no valid depth at all within `reach`
//!   pixels of \((u_j, v_j)\), with \(p_z\) within `no_return` metres. A surface that
//!   near returns depth, so \(X\) was likely gone (the floor behind a far walker
//!   lies beyond the sensor's range), unless the sensor could not read it (dark,
//!   shiny, at a grazing angle): weaker evidence than seeing through.
//! - otherwise nothing is known: something stood in front of \(X\) at time \(j\), there
//!   is no depth, or \(X\) falls outside \(j\)'s image.
//!
//! A pixel is *moving* when at least one neighbour saw through it and none saw it
//! still, or two neighbours saw through it, or the neighbours that saw through it or
//! returned nothing outnumber those that saw it still by two (a walker's foot stays
//! put while it bears the weight); isolated moving pixels are dropped (at least
//! `density` of the moving test's \((2 \cdot 4 + 1)^2\) window must be moving).
//! A pixel is *still* when at least two neighbours saw it still and none saw through
//! it. A person who stops is still while they stand: the detector's boxes keep them
//! out of the map then, the free space the moment they walk on.

use rayon::prelude::*;

use crate::geometry::camera::PinholeCamera;
use crate::geometry::se3::Se3;
use crate::io::image_files::DepthImage;
use crate::io::IoError;

/// How the neighbours are chosen and judged.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FreeSpaceSettings {
    /// The near neighbours: the frames nearest \(t \pm s\) and \(t \pm s/2\),
    /// seconds.
    pub seconds: f64,
    /// The far neighbours (0: none): the frames nearest \(t \pm f\) and
    /// \(t \pm f/2\), each target rounded to a multiple of \(f/8\) so that the
    /// frames fused one after another share them (a few frames kept loaded, not all
    /// of the last \(f\) seconds). A mover that stands still longer than the near
    /// window (a box set down, a person who waits) was elsewhere seconds before or
    /// after: those frames saw through where it stands.
    pub far_seconds: f64,
    /// \(\tau_0\) of the tolerance, metres.
    pub tolerance_base: f32,
    /// \(\tau_2\) of the tolerance, per metre.
    pub tolerance_growth: f32,
    /// Pixels around the projection whose nearest depth decides "seen through".
    pub reach: usize,
    /// Share of the 9x9 window around a moving pixel that must be moving too.
    pub density: f32,
    /// Every `stride`-th pixel of every `stride`-th row is judged by the neighbours;
    /// the pixels between take the verdict of those around them where they lie at the
    /// same depth and agree, and are judged themselves elsewhere (1: every pixel).
    pub stride: usize,
    /// A neighbour with no depth at all within `reach` pixels of where a point
    /// projects, the point lying within this many metres of it, returned nothing
    /// from it (0: off): a surface that near returns depth, so nothing was there (a
    /// walker's legs before a floor beyond the sensor's range), unless the sensor
    /// could not read it (dark, shiny, at a grazing angle). Weaker than seeing
    /// through: see [`Counts::class`].
    pub no_return: f32,
}

impl Default for FreeSpaceSettings {
    fn default() -> Self {
        Self {
            seconds: 0.5,
            far_seconds: 6.0,
            tolerance_base: 0.03,
            tolerance_growth: 0.005,
            reach: 2,
            density: 0.3,
            stride: 2,
            no_return: 0.0,
        }
    }
}

impl FreeSpaceSettings {
    /// The neighbours' target times around `t`, each with how far from it the chosen
    /// frame may lie and whether it is a far one (see [`Self::far_seconds`]).
    pub fn neighbour_times(&self, t: f64) -> Vec<Target> {
        let mut targets = Vec::with_capacity(8);
        let s = self.seconds;
        if s > 0.0 {
            targets.extend([-s, -s / 2.0, s / 2.0, s].map(|d| Target {
                time: t + d,
                within: s / 4.0,
                far: false,
            }));
        }
        let (f, step) = (self.far_seconds, self.far_seconds / 8.0);
        if f > 0.0 {
            targets.extend([-f, -f / 2.0, f / 2.0, f].map(|d| Target {
                time: ((t + d) / step).round() * step,
                within: step / 2.0,
                far: true,
            }));
        }
        targets
    }

    /// How long before the fused frame's time a loaded near (`far` false) or far
    /// neighbour can still be wanted.
    fn kept_back(&self, far: bool) -> f64 {
        match far {
            false => 1.25 * self.seconds,
            true => 1.125 * self.far_seconds,
        }
    }

    fn tau(&self, z: f32) -> f32 {
        self.tolerance_base + self.tolerance_growth * z * z
    }
}

/// A neighbour's target time: the posed frame nearest `time`, if within `within`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    /// The target time, seconds.
    pub time: f64,
    /// The largest distance from it, seconds.
    pub within: f64,
    /// Whether it is the far neighbour.
    pub far: bool,
}

/// A fused frame as the free-space test and the masks see it: its time, its depth and
/// its final pose.
#[derive(Clone, Copy)]
pub struct PosedDepth<'a> {
    /// Seconds.
    pub timestamp: f64,
    /// The frame's depth.
    pub depth: &'a DepthImage,
    /// Its pose.
    pub camera_from_world: &'a Se3,
}

/// A neighbour frame: its pose, depth, and the nearest valid depth around each pixel.
pub struct Neighbour {
    timestamp: f64,
    /// Wanted as a far neighbour (kept loaded longer).
    far: bool,
    camera_from_world: Se3,
    depth: DepthImage,
    /// The smallest valid depth within `reach` pixels (0: none).
    nearest: Vec<f32>,
}

impl Neighbour {
    /// A neighbour frame at `timestamp` with its pose and depth; `reach` pixels of tolerance.
    pub fn new(timestamp: f64, camera_from_world: Se3, depth: DepthImage, reach: usize) -> Self {
        let nearest = nearest_depth(&depth, reach);
        Self {
            timestamp,
            far: false,
            camera_from_world,
            depth,
            nearest,
        }
    }
}

/// The posed frames a [`NeighbourWindow`] takes its neighbours from.
pub trait PosedFrames: Sync {
    /// The posed frame nearest `time` (the earlier one on a tie), when one lies within
    /// `within` seconds of it: its time, index in the sequence and `camera_from_world`.
    fn nearest(&self, time: f64, within: f64) -> Result<Option<(f64, usize, Se3)>, IoError>;
}

/// Posed frames held in a list (time, index in the sequence, `camera_from_world`).
pub struct PosedList(Vec<(f64, usize, Se3)>);

impl PosedList {
    /// The frames `posed`, sorted by time.
    pub fn new(mut posed: Vec<(f64, usize, Se3)>) -> Self {
        posed.sort_by(|a, b| a.0.total_cmp(&b.0));
        Self(posed)
    }
}

impl PosedFrames for PosedList {
    fn nearest(&self, time: f64, within: f64) -> Result<Option<(f64, usize, Se3)>, IoError> {
        let i = self.0.partition_point(|p| p.0 < time);
        let nearest = [i.checked_sub(1), Some(i)]
            .into_iter()
            .flatten()
            .filter_map(|k| self.0.get(k))
            .min_by(|a, b| (a.0 - time).abs().total_cmp(&(b.0 - time).abs()));
        Ok(nearest.filter(|p| (p.0 - time).abs() <= within).copied())
    }
}

/// The neighbour frames of the frames fused in time order: each posed frame is loaded
/// once, when a fused frame first needs it, and let go once every later fused frame is
/// past it.
pub struct NeighbourWindow<'a> {
    settings: FreeSpaceSettings,
    posed: &'a dyn PosedFrames,
    loaded: std::collections::BTreeMap<usize, Neighbour>,
}

impl<'a> NeighbourWindow<'a> {
    /// The window over the `posed` frames.
    pub fn new(settings: FreeSpaceSettings, posed: &'a dyn PosedFrames) -> Self {
        Self {
            settings,
            posed,
            loaded: Default::default(),
        }
    }

    /// The evidence on `frame`, from
    /// the posed frames nearest its neighbour times (see
    /// [`FreeSpaceSettings::neighbour_times`]), loaded by `load` (a sequence index to
    /// its depth) when first needed, those new to the window in parallel.
    pub fn evidence<E: Send + From<IoError>>(
        &mut self,
        camera: &PinholeCamera,
        frame: PosedDepth,
        load: impl Fn(usize) -> Result<DepthImage, E> + Sync,
    ) -> Result<Evidence, E> {
        let PosedDepth {
            timestamp,
            depth,
            camera_from_world,
        } = frame;
        let settings = self.settings;
        self.loaded
            .retain(|_, n| n.timestamp >= timestamp - settings.kept_back(n.far) - 1e-6);
        let mut wanted: Vec<(f64, usize, Se3, bool)> = Vec::new();
        for target in settings.neighbour_times(timestamp) {
            let nearest = self.posed.nearest(target.time, target.within)?;
            if let Some((t, index, pose)) = nearest.filter(|p| (p.0 - timestamp).abs() > 1e-6) {
                match wanted.iter_mut().find(|w| w.1 == index) {
                    // Wanted near and far: kept loaded as long as a far one.
                    Some(w) => w.3 |= target.far,
                    None => wanted.push((t, index, pose, target.far)),
                }
            }
        }
        let reach = settings.reach;
        let new: Vec<(usize, Neighbour)> = wanted
            .par_iter()
            .filter(|w| !self.loaded.contains_key(&w.1))
            .map(|&(t, index, pose, _)| Ok((index, Neighbour::new(t, pose, load(index)?, reach))))
            .collect::<Result<_, E>>()?;
        self.loaded.extend(new);
        for w in wanted.iter().filter(|w| w.3) {
            if let Some(n) = self.loaded.get_mut(&w.1) {
                n.far = true;
            }
        }
        let neighbours: Vec<&Neighbour> = wanted.iter().map(|w| &self.loaded[&w.1]).collect();
        Ok(evidence(
            camera,
            depth,
            camera_from_world,
            &neighbours,
            &self.settings,
        ))
    }
}

/// The smallest valid (positive) depth in the square of side `2 r + 1` around each
/// pixel, 0 where there is none (separable: rows, then columns; a missing depth
/// counts as infinitely far).
fn nearest_depth(depth: &DepthImage, r: usize) -> Vec<f32> {
    let (w, h) = (depth.width as usize, depth.height as usize);
    if w == 0 || h == 0 {
        return Vec::new();
    }
    let far: Vec<f32> = depth
        .metres
        .iter()
        .map(|&d| if d > 0.0 { d } else { f32::INFINITY })
        .collect();
    // Each row's minimum over the shifted copies of itself, one shift at a time: whole
    // slices, which the compiler vectorises (a fold per pixel over its window was 6 %
    // of a dense pass).
    let mut rows = far.clone();
    for (row, line) in rows.chunks_mut(w).zip(far.chunks(w)) {
        for k in 1..=r.min(w - 1) {
            for (o, &m) in row[k..].iter_mut().zip(&line[..w - k]) {
                *o = o.min(m);
            }
            for (o, &m) in row[..w - k].iter_mut().zip(&line[k..]) {
                *o = o.min(m);
            }
        }
    }
    let mut out = vec![f32::INFINITY; w * h];
    for (v, line) in out.chunks_mut(w).enumerate() {
        for y in v.saturating_sub(r)..=(v + r).min(h - 1) {
            for (o, &m) in line.iter_mut().zip(&rows[y * w..(y + 1) * w]) {
                *o = o.min(m);
            }
        }
        for o in line.iter_mut().filter(|o| !o.is_finite()) {
            *o = 0.0;
        }
    }
    out
}

/// What the neighbours say of each pixel of a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Evidence {
    /// Seen through by the neighbours (a mover), isolated pixels dropped.
    pub moving: Vec<bool>,
    /// Seen in the same place by at least two neighbours, and through by none.
    pub still: Vec<bool>,
}

/// A pixel's ray of the frame seen from a neighbour, in `f32`: the neighbour's
/// camera point of pixel \((u, v)\) at depth \(z\) is
/// \(p = z (a_v + u\,b) + t\) with \(b = R e_x / f_x\) and
/// \(a_v = R ((-c_x / f_x), (v - c_y) / f_y, 1)^\top\), `R`, `t` the neighbour-from-frame
/// transform.
struct Ray {
    b: [f32; 3],
    a0: [f32; 3],
    a_per_row: [f32; 3],
    t: [f32; 3],
}

impl Ray {
    fn new(camera: &PinholeCamera, j_from_t: &Se3) -> Self {
        let r = j_from_t.rotation.matrix();
        let column = |k: usize| [r[(0, k)] as f32, r[(1, k)] as f32, r[(2, k)] as f32];
        let (c0, c1, c2) = (column(0), column(1), column(2));
        let (fx, fy, cx, cy) = (
            camera.fx as f32,
            camera.fy as f32,
            camera.cx as f32,
            camera.cy as f32,
        );
        let tv = j_from_t.translation.vector;
        Self {
            b: c0.map(|x| x / fx),
            a0: [0, 1, 2].map(|i| c0[i] * (-cx / fx) + c1[i] * (-cy / fy) + c2[i]),
            a_per_row: c1.map(|x| x / fy),
            t: [tv.x as f32, tv.y as f32, tv.z as f32],
        }
    }

    /// The neighbour's camera point of pixel `(u, v)` at depth `z`.
    fn point(&self, u: f32, v: f32, z: f32) -> [f32; 3] {
        [0, 1, 2].map(|i| z * (self.a0[i] + v * self.a_per_row[i] + u * self.b[i]) + self.t[i])
    }
}

/// The evidence of `neighbours` on the frame with `depth` at `camera_from_world`.
pub fn evidence(
    camera: &PinholeCamera,
    depth: &DepthImage,
    camera_from_world: &Se3,
    neighbours: &[&Neighbour],
    settings: &FreeSpaceSettings,
) -> Evidence {
    let (w, h) = (depth.width as usize, depth.height as usize);
    if w == 0 || h == 0 {
        return Evidence {
            moving: Vec::new(),
            still: Vec::new(),
        };
    }
    let world_from_camera = camera_from_world.inverse();
    let rays: Vec<Ray> = neighbours
        .iter()
        .map(|n| Ray::new(camera, &(n.camera_from_world * world_from_camera)))
        .collect();
    let verdicts = Judge {
        camera,
        depth,
        neighbours,
        rays: &rays,
        settings,
    }
    .verdicts();
    let (raw, still): (Vec<bool>, Vec<bool>) = verdicts.into_iter().map(Counts::class).unzip();
    Evidence {
        moving: keep_dense(&raw, w, h, 4, settings.density),
        still,
    }
}

/// What the verdicts of one frame's pixels need: the frame, its neighbours and the
/// rays from the frame into each.
struct Judge<'a> {
    camera: &'a PinholeCamera,
    depth: &'a DepthImage,
    neighbours: &'a [&'a Neighbour],
    rays: &'a [Ray],
    settings: &'a FreeSpaceSettings,
}

/// How many neighbours saw a pixel which way.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Counts {
    /// Saw through it.
    through: u8,
    /// Saw it in the same place.
    still: u8,
    /// Returned no depth around it, this near (weaker than seeing through: a surface
    /// a sensor cannot read, dark, shiny or at a grazing angle, returns none either).
    no_return: u8,
}

impl Counts {
    /// Adds one neighbour's verdict.
    fn add(&mut self, seen: Option<Seen>) {
        match seen {
            Some(Seen::Through) => self.through += 1,
            Some(Seen::Still) => self.still += 1,
            Some(Seen::NoReturn) => self.no_return += 1,
            None => {}
        }
    }

    /// The pixel tests' reading: (moving, still). Moving: two neighbours saw through
    /// it; or one did and none saw it still; or those that saw through it or returned
    /// nothing outnumber those that saw it still by two (a walker's foot stays put
    /// for a moment while it bears the weight).
    fn class(self) -> (bool, bool) {
        let Self {
            through,
            still,
            no_return,
        } = self;
        (
            through >= 2 || (still == 0 && through >= 1) || through + no_return >= still + 2,
            through == 0 && still >= 2,
        )
    }
}

/// What one neighbour saw of a pixel's point.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Seen {
    /// Depth beyond it all around: nothing was there.
    Through,
    /// The same surface in the same place.
    Still,
    /// No depth at all around it, though it lies near enough to return some.
    NoReturn,
}

impl Judge<'_> {
    /// Each pixel's counts: the neighbours that saw through it and those that saw it
    /// still. The pixels on the grid of `stride` are judged by every neighbour; each
    /// other pixel takes the counts of the grid pixels around it where they lie at its
    /// depth (within the tolerance) and agree, and is judged itself where they do not
    /// (a depth edge, a mover's outline).
    fn verdicts(&self) -> Vec<Counts> {
        let (w, h) = (self.depth.width as usize, self.depth.height as usize);
        let s = self.settings.stride.max(1);
        let mut grid = vec![Counts::default(); w * h];
        grid.par_chunks_mut(w)
            .enumerate()
            .filter(|(v, _)| v % s == 0)
            .for_each(|(v, row)| self.judge_row(v, row, s));
        if s == 1 {
            return grid;
        }
        let mut out = grid.clone();
        out.par_chunks_mut(w).enumerate().for_each(|(v, row)| {
            let rows = around(v, s, h);
            for u in (0..w).filter(|u| u % s != 0 || v % s != 0) {
                let z = self.depth.metres[v * w + u];
                if z > 0.0 {
                    row[u] = self
                        .copied(&grid, z, rows, around(u, s, w))
                        .unwrap_or_else(|| self.judge_pixel(u, v, z));
                }
            }
        });
        out
    }

    /// The counts of the grid pixels at `rows` x `columns` when each lies within the
    /// tolerance of depth `z` and all agree.
    fn copied(
        &self,
        grid: &[Counts],
        z: f32,
        rows: [usize; 2],
        columns: [usize; 2],
    ) -> Option<Counts> {
        let w = self.depth.width as usize;
        let tau = self.settings.tau(z);
        let first = grid[rows[0] * w + columns[0]];
        let class = first.class();
        let corners = [(0, 0), (0, 1), (1, 0), (1, 1)].map(|(a, b)| rows[a] * w + columns[b]);
        corners
            .iter()
            .all(|&i| {
                let zc = self.depth.metres[i];
                zc > 0.0 && (zc - z).abs() <= tau && grid[i].class() == class
            })
            .then_some(first)
    }

    /// Row `v`'s pixels every `step` columns, one neighbour at a time along the row
    /// (its depth is read row by row).
    fn judge_row(&self, v: usize, row: &mut [Counts], step: usize) {
        let w = row.len();
        let row_depth = &self.depth.metres[v * w..(v + 1) * w];
        for (n, ray) in self.neighbours.iter().zip(self.rays) {
            for u in (0..w).step_by(step) {
                let z = row_depth[u];
                if z > 0.0 {
                    row[u].add(judge(
                        self.camera,
                        n,
                        ray.point(u as f32, v as f32, z),
                        self.settings,
                    ));
                }
            }
        }
    }

    /// Pixel `(u, v)` at depth `z`, judged by every neighbour.
    fn judge_pixel(&self, u: usize, v: usize, z: f32) -> Counts {
        let mut verdict = Counts::default();
        for (n, ray) in self.neighbours.iter().zip(self.rays) {
            verdict.add(judge(
                self.camera,
                n,
                ray.point(u as f32, v as f32, z),
                self.settings,
            ));
        }
        verdict
    }
}

/// The grid lines (multiples of `s` below `n`) around `x`: `x` itself when it lies on
/// one, else the one before and the one after (where it exists); the second repeats the
/// first when there is one line.
fn around(x: usize, s: usize, n: usize) -> [usize; 2] {
    let before = x - x % s;
    match x % s {
        0 => [x, x],
        _ if before + s < n => [before, before + s],
        _ => [before, before],
    }
}

/// What neighbour `n` saw of `p` (in its camera frame); `None`: it cannot tell.
fn judge(
    camera: &PinholeCamera,
    n: &Neighbour,
    [x, y, z]: [f32; 3],
    settings: &FreeSpaceSettings,
) -> Option<Seen> {
    if z < 0.1 {
        return None;
    }
    // Rounded to the nearest pixel (`+ 0.5` then truncated, valid from -0.5 on).
    let u = camera.fx as f32 * x / z + camera.cx as f32 + 0.5;
    let v = camera.fy as f32 * y / z + camera.cy as f32 + 0.5;
    let (w, h) = (n.depth.width as f32, n.depth.height as f32);
    if !(u >= 0.0 && v >= 0.0 && u < w && v < h) {
        return None;
    }
    let i = v as usize * n.depth.width as usize + u as usize;
    let tau = settings.tau(z);
    if n.nearest[i] > z + tau {
        return Some(Seen::Through);
    }
    let d = n.depth.metres[i];
    if d > 0.0 && (d - z).abs() <= tau {
        return Some(Seen::Still);
    }
    (z <= settings.no_return && n.nearest[i] == 0.0).then_some(Seen::NoReturn)
}

/// The set pixels of `mask` with at least `share` of the square of side `2 r + 1`
/// around them set too (summed-area table).
fn keep_dense(mask: &[bool], w: usize, h: usize, r: usize, share: f32) -> Vec<bool> {
    let mut sums = vec![0u32; (w + 1) * (h + 1)];
    for v in 0..h {
        let mut row = 0u32;
        for u in 0..w {
            row += mask[v * w + u] as u32;
            sums[(v + 1) * (w + 1) + u + 1] = sums[v * (w + 1) + u + 1] + row;
        }
    }
    let area = ((2 * r + 1) * (2 * r + 1)) as f32;
    (0..w * h)
        .map(|i| {
            if !mask[i] {
                return false;
            }
            let (u, v) = (i % w, i / w);
            let (x1, y1) = (u.saturating_sub(r), v.saturating_sub(r));
            let (x2, y2) = ((u + r + 1).min(w), (v + r + 1).min(h));
            let count = sums[y2 * (w + 1) + x2] + sums[y1 * (w + 1) + x1]
                - sums[y1 * (w + 1) + x2]
                - sums[y2 * (w + 1) + x1];
            count as f32 >= share * area
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn camera() -> PinholeCamera {
        PinholeCamera {
            fx: 100.0,
            fy: 100.0,
            cx: 32.0,
            cy: 24.0,
            width: 64,
            height: 48,
            distortion: [0.0; 5],
            rational: [0.0; 3],
        }
    }

    /// A wall at 3 m, and a block at 1.5 m over columns `x1..x2`, rows 10..30.
    fn scene(block: Option<(usize, usize)>) -> DepthImage {
        let mut depth = DepthImage::new(64, 48);
        for v in 0..48 {
            for u in 0..64 {
                let on_block =
                    block.is_some_and(|(x1, x2)| (x1..x2).contains(&u) && (10..30).contains(&v));
                depth.metres[v * 64 + u] = if on_block { 1.5 } else { 3.0 };
            }
        }
        depth
    }

    #[test]
    fn a_block_that_moved_is_moving_and_the_wall_is_still() {
        let settings = FreeSpaceSettings::default();
        let pose = Se3::identity();
        // The block stands at columns 20..36 now, at 4..20 before and 36..52 after.
        let now = scene(Some((20, 36)));
        let before = Neighbour::new(0.0, pose, scene(Some((4, 20))), settings.reach);
        let after = Neighbour::new(1.0, pose, scene(Some((36, 52))), settings.reach);
        let e = evidence(&camera(), &now, &pose, &[&before, &after], &settings);
        let at = |u: usize, v: usize| v * 64 + u;
        // Inside the block (away from its outline): seen through before and after.
        assert!(e.moving[at(28, 20)]);
        assert!(!e.still[at(28, 20)]);
        // The wall far from every position of the block: still, not moving.
        assert!(e.still[at(60, 40)] && !e.moving[at(60, 40)]);
        // The wall where the block stood before: hidden then, seen after; not moving.
        assert!(!e.moving[at(10, 20)]);
        // No pixel of the wall is called moving.
        let wall_moving = (0..48 * 64)
            .filter(|&i| now.metres[i] > 2.0 && e.moving[i])
            .count();
        assert_eq!(wall_moving, 0);
    }

    /// The block of `scene` before a background the sensor cannot reach (no depth):
    /// a walker before a floor beyond the range.
    fn before_nothing(block: (usize, usize)) -> DepthImage {
        let mut depth = scene(Some(block));
        depth
            .metres
            .iter_mut()
            .filter(|d| **d > 2.0)
            .for_each(|d| *d = 0.0);
        depth
    }

    #[test]
    fn neighbours_that_return_nothing_where_a_block_stood_see_it_move() {
        let on = FreeSpaceSettings {
            no_return: 4.0,
            ..FreeSpaceSettings::default()
        };
        let pose = Se3::identity();
        let now = before_nothing((20, 36));
        let neighbours = [(4, 20), (36, 52), (40, 56)]
            .map(|block| Neighbour::new(0.0, pose, before_nothing(block), on.reach));
        let judged = |settings: &FreeSpaceSettings, n: &[&Neighbour]| {
            evidence(&camera(), &now, &pose, n, settings).moving[28 + 20 * 64]
        };
        let [a, b, c] = &neighbours;
        // Two neighbours returning nothing there: moving; off, or only one: unknown.
        assert!(judged(&on, &[a, b]));
        assert!(!judged(&FreeSpaceSettings::default(), &[a, b]));
        assert!(!judged(&on, &[a]));
        // Farther than `no_return`: a surface there may return nothing.
        let near = FreeSpaceSettings {
            no_return: 1.4,
            ..on
        };
        assert!(!judged(&near, &[a, b]));
        // A neighbour that saw the block in place outweighs one more that returned
        // nothing, not two more.
        let still = Neighbour::new(0.0, pose, now.clone(), on.reach);
        assert!(!judged(&on, &[a, b, &still]));
        assert!(judged(&on, &[a, b, c, &still]));
    }

    #[test]
    fn a_block_that_stays_is_still_and_a_moved_camera_changes_nothing() {
        let settings = FreeSpaceSettings::default();
        let now_pose = Se3::identity();
        // The camera moves 5 cm to the right; the whole scene is static.
        let moved = crate::geometry::se3::from_parts(
            nalgebra::Vector3::new(-0.05, 0.0, 0.0),
            nalgebra::Matrix3::identity(),
        );
        let now = scene(Some((20, 36)));
        // The static scene seen from the moved camera: the block (1.5 m) shifts by
        // fx * 0.05 / 1.5 = 3.3 pixels to the left; the wall is the same everywhere.
        let render_from = |camera_from_world: &Se3| {
            let shift = (camera_from_world.translation.vector.x * 100.0 / 1.5).round() as i64;
            let mut depth = DepthImage::new(64, 48);
            for v in 0..48i64 {
                for u in 0..64i64 {
                    let on_block = (20 + shift..36 + shift).contains(&u) && (10..30).contains(&v);
                    depth.metres[(v * 64 + u) as usize] = if on_block { 1.5 } else { 3.0 };
                }
            }
            depth
        };
        let before = Neighbour::new(0.0, moved, render_from(&moved), settings.reach);
        let same = Neighbour::new(1.0, now_pose, now.clone(), settings.reach);
        let e = evidence(&camera(), &now, &now_pose, &[&before, &same], &settings);
        assert!(e.moving.iter().all(|m| !m), "nothing moves");
        assert!(e.still[28 + 20 * 64], "the block is still");
        assert!(e.still[60 + 40 * 64], "the wall is still");
    }

    /// A block that stands still through the near window (4.5-5.5 s) but stood
    /// elsewhere before 4 s and after 6 s: only the far neighbours see through it.
    #[test]
    fn far_neighbours_find_a_mover_that_stands_still_through_the_near_window() {
        let fps = 30.0;
        let time = |i: usize| i as f64 / fps;
        let block_at = |t: f64| match (t - 5.0).abs() < 1.0 {
            true => (20, 36),
            false => (44, 60),
        };
        let posed: Vec<(f64, usize, Se3)> =
            (0..300).map(|i| (time(i), i, Se3::identity())).collect();
        let load = |i: usize| Ok::<_, IoError>(scene(Some(block_at(time(i)))));
        let now = scene(Some(block_at(5.0)));
        let at_block = 28 + 20 * 64;
        let judged = |far_seconds: f64| {
            let settings = FreeSpaceSettings {
                far_seconds,
                ..FreeSpaceSettings::default()
            };
            let posed = PosedList::new(posed.clone());
            let mut window = NeighbourWindow::new(settings, &posed);
            window
                .evidence(
                    &camera(),
                    PosedDepth {
                        timestamp: 5.0,
                        depth: &now,
                        camera_from_world: &Se3::identity(),
                    },
                    load,
                )
                .unwrap()
        };
        let near = judged(0.0);
        assert!(!near.moving[at_block] && near.still[at_block]);
        let far = judged(4.0);
        assert!(far.moving[at_block] && !far.still[at_block]);
        // The wall away from both places of the block is still either way.
        assert!(far.still[2 + 40 * 64] && !far.moving[2 + 40 * 64]);
    }

    /// Frames fused one after another share their far neighbours (targets on a grid
    /// of an eighth of `far_seconds`), each near target lies `seconds` or half of it
    /// away.
    #[test]
    fn far_targets_lie_on_a_grid_and_near_ones_follow_the_frame() {
        let settings = FreeSpaceSettings {
            far_seconds: 4.0,
            ..FreeSpaceSettings::default()
        };
        let far = |t: f64| -> Vec<f64> {
            let targets = settings.neighbour_times(t);
            targets.iter().filter(|x| x.far).map(|x| x.time).collect()
        };
        assert_eq!(far(10.0), far(10.0 + 1.0 / 30.0));
        assert_eq!(far(10.0), vec![6.0, 8.0, 12.0, 14.0]);
        let near: Vec<f64> = settings
            .neighbour_times(10.1)
            .iter()
            .filter(|x| !x.far)
            .map(|x| x.time)
            .collect();
        assert_eq!(near.len(), 4);
        for (got, want) in near.iter().zip([9.6, 9.85, 10.35, 10.6]) {
            assert!((got - want).abs() < 1e-9, "{got} != {want}");
        }
        let off = FreeSpaceSettings {
            far_seconds: 0.0,
            ..settings
        };
        assert!(off.neighbour_times(10.0).iter().all(|x| !x.far));
    }

    /// The pixels between the grid take their neighbours' verdict only where those
    /// agree at the same depth: on a block that moved, seen from a camera that moved
    /// too, every pixel's verdict is the one judging every pixel gives.
    #[test]
    fn judging_every_second_pixel_gives_every_pixel_s_verdict() {
        let exact = FreeSpaceSettings {
            stride: 1,
            ..FreeSpaceSettings::default()
        };
        let moved = crate::geometry::se3::from_parts(
            nalgebra::Vector3::new(-0.03, 0.01, 0.0),
            nalgebra::Matrix3::identity(),
        );
        let now = scene(Some((21, 37)));
        let before = Neighbour::new(0.0, moved, scene(Some((5, 19))), exact.reach);
        let after = Neighbour::new(1.0, Se3::identity(), scene(Some((39, 55))), exact.reach);
        let judged = |stride: usize| {
            let settings = FreeSpaceSettings { stride, ..exact };
            evidence(
                &camera(),
                &now,
                &Se3::identity(),
                &[&before, &after],
                &settings,
            )
        };
        let (every, second, third) = (judged(1), judged(2), judged(3));
        assert!(every.moving.iter().any(|&m| m), "the block is seen moving");
        assert!(every.still.iter().any(|&s| s), "the wall is seen still");
        assert_eq!(second, every);
        assert_eq!(third, every);
    }

    /// The nearest valid depth around each pixel equals a scan of its window, at the
    /// borders too, with holes (no depth) left out and windows without depth at 0.
    #[test]
    fn the_nearest_depth_is_the_smallest_valid_one_in_the_window() {
        let (w, h) = (23usize, 7usize);
        let mut depth = DepthImage::new(w as u32, h as u32);
        let mut rng = crate::random::Rng::new(12345);
        for d in depth.metres.iter_mut() {
            let x = rng.uniform() as f32;
            *d = if x < 0.3 { 0.0 } else { 0.5 + 4.0 * x };
        }
        for v in 0..h {
            depth.metres[v * w + 20] = 0.0;
            depth.metres[v * w + 21] = 0.0;
            depth.metres[v * w + 22] = 0.0;
        }
        for r in [0, 1, 2, 5, 30] {
            let fast = nearest_depth(&depth, r);
            for v in 0..h {
                for u in 0..w {
                    let mut scan = f32::INFINITY;
                    for y in v.saturating_sub(r)..=(v + r).min(h - 1) {
                        for x in u.saturating_sub(r)..=(u + r).min(w - 1) {
                            let d = depth.metres[y * w + x];
                            if d > 0.0 {
                                scan = scan.min(d);
                            }
                        }
                    }
                    let scan = if scan.is_finite() { scan } else { 0.0 };
                    assert_eq!(fast[v * w + u], scan, "r {r}, pixel ({u}, {v})");
                }
            }
        }
        assert!(
            nearest_depth(&depth, 0)
                .iter()
                .filter(|&&d| d == 0.0)
                .count()
                >= 3 * h
        );
    }

    #[test]
    fn lone_moving_pixels_are_dropped() {
        let mut mask = vec![false; 20 * 20];
        mask[5 * 20 + 5] = true;
        for v in 10..18 {
            for u in 10..18 {
                mask[v * 20 + u] = true;
            }
        }
        let kept = keep_dense(&mask, 20, 20, 4, 0.3);
        assert!(!kept[5 * 20 + 5]);
        assert!(kept[14 * 20 + 14]);
    }
}
