//! A truncated signed distance field on sparse voxel hashing (Nießner et al. 2013):
//! blocks of \(8^3\) voxels allocated where depth is seen, found by their integer
//! block coordinate in a hash map.
//!
//! A voxel at world point \(p_w\) seen by a camera at `camera_from_world` \(T_{cw}\)
//! projects to pixel \(\pi(T_{cw} p_w)\) with depth \(z\); with measured depth \(d\)
//! there, its projective signed distance is \(\eta = d - z\) (positive in front of
//! the surface). Where \(\eta \ge -\tau\) (\(\tau\): truncation) the voxel takes
//! \(\phi = \min(1, \eta/\tau)\) into its running weighted mean, \(k\) times for a
//! frame that stands for \(k\) frames ([`FrameInput::weight`], 1 unless frames were
//! left out):
//! \[ F \leftarrow \frac{W F + k\phi}{W + k}, \qquad W \leftarrow \min(W + k, W_{max}) \]
//! and the colour likewise (once a frame). Capping \(W\) lets newer observations win: a surface
//! that later proves to be free space (a person who sat and then left) is carved
//! away by the \(\phi = 1\) observations of the rays that now pass through it.
//! A pixel a mask marks dynamic fuses nothing at or behind its depth (\(\eta \le \tau\)),
//! but the free space in front of the mover (\(\eta > \tau\)) still carves.
//!
//! Integration is rayon-parallel over the blocks a frame touches: those within
//! \(\tau\) of its depth (allocated) and, for carving, existing surface blocks that
//! lie in front of the depth they project onto.
//!
//! With a memory budget ([`TsdfVolume::spill_to`]) the voxels of the blocks least
//! recently touched are written to a spill file once the blocks in memory exceed it,
//! and read back when a frame changes them again (the camera returned), when meshing
//! reaches them, or (one voxel at a time) when a query asks for them: the same
//! arithmetic on the same values, so the same volume as without a budget.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Mutex;

use nalgebra::{Point3, Vector3};
use rayon::prelude::*;

use crate::geometry::camera::PinholeCamera;
use crate::geometry::se3::Se3;
use crate::io::image_files::DepthImage;
use crate::io::IoError;

use crate::io::spill::{read_table, write_table, SpillFile};

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
/// Bytes of one block's voxels: field and weight (`f32`), colour (3 `u8`), colour
/// count (`u16`); a record of the spill file in this order, little-endian.
pub const BLOCK_BYTES: usize = BLOCK_VOXELS * (4 + 4 + 3 + 2);

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
    /// A depth beyond `max_depth` fuses no surface but carves its ray up to
    /// `max_depth` (voxblox's `allow_clear`). Without it, a pixel that flickers
    /// between a surface just within `max_depth` and one beyond it keeps only the near
    /// one: the real IST recording kept 2556 mesh vertices at 3-4 m in front of the
    /// background, 383 with it (docs/design.md).
    pub far_carves: bool,
    /// Pixels this close to the image border (pixels) fuse no surface, as masked
    /// pixels do; their free space still carves. A person cut by the border to a sliver
    /// a few pixels wide is found by no detector, and what no later frame sees through
    /// would stay in the map (measured: cutout_xyz's last ghost, a sliver seen at
    /// columns 636-638 of 7 frames).
    pub margin: u32,
}

/// Whether pixel `(u, v)` of a `w` x `h` image lies within `margin` of its border.
fn in_margin(u: usize, v: usize, w: usize, h: usize, margin: usize) -> bool {
    u < margin || v < margin || u + margin >= w || v + margin >= h
}

impl Default for TsdfSettings {
    fn default() -> Self {
        Self {
            voxel: 0.01,
            truncation: 0.04,
            max_depth: 4.0,
            max_weight: 64.0,
            carve: true,
            far_carves: true,
            margin: 8,
        }
    }
}

/// Block coordinates are packed into sortable keys of 21 bits each (offset by
/// \(2^{20}\): \(\pm 84\) km at 1 cm voxels).
const KEY_OFFSET: i32 = 1 << 20;
const KEY_MASK: u64 = (1 << 21) - 1;

/// A block coordinate as one `u64` (ordered as the coordinates are); `None` outside
/// the packed range.
fn block_key(coord: [i32; 3]) -> Option<u64> {
    let field = |c: i32| {
        let shifted = c.checked_add(KEY_OFFSET)?;
        (0..1 << 21).contains(&shifted).then_some(shifted as u64)
    };
    Some((field(coord[0])? << 42) | (field(coord[1])? << 21) | field(coord[2])?)
}

/// The block coordinate of a [`block_key`].
fn key_block(key: u64) -> [i32; 3] {
    let field = |shift: u32| ((key >> shift) & KEY_MASK) as i32 - KEY_OFFSET;
    [field(42), field(21), field(0)]
}

/// One block of voxels, x fastest. Its voxel arrays are empty while it is out of
/// memory: spilled ([`TsdfVolume::spill_to`]), or allocated ahead and not yet changed.
#[derive(Debug, Clone)]
pub struct Block {
    /// Signed distance per voxel, in truncation units.
    pub sdf: Vec<f32>,
    /// Weight per voxel.
    pub weight: Vec<f32>,
    /// Colour per voxel.
    pub colour: Vec<[u8; 3]>,
    /// Observations within the truncation band (those that set the colour).
    pub colour_weight: Vec<u16>,
    /// Whether some observed voxel is behind a surface (\(F < 0\)): only such blocks
    /// hold something that carving could erase.
    surface: bool,
    /// Allocated ahead of integration by [`TsdfVolume::allocate`]: carving reaches it
    /// before it holds a surface, so that free space seen before a mover came counts.
    ahead: bool,
    /// Every voxel is free space at the weight cap (\(F = 1\), \(W = W_{max}\)), as
    /// integration left it: a reading that sees the whole block as free space (or does
    /// not see it) changes nothing, and integration skips it without reading its voxels.
    free: bool,
    /// The last integration (or meshing batch) that touched this block.
    stamp: u32,
    /// Its record in the spill file, once written there.
    slot: Option<u32>,
    /// Changed since it was last written to its slot (or never written).
    dirty: bool,
}

impl Block {
    /// A block out of memory that has never been written: unobserved voxels.
    fn unloaded() -> Self {
        Self {
            sdf: Vec::new(),
            weight: Vec::new(),
            colour: Vec::new(),
            colour_weight: Vec::new(),
            surface: false,
            ahead: false,
            free: false,
            stamp: 0,
            slot: None,
            dirty: false,
        }
    }

    /// Whether its voxels are in memory.
    pub fn resident(&self) -> bool {
        !self.sdf.is_empty()
    }

    /// Unobserved voxels (\(F = 1\), \(W = 0\)) in memory, in `arrays`. Not dirty: a
    /// block without a slot that nothing changed is unobserved again when it comes
    /// back, so it leaves memory without a record (and meshing or queries never write).
    fn fill_unobserved(&mut self, arrays: Voxels) {
        self.put(arrays);
        self.sdf.resize(BLOCK_VOXELS, 1.0);
        self.weight.resize(BLOCK_VOXELS, 0.0);
        self.colour.resize(BLOCK_VOXELS, [0; 3]);
        self.colour_weight.resize(BLOCK_VOXELS, 0);
        self.dirty = false;
    }

    /// Its voxels as a spill record ([`BLOCK_BYTES`]).
    fn write_record(&self, out: &mut Vec<u8>) {
        out.clear();
        out.extend(self.sdf.iter().flat_map(|f| f.to_le_bytes()));
        out.extend(self.weight.iter().flat_map(|w| w.to_le_bytes()));
        out.extend(self.colour.iter().flatten());
        out.extend(self.colour_weight.iter().flat_map(|n| n.to_le_bytes()));
    }

