//! ROS 1 bags, format 2.0 (what `rosbag record`, TUM's published bags and librealsense
//! before 2.56 write).
//!
//! A bag is a sequence of records, each `header_len: u32, header, data_len: u32, data`;
//! a header is a list of `field_len: u32, name=value` fields, whose `op` field says the
//! record's kind. Messages and connection records live in chunks (op 5), each
//! uncompressed, bz2 or lz4 (LZ4 frame format). The index after the chunks is not
//! needed: the reader scans the chunks once, which also reads a bag whose recorder died
//! before writing its index, and stops at a record cut by the end of the file (a
//! truncated bag), with a warning naming the offset.
//!
//! The file is memory-mapped ([`super::mapped`]): a message in an uncompressed chunk is
//! handed to its decoder where it lies in the file (no read into a buffer, no copy out
//! of it), and the scan touches only the records' headers.
//!
//! The `rosbag` crate reads the same records, but slices its memory map with the
//! header's `index_pos` unchecked: a bag without an index or cut short makes it panic,
//! and it does not expose where a chunk starts, which random access needs.

use std::borrow::Cow;
use std::io::Read;
use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use memmap2::Mmap;

use super::mapped::{self, release};
use super::{Catalog, Location, Store};
use crate::io::IoError;

const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
const OP_MESSAGE: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_CHUNK: u8 = 0x05;
const OP_CONNECTION: u8 = 0x07;

/// An opened ROS 1 bag: its file, mapped, and the chunk read last.
pub struct Ros1Bag {
    path: PathBuf,
    /// The file as it was when opened: records past its end are cut off.
    map: Mmap,
    /// The chunk read last (the next frame is almost always in it).
    cache: Mutex<Option<Chunk>>,
}

/// A chunk read: where its record lies in the file, and its records.
struct Chunk {
    /// Its byte position in the file (what a [`Location`] names).
    pos: u64,
    /// Its record's bytes in the file.
    span: Range<usize>,
    records: Records,
}

/// A chunk's records: where they lie in the file (stored uncompressed: read in place),
/// or decompressed.
enum Records {
    InPlace(Range<usize>),
    Decompressed(Vec<u8>),
}

/// A record of the file: its header, its data and the position after it.
struct FileRecord<'a> {
    header: Header,
    data: &'a [u8],
    end: u64,
}

/// The fields of a record header.
struct Header(Vec<(String, Vec<u8>)>);

impl Header {
    fn parse(bytes: &[u8]) -> Result<Self, String> {
        let mut fields = Vec::new();
        let mut rest = bytes;
        while !rest.is_empty() {
            let (len, tail) = split_u32(rest).ok_or("a header field cut short")?;
            let field = tail
                .get(..len as usize)
                .ok_or("a header field longer than its header")?;
            let eq = field
                .iter()
                .position(|&b| b == b'=')
                .ok_or("a header field without '='")?;
            fields.push((
                String::from_utf8_lossy(&field[..eq]).into_owned(),
                field[eq + 1..].to_vec(),
            ));
            rest = &tail[len as usize..];
        }
        Ok(Self(fields))
    }

    fn get(&self, name: &str) -> Option<&[u8]> {
        self.0
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_slice())
    }

    fn op(&self) -> Result<u8, String> {
        match self.get("op") {
            Some([op]) => Ok(*op),
            _ => Err("a record without its 'op' field".into()),
        }
    }

    fn string(&self, name: &str) -> Result<String, String> {
        let value = self
            .get(name)
            .ok_or_else(|| format!("a record without its '{name}' field"))?;
        Ok(String::from_utf8_lossy(value).into_owned())
    }

    fn u32(&self, name: &str) -> Result<u32, String> {
        match self.get(name) {
            Some(v) if v.len() == 4 => Ok(u32::from_le_bytes(v.try_into().expect("4 bytes"))),
            _ => Err(format!("a record without a 4-byte '{name}' field")),
        }
    }

    fn u64(&self, name: &str) -> Result<u64, String> {
        match self.get(name) {
            Some(v) if v.len() == 8 => Ok(u64::from_le_bytes(v.try_into().expect("8 bytes"))),
            _ => Err(format!("a record without an 8-byte '{name}' field")),
        }
    }
}

