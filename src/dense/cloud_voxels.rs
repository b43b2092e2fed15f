//! The point cloud's voxel sums ([`super::cloud::CloudBuilder`]) in chunks of 16³
//! voxels. Under a memory budget ([`CloudVoxels::spill_to`]) the chunks least recently
//! added to are written to a spill file once the chunks in memory exceed it, and read
//! back when a frame adds to them again; [`CloudVoxels::drain_sorted`] hands every
//! chunk out once, in order, from memory or from the file. The sums are the same
//! numbers added in the same order either way, so the cloud is the same.

use std::collections::hash_map::Entry;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::spill::SpillFile;
use super::tsdf::FxMap;
use crate::io::IoError;

/// Voxels along one side of a chunk.
const CHUNK: i32 = 16;
/// Bytes of one voxel in a spill record: its place in its chunk (`u16`), then
/// [`Voxel`]'s fields in order (`f64`, `u32`), little-endian.
const VOXEL_BYTES: usize = 2 + 3 * 8 + 3 * 4 + 3 * 8 + 4;
/// Bytes a voxel takes in memory (a hash table entry and its control byte).
const VOXEL_MEMORY: usize = std::mem::size_of::<(u16, Voxel)>() + 1;

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
    /// Chunk records read back into memory while frames were added.
    pub chunks_reloaded: u64,
    /// The spill file's size at the end, MB.
    pub file_mb: f64,
    /// The most voxel sums in memory at once, MB.
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

/// A voxel's chunk and its place in it.
fn chunk_of(key: [i32; 3]) -> ([i32; 3], u16) {
    let chunk = key.map(|k| k.div_euclid(CHUNK));
    let [x, y, z] = key.map(|k| k.rem_euclid(CHUNK) as u16);
    (chunk, (z * CHUNK as u16 + y) * CHUNK as u16 + x)
}

/// The voxel key of `place` in `chunk`.
fn key_of(chunk: [i32; 3], place: u16) -> [i32; 3] {
    let c = CHUNK as u16;
    let local = [place % c, place / c % c, place / (c * c)];
    [0, 1, 2].map(|k| chunk[k] * CHUNK + local[k] as i32)
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

    /// The voxel at `key`, new (zero) if none was; its chunk read back first when it
    /// is out of memory.
    pub fn voxel_mut(&mut self, key: [i32; 3]) -> Result<&mut Voxel, IoError> {
        let (at, place) = chunk_of(key);
        let chunk = self.chunks.entry(at).or_default();
        if !chunk.resident {
            if let (Some(record), Some(spill)) = (chunk.record, self.spill.as_mut()) {
                chunk.voxels = read_chunk(spill, record)?;
                self.counts.chunks_reloaded += 1;
            }
            chunk.resident = true;
            self.resident += chunk.voxels.len();
        }
        (chunk.stamp, chunk.dirty) = (self.stamp, true);
        Ok(match chunk.voxels.entry(place) {
            Entry::Occupied(voxel) => voxel.into_mut(),
            Entry::Vacant(place) => {
                self.resident += 1;
                self.len += 1;
                place.insert(Voxel::default())
            }
        })
    }

    /// Ends a frame: when more than the budget's voxels are in memory, the chunks
    /// least recently added to (not this frame's) go to the spill file until a quarter
    /// of the budget is free.
    pub fn end_frame(&mut self) -> Result<(), IoError> {
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
            if chunk.dirty || chunk.record.is_none() {
                chunk.record = Some(write_chunk(spill, &chunk.voxels)?);
                self.counts.chunks_written += 1;
            }
            let n = chunk.voxels.len();
            (chunk.voxels, chunk.resident, chunk.dirty) = (FxMap::default(), false, false);
            self.resident -= n;
            over = over.saturating_sub(n);
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

    /// Every chunk's voxels once, chunks in key order, each chunk's sorted by key:
    /// `each` takes them; the chunk is gone from memory before the next one comes.
    pub fn drain_sorted(
        mut self,
        mut each: impl FnMut(Vec<([i32; 3], Voxel)>),
    ) -> Result<(), IoError> {
        let mut keys: Vec<[i32; 3]> = self.chunks.keys().copied().collect();
        keys.sort_unstable();
        for at in keys {
            let chunk = self.chunks.remove(&at).expect("listed");
            let voxels = match (chunk.resident, chunk.record, self.spill.as_mut()) {
                (false, Some(record), Some(spill)) => read_chunk(spill, record)?,
                _ => chunk.voxels,
            };
            let mut voxels: Vec<([i32; 3], Voxel)> = (voxels.into_iter())
                .map(|(place, v)| (key_of(at, place), v))
                .collect();
            voxels.sort_unstable_by_key(|(k, _)| *k);
            each(voxels);
        }
        Ok(())
    }
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