    /// Its voxels from a spill record, in `arrays`.
    fn read_record(&mut self, bytes: &[u8], arrays: Voxels) {
        self.put(arrays);
        let (sdf, rest) = bytes.split_at(4 * BLOCK_VOXELS);
        let (weight, rest) = rest.split_at(4 * BLOCK_VOXELS);
        let (colour, counts) = rest.split_at(3 * BLOCK_VOXELS);
        let f32s = |into: &mut Vec<f32>, b: &[u8]| {
            into.extend(
                b.chunks_exact(4)
                    .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])),
            )
        };
        f32s(&mut self.sdf, sdf);
        f32s(&mut self.weight, weight);
        (self.colour).extend(colour.chunks_exact(3).map(|c| [c[0], c[1], c[2]]));
        (self.colour_weight).extend(
            counts
                .chunks_exact(2)
                .map(|c| u16::from_le_bytes([c[0], c[1]])),
        );
        self.dirty = false;
    }

    /// Takes `arrays` (emptied) as its voxel arrays.
    fn put(&mut self, arrays: Voxels) {
        let Voxels {
            mut sdf,
            mut weight,
            mut colour,
            mut colour_weight,
        } = arrays;
        sdf.clear();
        weight.clear();
        colour.clear();
        colour_weight.clear();
        (self.sdf, self.weight, self.colour, self.colour_weight) =
            (sdf, weight, colour, colour_weight);
    }

    /// Takes its voxel arrays out (it is then out of memory).
    fn unload(&mut self) -> Voxels {
        Voxels {
            sdf: std::mem::take(&mut self.sdf),
            weight: std::mem::take(&mut self.weight),
            colour: std::mem::take(&mut self.colour),
            colour_weight: std::mem::take(&mut self.colour_weight),
        }
    }
}

/// A block's voxel arrays without the block: those of blocks that went out of memory
/// are kept for the next ones that come in, so that the volume's memory stays at its
/// budget instead of leaving freed pieces through the heap.
#[derive(Debug, Default)]
struct Voxels {
    sdf: Vec<f32>,
    weight: Vec<f32>,
    colour: Vec<[u8; 3]>,
    colour_weight: Vec<u16>,
}

/// The index of voxel `(x, y, z)` inside a block.
pub fn voxel_index(x: usize, y: usize, z: usize) -> usize {
    (z * BLOCK + y) * BLOCK + x
}

/// One frame to fuse: depth in metres, colour, and an optional mask (`true`: dynamic,
/// not fused), all of the camera's size.
pub struct FrameInput<'a> {
    /// Depth, metres.
    pub depth: &'a DepthImage,
    /// Colour.
    pub colour: &'a image::RgbImage,
    /// Per pixel: dynamic (not fused).
    pub dynamic: Option<&'a [bool]>,
    /// \(T_{cw}\).
    pub camera_from_world: &'a Se3,
    /// The frames this one stands for (1; more when the frames just before it were
    /// left out, [`super::config::DenseFrames::min_translation`]): its observations
    /// count that many times, so that what those frames would have carved or fused
    /// keeps its share against the frames fused in full.
    pub weight: f32,
}

/// A sparse TSDF volume.
#[derive(Debug)]
pub struct TsdfVolume {
    /// Its settings.
    pub settings: TsdfSettings,
    camera: PinholeCamera,
    /// The blocks.
    pub blocks: Vec<Block>,
    /// Each block's coordinates.
    pub coords: Vec<[i32; 3]>,
    index: FxMap<[i32; 3], u32>,
    frames: u32,
    /// \(2^{16} / (n + 1)\) for colour counts \(n\) up to the weight cap.
    colour_reciprocals: Vec<u32>,
    /// Blocks whose voxels are in memory.
    resident: usize,
    /// The most that ever were.
    peak_resident: usize,
    /// Where blocks go beyond the budget, when there is one.
    spill: Option<Spill>,
}

/// A volume's spill file and budget ([`TsdfVolume::spill_to`]).
#[derive(Debug)]
struct Spill {
    file: SpillFile,
    /// Blocks in memory allowed before the least recently touched are written out.
    budget: usize,
    /// Blocks written to the file, and read back from it.
    written: u64,
    reloaded: u64,
    /// The first error of a query's read (queries answer `false` and keep it).
    failed: Mutex<Option<IoError>>,
    /// The arrays of blocks that went out, for those that come in.
    spare: Vec<Voxels>,
    /// One record's bytes, written or read.
    bytes: Vec<u8>,
}

impl Spill {
    /// `read` as it was, its error also kept (the first one) for
    /// [`TsdfVolume::spill_counts`]: queries answer as if the voxel were unobserved.
    fn keep_error(&self, read: Result<(), IoError>) -> Result<(), ()> {
        read.map_err(|e| {
            self.failed.lock().expect("not poisoned").get_or_insert(e);
        })
    }
}

/// Writes `block` to the spill file when it changed since it was last written there
/// (or since it came in unobserved), and takes its arrays out of memory.
fn spill_block(spill: &mut Spill, block: &mut Block) -> Result<Voxels, IoError> {
    if block.dirty {
        block.write_record(&mut spill.bytes);
        block.slot = Some(spill.file.write(block.slot, &spill.bytes)?);
        block.dirty = false;
        spill.written += 1;
    }
    Ok(block.unload())
}

/// Observed free space: a voxel's `(field, weight)` with weight above zero and
/// \(F > \) `limit` ([`TsdfVolume::seen_through`]).
fn free_space(voxel: Option<(f32, f32)>, limit: f32) -> bool {
    voxel.is_some_and(|(sdf, weight)| weight > 0.0 && sdf > limit)
}

/// A kept volume's voxels ([`TsdfVolume::keep`]): the spill file's records.
pub const KEPT_VOXELS: &str = "tsdf.bin";
/// A kept volume's blocks: per block its coordinates (3 `i32`), its slot in
/// [`KEPT_VOXELS`] (`u32`, `u32::MAX` for none: unobserved) and its flags (`u8`: bit 0
/// surface, 1 allocated ahead, 2 free space), little-endian.
pub const KEPT_BLOCKS: &str = "tsdf_blocks.bin";
const KEPT_ENTRY: usize = 17;

/// What a kept volume's files hold ([`TsdfVolume::keep`]).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KeptVolume {
    /// Blocks in the table.
    pub blocks: usize,
    /// Bytes of the voxels' file that the table refers to.
    pub bytes: u64,
    /// Frames fused (and meshing batches) when it was kept.
    pub frames: u32,
}

/// What a volume's budget made it do ([`TsdfVolume::spill_counts`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SpillCounts {
    /// Block records written to the spill file (a block written again counts again).
    pub blocks_written: u64,
    /// Block records read back into memory.
    pub blocks_reloaded: u64,
    /// The spill file's size at the end, MB.
    pub file_mb: f64,
    /// The most block voxels in memory at once, MB.
    pub peak_resident_mb: f64,
}

impl TsdfVolume {
    /// An empty volume for `camera`'s frames.
    pub fn new(settings: TsdfSettings, camera: PinholeCamera) -> Self {
        Self {
            settings,
            camera,
            blocks: Vec::new(),
            coords: Vec::new(),
            index: FxMap::default(),
            frames: 0,
            colour_reciprocals: (0..=settings.max_weight.clamp(0.0, u16::MAX as f32) as u32)
                .map(|n| (65536.0 / f64::from(n + 1)).round() as u32)
                .collect(),
            resident: 0,
            peak_resident: 0,
            spill: None,
        }
    }

    /// Keeps at most `budget_bytes` of block voxels in memory (at least one frame's
    /// blocks): beyond it, the blocks least recently touched go to a spill file in
    /// `dir`, removed when the volume is dropped.
    pub fn spill_to(&mut self, dir: &Path, budget_bytes: usize) -> Result<(), IoError> {
        let file = SpillFile::create(dir, "tsdf", BLOCK_BYTES)?;
        self.spill_into(file, budget_bytes);
        Ok(())
    }

    fn spill_into(&mut self, file: SpillFile, budget_bytes: usize) {
        self.spill = Some(Spill {
            file,
            budget: (budget_bytes / BLOCK_BYTES).max(1),
            written: 0,
            reloaded: 0,
            failed: Mutex::new(None),
            spare: Vec::new(),
            bytes: Vec::with_capacity(BLOCK_BYTES),
        });
    }

