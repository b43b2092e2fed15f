//! The point cloud's voxel sums ([`super::cloud::CloudBuilder`]) in chunks of 16³
//! voxels. Under a memory budget ([`CloudVoxels::spill_to`]) the chunks least recently
//! used are written to a spill file once the chunks in memory exceed it, and read
//! back when a frame adds to them again or the cloud's carving and finishing reach
//! them, chunk by chunk. The sums are the same numbers added in the same order either
//! way, so the cloud is the same.

use std::collections::hash_map::Entry;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::tsdf::FxMap;
use crate::io::spill::{read_table, write_table, SpillFile};
use crate::io::IoError;

/// Voxels along one side of a chunk.
const CHUNK: i32 = 16;
/// Bytes of one voxel in a spill record: its place in its chunk (`u16`), then
/// [`Voxel`]'s fields in order (`f64`, `u32`), little-endian.
const VOXEL_BYTES: usize = 2 + 3 * 8 + 3 * 4 + 3 * 8 + 4;
/// Bytes a voxel takes in memory (a hash table entry and its control byte).
const VOXEL_MEMORY: usize = std::mem::size_of::<(u16, Voxel)>() + 1;

/// Kept sums ([`CloudVoxels::keep`]): the spill file's records.
pub const KEPT_SUMS: &str = "cloud.bin";
/// Kept sums' chunks: per chunk its key (3 `i32`), where its record lies in
/// [`KEPT_SUMS`] (`u64`, `u64::MAX` for none) and its voxels (`u32`), little-endian.
pub const KEPT_CHUNKS: &str = "cloud_chunks.bin";
const KEPT_ENTRY: usize = 24;

/// What kept sums' files hold ([`CloudVoxels::keep`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct KeptCloud {
    /// Chunks in the table.
    pub chunks: usize,
    /// Bytes of the sums' file that the table refers to.
    pub bytes: u64,
}

/// One voxel's sums.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Voxel {
    pub sum: [f64; 3],
    pub colour: [u32; 3],
    /// Sum of unit directions from the point to the cameras that saw it.
    pub view: [f64; 3],
    pub count: u32,
}

impl Voxel {
    fn write(&self, place: u16, out: &mut Vec<u8>) {
        out.extend_from_slice(&place.to_le_bytes());
        self.sum.iter().for_each(|v| out.extend(v.to_le_bytes()));
        self.colour.iter().for_each(|v| out.extend(v.to_le_bytes()));
        self.view.iter().for_each(|v| out.extend(v.to_le_bytes()));
        out.extend(self.count.to_le_bytes());
    }

    fn read(bytes: &[u8]) -> (u16, Self) {
        let word = |at: usize| -> [u8; 8] { bytes[at..at + 8].try_into().expect("8 bytes") };
        let half = |at: usize| -> [u8; 4] { bytes[at..at + 4].try_into().expect("4 bytes") };
        let place = u16::from_le_bytes([bytes[0], bytes[1]]);
        let voxel = Self {
            sum: [0, 1, 2].map(|k| f64::from_le_bytes(word(2 + 8 * k))),
            colour: [0, 1, 2].map(|k| u32::from_le_bytes(half(26 + 4 * k))),
            view: [0, 1, 2].map(|k| f64::from_le_bytes(word(38 + 8 * k))),
            count: u32::from_le_bytes(half(62)),
        };
        (place, voxel)
    }
}

/// A chunk: its voxels while in memory, and where its record lies in the spill file
/// once written there.
#[derive(Default)]
struct Chunk {
    voxels: FxMap<u16, Voxel>,
    resident: bool,
    /// Changed since its record was written.
    dirty: bool,
    /// The last frame that added to it.
    stamp: u64,
    record: Option<Record>,
}

/// A chunk's record in the spill file.
#[derive(Debug, Clone, Copy)]
struct Record {
    at: u64,
    voxels: u32,
}

/// A cloud's spill file and budget.
struct CloudSpill {
    file: SpillFile,
    /// Bytes of voxels in memory allowed.
    budget: usize,
    bytes: Vec<u8>,
}

/// What a cloud's budget made it do (`dense.json` `cloud_spill`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct CloudSpillCounts {
    /// Chunk records written to the spill file (a chunk written again counts again).
    pub chunks_written: u64,
    /// Chunk records read back into memory (by frames, the carving and the writing).
    pub chunks_reloaded: u64,
    /// The spill file's size at the end, MB.
    pub file_mb: f64,
    /// The most voxel sums in memory at once (hash table entries), MB.
    pub peak_resident_mb: f64,
}

