//! A Matroska (`.mkv`) scan: the tracks, where each frame lies, the attachments and the
//! tags, without reading the frames themselves (they are read one at a time later, at
//! the byte range the scan found).
//!
//! Matroska is EBML: each element is an ID (a variable-length integer, 1-4 bytes, its
//! length marker kept), a size (a variable-length integer, 1-8 bytes: the number of
//! leading zero bits of the first byte, plus one, is its length in bytes; the marker
//! bit is dropped; all ones means "unknown", as a live recorder writes for a cluster),
//! then the payload. A `Segment` holds `Info` (the `TimestampScale`, nanoseconds per
//! tick), `Tracks`, `Attachments`, `Tags` and the `Cluster`s; a cluster holds its
//! `Timestamp` and `SimpleBlock`s (or `BlockGroup`s with a `Block`), each a track
//! number, a signed 16-bit timestamp relative to the cluster's, flags, then one frame.
//! A frame's time is \((t_{cluster} + t_{block}) \cdot \text{TimestampScale}\) ns.
//!
//! Why not the `matroska-demuxer` crate: it hands frames out in file order but neither
//! the attachments (the Azure Kinect's `calibration.json` is one) nor where a frame lies,
//! and the tracking and dense passes read frames by index, so the scan here keeps byte
//! ranges, as the ROS 1 bag reader does.

use std::fs::File;
use std::io::{BufReader, Read};
use std::path::Path;

use crate::io::IoError;

const EBML: u32 = 0x1A45_DFA3;
const SEGMENT: u32 = 0x1853_8067;
const INFO: u32 = 0x1549_A966;
const TIMESTAMP_SCALE: u32 = 0x2A_D7B1;
const TRACKS: u32 = 0x1654_AE6B;
const TRACK_ENTRY: u32 = 0xAE;
const TRACK_NUMBER: u32 = 0xD7;
const TRACK_UID: u32 = 0x73C5;
const TRACK_NAME: u32 = 0x536E;
const CODEC_ID: u32 = 0x86;
const CODEC_PRIVATE: u32 = 0x63A2;
const VIDEO: u32 = 0xE0;
const PIXEL_WIDTH: u32 = 0xB0;
const PIXEL_HEIGHT: u32 = 0xBA;
const COLOUR_SPACE: u32 = 0x2E_B524;
const CONTENT_ENCODINGS: u32 = 0x6D80;
const CLUSTER: u32 = 0x1F43_B675;
const CLUSTER_TIMESTAMP: u32 = 0xE7;
const SIMPLE_BLOCK: u32 = 0xA3;
const BLOCK_GROUP: u32 = 0xA0;
const BLOCK: u32 = 0xA1;
const ATTACHMENTS: u32 = 0x1941_A469;
const ATTACHED_FILE: u32 = 0x61A7;
const FILE_NAME: u32 = 0x466E;
const FILE_DATA: u32 = 0x465C;
const TAGS: u32 = 0x1254_C367;
const TAG: u32 = 0x7373;
const TARGETS: u32 = 0x63C0;
const TAG_TRACK_UID: u32 = 0x63C5;
const SIMPLE_TAG: u32 = 0x67C8;
const TAG_NAME: u32 = 0x45A3;
const TAG_STRING: u32 = 0x4487;

/// The Segment's children: an element of an unknown-size cluster that is one of these
/// ends the cluster.
const TOP_LEVEL: [u32; 7] = [
    CLUSTER,
    INFO,
    TRACKS,
    ATTACHMENTS,
    TAGS,
    0x1C53_BB6B, // Cues
    0x114D_9B74, // SeekHead
];