fn split_u32(bytes: &[u8]) -> Option<(u32, &[u8])> {
    let (head, tail) = bytes.split_first_chunk::<4>()?;
    Some((u32::from_le_bytes(*head), tail))
}

/// The record at `offset` of `bytes`: its header's bytes, its data and where it ends;
/// `None` when it runs past the end of `bytes`.
fn split_record(bytes: &[u8], offset: usize) -> Option<(&[u8], &[u8], usize)> {
    let (header_len, rest) = split_u32(bytes.get(offset..)?)?;
    let header = rest.get(..header_len as usize)?;
    let (data_len, rest) = split_u32(&rest[header_len as usize..])?;
    let data = rest.get(..data_len as usize)?;
    let end = offset + 8 + header_len as usize + data_len as usize;
    Some((header, data, end))
}

/// One record inside a chunk: its header, its data and where it ends.
fn record_at(chunk: &[u8], offset: usize) -> Result<(Header, &[u8], usize), String> {
    let (header, data, end) = split_record(chunk, offset).ok_or_else(|| {
        format!("a record at offset {offset} of a chunk runs past the chunk's end")
    })?;
    Ok((Header::parse(header)?, data, end))
}

impl Ros1Bag {
    /// Opens a bag and scans its chunks into a catalogue.
    pub fn open(path: &Path) -> Result<(Self, Catalog), IoError> {
        let map = mapped::map(path)?;
        let magic = &map[..map.len().min(MAGIC.len())];
        if magic != MAGIC {
            let version = if magic.starts_with(b"#ROSBAG V") {
                format!(
                    "a ROS bag of version {}",
                    String::from_utf8_lossy(&magic[9..]).trim()
                )
            } else {
                "not a ROS bag".to_owned()
            };
            return Err(IoError::invalid(
                path,
                format!("{version}: only format 2.0 (\"#ROSBAG V2.0\") is read; `rosbag fix` converts older bags"),
            ));
        }
        let bag = Self {
            path: path.to_path_buf(),
            map,
            cache: Mutex::new(None),
        };
        let catalog = bag.scan()?;
        Ok((bag, catalog))
    }

    fn invalid(&self, message: impl Into<String>) -> IoError {
        IoError::invalid(&self.path, message)
    }