/// The voxel sums, chunked.
#[derive(Default)]
pub(super) struct CloudVoxels {
    chunks: FxMap<[i32; 3], Chunk>,
    stamp: u64,
    spill: Option<CloudSpill>,
    counts: CloudSpillCounts,
    /// Voxels in memory.
    resident: usize,
    /// Voxels in all.
    len: usize,
}

/// A voxel's chunk and its place in it (places in the order of the keys).
fn chunk_of(key: [i32; 3]) -> ([i32; 3], u16) {
    let chunk = key.map(|k| k.div_euclid(CHUNK));
    let [x, y, z] = key.map(|k| k.rem_euclid(CHUNK) as u16);
    (chunk, (x * CHUNK as u16 + y) * CHUNK as u16 + z)
}

/// The voxel key of `place` in `chunk`.
fn key_of(chunk: [i32; 3], place: u16) -> [i32; 3] {
    let c = CHUNK as u16;
    let local = [place / (c * c), place / c % c, place % c];
    [0, 1, 2].map(|k| chunk[k] * CHUNK + local[k] as i32)
}

/// The Morton code of `key` (each coordinate taken from `min`): chunks in this order
/// follow each other in space, so that a chunk's neighbours were mostly just used.
fn morton(key: [i32; 3], min: [i32; 3]) -> u64 {
    let mut code = 0u64;
    for k in 0..3 {
        let v = (key[k] as i64 - min[k] as i64) as u64;
        for bit in 0..21 {
            code |= ((v >> bit) & 1) << (3 * bit + k);
        }
    }
    code
}

impl CloudVoxels {
    /// Keeps at most `budget_bytes` of voxel sums in memory: beyond it the chunks
    /// least recently added to go to a spill file in `dir`, removed when the sums are
    /// dropped.
    pub fn spill_to(&mut self, dir: &Path, budget_bytes: usize) -> Result<(), IoError> {
        self.spill = Some(CloudSpill {
            file: SpillFile::create(dir, "cloud", 1)?,
            budget: budget_bytes,
            bytes: Vec::new(),
        });
        Ok(())
    }

    /// Keeps the sums in `dir` ([`super::kept`]): the spill file linked as
    /// [`KEPT_SUMS`], the chunks' table written as [`KEPT_CHUNKS`]. Every chunk is in
    /// the file by then ([`CloudVoxels::spill_everything`]); an error without one.
    pub fn keep(&self, dir: &Path) -> Result<KeptCloud, IoError> {
        let Some(spill) = &self.spill else {
            return Err(IoError::invalid(
                dir,
                "a cloud without a spill file cannot be kept",
            ));
        };
        if self.resident > 0 || self.chunks.values().any(|c| c.resident) {
            return Err(IoError::invalid(
                dir,
                "a cloud is kept with every chunk spilled",
            ));
        }
        spill.file.keep_as(&dir.join(KEPT_SUMS))?;
        let mut table = Vec::with_capacity(self.chunks.len() * KEPT_ENTRY);
        for (key, chunk) in &self.chunks {
            let record = chunk.record.unwrap_or(Record {
                at: u64::MAX,
                voxels: 0,
            });
            key.iter().for_each(|k| table.extend(k.to_le_bytes()));
            table.extend(record.at.to_le_bytes());
            table.extend(record.voxels.to_le_bytes());
        }
        write_table(&dir.join(KEPT_CHUNKS), &table)?;
        Ok(KeptCloud {
            chunks: self.chunks.len(),
            bytes: spill.file.bytes(),
        })
    }

    /// The sums [`CloudVoxels::keep`] left in `dir`, as `kept` describes them: read
    /// from there and never written, chunks beyond `budget_bytes` spilled into a new
    /// spill file in `spill_dir`.
    pub fn from_kept(
        dir: &Path,
        kept: &KeptCloud,
        spill_dir: &Path,
        budget_bytes: usize,
    ) -> Result<Self, IoError> {
        let table = read_table(&dir.join(KEPT_CHUNKS), kept.chunks * KEPT_ENTRY)?;
        let mut sums = Self::default();
        for entry in table.chunks_exact(KEPT_ENTRY) {
            let half = |at: usize| -> [u8; 4] { entry[at..at + 4].try_into().expect("4 bytes") };
            let key = [0, 4, 8].map(|at| i32::from_le_bytes(half(at)));
            let at = u64::from_le_bytes(entry[12..20].try_into().expect("8 bytes"));
            let voxels = u32::from_le_bytes(half(20));
            let record = (at != u64::MAX).then_some(Record { at, voxels });
            sums.len += voxels as usize;
            sums.chunks.insert(
                key,
                Chunk {
                    record,
                    ..Chunk::default()
                },
            );
        }
        sums.spill = Some(CloudSpill {
            file: SpillFile::over(&dir.join(KEPT_SUMS), kept.bytes, spill_dir, "cloud", 1)?,
            budget: budget_bytes,
            bytes: Vec::new(),
        });
        Ok(sums)
    }