    /// Keeps the volume in `dir` ([`super::kept`]): its spill file linked as
    /// [`KEPT_VOXELS`], its blocks' table written as [`KEPT_BLOCKS`]. Every voxel is
    /// in the file by then ([`TsdfVolume::spill_everything`]); an error without one.
    pub fn keep(&self, dir: &Path) -> Result<KeptVolume, IoError> {
        let Some(spill) = &self.spill else {
            return Err(IoError::invalid(
                dir,
                "a volume without a spill file cannot be kept",
            ));
        };
        if self.resident > 0 {
            return Err(IoError::invalid(
                dir,
                "a volume is kept with every block spilled",
            ));
        }
        spill.file.keep_as(&dir.join(KEPT_VOXELS))?;
        let mut table = Vec::with_capacity(self.blocks.len() * KEPT_ENTRY);
        for (block, coord) in self.blocks.iter().zip(&self.coords) {
            coord.iter().for_each(|c| table.extend(c.to_le_bytes()));
            table.extend(block.slot.unwrap_or(u32::MAX).to_le_bytes());
            let flags = [block.surface, block.ahead, block.free];
            table.push((0..3).fold(0u8, |f, k| f | (u8::from(flags[k]) << k)));
        }
        write_table(&dir.join(KEPT_BLOCKS), &table)?;
        Ok(KeptVolume {
            blocks: self.blocks.len(),
            bytes: spill.file.bytes(),
            frames: self.frames,
        })
    }

    /// The volume [`TsdfVolume::keep`] left in `dir`, as `kept` describes it: its voxels
    /// read from there and never written, blocks beyond `budget_bytes` spilled into a
    /// new spill file in `spill_dir`.
    pub fn from_kept(
        settings: TsdfSettings,
        camera: PinholeCamera,
        dir: &Path,
        kept: &KeptVolume,
        spill_dir: &Path,
        budget_bytes: usize,
    ) -> Result<Self, IoError> {
        let mut volume = Self::new(settings, camera);
        let table = read_table(&dir.join(KEPT_BLOCKS), kept.blocks * KEPT_ENTRY)?;
        for entry in table.chunks_exact(KEPT_ENTRY) {
            let word =
                |k: usize| -> [u8; 4] { entry[4 * k..4 * k + 4].try_into().expect("4 bytes") };
            let coord = [0, 1, 2].map(|k| i32::from_le_bytes(word(k)));
            let i = volume.index_of(coord);
            let block = &mut volume.blocks[i];
            let slot = u32::from_le_bytes(word(3));
            block.slot = (slot != u32::MAX).then_some(slot);
            let flags = entry[16];
            (block.surface, block.ahead, block.free) =
                (flags & 1 != 0, flags & 2 != 0, flags & 4 != 0);
        }
        volume.frames = kept.frames;
        let file = SpillFile::over(
            &dir.join(KEPT_VOXELS),
            kept.bytes,
            spill_dir,
            "tsdf",
            BLOCK_BYTES,
        )?;
        volume.spill_into(file, budget_bytes);
        Ok(volume)
    }

    /// What the budget made the volume do so far (zeros without one), or the first
    /// error reading the spill file met by a query.
    pub fn spill_counts(&self) -> Result<SpillCounts, IoError> {
        let mb = |blocks: usize| (blocks * BLOCK_BYTES) as f64 / 1e6;
        let mut counts = SpillCounts {
            peak_resident_mb: mb(self.peak_resident),
            ..SpillCounts::default()
        };
        if let Some(spill) = &self.spill {
            if let Some(e) = spill.failed.lock().expect("not poisoned").take() {
                return Err(e);
            }
            counts.blocks_written = spill.written;
            counts.blocks_reloaded = spill.reloaded;
            counts.file_mb = spill.file.bytes() as f64 / 1e6;
        }
        Ok(counts)
    }

    /// Edge of a block, metres.
    pub fn block_size(&self) -> f64 {
        self.settings.voxel * BLOCK as f64
    }

    /// The block at `coord`, if allocated and in memory.
    pub fn block(&self, coord: [i32; 3]) -> Option<&Block> {
        let block = &self.blocks[*self.index.get(&coord)? as usize];
        block.resident().then_some(block)
    }

    /// The number of the block at `coord` (its place in `coords` and `blocks`), if
    /// there is one.
    pub fn block_number(&self, coord: [i32; 3]) -> Option<u32> {
        self.index.get(&coord).copied()
    }

    /// The block at `coord` in memory, allocated if it was not.
    pub fn block_mut(&mut self, coord: [i32; 3]) -> Result<&mut Block, IoError> {
        let i = self.index_of(coord);
        self.load(i)?;
        Ok(&mut self.blocks[i])
    }

    /// The index of the block at `coord`, allocated (out of memory) if it was not.
    fn index_of(&mut self, coord: [i32; 3]) -> usize {
        let next = self.blocks.len() as u32;
        let i = *self.index.entry(coord).or_insert(next);
        if i == next {
            self.blocks.push(Block::unloaded());
            self.coords.push(coord);
        }
        i as usize
    }

    /// Brings block `i`'s voxels into memory: from its spill record, or unobserved.
    fn load(&mut self, i: usize) -> Result<(), IoError> {
        let block = &mut self.blocks[i];
        if block.resident() {
            return Ok(());
        }
        let arrays = (self.spill.as_mut())
            .and_then(|s| s.spare.pop())
            .unwrap_or_default();
        match (block.slot, self.spill.as_mut()) {
            (Some(slot), Some(spill)) => {
                spill.bytes.resize(BLOCK_BYTES, 0);
                spill.file.read(slot, &mut spill.bytes)?;
                block.read_record(&spill.bytes, arrays);
                spill.reloaded += 1;
            }
            _ => block.fill_unobserved(arrays),
        }
        self.resident += 1;
        self.peak_resident = self.peak_resident.max(self.resident);
        Ok(())
    }

    /// Within the budget: when the blocks in memory exceed it, the least recently
    /// touched (never those of the current stamp) go to the spill file until a
    /// quarter of the budget is free, so that this runs now and then, not every frame.
    fn keep_within_budget(&mut self) -> Result<(), IoError> {
        let Some(spill) = self.spill.as_mut() else {
            return Ok(());
        };
        if self.resident <= spill.budget {
            return Ok(());
        }
        let now = self.frames;
        let mut old: Vec<(u32, u32)> = (self.blocks.iter().enumerate())
            .filter(|(_, b)| b.resident() && b.stamp != now)
            .map(|(i, b)| (b.stamp, i as u32))
            .collect();
        let surplus = (self.resident - spill.budget * 3 / 4).min(old.len());
        if surplus == 0 {
            return Ok(());
        }
        old.select_nth_unstable(surplus - 1);
        for &(_, i) in &old[..surplus] {
            let arrays = spill_block(spill, &mut self.blocks[i as usize])?;
            spill.spare.push(arrays);
        }
        self.resident -= surplus;
        Ok(())
    }

    /// With a budget: every block in memory goes to the spill file (those not changed
    /// since they were read back are only dropped), and no spare arrays stay, so that
    /// the volume holds no voxels; queries read them from the file. Meshing is done by
    /// then, and the cloud's carving only queries.
    pub fn spill_everything(&mut self) -> Result<(), IoError> {
        self.spill_resident()?;
        if let Some(spill) = self.spill.as_mut() {
            spill.spare = Vec::new();
        }
        Ok(())
    }

    /// With a budget: every block in memory goes to the spill file, its arrays kept
    /// for the blocks that come in next (meshing: before each batch, so that it holds
    /// one batch's blocks, not the budget's).
    pub(crate) fn spill_resident(&mut self) -> Result<(), IoError> {
        let Some(spill) = self.spill.as_mut() else {
            return Ok(());
        };
        for block in self.blocks.iter_mut().filter(|b| b.resident()) {
            let arrays = spill_block(spill, block)?;
            spill.spare.push(arrays);
        }
        self.resident = 0;
        Ok(())
    }

    /// Brings the blocks that meshing the blocks `first..last` reads into memory
    /// (each with its neighbours above it on each axis), touched now, and keeps
    /// within the budget.
    pub(crate) fn load_for_meshing(&mut self, first: usize, last: usize) -> Result<(), IoError> {
        self.frames += 1;
        let now = self.frames;
        for i in first..last {
            let c = self.coords[i];
            for k in 0..8 {
                let n = [c[0] + (k & 1), c[1] + ((k >> 1) & 1), c[2] + ((k >> 2) & 1)];
                if let Some(&j) = self.index.get(&n) {
                    self.blocks[j as usize].stamp = now;
                    self.load(j as usize)?;
                }
            }
        }
        self.keep_within_budget()
    }