/// A video track.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Track {
    /// The number blocks name it by.
    pub number: u64,
    /// Its unique id (tags name tracks by it).
    pub uid: u64,
    /// Its name (`COLOR`, `DEPTH`, `IR`, `IMU` in an Azure Kinect recording).
    pub name: String,
    /// `V_MS/VFW/FOURCC`, `V_MJPEG`, ….
    pub codec: String,
    /// The codec's private data (for `V_MS/VFW/FOURCC`, a `BITMAPINFOHEADER`).
    pub codec_private: Vec<u8>,
    /// Pixels.
    pub width: u32,
    /// Pixels.
    pub height: u32,
    /// Whether its frames are stored with a content encoding (compression), not read.
    pub encoded: bool,
    /// A `V_UNCOMPRESSED` track's pixel layout (`ColourSpace`: a FOURCC).
    pub colour_space: Vec<u8>,
}

impl Track {
    /// The pixel layout's code (`MJPG`, `NV12`, `YUY2`, `BGRA`, `b16g`): the
    /// `BITMAPINFOHEADER`'s compression of a `V_MS/VFW/FOURCC` track (as k4arecorder
    /// writes), or the `ColourSpace` of a `V_UNCOMPRESSED` one (as ffmpeg writes raw YUV).
    pub fn fourcc(&self) -> Option<[u8; 4]> {
        let code = match self.codec.as_str() {
            "V_MS/VFW/FOURCC" => self.codec_private.get(16..20),
            "V_UNCOMPRESSED" => self.colour_space.get(..4),
            _ => None,
        };
        code.map(|b| [b[0], b[1], b[2], b[3]])
    }
}

/// One frame: its track, its time in nanoseconds from the segment's start, and where
/// its bytes lie.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Block {
    /// The track number.
    pub track: u64,
    /// \((t_{cluster} + t_{block}) \cdot \text{TimestampScale}\), nanoseconds.
    pub time_ns: i64,
    /// The frame's first byte in the file.
    pub offset: u64,
    /// Its length in bytes.
    pub len: u64,
}

/// What a scan found.
#[derive(Debug, Clone, Default)]
pub struct Scan {
    /// Video and other tracks.
    pub tracks: Vec<Track>,
    /// Every frame, in file order.
    pub blocks: Vec<Block>,
    /// Attached files: name and bytes.
    pub attachments: Vec<(String, Vec<u8>)>,
    /// Simple tags: the track uid they target (0: the whole file), name, value.
    pub tags: Vec<(u64, String, String)>,
    /// Said once to the user: a file cut short, laced or encoded blocks skipped.
    pub warnings: Vec<String>,
}

impl Scan {
    /// The value of tag `name` for the track `uid` (0: a file-wide tag).
    pub fn tag(&self, uid: u64, name: &str) -> Option<&str> {
        self.tags
            .iter()
            .find(|(u, n, _)| *u == uid && n == name)
            .map(|(_, _, v)| v.as_str())
    }
}

/// An element's header: its ID, where its payload starts, and its size (`None`:
/// unknown).
#[derive(Debug, Clone, Copy)]
struct Header {
    id: u32,
    start: u64,
    size: Option<u64>,
}

/// Reads EBML headers and payloads from a file, knowing its length.
struct Reader {
    file: BufReader<File>,
    pos: u64,
    len: u64,
}

/// Reads an EBML variable-length integer from `bytes`: its value (with or without the
/// length marker) and length; `None` when the first byte is 0 or the bytes end first.
fn vint(bytes: &[u8], keep_marker: bool) -> Option<(u64, usize)> {
    let first = *bytes.first()?;
    let len = first.leading_zeros() as usize + 1;
    if len > 8 || bytes.len() < len {
        return None;
    }
    let mut value = if keep_marker {
        first as u64
    } else {
        (first as u64) & (0xFF >> len)
    };
    for b in &bytes[1..len] {
        value = (value << 8) | *b as u64;
    }
    Some((value, len))
}

impl Reader {
    fn at(&mut self, pos: u64) -> std::io::Result<()> {
        if pos != self.pos {
            self.file.seek_relative(pos as i64 - self.pos as i64)?;
            self.pos = pos;
        }
        Ok(())
    }