    /// The voxel at `key`, new (zero) if none was; its chunk read back first when it
    /// is out of memory.
    pub fn voxel_mut(&mut self, key: [i32; 3]) -> Result<&mut Voxel, IoError> {
        let (at, place) = chunk_of(key);
        self.chunks.entry(at).or_default();
        self.load(at)?;
        let chunk = self.chunks.get_mut(&at).expect("just made");
        chunk.dirty = true;
        Ok(match chunk.voxels.entry(place) {
            Entry::Occupied(voxel) => voxel.into_mut(),
            Entry::Vacant(place) => {
                self.resident += 1;
                self.len += 1;
                place.insert(Voxel::default())
            }
        })
    }

    /// Brings chunk `at`'s voxels into memory (from its spill record) and stamps it.
    fn load(&mut self, at: [i32; 3]) -> Result<(), IoError> {
        let chunk = self.chunks.get_mut(&at).expect("a chunk of the cloud");
        if !chunk.resident {
            if let (Some(record), Some(spill)) = (chunk.record, self.spill.as_mut()) {
                chunk.voxels = read_chunk(spill, record)?;
                self.counts.chunks_reloaded += 1;
            }
            chunk.resident = true;
            self.resident += chunk.voxels.len();
        }
        chunk.stamp = self.stamp;
        Ok(())
    }

    /// The chunks' keys, in Morton order.
    pub fn chunk_keys(&self) -> Vec<[i32; 3]> {
        let mut keys: Vec<[i32; 3]> = self.chunks.keys().copied().collect();
        let min = [0, 1, 2].map(|k| keys.iter().map(|c| c[k]).min().unwrap_or(0));
        keys.sort_unstable_by_key(|c| morton(*c, min));
        keys
    }

    /// Chunk `at`'s voxels, sorted by key (read back first when out of memory).
    pub fn sorted(&mut self, at: [i32; 3]) -> Result<Vec<([i32; 3], Voxel)>, IoError> {
        self.load(at)?;
        let chunk = &self.chunks[&at];
        let mut voxels: Vec<(u16, Voxel)> = chunk.voxels.iter().map(|(p, v)| (*p, *v)).collect();
        voxels.sort_unstable_by_key(|(p, _)| *p);
        Ok(voxels
            .into_iter()
            .map(|(p, v)| (key_of(at, p), v))
            .collect())
    }

    /// Keeps those of chunk `at`'s voxels (in [`CloudVoxels::sorted`]'s order) that
    /// `keep` marks.
    pub fn retain(&mut self, at: [i32; 3], keep: &[bool]) -> Result<(), IoError> {
        let voxels = self.sorted(at)?;
        let gone: Vec<u16> = (voxels.iter().zip(keep))
            .filter(|(_, &keep)| !keep)
            .map(|((key, _), _)| chunk_of(*key).1)
            .collect();
        let chunk = self.chunks.get_mut(&at).expect("loaded");
        for place in &gone {
            chunk.voxels.remove(place);
        }
        chunk.dirty |= !gone.is_empty();
        self.resident -= gone.len();
        self.len -= gone.len();
        Ok(())
    }

    /// Ends a step (a frame added, a chunk carved or finished): when more than the
    /// budget's voxels are in memory, the chunks least recently used (not this
    /// step's) go to the spill file until a quarter of the budget is free.
    pub fn end_step(&mut self) -> Result<(), IoError> {
        let memory = self.resident * VOXEL_MEMORY;
        self.counts.peak_resident_mb = self.counts.peak_resident_mb.max(memory as f64 / 1e6);
        self.stamp += 1;
        let Some(spill) = self.spill.as_mut() else {
            return Ok(());
        };
        if memory <= spill.budget {
            return Ok(());
        }
        let current = self.stamp - 1;
        let mut old: Vec<(u64, [i32; 3])> = (self.chunks.iter())
            .filter(|(_, c)| c.resident && c.stamp < current)
            .map(|(k, c)| (c.stamp, *k))
            .collect();
        old.sort_unstable();
        let mut over = memory.saturating_sub(spill.budget * 3 / 4) / VOXEL_MEMORY;
        for (_, key) in old {
            if over == 0 {
                break;
            }
            let chunk = self.chunks.get_mut(&key).expect("listed");
            let n = spill_chunk(spill, chunk, &mut self.counts)?;
            self.resident -= n;
            over = over.saturating_sub(n);
        }
        Ok(())
    }