    /// Whether the voxel nearest to world point `p` is observed free space: weight above
    /// zero and \(F > \) `limit` (in truncation units: \(F = 1\) lies \(\tau\) or more in
    /// front of every surface seen there). A point the depth once put there belonged to
    /// something that has since been seen through, a mover that left.
    pub fn seen_through(&self, p: &Vector3<f64>, limit: f32) -> bool {
        free_space(self.voxel(p), limit)
    }

    /// Whether world point `p` lies on a surface fused with at least `min_weight`: the
    /// voxel nearest to it has that weight and \(F \le\) `band` (truncation units; a
    /// point more than `band` truncations in front of every surface seen there is in
    /// free space).
    pub fn on_surface(&self, p: &Vector3<f64>, min_weight: f32, band: f32) -> bool {
        self.voxel(p)
            .is_some_and(|(sdf, weight)| weight >= min_weight && sdf <= band)
    }

    /// The field and weight of the voxel nearest to world point `p`, when its block
    /// is allocated and has been observed: from memory, or read from the spill file.
    fn voxel(&self, p: &Vector3<f64>) -> Option<(f32, f32)> {
        let (i, k) = self.voxel_index_at(p)?;
        let block = &self.blocks[i];
        if block.resident() {
            return Some((block.sdf[k], block.weight[k]));
        }
        let (slot, spill) = (block.slot?, self.spill.as_ref()?);
        let mut sdf = [0u8; 4];
        let mut weight = [0u8; 4];
        let read = spill.file.read_part(slot, 4 * k, &mut sdf).and_then(|()| {
            spill
                .file
                .read_part(slot, 4 * (BLOCK_VOXELS + k), &mut weight)
        });
        spill.keep_error(read).ok()?;
        Some((f32::from_le_bytes(sdf), f32::from_le_bytes(weight)))
    }

    /// [`Self::seen_through`] for each of `points`, reading each block out of memory
    /// once (not once a point).
    pub fn seen_through_each(&self, points: &[Vector3<f64>], limit: f32) -> Vec<bool> {
        let values = self.voxels(points);
        values.into_iter().map(|v| free_space(v, limit)).collect()
    }

    /// [`Self::voxel`] for each of `points`: those in blocks out of memory grouped by
    /// block, whose fields and weights are read from the spill file once.
    fn voxels(&self, points: &[Vector3<f64>]) -> Vec<Option<(f32, f32)>> {
        let at: Vec<Option<(usize, usize)>> =
            points.par_iter().map(|p| self.voxel_index_at(p)).collect();
        let mut values: Vec<Option<(f32, f32)>> = (at.par_iter())
            .map(|&a| {
                let (i, k) = a?;
                let block = &self.blocks[i];
                block.resident().then(|| (block.sdf[k], block.weight[k]))
            })
            .collect();
        let Some(spill) = &self.spill else {
            return values;
        };
        // (block, voxel, point) of the points in spilled blocks, by block.
        let mut out: Vec<(u32, u32, u32)> = (at.iter().enumerate())
            .filter_map(|(n, a)| {
                let (i, k) = (*a)?;
                let block = &self.blocks[i];
                (!block.resident() && block.slot.is_some())
                    .then_some((i as u32, k as u32, n as u32))
            })
            .collect();
        out.par_sort_unstable();
        let read: Vec<(u32, Option<(f32, f32)>)> = out
            .par_chunk_by(|a, b| a.0 == b.0)
            .flat_map_iter(|group| {
                let slot = self.blocks[group[0].0 as usize].slot.expect("spilled");
                let mut bytes = vec![0u8; 8 * BLOCK_VOXELS];
                let failed = spill
                    .keep_error(spill.file.read_part(slot, 0, &mut bytes))
                    .is_err();
                let f32_at =
                    |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
                group
                    .iter()
                    .map(|&(_, k, n)| {
                        let k = k as usize;
                        let v = (!failed).then(|| (f32_at(4 * k), f32_at(4 * (BLOCK_VOXELS + k))));
                        (n, v)
                    })
                    .collect::<Vec<_>>()
            })
            .collect();
        for (n, v) in read {
            values[n as usize] = v;
        }
        values
    }

    /// The block holding the voxel nearest to world point `p` (when allocated) and the
    /// voxel's index in it.
    fn voxel_index_at(&self, p: &Vector3<f64>) -> Option<(usize, usize)> {
        // Voxel centres lie at integer multiples of the voxel edge.
        let v = |x: f64| floor(x / self.settings.voxel + 0.5);
        let (x, y, z) = (v(p.x), v(p.y), v(p.z));
        let b = BLOCK as i32;
        let coord = [x.div_euclid(b), y.div_euclid(b), z.div_euclid(b)];
        let k = voxel_index(
            x.rem_euclid(b) as usize,
            y.rem_euclid(b) as usize,
            z.rem_euclid(b) as usize,
        );
        Some((*self.index.get(&coord)? as usize, k))
    }

    /// Bytes the whole volume's voxels take (in memory or not).
    pub fn memory_bytes(&self) -> usize {
        self.blocks.len() * BLOCK_BYTES
    }

    /// Allocates the blocks within \(\tau\) of a frame's depth without fusing it. An
    /// offline pass allocates every frame's blocks first: carving then also reaches
    /// the places a mover will stand (or a surface will be seen) from the frames before,
    /// whose free-space observations otherwise find no block to update. A mover the
    /// masks miss, seen through before it came but never after it left, is then carved
    /// by the earlier frames.
    pub fn allocate(&mut self, depth: &DepthImage, camera_from_world: &Se3) {
        for coord in self.blocks_near_surface(depth, None, camera_from_world) {
            let i = self.index_of(coord);
            self.blocks[i].ahead = true;
        }
    }

    /// Fuses one frame (see the module doc); an error only from the spill file.
    pub fn integrate(&mut self, frame: &FrameInput) -> Result<(), IoError> {
        self.frames += 1;
        let stamp = self.frames;
        let carved = if self.settings.carve {
            self.blocks_in_front(frame)
        } else {
            Vec::new()
        };
        // The frame's blocks out of memory, gathered as they are stamped.
        let mut out = Vec::new();
        for i in carved {
            self.blocks[i as usize].stamp = stamp;
            out.extend((!self.blocks[i as usize].resident()).then_some(i as usize));
        }
        for coord in self.blocks_near_surface(frame.depth, frame.dynamic, frame.camera_from_world) {
            let i = self.index_of(coord);
            self.blocks[i].stamp = stamp;
            out.extend((!self.blocks[i].resident()).then_some(i));
        }
        self.load_changed(frame, out)?;
        let (settings, camera, block_size) = (self.settings, self.camera, self.block_size());
        let reciprocals = &self.colour_reciprocals;
        let mut chosen: Vec<(&mut Block, &[i32; 3])> = self
            .blocks
            .iter_mut()
            .zip(&self.coords)
            .filter(|(b, _)| b.stamp == stamp && b.resident())
            .collect();
        chosen.par_iter_mut().for_each(|(block, coord)| {
            let changed = integrate_block(
                block,
                coord,
                block_size,
                &settings,
                &camera,
                reciprocals,
                frame,
            );
            block.dirty |= changed;
        });
        self.keep_within_budget()
    }

    /// Brings into memory those of this frame's blocks `out` of memory that it changes;
    /// those it leaves as they are stay out.
    fn load_changed(&mut self, frame: &FrameInput, mut out: Vec<usize>) -> Result<(), IoError> {
        // A block both carved and near the surface comes twice.
        out.sort_unstable();
        out.dedup();
        let (settings, camera, block_size) = (self.settings, self.camera, self.block_size());
        let (blocks, coords) = (&self.blocks, &self.coords);
        let out: Vec<usize> = (out.into_par_iter())
            .filter(|&i| {
                changes(
                    blocks[i].free,
                    &coords[i],
                    block_size,
                    &settings,
                    &camera,
                    frame,
                )
            })
            .collect();
        for i in out {
            self.load(i)?;
        }
        Ok(())
    }