    /// The record at `pos` of the file, `None` when it is cut by the end of the file.
    fn file_record(&self, pos: u64) -> Result<Option<FileRecord<'_>>, IoError> {
        let split = usize::try_from(pos)
            .ok()
            .and_then(|at| split_record(&self.map, at));
        let Some((header, data, end)) = split else {
            return Ok(None);
        };
        let header =
            Header::parse(header).map_err(|e| self.invalid(format!("offset {pos}: {e}")))?;
        let end = end as u64;
        Ok(Some(FileRecord { header, data, end }))
    }

    /// Scans every chunk once: the connections, and each message's place and stamp.
    fn scan(&self) -> Result<Catalog, IoError> {
        let len = self.map.len() as u64;
        let mut catalog = Catalog::new(super::Wire::Ros1);
        let mut pos = MAGIC.len() as u64;
        let mut index_pos = None;
        while pos < len {
            let Some(FileRecord { header, data, end }) = self.file_record(pos)? else {
                if let Some(next) = self.next_chunk(pos) {
                    catalog.warnings.push(format!(
                        "{}: the record at byte {pos} is damaged (its length runs past the file's end, {len} bytes): {} bytes skipped to the next chunk, at byte {next}",
                        self.path.display(),
                        next - pos
                    ));
                    pos = next;
                    continue;
                }
                catalog.warnings.push(format!(
                    "{}: the bag is cut short: the record at byte {pos} runs past its end ({len} bytes); the messages before it are read",
                    self.path.display()
                ));
                break;
            };
            let op = header.op().map_err(|e| self.invalid(e))?;
            match op {
                OP_BAG_HEADER => {
                    index_pos = Some(header.u64("index_pos").map_err(|e| self.invalid(e))?)
                }
                OP_CHUNK => {
                    let chunk = self.decompress(&header, data, pos)?;
                    self.scan_chunk(&chunk, pos, &mut catalog)?;
                    release(&self.map, pos as usize..end as usize);
                }
                _ => {}
            }
            if index_pos.is_some_and(|i| i != 0 && end >= i) {
                break;
            }
            pos = end;
        }
        if index_pos == Some(0) {
            catalog.warnings.push(format!(
                "{}: the bag has no index (its recorder did not close it): read by scanning its chunks",
                self.path.display()
            ));
        }
        Ok(catalog)
    }

    /// The first whole chunk record after `pos`, found by its header's `op` field: where
    /// a damaged length hides the records after it, the scan goes on from there.
    fn next_chunk(&self, pos: u64) -> Option<u64> {
        const OP_FIELD: [u8; 8] = [4, 0, 0, 0, b'o', b'p', b'=', OP_CHUNK];
        /// How far before its `op` field a chunk record may start (its header_len, and
        /// the `compression` and `size` fields).
        const BEFORE: usize = 64;
        let from = usize::try_from(pos).ok()? + 1;
        let tail = self.map.get(from..)?;
        tail.windows(OP_FIELD.len())
            .enumerate()
            .filter(|(_, w)| *w == OP_FIELD)
            .find_map(|(at, _)| {
                let field = from + at;
                (field.saturating_sub(BEFORE).max(from)..field).find(|&start| {
                    split_record(&self.map, start).is_some_and(|(header, _, _)| {
                        let header_at = start + 4;
                        (header_at..header_at + header.len()).contains(&field)
                            && Header::parse(header).is_ok_and(|h| h.op() == Ok(OP_CHUNK))
                    })
                })
            })
            .map(|start| start as u64)
    }

    fn scan_chunk(
        &self,
        chunk: &[u8],
        chunk_pos: u64,
        catalog: &mut Catalog,
    ) -> Result<(), IoError> {
        let mut offset = 0;
        while offset < chunk.len() {
            let (header, data, end) = record_at(chunk, offset)
                .map_err(|e| self.invalid(format!("chunk at byte {chunk_pos}: {e}")))?;
            let in_chunk = |e: String| self.invalid(format!("chunk at byte {chunk_pos}: {e}"));
            match header.op().map_err(in_chunk)? {
                OP_CONNECTION => {
                    let id = header.u32("conn").map_err(in_chunk)?;
                    let topic = header.string("topic").map_err(in_chunk)?;
                    let fields = Header::parse(data).map_err(in_chunk)?;
                    let msg_type = fields.string("type").map_err(in_chunk)?;
                    catalog.add_topic(id, &topic, &msg_type);
                }
                OP_MESSAGE => {
                    let id = header.u32("conn").map_err(in_chunk)?;
                    let time = header.u64("time").map_err(in_chunk)?;
                    let received = (time & 0xffff_ffff) as f64 + (time >> 32) as f64 / 1e9;
                    catalog.add_message(id, Location(chunk_pos, offset as u64), data, received);
                }
                _ => {}
            }
            offset = end;
        }
        Ok(())
    }

    /// A chunk's records: its data as it is when stored uncompressed, else decompressed.
    fn decompress<'a>(
        &self,
        header: &Header,
        data: &'a [u8],
        pos: u64,
    ) -> Result<Cow<'a, [u8]>, IoError> {
        let at = |e: String| self.invalid(format!("chunk at byte {pos}: {e}"));
        let compression = header.string("compression").map_err(at)?;
        let size = header.u32("size").map_err(at)? as usize;
        if compression != "none" && size > MAX_CHUNK_BYTES {
            return Err(at(format!(
                "it announces {size} bytes decompressed, more than the {MAX_CHUNK_BYTES} a chunk may hold here"
            )));
        }
        let out = match compression.as_str() {
            "none" => Cow::Borrowed(data),
            "bz2" => Cow::Owned(
                inflate(bzip2::read::BzDecoder::new(data), data.len(), size)
                    .map_err(|e| at(format!("bz2: {e}")))?,
            ),
            "lz4" => Cow::Owned(
                inflate(lz4_flex::frame::FrameDecoder::new(data), data.len(), size)
                    .map_err(|e| at(format!("lz4: {e}")))?,
            ),
            other => {
                return Err(at(format!(
                    "compression {other:?} is not one of none, bz2, lz4"
                )))
            }
        };
        if out.len() != size {
            return Err(at(format!(
                "{} bytes decompressed, {size} announced",
                out.len()
            )));
        }
        Ok(out)
    }

    /// Reads the chunk at `pos` (decompressing it when it is compressed).
    fn chunk(&self, pos: u64) -> Result<Chunk, IoError> {
        let record = self.file_record(pos)?;
        let Some(FileRecord { header, data, end }) =
            record.filter(|r| r.header.op().ok() == Some(OP_CHUNK))
        else {
            return Err(self.invalid(format!(
                "no chunk at byte {pos} any more (was the bag changed?)"
            )));
        };
        let records = match self.decompress(&header, data, pos)? {
            Cow::Borrowed(data) => {
                let start = data.as_ptr() as usize - self.map.as_ptr() as usize;
                Records::InPlace(start..start + data.len())
            }
            Cow::Owned(data) => Records::Decompressed(data),
        };
        Ok(Chunk {
            pos,
            span: pos as usize..end as usize,
            records,
        })
    }
}