    fn read(&mut self, n: usize) -> std::io::Result<Vec<u8>> {
        let mut buf = vec![0; n];
        self.file.read_exact(&mut buf)?;
        self.pos += n as u64;
        Ok(buf)
    }

    /// The header at `pos`, or `None` where the file ends (or is cut) inside it.
    fn header(&mut self, pos: u64) -> std::io::Result<Option<Header>> {
        let available = (self.len.saturating_sub(pos)).min(12) as usize;
        self.at(pos)?;
        let bytes = self.read(available)?;
        let Some((id, id_len)) = vint(&bytes, true).filter(|(_, l)| *l <= 4) else {
            return Ok(None);
        };
        let Some((size, size_len)) = vint(&bytes[id_len..], false) else {
            return Ok(None);
        };
        let unknown = size == (1u64 << (7 * size_len)) - 1;
        Ok(Some(Header {
            id: id as u32,
            start: pos + (id_len + size_len) as u64,
            size: (!unknown).then_some(size),
        }))
    }

    /// The payload of a known-size element (read whole: small elements only); an error
    /// when it claims to reach past the file's end or more than 256 MiB (a damaged size
    /// must not become an allocation).
    fn payload(&mut self, h: &Header) -> std::io::Result<Vec<u8>> {
        let size = h.size.unwrap_or(0);
        if size > self.len.saturating_sub(h.start) || size > 256 << 20 {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!(
                    "the element at byte {} claims {size} bytes, past the end of the file or too large to be one",
                    h.start
                ),
            ));
        }
        self.at(h.start)?;
        self.read(size as usize)
    }

    fn unsigned(&mut self, h: &Header) -> std::io::Result<u64> {
        Ok(self
            .payload(h)?
            .iter()
            .take(8)
            .fold(0u64, |v, b| (v << 8) | *b as u64))
    }

    fn text(&mut self, h: &Header) -> std::io::Result<String> {
        let bytes = self.payload(h)?;
        let end = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
        Ok(String::from_utf8_lossy(&bytes[..end]).into_owned())
    }

    /// The children of the element `parent` (known size), as headers; stops quietly
    /// where the file is cut.
    fn children(&mut self, parent: &Header) -> std::io::Result<Vec<Header>> {
        let end = parent.start + parent.size.unwrap_or(0);
        let mut out = Vec::new();
        let mut pos = parent.start;
        while pos < end.min(self.len) {
            let Some(h) = self.header(pos)? else { break };
            let Some(size) = h.size else { break };
            out.push(h);
            pos = h.start + size;
        }
        Ok(out)
    }
}

/// Scans the Matroska file at `path`.
pub fn scan(path: &Path) -> Result<Scan, IoError> {
    let file = File::open(path).map_err(|e| IoError::read(path, e))?;
    let len = file.metadata().map_err(|e| IoError::read(path, e))?.len();
    let mut reader = Reader {
        file: BufReader::with_capacity(1 << 16, file),
        pos: 0,
        len,
    };
    scan_file(&mut reader, path)
}

fn scan_file(r: &mut Reader, path: &Path) -> Result<Scan, IoError> {
    let io = |e| IoError::read(path, e);
    let ebml_end = match r.header(0).map_err(io)? {
        Some(Header {
            id: EBML,
            start,
            size: Some(size),
        }) => start + size,
        _ => {
            return Err(IoError::invalid(
                path,
                "not a Matroska file (no EBML header)",
            ))
        }
    };
    let Some(segment) = r.header(ebml_end).map_err(io)?.filter(|h| h.id == SEGMENT) else {
        return Err(IoError::invalid(path, "a Matroska file without a Segment"));
    };
    let mut scan = Scan::default();
    let mut scale = 1_000_000u64;
    let end = segment.size.map_or(r.len, |s| segment.start + s);
    if end > r.len {
        scan.warnings.push(format!(
            "the file is cut short: its segment ends at byte {end} but the file has {} bytes; the frames before the cut are read",
            r.len
        ));
    }
    let mut pos = segment.start;
    while pos < end.min(r.len) {
        let Some(h) = r.header(pos).map_err(io)? else {
            scan.warnings.push(format!(
                "no readable element at byte {pos} of {}: what follows is not read",
                r.len
            ));
            break;
        };
        pos = top_level(r, &h, &mut scale, &mut scan).map_err(io)?;
    }
    Ok(scan)
}