    /// Block coordinates within \(\tau\) of the frame's depth (every 4th pixel of every
    /// 4th row; not at masked pixels): a surface point \(p\) needs the blocks that meet
    /// the cube \(p \pm \tau\). With \(R, t\) = `world_from_camera`, pixel \((u, v)\) at
    /// depth \(d\) lies at \(p = t + d\,(a u + b v + c)\), \(a = R e_x / f_x\),
    /// \(b = R e_y / f_y\), \(c = R\,(-c_x/f_x, -c_y/f_y, 1)^\top\).
    fn blocks_near_surface(
        &self,
        depth: &DepthImage,
        dynamic: Option<&[bool]>,
        camera_from_world: &Se3,
    ) -> Vec<[i32; 3]> {
        let (w, h) = (depth.width as usize, depth.height as usize);
        let world_from_camera = camera_from_world.inverse();
        let r = world_from_camera.rotation.matrix();
        let t = world_from_camera.translation.vector;
        let cam = &self.camera;
        let a = r.column(0) / cam.fx;
        let b = r.column(1) / cam.fy;
        let c = r * Vector3::new(-cam.cx / cam.fx, -cam.cy / cam.fy, 1.0);
        let (tau, max_depth) = (self.settings.truncation, self.settings.max_depth);
        let margin = self.settings.margin as usize;
        // The block holding a world point.
        let inv_block = 1.0 / self.block_size();
        let block_of = |p: Vector3<f64>| [p.x, p.y, p.z].map(|x| floor(x * inv_block));
        let step = 4;
        // Each sample's cube as its (lowest, highest) block; neighbouring samples mostly
        // repeat the last cube. Rows expand their cubes into packed block keys.
        let mut keys: Vec<u64> = (0..h)
            .into_par_iter()
            .step_by(step)
            .flat_map_iter(|v| {
                let row = b * v as f64 + c;
                let mut keys = Vec::new();
                let mut last = None;
                for u in (0..w).step_by(step) {
                    let i = v * w + u;
                    let d = depth.metres[i] as f64;
                    if d <= 0.0
                        || d > max_depth
                        || dynamic.is_some_and(|m| m[i])
                        || in_margin(u, v, w, h, margin)
                    {
                        continue;
                    }
                    let p = t + (a * u as f64 + row) * d;
                    let cube = (block_of(p.add_scalar(-tau)), block_of(p.add_scalar(tau)));
                    if last == Some(cube) {
                        continue;
                    }
                    last = Some(cube);
                    let (lo, hi) = cube;
                    for bz in lo[2]..=hi[2] {
                        for by in lo[1]..=hi[1] {
                            keys.extend((lo[0]..=hi[0]).filter_map(|bx| block_key([bx, by, bz])));
                        }
                    }
                }
                keys.sort_unstable();
                keys.dedup();
                keys
            })
            .collect();
        keys.par_sort_unstable();
        keys.dedup();
        keys.into_iter().map(key_block).collect()
    }

    /// Indices of existing blocks holding a surface (or allocated ahead) that this frame's depth sees
    /// through: blocks whose centre \(c\) at depth \(z_c\) has, among the pixels of its
    /// centre and of the corners of its projected extent (clamped to the image), one of
    /// depth \(d\) with \(z_c - r < d - \tau\) (\(r\): half the block's diagonal), so that
    /// some of the block may lie in the free space in front of the measured surface
    /// (see the module doc: such observations carve).
    fn blocks_in_front(&self, frame: &FrameInput) -> Vec<u32> {
        let (w, h) = (frame.depth.width as f64, frame.depth.height as f64);
        let cam = &self.camera;
        // Voxel centres lie at multiples of the voxel: a block's centre is 3.5 voxels in.
        let inset = 0.5 * (BLOCK - 1) as f64 * self.settings.voxel;
        let block_size = self.block_size();
        let radius = 0.5 * block_size * 3f64.sqrt();
        let (tau, max_depth) = (self.settings.truncation, self.settings.max_depth);
        let far_carves = self.settings.far_carves;
        let pose = frame.camera_from_world;
        let depth_at = |u: f64, v: f64| {
            let (u, v) = (u.clamp(0.0, w - 1.0), v.clamp(0.0, h - 1.0));
            let d = frame.depth.metres[v as usize * w as usize + u as usize] as f64;
            if d > 0.0 && (d <= max_depth || far_carves) {
                d
            } else {
                0.0
            }
        };
        self.coords
            .par_iter()
            .zip(self.blocks.par_iter())
            .enumerate()
            .filter(|(_, (_, block))| block.surface || block.ahead)
            .filter_map(|(i, (coord, _))| {
                let centre = Vector3::new(coord[0] as f64, coord[1] as f64, coord[2] as f64)
                    * block_size
                    + Vector3::repeat(inset);
                let p = pose * Point3::from(centre);
                if p.z <= radius {
                    return None;
                }
                let (u, v) = (cam.fx * p.x / p.z + cam.cx, cam.fy * p.y / p.z + cam.cy);
                let (ru, rv) = (cam.fx * radius / p.z, cam.fy * radius / p.z);
                if u + ru < 0.0 || v + rv < 0.0 || u - ru >= w || v - rv >= h {
                    return None;
                }
                let deepest = [(0.0, 0.0), (-ru, -rv), (ru, -rv), (-ru, rv), (ru, rv)]
                    .iter()
                    .map(|(du, dv)| depth_at(u + du, v + dv))
                    .fold(0.0, f64::max);
                (deepest > 0.0 && p.z - radius < deepest - tau).then_some(i as u32)
            })
            .collect()
    }
}

/// \(\lfloor x \rfloor\) without libm's `floor`, which x86-64 without SSE4.1 calls.
fn floor(x: f64) -> i32 {
    let i = x as i32;
    i - i32::from((i as f64) > x)
}

/// The pixel nearest to image coordinate `x` in `[0, size)`, clamped: the float
/// "magic number" rounding (adding \(2^{23}\) leaves the rounded integer in the low
/// mantissa bits), which unlike `as` has no branches and so vectorises.
#[inline(always)]
fn nearest(x: f32, size: f32) -> i32 {
    const MAGIC: f32 = 8_388_608.0;
    ((x.max(0.0).min(size - 1.0) + MAGIC).to_bits() - MAGIC.to_bits()) as i32
}

/// Fuses one frame into one block. First every voxel's pixel and depth, in a loop
/// without branches that the compiler vectorises; then the updates, voxel by voxel.
/// Compiled for AVX2 as well, taken when the CPU has it (the same arithmetic, so the
/// same result: no fused multiply-add).
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn integrate_block(
    block: &mut Block,
    coord: &[i32; 3],
    block_size: f64,
    settings: &TsdfSettings,
    camera: &PinholeCamera,
    reciprocals: &[u32],
    frame: &FrameInput,
) -> bool {
    let Seen {
        pixels,
        mut measured,
        updates:
            Updates {
                etas,
                updates,
                any,
                within,
            },
    } = seen(coord, block_size, settings, camera, frame);
    if !any || (block.free && !within) {
        return false;
    }
    let tau = settings.truncation as f32;
    let inv_tau = 1.0 / tau;
    let max_weight = settings.max_weight;
    let k = frame.weight;
    let sdf = &mut block.sdf[..BLOCK_VOXELS];
    let weight = &mut block.weight[..BLOCK_VOXELS];
    for ((((f, w), d), &eta), &m) in sdf
        .iter_mut()
        .zip(weight.iter_mut())
        .zip(measured.iter_mut())
        .zip(&etas)
        .zip(&updates)
    {
        // Blends with 0/1 factors, not branches, so that this loop vectorises.
        let fused = (*f * *w + k * (eta * inv_tau).min(1.0)) / (*w + k);
        *f += m * (fused - *f);
        *w += m * ((*w + k).min(max_weight) - *w);
        // Colour only within the band; `measured` becomes that flag.
        *d = m * f32::from(u8::from(eta <= tau));
    }
    fuse_colour(block, &pixels, &measured, reciprocals, frame);
    // Counts again, so that the loop vectorises.
    let (mut surface, mut held) = (0u32, 0u32);
    for (&f, &w) in block.sdf.iter().zip(&block.weight) {
        surface += u32::from((f < 0.0) & (w > 0.0));
        held += u32::from(!((f == 1.0) & (w >= max_weight)));
    }
    (block.surface, block.free) = (surface > 0, held == 0);
    true
}