impl Store for Ros1Bag {
    fn read(&self, at: Location) -> Result<Cow<'_, [u8]>, IoError> {
        let mut cache = self.cache.lock().unwrap_or_else(|p| p.into_inner());
        if cache.as_ref().is_none_or(|c| c.pos != at.0) {
            let chunk = self.chunk(at.0)?;
            // The pages of the chunk read before are not needed again.
            if let Some(before) = cache.replace(chunk) {
                release(&self.map, before.span);
            }
        }
        let chunk = cache.as_ref().expect("filled above");
        let in_chunk = |e: String| self.invalid(format!("chunk at byte {}: {e}", at.0));
        match &chunk.records {
            Records::InPlace(range) => {
                let (_, data, _) =
                    record_at(&self.map[range.clone()], at.1 as usize).map_err(in_chunk)?;
                Ok(Cow::Borrowed(data))
            }
            Records::Decompressed(records) => {
                let (_, data, _) = record_at(records, at.1 as usize).map_err(in_chunk)?;
                Ok(Cow::Owned(data.to_vec()))
            }
        }
    }
}

/// The most bytes a compressed chunk may announce: rosbag's chunks hold 768 KiB by
/// default, and a chunk is at least one message (a 4K 32-bit depth image is 33 MB).
const MAX_CHUNK_BYTES: usize = 1 << 30;

/// How many times its compressed size a chunk's first buffer may be: the header's size
/// is taken for the buffer only where the data could hold it, so a lying header cannot
/// make a large allocation from a small file.
const MAX_RATIO: usize = 64;