    /// With a budget: every chunk in memory goes to the spill file (those not
    /// changed since they were read back are only dropped), so that the sums hold no
    /// memory while the mesh is made.
    pub fn spill_everything(&mut self) -> Result<(), IoError> {
        let Some(spill) = self.spill.as_mut() else {
            return Ok(());
        };
        for chunk in self.chunks.values_mut().filter(|c| c.resident) {
            self.resident -= spill_chunk(spill, chunk, &mut self.counts)?;
        }
        Ok(())
    }

    /// Voxels in all, in memory or not.
    pub fn len(&self) -> usize {
        self.len
    }

    /// What the budget made the sums do.
    pub fn spill_counts(&self) -> CloudSpillCounts {
        let file_mb = (self.spill.as_ref()).map_or(0.0, |s| s.file.bytes() as f64 / 1e6);
        CloudSpillCounts {
            file_mb,
            ..self.counts
        }
    }
}

/// Writes `chunk` to the spill file when it changed since it was last written there,
/// and takes its voxels out of memory; how many there were.
fn spill_chunk(
    spill: &mut CloudSpill,
    chunk: &mut Chunk,
    counts: &mut CloudSpillCounts,
) -> Result<usize, IoError> {
    if chunk.dirty || chunk.record.is_none() {
        chunk.record = Some(write_chunk(spill, &chunk.voxels)?);
        counts.chunks_written += 1;
    }
    let n = chunk.voxels.len();
    (chunk.voxels, chunk.resident, chunk.dirty) = (FxMap::default(), false, false);
    Ok(n)
}

fn write_chunk(spill: &mut CloudSpill, voxels: &FxMap<u16, Voxel>) -> Result<Record, IoError> {
    spill.bytes.clear();
    for (place, voxel) in voxels {
        voxel.write(*place, &mut spill.bytes);
    }
    let at = spill.file.append(&spill.bytes)?;
    Ok(Record {
        at,
        voxels: voxels.len() as u32,
    })
}

fn read_chunk(spill: &mut CloudSpill, record: Record) -> Result<FxMap<u16, Voxel>, IoError> {
    spill.bytes.resize(record.voxels as usize * VOXEL_BYTES, 0);
    spill.file.read_at(record.at, &mut spill.bytes)?;
    let mut voxels = FxMap::default();
    voxels.reserve(record.voxels as usize);
    voxels.extend(spill.bytes.chunks_exact(VOXEL_BYTES).map(Voxel::read));
    Ok(voxels)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_map_to_a_chunk_and_a_place_and_back() {
        for key in [[0, 0, 0], [-1, 15, 16], [-17, -16, 31], [100, -200, 7]] {
            let (chunk, place) = chunk_of(key);
            assert_eq!(key_of(chunk, place), key);
        }
        assert_eq!(chunk_of([-1, 0, 16]).0, [-1, 0, 1]);
        // Places follow the keys' order within a chunk.
        let mut keys = vec![[3, 1, 2], [0, 15, 15], [15, 0, 0], [3, 0, 9]];
        let mut places: Vec<u16> = keys.iter().map(|k| chunk_of(*k).1).collect();
        keys.sort_unstable();
        places.sort_unstable();
        assert_eq!(
            places
                .iter()
                .map(|p| key_of([0; 3], *p))
                .collect::<Vec<_>>(),
            keys
        );
        assert!(morton([1, 0, 0], [0; 3]) < morton([0, 0, 1], [0; 3]));
        assert!(morton([1, 1, 1], [0; 3]) < morton([2, 0, 0], [0; 3]));
    }

    #[test]
    fn a_voxel_record_reads_back_as_written() {
        let voxel = Voxel {
            sum: [1.5, -2.25, 1e9],
            colour: [1, 70000, 3],
            view: [0.1, 0.2, -0.3],
            count: 42,
        };
        let mut bytes = Vec::new();
        voxel.write(4095, &mut bytes);
        assert_eq!(bytes.len(), VOXEL_BYTES);
        let (place, back) = Voxel::read(&bytes);
        assert_eq!(place, 4095);
        assert_eq!(
            (back.sum, back.colour, back.view, back.count),
            (voxel.sum, voxel.colour, voxel.view, voxel.count)
        );
    }
}