/// Whether `frame` changes a block at `coord` (`free`: [`Block::free`]), as
/// [`integrate_block`] finds before it reads the voxels.
fn changes(
    free: bool,
    coord: &[i32; 3],
    block_size: f64,
    settings: &TsdfSettings,
    camera: &PinholeCamera,
    frame: &FrameInput,
) -> bool {
    let Updates { any, within, .. } = seen(coord, block_size, settings, camera, frame).updates;
    any && (within || !free)
}

/// What a frame says about a block's voxels, before they are read ([`seen`]).
struct Seen {
    /// Each voxel's pixel ([`project_block`]).
    pixels: [i32; BLOCK_VOXELS],
    /// Each voxel's measured depth (0: none).
    measured: [f32; BLOCK_VOXELS],
    updates: Updates,
}

/// The block at `coord` seen by `frame`: its voxels' pixels, depths and updates.
#[inline(always)]
fn seen(
    coord: &[i32; 3],
    block_size: f64,
    settings: &TsdfSettings,
    camera: &PinholeCamera,
    frame: &FrameInput,
) -> Seen {
    let tau = settings.truncation as f32;
    let max_depth = settings.max_depth as f32;
    let far_carves = settings.far_carves;
    let Projected { pixels, zs, rims } = project_block(coord, block_size, settings, camera, frame);
    // The measured depth at each voxel's pixel (0: none), and whether a mask marks
    // that pixel dynamic (or it lies in the border margin, which fuses no surface).
    let depth = &frame.depth.metres;
    let last = depth.len() - 1;
    let mut measured = [0f32; BLOCK_VOXELS];
    let mut moving = [false; BLOCK_VOXELS];
    for (((&pixel, d), moving), &rim) in
        pixels.iter().zip(&mut measured).zip(&mut moving).zip(&rims)
    {
        let i = (pixel as usize).min(last);
        let value = depth[i];
        // Beyond `max_depth` a pixel fuses no surface; with `far_carves` the ray to it
        // still carves (as a masked pixel's does).
        let far = value > max_depth;
        *d = if pixel == NONE || (far && !far_carves) {
            0.0
        } else {
            value
        };
        *moving = rim || far || frame.dynamic.is_some_and(|m| m[i]);
    }
    // \(\eta = d - z\) updates a voxel where \(d > 0\) and \(\eta \ge -\tau\); at a
    // masked pixel only where \(\eta > \tau\) (a mover's depth fuses nothing at or
    // behind it, but the free space in front of it still carves). First on the stack
    // alone: a block no voxel of which changes is not read (see [`Block::free`]).
    let updates = updates(&measured, &zs, &moving, tau);
    Seen {
        pixels,
        measured,
        updates,
    }
}

/// Which voxels of a block a frame updates ([`updates`]).
struct Updates {
    /// \(\eta = d - z\) per voxel.
    etas: [f32; BLOCK_VOXELS],
    /// 1 where the voxel is updated, else 0.
    updates: [f32; BLOCK_VOXELS],
    /// Some voxel is updated.
    any: bool,
    /// Some voxel is updated with a reading that is not free space (\(\eta \le \tau\)
    /// or \(\eta / \tau < 1\)): the only updates that change a free block.
    within: bool,
}

/// The updates of [`integrate_block`] from each voxel's `measured` depth (0: none), its
/// depth `zs` in the camera and whether its pixel is `moving` (masked), with
/// truncation `tau`.
#[inline(always)]
fn updates(
    measured: &[f32; BLOCK_VOXELS],
    zs: &[f32; BLOCK_VOXELS],
    moving: &[bool; BLOCK_VOXELS],
    tau: f32,
) -> Updates {
    let inv_tau = 1.0 / tau;
    let mut etas = [0.0; BLOCK_VOXELS];
    let mut updates = [0.0; BLOCK_VOXELS];
    // Counts, not `|=` on flags: integer sums vectorise, flag reductions did not (a
    // quarter of the integration's time on a static camera).
    let (mut any, mut within) = (0u32, 0u32);
    for (((eta, m), &d), (&z, &moving)) in etas
        .iter_mut()
        .zip(&mut updates)
        .zip(measured)
        .zip(zs.iter().zip(moving))
    {
        let e = d - z;
        *eta = e;
        let update = (d > 0.0) & (e >= -tau) & (!moving | (e > tau));
        any += u32::from(update);
        within += u32::from(update & ((e <= tau) | (e * inv_tau < 1.0)));
        *m = f32::from(u8::from(update));
    }
    Updates {
        etas,
        updates,
        any: any > 0,
        within: within > 0,
    }
}

/// Where a block's voxels fall in a frame ([`project_block`]).
struct Projected {
    pixels: [i32; BLOCK_VOXELS],
    zs: [f32; BLOCK_VOXELS],
    rims: [bool; BLOCK_VOXELS],
}

/// A voxel no pixel sees.
const NONE: i32 = -1;

/// Each voxel of the block at `coord`: the index of its pixel in `frame` (`NONE`
/// where the camera does not see it), its depth in the camera, and whether its pixel
/// lies in the border margin. In a loop without branches that the compiler vectorises.
#[inline(always)]
fn project_block(
    coord: &[i32; 3],
    block_size: f64,
    settings: &TsdfSettings,
    camera: &PinholeCamera,
    frame: &FrameInput,
) -> Projected {
    let (w, h) = (frame.depth.width, frame.depth.height);
    let far = (settings.max_depth + settings.truncation) as f32;
    let (fx, fy, cx, cy) = (
        camera.fx as f32,
        camera.fy as f32,
        camera.cx as f32,
        camera.cy as f32,
    );
    // Voxel centres sit at integer multiples of the voxel size (a corner-aligned
    // lattice shared by neighbouring blocks); in the camera voxel (x, y, z) is
    // p = R c + t + x R e_x v + y R e_y v + z R e_z v.
    let r = frame.camera_from_world.rotation.matrix();
    let corner = Vector3::new(coord[0] as f64, coord[1] as f64, coord[2] as f64) * block_size;
    let o = (r * corner + frame.camera_from_world.translation.vector).cast::<f32>();
    let step = |k: usize| (r.column(k) * settings.voxel).into_owned().cast::<f32>();
    let (dx, dy, dz) = (step(0), step(1), step(2));
    let (wf, hf) = (w as f32, h as f32);
    let w = w as i32;
    // Voxel (x, y, z) sits at index k = (z B + y) B + x: rows of B voxels along x, in
    // lanes the compiler vectorises (no branches, signed conversions).
    let xs: [f32; BLOCK] = std::array::from_fn(|x| x as f32);
    let mut pixels = [NONE; BLOCK_VOXELS];
    let mut zs = [0f32; BLOCK_VOXELS];
    // Whether the pixel lies within the border margin (its index rounds below
    // `margin` or to `size - margin` or beyond).
    let mut rims = [false; BLOCK_VOXELS];
    let m = settings.margin as f32 - 0.5;
    for (row, ((pixels, zs), rims)) in pixels
        .chunks_exact_mut(BLOCK)
        .zip(zs.chunks_exact_mut(BLOCK))
        .zip(rims.chunks_exact_mut(BLOCK))
        .enumerate()
    {
        let (y, z) = ((row % BLOCK) as f32, (row / BLOCK) as f32);
        let base = o + dy * y + dz * z;
        for (((pixel, z_out), rim), &x) in pixels
            .iter_mut()
            .zip(zs.iter_mut())
            .zip(rims.iter_mut())
            .zip(&xs)
        {
            let (px, py, pz) = (base.x + dx.x * x, base.y + dx.y * x, base.z + dx.z * x);
            let inv = 1.0 / pz;
            let uf = fx * px * inv + cx;
            let vf = fy * py * inv + cy;
            let seen = (pz > 0.0)
                & (pz <= far)
                & (uf >= -0.5)
                & (vf >= -0.5)
                & (uf < wf - 0.5)
                & (vf < hf - 0.5);
            let (u, v) = (nearest(uf, wf), nearest(vf, hf));
            *pixel = if seen { v * w + u } else { NONE };
            *z_out = pz;
            *rim = (uf < m) | (vf < m) | (uf >= wf - 1.0 - m) | (vf >= hf - 1.0 - m);
        }
    }
    Projected { pixels, zs, rims }
}