/// Decompresses `decoder` (over `packed` compressed bytes) into at most `size` + 1
/// bytes: a stream that inflates past what its chunk announced stops there (the caller
/// then names the difference) rather than filling memory.
fn inflate(decoder: impl Read, packed: usize, size: usize) -> std::io::Result<Vec<u8>> {
    let mut out = Vec::with_capacity(size.min(packed.saturating_mul(MAX_RATIO)));
    decoder.take(size as u64 + 1).read_to_end(&mut out)?;
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn field(name: &str, value: &[u8]) -> Vec<u8> {
        let mut f = ((name.len() + 1 + value.len()) as u32)
            .to_le_bytes()
            .to_vec();
        f.extend(name.as_bytes());
        f.push(b'=');
        f.extend(value);
        f
    }

    fn record(fields: &[Vec<u8>], data: &[u8]) -> Vec<u8> {
        let header: Vec<u8> = fields.concat();
        let mut r = (header.len() as u32).to_le_bytes().to_vec();
        r.extend(header);
        r.extend((data.len() as u32).to_le_bytes());
        r.extend(data);
        r
    }

    /// A bag with one uncompressed chunk of a connection and `n` `std_msgs/Header`-led
    /// messages, and no index (index_pos 0, as a recorder that died leaves it).
    fn bag(n: u32) -> Vec<u8> {
        let chunk = chunk_records(n);
        with_chunk(b"none", chunk.len() as u32, &chunk)
    }

    /// The records of [`bag`]'s chunk.
    fn chunk_records(n: u32) -> Vec<u8> {
        let mut chunk = record(
            &[
                field("op", &[OP_CONNECTION]),
                field("conn", &0u32.to_le_bytes()),
                field("topic", b"/cam/info"),
            ],
            &[
                field("topic", b"/cam/info"),
                field("type", b"sensor_msgs/CameraInfo"),
            ]
            .concat(),
        );
        for i in 0..n {
            let mut msg = i.to_le_bytes().to_vec(); // seq
            msg.extend((100 + i).to_le_bytes()); // sec
            msg.extend(0u32.to_le_bytes()); // nsec
            msg.extend(0u32.to_le_bytes()); // frame_id ""
            let time = (100u64 + i as u64) | (5u64 << 32);
            chunk.extend(record(
                &[
                    field("op", &[OP_MESSAGE]),
                    field("conn", &0u32.to_le_bytes()),
                    field("time", &time.to_le_bytes()),
                ],
                &msg,
            ));
        }
        chunk
    }

    /// A bag without index holding one chunk of `data`, stored with `compression` and
    /// announcing `size` bytes.
    fn with_chunk(compression: &[u8], size: u32, data: &[u8]) -> Vec<u8> {
        let mut out = MAGIC.to_vec();
        out.extend(record(
            &[
                field("op", &[OP_BAG_HEADER]),
                field("index_pos", &0u64.to_le_bytes()),
            ],
            &[b' '; 16],
        ));
        out.extend(record(
            &[
                field("op", &[OP_CHUNK]),
                field("compression", compression),
                field("size", &size.to_le_bytes()),
            ],
            data,
        ));
        out
    }

    #[test]
    fn a_bag_without_index_is_scanned_and_a_cut_one_keeps_what_is_whole() {
        let dir = std::env::temp_dir().join(format!("dopslam-ros1-scan-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.bag");
        std::fs::write(&path, bag(3)).unwrap();
        let (store, catalog) = Ros1Bag::open(&path).unwrap();
        let topic = &catalog.topics[0];
        assert_eq!(
            (topic.name.as_str(), topic.msg_type.as_str()),
            ("/cam/info", "sensor_msgs/CameraInfo")
        );
        let stamps: Vec<f64> = topic.messages.iter().map(|m| m.stamp).collect();
        assert_eq!(stamps, vec![100.0, 101.0, 102.0]);
        assert!(catalog.warnings.iter().any(|w| w.contains("no index")));
        let third = store.read(topic.messages[2].at).unwrap();
        assert_eq!(&third[4..8], &102u32.to_le_bytes());
        assert!(matches!(third, Cow::Borrowed(_)), "read in place");
        // Its map goes before the file is written again.
        drop(store);
        // Cut in the middle of the only chunk: nothing whole is left, and it says where.
        let full = bag(3);
        std::fs::write(&path, &full[..full.len() - 5]).unwrap();
        let (_, catalog) = Ros1Bag::open(&path).unwrap();
        assert!(catalog.topics.is_empty());
        assert!(
            catalog
                .warnings
                .iter()
                .any(|w| w.contains("cut short") && w.contains("byte")),
            "{:?}",
            catalog.warnings
        );
        std::fs::write(&path, b"#ROSBAG V1.2\nxx").unwrap();
        let error = Ros1Bag::open(&path).err().unwrap().to_string();
        assert!(
            error.contains("version 1.2") && error.contains("2.0"),
            "{error}"
        );
        std::fs::remove_dir_all(dir).unwrap();
    }

    /// [`bag`]'s chunk lz4-compressed, announcing `size` bytes.
    fn lz4_bag(size: u32) -> Vec<u8> {
        let mut encoder = lz4_flex::frame::FrameEncoder::new(Vec::new());
        std::io::Write::write_all(&mut encoder, &chunk_records(3)).unwrap();
        with_chunk(b"lz4", size, &encoder.finish().unwrap())
    }

    /// A damaged length in the first of two chunks: the scan skips to the second, and
    /// says how much it skipped; a bag cut inside its last chunk is still "cut short".
    #[test]
    fn a_damaged_record_length_skips_to_the_next_chunk() {
        let mut bytes = bag(3);
        let first = split_record(&bytes, MAGIC.len()).unwrap().2;
        let second = chunk_records(2);
        bytes.extend(record(
            &[
                field("op", &[OP_CHUNK]),
                field("compression", b"none"),
                field("size", &(second.len() as u32).to_le_bytes()),
            ],
            &second,
        ));
        let header_len = u32::from_le_bytes(bytes[first..first + 4].try_into().unwrap()) as usize;
        let data_len_at = first + 4 + header_len;
        bytes[data_len_at..data_len_at + 4].copy_from_slice(&0x7fff_ffffu32.to_le_bytes());
        let dir = std::env::temp_dir().join(format!("dopslam-ros1-skip-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.bag");
        std::fs::write(&path, &bytes).unwrap();
        let (_, catalog) = Ros1Bag::open(&path).unwrap();
        assert_eq!(catalog.topics[0].messages.len(), 2, "the second chunk's");
        let warnings = catalog.warnings.join("\n");
        assert!(
            warnings.contains(&format!("record at byte {first} is damaged"))
                && warnings.contains("skipped to the next chunk"),
            "{warnings}"
        );
        std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
        let (_, catalog) = Ros1Bag::open(&path).unwrap();
        assert!(catalog.warnings.iter().any(|w| w.contains("cut short")));
        std::fs::remove_dir_all(dir).unwrap();
    }

    #[test]
    fn a_chunk_header_that_lies_about_its_size_is_refused_before_any_allocation() {
        let dir = std::env::temp_dir().join(format!("dopslam-ros1-lz4-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("a.bag");
        // The honest bag reads.
        let real = chunk_records(3).len() as u32;
        std::fs::write(&path, lz4_bag(real)).unwrap();
        assert_eq!(Ros1Bag::open(&path).unwrap().1.topics[0].messages.len(), 3);
        std::fs::write(&path, lz4_bag(u32::MAX)).unwrap();
        let error = Ros1Bag::open(&path).err().unwrap().to_string();
        assert!(error.contains("announces 4294967295 bytes"), "{error}");
        // A size under the cap but far past what the data holds: refused by what
        // decompressed, and the buffer was sized from the data, not the header.
        std::fs::write(&path, lz4_bag(500 << 20)).unwrap();
        let error = Ros1Bag::open(&path).err().unwrap().to_string();
        assert!(
            error.contains(&format!("{real} bytes decompressed, 524288000 announced")),
            "{error}"
        );
        let out = inflate(&b"abc"[..], 3, 500 << 20).unwrap();
        assert_eq!(out.capacity(), 3 * MAX_RATIO);
        // A stream that inflates past its announced size stops one byte after it.
        assert_eq!(inflate(&[7u8; 100][..], 100, 10).unwrap().len(), 11);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