/// Reads one child of the Segment; returns where the next one starts (the file's end
/// after one of unknown size that is not a cluster).
fn top_level(r: &mut Reader, h: &Header, scale: &mut u64, scan: &mut Scan) -> std::io::Result<u64> {
    match h.id {
        INFO => {
            for c in r.children(h)? {
                if c.id == TIMESTAMP_SCALE {
                    *scale = r.unsigned(&c)?.max(1);
                }
            }
        }
        TRACKS => scan.tracks = tracks(r, h)?,
        ATTACHMENTS => attachments(r, h, scan)?,
        TAGS => tags(r, h, scan)?,
        CLUSTER => return cluster(r, h, *scale, scan),
        _ => {}
    }
    Ok(h.size.map_or(r.len, |size| h.start + size))
}

fn tracks(r: &mut Reader, h: &Header) -> std::io::Result<Vec<Track>> {
    let mut out = Vec::new();
    for entry in r.children(h)?.into_iter().filter(|c| c.id == TRACK_ENTRY) {
        let mut track = Track::default();
        for c in r.children(&entry)? {
            match c.id {
                TRACK_NUMBER => track.number = r.unsigned(&c)?,
                TRACK_UID => track.uid = r.unsigned(&c)?,
                TRACK_NAME => track.name = r.text(&c)?,
                CODEC_ID => track.codec = r.text(&c)?,
                CODEC_PRIVATE => track.codec_private = r.payload(&c)?,
                CONTENT_ENCODINGS => track.encoded = true,
                VIDEO => {
                    for v in r.children(&c)? {
                        match v.id {
                            PIXEL_WIDTH => track.width = r.unsigned(&v)? as u32,
                            PIXEL_HEIGHT => track.height = r.unsigned(&v)? as u32,
                            COLOUR_SPACE => track.colour_space = r.payload(&v)?,
                            _ => {}
                        }
                    }
                }
                _ => {}
            }
        }
        out.push(track);
    }
    Ok(out)
}

fn attachments(r: &mut Reader, h: &Header, scan: &mut Scan) -> std::io::Result<()> {
    for file in r.children(h)?.into_iter().filter(|c| c.id == ATTACHED_FILE) {
        let (mut name, mut data) = (String::new(), Vec::new());
        for c in r.children(&file)? {
            match c.id {
                FILE_NAME => name = r.text(&c)?,
                FILE_DATA => data = r.payload(&c)?,
                _ => {}
            }
        }
        scan.attachments.push((name, data));
    }
    Ok(())
}

fn tags(r: &mut Reader, h: &Header, scan: &mut Scan) -> std::io::Result<()> {
    for tag in r.children(h)?.into_iter().filter(|c| c.id == TAG) {
        let mut uid = 0;
        let mut simple = Vec::new();
        for c in r.children(&tag)? {
            match c.id {
                TARGETS => {
                    for t in r.children(&c)? {
                        if t.id == TAG_TRACK_UID {
                            uid = r.unsigned(&t)?;
                        }
                    }
                }
                SIMPLE_TAG => {
                    let (mut name, mut value) = (String::new(), String::new());
                    for s in r.children(&c)? {
                        match s.id {
                            TAG_NAME => name = r.text(&s)?,
                            TAG_STRING => value = r.text(&s)?,
                            _ => {}
                        }
                    }
                    simple.push((name, value));
                }
                _ => {}
            }
        }
        scan.tags
            .extend(simple.into_iter().map(|(n, v)| (uid, n, v)));
    }
    Ok(())
}