/// Colour of the voxels whose `flags` are set: the running mean, from their pixels.
#[inline(always)]
fn fuse_colour(
    block: &mut Block,
    pixels: &[i32; BLOCK_VOXELS],
    flags: &[f32; BLOCK_VOXELS],
    reciprocals: &[u32],
    frame: &FrameInput,
) {
    // Colour: the running mean c <- c + (c_pixel - c) / (n + 1), with n the capped
    // count, in 16-bit fixed point (`reciprocals[n]` = 2^16 / (n + 1), rounded).
    let colour = frame.colour.as_raw();
    let cap = reciprocals.len() - 1;
    for ((&pixel, &flag), (old, seen)) in pixels
        .iter()
        .zip(flags)
        .zip(block.colour.iter_mut().zip(block.colour_weight.iter_mut()))
    {
        if flag == 0.0 {
            continue;
        }
        let pixel = pixel as usize;
        let c = &colour[3 * pixel..3 * pixel + 3];
        let step = reciprocals[(*seen as usize).min(cap)] as i32;
        for (old, &new) in old.iter_mut().zip(c) {
            let change = (new as i32 - *old as i32) * step;
            *old = (*old as i32 + ((change + (1 << 15)) >> 16)) as u8;
        }
        *seen = seen.saturating_add(1);
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::dense::marching_cubes::extract;
    use crate::geometry::se3;
    use nalgebra::Matrix3;
    use proptest::prelude::*;
    use std::collections::HashMap;

    proptest! {
        #[test]
        fn block_keys_round_trip_and_keep_the_order(
            a in prop::array::uniform3(-(1i32 << 20)..(1 << 20)),
            b in prop::array::uniform3(-(1i32 << 20)..(1 << 20)),
        ) {
            let (ka, kb) = (block_key(a).unwrap(), block_key(b).unwrap());
            prop_assert_eq!(key_block(ka), a);
            prop_assert_eq!(ka.cmp(&kb), a.cmp(&b));
        }

        #[test]
        fn floor_and_nearest_agree_with_libm(x in -1e6f64..1e6, p in -50f32..700.0) {
            prop_assert_eq!(floor(x), x.floor() as i32);
            let expected = p.round_ties_even().clamp(0.0, 639.0) as i32;
            prop_assert_eq!(nearest(p, 640.0), expected);
        }
    }

    /// Settings, a ball 1.2 m ahead of a wall at 2 m, and ten views of it side by side.
    fn ball_before_a_wall() -> (TsdfSettings, (Vector3<f64>, f64), Vec<Se3>) {
        let settings = TsdfSettings {
            voxel: 0.02,
            truncation: 0.06,
            max_weight: 20.0,
            ..TsdfSettings::default()
        };
        let views = (0..10)
            .map(|k| {
                looking_at(
                    Vector3::new(-0.1 + 0.02 * k as f64, 0.0, 0.0),
                    Vector3::new(0.0, 0.0, 2.0),
                )
            })
            .collect();
        (settings, (Vector3::new(0.0, 0.0, 1.2), 0.2), views)
    }

    /// A camera that pans 3 m along a wall past a ball and back after the ball left:
    /// the blocks it left go to the spill file and come back, carved, on the return.
    #[test]
    fn a_volume_over_its_budget_spills_and_gives_the_same_map() {
        let (settings, ball, _) = ball_before_a_wall();
        let camera = small_camera();
        let out: Vec<Se3> = (0..30)
            .map(|k| {
                let x = -1.5 + 0.1 * k as f64;
                looking_at(Vector3::new(x, 0.0, 0.0), Vector3::new(x, 0.0, 2.0))
            })
            .collect();
        let back: Vec<Se3> = out.iter().rev().copied().collect();
        let fused = |budget: Option<usize>, dir: &std::path::Path| {
            let mut volume = TsdfVolume::new(settings, camera);
            if let Some(blocks) = budget {
                volume.spill_to(dir, blocks * BLOCK_BYTES).unwrap();
            }
            for pose in &out {
                let depth = render_depth(&camera, pose, &[ball], Some(2.0));
                volume.allocate(&depth, pose);
            }
            fuse_views(&mut volume, &out, &[ball], Some(2.0));
            fuse_views(&mut volume, &back, &[], Some(2.0));
            volume
        };
        let dir = std::env::temp_dir().join(format!("dopslam-tsdf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut whole = fused(None, &dir);
        let mut spilled = fused(Some(40), &dir);
        let counts = spilled.spill_counts().unwrap();
        let all = whole.spill_counts().unwrap();
        assert!(
            counts.blocks_written > 0 && counts.blocks_reloaded > 0,
            "{counts:?}"
        );
        assert!(
            counts.peak_resident_mb < 0.6 * all.peak_resident_mb,
            "{counts:?} {all:?}"
        );
        // Queries read spilled voxels from the file.
        let mut rng = crate::random::Rng::new(3);
        for _ in 0..2000 {
            let p = Vector3::new(
                -1.8 + 3.6 * rng.uniform(),
                -0.8 + 1.6 * rng.uniform(),
                0.8 + 1.4 * rng.uniform(),
            );
            assert_eq!(whole.seen_through(&p, 0.5), spilled.seen_through(&p, 0.5));
            assert_eq!(
                whole.on_surface(&p, 2.0, 0.5),
                spilled.on_surface(&p, 2.0, 0.5)
            );
        }
        let (a, b) = (extract(&mut whole).unwrap(), extract(&mut spilled).unwrap());
        assert!(a.triangles.len() > 1000);
        assert_eq!(a.vertices, b.vertices);
        assert_eq!(a.colours, b.colours);
        assert_eq!(a.triangles, b.triangles);
        // With every block in the file, the grouped queries answer the same.
        spilled.spill_everything().unwrap();
        assert!(spilled.blocks.iter().all(|b| !b.resident()));
        let points: Vec<Vector3<f64>> = (0..2000)
            .map(|_| {
                let r = [3.6, 1.6, 1.4].map(|size| size * rng.uniform());
                Vector3::new(r[0] - 1.8, r[1] - 0.8, r[2] + 0.8)
            })
            .collect();
        let seen = whole.seen_through_each(&points, 0.5);
        assert!(seen.iter().any(|&s| s) && seen.iter().any(|&s| !s));
        assert_eq!(spilled.seen_through_each(&points, 0.5), seen);
        let path = spilled.spill.as_ref().unwrap().file.path().to_path_buf();
        assert!(path.exists());
        drop(spilled);
        assert!(!path.exists(), "the spill file goes with the volume");
        std::fs::remove_dir(&dir).unwrap();
        let front = Vector3::new(0.0, 0.0, ball.0.z - ball.1);
        assert!(whole.seen_through(&front, 0.5), "the ball was carved");
    }

    /// The block in memory holding the voxel nearest to `p`, and the voxel's index.
    fn voxel_at<'a>(volume: &'a TsdfVolume, p: &Vector3<f64>) -> Option<(&'a Block, usize)> {
        let (i, k) = volume.voxel_index_at(p)?;
        let block = &volume.blocks[i];
        block.resident().then_some((block, k))
    }

    #[test]
    fn a_place_seen_through_after_it_was_a_surface_reads_as_free_space() {
        let (settings, ball, views) = ball_before_a_wall();
        let front = Vector3::new(0.0, 0.0, 1.0);
        let wall = Vector3::new(0.0, 0.0, 2.0);
        let mut volume = TsdfVolume::new(settings, small_camera());
        fuse_views(&mut volume, &views, &[ball], Some(2.0));
        assert!(
            !volume.seen_through(&front, 0.5),
            "the ball's surface is there"
        );
        for _ in 0..3 {
            fuse_views(&mut volume, &views, &[], Some(2.0));
        }
        assert!(volume.seen_through(&front, 0.5), "the ball left");
        assert!(!volume.seen_through(&wall, 0.5), "the wall stays");
        assert!(
            !volume.seen_through(&Vector3::new(5.0, 5.0, 5.0), 0.5),
            "never seen"
        );
    }

    #[test]
    fn a_free_block_is_skipped_only_while_nothing_in_it_would_change() {
        let (settings, ball, views) = ball_before_a_wall();
        let camera = small_camera();
        let mut volume = TsdfVolume::new(settings, camera);
        for pose in &views {
            volume.allocate(&render_depth(&camera, pose, &[ball], Some(2.0)), pose);
        }
        // Seen free 30 times, past the weight cap of 20.
        for _ in 0..3 {
            fuse_views(&mut volume, &views, &[], Some(2.0));
        }
        let front = Vector3::new(0.0, 0.0, ball.0.z - ball.1);
        let (block, _) = voxel_at(&volume, &front).expect("allocated ahead");
        assert!(block.free, "free space at the weight cap");
        let before = (
            block.sdf.clone(),
            block.weight.clone(),
            block.colour.clone(),
        );
        fuse_views(&mut volume, &views, &[], Some(2.0));
        let (block, _) = voxel_at(&volume, &front).unwrap();
        let after = (
            block.sdf.clone(),
            block.weight.clone(),
            block.colour.clone(),
        );
        assert!(before == after, "more free space changes nothing");
        fuse_views(&mut volume, &views, &[ball], Some(2.0));
        let (block, _) = voxel_at(&volume, &front).unwrap();
        assert!(
            !block.free,
            "the ball's surface is fused into the free block"
        );
        assert!(block.sdf.iter().any(|&f| f < 1.0));
        assert!(block.colour_weight.iter().any(|&n| n > 0));
    }

    #[test]
    fn depth_beyond_max_depth_carves_only_with_far_carves() {
        let (settings, ball, views) = ball_before_a_wall();
        let front = Vector3::new(0.0, 0.0, 1.0);
        for far_carves in [true, false] {
            // The wall at 2 m lies beyond max_depth: it fuses nothing either way.
            let settings = TsdfSettings {
                max_depth: 1.5,
                far_carves,
                ..settings
            };
            let mut volume = TsdfVolume::new(settings, small_camera());
            fuse_views(&mut volume, &views, &[ball], Some(2.0));
            assert!(!volume.seen_through(&front, 0.5), "the ball is there");
            for _ in 0..3 {
                fuse_views(&mut volume, &views, &[], Some(2.0));
            }
            assert_eq!(
                volume.seen_through(&front, 0.5),
                far_carves,
                "far_carves = {far_carves}: rays to the far wall carve the ball"
            );
        }
    }

    #[test]
    fn block_keys_refuse_coordinates_out_of_range() {
        assert!(block_key([1 << 20, 0, 0]).is_none());
        assert!(block_key([0, -(1 << 20) - 1, 0]).is_none());
        assert!(block_key([0, 0, i32::MIN]).is_none());
    }

    pub fn small_camera() -> PinholeCamera {
        PinholeCamera {
            fx: 140.0,
            fy: 140.0,
            cx: 80.0,
            cy: 60.0,
            width: 160,
            height: 120,
            distortion: [0.0; 5],
            rational: [0.0; 3],
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
            volume
                .integrate(&FrameInput {
                    depth: &depth,
                    colour: &colour,
                    dynamic: None,
                    camera_from_world: pose,
                    weight: 1.0,
                })
                .unwrap();
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
        let mesh = extract(&mut volume).unwrap();
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
    fn free_space_seen_before_a_mover_came_carves_it_once_blocks_are_allocated_first() {
        // The wall is seen alone three times, then the ball arrives for one pass of the
        // views and is never seen through again.
        let (settings, ball, views) = ball_before_a_wall();
        let camera = small_camera();
        let colour = image::RgbImage::new(camera.width, camera.height);
        let passes: Vec<(&Se3, DepthImage)> = (0..4)
            .flat_map(|pass| {
                let spheres = if pass == 3 { vec![ball] } else { vec![] };
                views
                    .iter()
                    .map(move |pose| (pose, render_depth(&camera, pose, &spheres, Some(2.0))))
            })
            .collect();
        // Each frame into `volume`, allocated only or fused.
        let each = |volume: &mut TsdfVolume, fuse: bool| {
            for (pose, depth) in &passes {
                let input = FrameInput {
                    depth,
                    colour: &colour,
                    dynamic: None,
                    camera_from_world: pose,
                    weight: 1.0,
                };
                if fuse {
                    volume.integrate(&input).unwrap();
                } else {
                    volume.allocate(depth, pose);
                }
            }
        };
        let ball_vertices = |volume: &mut TsdfVolume| {
            let mesh = extract(volume).unwrap();
            let near = (0..mesh.len())
                .filter(|&i| (mesh.vertex(i) - ball.0).norm() < ball.1 + 0.05)
                .count();
            (near, mesh.len())
        };
        let mut online = TsdfVolume::new(settings, camera);
        each(&mut online, true);
        let (stays, _) = ball_vertices(&mut online);
        assert!(
            stays > 50,
            "fused in one pass, the late ball stays ({stays})"
        );
        let mut offline = TsdfVolume::new(settings, camera);
        each(&mut offline, false);
        each(&mut offline, true);
        let (near, all) = ball_vertices(&mut offline);
        assert_eq!(near, 0, "the earlier views carve the ball");
        assert!(all > 100, "the wall is there ({all} vertices)");
    }

    /// A ball seen only at the right border of the image (a person cut to a sliver)
    /// fuses no surface inside the margin; the wall beyond it still does.
    #[test]
    fn the_border_margin_fuses_no_surface() {
        let camera = small_camera();
        let pose = looking_at(Vector3::zeros(), Vector3::new(0.0, 0.0, 2.0));
        // Centre at u = 80 + 140 x / z = 155, radius about 3.5 pixels.
        let ball = (Vector3::new(0.643, 0.0, 1.2), 0.03);
        let near_ball = |margin: u32| {
            let settings = TsdfSettings {
                voxel: 0.01,
                truncation: 0.03,
                margin,
                ..TsdfSettings::default()
            };
            let mut volume = TsdfVolume::new(settings, camera);
            fuse_views(&mut volume, &[pose; 3], &[ball], Some(2.0));
            let mesh = extract(&mut volume).unwrap();
            let near = (0..mesh.len())
                .filter(|&i| (mesh.vertex(i) - ball.0).norm() < ball.1 + 0.02)
                .count();
            (near, mesh.len())
        };
        let (without, _) = near_ball(0);
        assert!(without > 10, "no margin: the ball is fused ({without})");
        let (with, all) = near_ball(12);
        assert_eq!(with, 0, "the ball lies in the margin");
        assert!(all > 1000, "the wall is fused ({all} vertices)");
    }

    #[test]
    fn a_ball_that_leaves_is_carved_away_and_masked_pixels_are_not_fused() {
        let (settings, ball, views) = ball_before_a_wall();
        let near_ball = |volume: &mut TsdfVolume| {
            let mesh = extract(volume).unwrap();
            (0..mesh.len())
                .filter(|&i| (mesh.vertex(i) - ball.0).norm() < ball.1 + 0.05)
                .count()
        };
        let mut volume = TsdfVolume::new(settings, small_camera());
        fuse_views(&mut volume, &views, &[ball], Some(2.0));
        assert!(
            near_ball(&mut volume) > 50,
            "the ball is in the map while it is there"
        );
        // It leaves: the wall behind is seen through where it was.
        for _ in 0..3 {
            fuse_views(&mut volume, &views, &[], Some(2.0));
        }
        assert_eq!(near_ball(&mut volume), 0, "the ball is carved away");
        // Masked as dynamic, it never enters.
        let camera = small_camera();
        let mut clean = TsdfVolume::new(settings, camera);
        let colour = image::RgbImage::new(camera.width, camera.height);
        for pose in &views {
            let depth = render_depth(&camera, pose, &[ball], Some(2.0));
            let mask: Vec<bool> = depth.metres.iter().map(|&d| d < 1.9).collect();
            clean
                .integrate(&FrameInput {
                    depth: &depth,
                    colour: &colour,
                    dynamic: Some(&mask),
                    camera_from_world: pose,
                    weight: 1.0,
                })
                .unwrap();
        }
        assert_eq!(near_ball(&mut clean), 0);
        assert!(
            extract(&mut clean).unwrap().len() > 100,
            "the wall is there"
        );
    }
}
