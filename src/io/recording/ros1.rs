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
//! The `rosbag` crate reads the same records, but slices its memory map with the
//! header's `index_pos` unchecked: a bag without an index or cut short makes it panic,
//! and it does not expose where a chunk starts, which random access needs.

use std::fs::File;
use std::io::Read;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use super::{Catalog, Location, Store};
use crate::io::IoError;

const MAGIC: &[u8] = b"#ROSBAG V2.0\n";
const OP_MESSAGE: u8 = 0x02;
const OP_BAG_HEADER: u8 = 0x03;
const OP_CHUNK: u8 = 0x05;
const OP_CONNECTION: u8 = 0x07;

/// An opened ROS 1 bag: its file and its catalogue of messages.
pub struct Ros1Bag {
    path: PathBuf,
    file: File,
    /// The file's length when it was opened: records past it are cut off.
    len: u64,
    /// The chunk last decompressed (the next frame is almost always in it).
    cache: Mutex<Option<(u64, Arc<Vec<u8>>)>>,
}

/// A record read from the file: its header, its data when asked for, and the
/// position after it.
struct FileRecord {
    header: Header,
    data: Option<Vec<u8>>,
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

/// One record inside a decompressed chunk: its header, its data and where it ends.
fn record_at(chunk: &[u8], offset: usize) -> Result<(Header, &[u8], usize), String> {
    let cut = || format!("a record at offset {offset} of a chunk runs past the chunk's end");
    let rest = chunk.get(offset..).ok_or_else(cut)?;
    let (header_len, rest) = split_u32(rest).ok_or_else(cut)?;
    let header = rest.get(..header_len as usize).ok_or_else(cut)?;
    let (data_len, rest) = split_u32(&rest[header_len as usize..]).ok_or_else(cut)?;
    let data = rest.get(..data_len as usize).ok_or_else(cut)?;
    let end = offset + 8 + header_len as usize + data_len as usize;
    Ok((Header::parse(header)?, data, end))
}

impl Ros1Bag {
    /// Opens a bag and scans its chunks into a catalogue.
    pub fn open(path: &Path) -> Result<(Self, Catalog), IoError> {
        let read_error = |source| IoError::Read {
            path: path.to_path_buf(),
            source,
        };
        let mut file = File::open(path).map_err(read_error)?;
        let mut magic = [0u8; 13];
        let n = file.read(&mut magic).map_err(read_error)?;
        if &magic[..n] != MAGIC {
            let version = if magic.starts_with(b"#ROSBAG V") {
                format!(
                    "a ROS bag of version {}",
                    String::from_utf8_lossy(&magic[9..n]).trim()
                )
            } else {
                "not a ROS bag".to_owned()
            };
            return Err(IoError::invalid(
                path,
                format!("{version}: only format 2.0 (\"#ROSBAG V2.0\") is read; `rosbag fix` converts older bags"),
            ));
        }
        let len = file.metadata().map_err(read_error)?.len();
        let bag = Self {
            path: path.to_path_buf(),
            file,
            len,
            cache: Mutex::new(None),
        };
        let catalog = bag.scan()?;
        Ok((bag, catalog))
    }

    fn invalid(&self, message: impl Into<String>) -> IoError {
        IoError::invalid(&self.path, message)
    }

    /// Reads the record at `pos` of the file: its header, and its data (when the
    /// header's op is in `want_data`), and the position after it. `None` when the
    /// record is cut by the end of the file.
    fn file_record(&self, pos: u64, want_data: &[u8]) -> Result<Option<FileRecord>, IoError> {
        let len = self.len;
        let read = |at: u64, n: usize| -> Result<Option<Vec<u8>>, IoError> {
            if at + n as u64 > len {
                return Ok(None);
            }
            let mut buf = vec![0u8; n];
            self.file
                .read_exact_at(&mut buf, at)
                .map_err(|source| IoError::Read {
                    path: self.path.clone(),
                    source,
                })?;
            Ok(Some(buf))
        };
        let Some(n) = read(pos, 4)? else {
            return Ok(None);
        };
        let header_len = u32::from_le_bytes(n.try_into().expect("4 bytes")) as usize;
        let Some(header) = read(pos + 4, header_len)? else {
            return Ok(None);
        };
        let header =
            Header::parse(&header).map_err(|e| self.invalid(format!("offset {pos}: {e}")))?;
        let data_at = pos + 4 + header_len as u64;
        let Some(n) = read(data_at, 4)? else {
            return Ok(None);
        };
        let data_len = u32::from_le_bytes(n.try_into().expect("4 bytes")) as usize;
        let end = data_at + 4 + data_len as u64;
        if end > len {
            return Ok(None);
        }
        let op = header
            .op()
            .map_err(|e| self.invalid(format!("offset {pos}: {e}")))?;
        let data = if want_data.contains(&op) {
            read(data_at + 4, data_len)?
        } else {
            None
        };
        Ok(Some(FileRecord { header, data, end }))
    }

    /// Scans every chunk once: the connections, and each message's place and stamp.
    fn scan(&self) -> Result<Catalog, IoError> {
        let len = self.len;
        let mut catalog = Catalog::new(super::Wire::Ros1);
        let mut pos = MAGIC.len() as u64;
        let mut index_pos = None;
        while pos < len {
            let Some(FileRecord { header, data, end }) = self.file_record(pos, &[OP_CHUNK])? else {
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
                    let chunk = self.decompress(&header, data.expect("chunk data read"), pos)?;
                    self.scan_chunk(&chunk, pos, &mut catalog)?;
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

    fn decompress(&self, header: &Header, data: Vec<u8>, pos: u64) -> Result<Vec<u8>, IoError> {
        let at = |e: String| self.invalid(format!("chunk at byte {pos}: {e}"));
        let compression = header.string("compression").map_err(at)?;
        let size = header.u32("size").map_err(at)? as usize;
        let out = match compression.as_str() {
            "none" => data,
            "bz2" => {
                let mut out = Vec::with_capacity(size);
                bzip2::read::BzDecoder::new(data.as_slice())
                    .read_to_end(&mut out)
                    .map_err(|e| at(format!("bz2: {e}")))?;
                out
            }
            "lz4" => {
                let mut out = Vec::with_capacity(size);
                lz4_flex::frame::FrameDecoder::new(data.as_slice())
                    .read_to_end(&mut out)
                    .map_err(|e| at(format!("lz4: {e}")))?;
                out
            }
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

    fn chunk(&self, pos: u64) -> Result<Arc<Vec<u8>>, IoError> {
        let mut cache = self.cache.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((at, chunk)) = cache.as_ref() {
            if *at == pos {
                return Ok(chunk.clone());
            }
        }
        let Some(FileRecord {
            header,
            data: Some(data),
            ..
        }) = self.file_record(pos, &[OP_CHUNK])?
        else {
            return Err(self.invalid(format!(
                "no chunk at byte {pos} any more (was the bag changed?)"
            )));
        };
        let chunk = Arc::new(self.decompress(&header, data, pos)?);
        *cache = Some((pos, chunk.clone()));
        Ok(chunk)
    }
}

impl Store for Ros1Bag {
    fn read(&self, at: Location) -> Result<Vec<u8>, IoError> {
        let chunk = self.chunk(at.0)?;
        let (_, data, _) = record_at(&chunk, at.1 as usize)
            .map_err(|e| self.invalid(format!("chunk at byte {}: {e}", at.0)))?;
        Ok(data.to_vec())
    }
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
                field("compression", b"none"),
                field("size", &(chunk.len() as u32).to_le_bytes()),
            ],
            &chunk,
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
}