/// Scans one cluster's blocks; returns where the next top-level element starts.
fn cluster(r: &mut Reader, h: &Header, scale: u64, scan: &mut Scan) -> std::io::Result<u64> {
    let end = h.size.map_or(u64::MAX, |s| h.start + s);
    let mut cluster_time = 0i64;
    let mut pos = h.start;
    while pos < end.min(r.len) {
        let Some(c) = r.header(pos)? else {
            return Ok(r.len);
        };
        if h.size.is_none() && TOP_LEVEL.contains(&c.id) {
            return Ok(pos);
        }
        let Some(size) = c.size else {
            return Ok(r.len);
        };
        let block_end = c.start + size;
        if block_end > r.len {
            scan.warnings.push(format!(
                "the file is cut short inside a cluster at byte {pos} (its next element ends at byte {block_end}, the file has {} bytes); the frames before the cut are read",
                r.len
            ));
            return Ok(r.len);
        }
        match c.id {
            CLUSTER_TIMESTAMP => cluster_time = r.unsigned(&c)? as i64,
            SIMPLE_BLOCK => block(r, &c, cluster_time, scale, scan)?,
            BLOCK_GROUP => {
                for b in r.children(&c)?.into_iter().filter(|b| b.id == BLOCK) {
                    block(r, &b, cluster_time, scale, scan)?;
                }
            }
            _ => {}
        }
        pos = block_end;
    }
    Ok(end.min(r.len))
}

/// Records a `SimpleBlock` or `Block`: its track, time and frame bytes' range.
fn block(
    r: &mut Reader,
    h: &Header,
    cluster_time: i64,
    scale: u64,
    scan: &mut Scan,
) -> std::io::Result<()> {
    let size = h.size.unwrap_or(0);
    r.at(h.start)?;
    let head = r.read(size.min(12) as usize)?;
    let Some((track, n)) = vint(&head, false) else {
        return Ok(());
    };
    let Some(rest) = head.get(n..n + 3) else {
        return Ok(());
    };
    let relative = i16::from_be_bytes([rest[0], rest[1]]) as i64;
    if rest[2] & 0x06 != 0 {
        let warning = format!("track {track}: laced blocks are not read");
        if !scan.warnings.contains(&warning) {
            scan.warnings.push(warning);
        }
        return Ok(());
    }
    let header_len = (n + 3) as u64;
    scan.blocks.push(Block {
        track,
        time_ns: (cluster_time + relative).saturating_mul(scale as i64),
        offset: h.start + header_len,
        len: size.saturating_sub(header_len),
    });
    Ok(())
}

/// Reads the bytes of `block` from `file`.
pub fn read_block(file: &File, block: &Block) -> std::io::Result<Vec<u8>> {
    let mut buf = vec![0; block.len as usize];
    read_block_into(file, block, &mut buf)?;
    Ok(buf)
}

/// Reads the bytes of `block` from `file` into `buf`, which has its length.
pub fn read_block_into(file: &File, block: &Block, buf: &mut [u8]) -> std::io::Result<()> {
    use std::os::unix::fs::FileExt;
    file.read_exact_at(buf, block.offset)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn variable_length_integers_read_as_ebml_defines_them() {
        // 0x81: one byte, value 1; 0x4001: two bytes, value 1; an ID keeps its marker.
        assert_eq!(vint(&[0x81], false), Some((1, 1)));
        assert_eq!(vint(&[0x40, 0x01], false), Some((1, 2)));
        assert_eq!(
            vint(&[0x1A, 0x45, 0xDF, 0xA3], true),
            Some((EBML as u64, 4))
        );
        assert_eq!(vint(&[0x00], false), None);
        assert_eq!(vint(&[0x40], false), None, "cut inside the integer");
        // All ones is "unknown size".
        assert_eq!(vint(&[0xFF], false), Some((0x7F, 1)));
    }
}
