//! ROS 2 bags: a folder with `metadata.yaml` and its storage files, SQLite 3 (`.db3`:
//! tables `topics` and `messages`, what `ros2 bag record` wrote until Iron and current
//! librealsense writes) or MCAP (`.mcap`, read with the `mcap` crate); messages are
//! CDR. A single `.db3` or `.mcap` file opens the same way.
//!
//! `metadata.yaml` lists the files (`relative_file_paths`: a bag split by size or
//! duration has several, read as one) and the compression: `compression_mode: file`
//! compresses each storage file whole (`.db3.zstd`: decompressed to a temporary file,
//! removed as soon as it is open), `message` each message's bytes (decompressed
//! as they are read; the scan decompresses only a message's first bytes, its header).

use std::borrow::Cow;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use super::mapped::{self, release};
use super::mcap_chunks::{check_chunk_index, check_summary, uncompressed_messages, Span};
use super::{Catalog, Location, Store, Wire};
use crate::io::IoError;

/// How rosbag2 compressed a bag (`compression_mode` with `compression_format: zstd`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Compression {
    None,
    File,
    Message,
}

/// The storage files and compression `metadata.yaml` gives.
fn metadata(dir: &Path) -> Result<(Vec<PathBuf>, Compression), IoError> {
    let path = dir.join("metadata.yaml");
    let text = std::fs::read_to_string(&path).map_err(|e| IoError::read(&path, e))?;
    let bad = |m: String| IoError::invalid(&path, m);
    let docs = yaml_rust2::YamlLoader::load_from_str(&text).map_err(|e| bad(e.to_string()))?;
    let info = &docs.first().ok_or_else(|| bad("empty".into()))?["rosbag2_bagfile_information"];
    if info.is_badvalue() {
        return Err(bad(
            "no rosbag2_bagfile_information: not a ROS 2 bag's metadata".into(),
        ));
    }
    let format = info["compression_format"].as_str().unwrap_or("");
    let mode = info["compression_mode"]
        .as_str()
        .unwrap_or("")
        .to_ascii_lowercase();
    let compression = match (format, mode.as_str()) {
        ("", _) | (_, "" | "none") => Compression::None,
        ("zstd", "file") => Compression::File,
        ("zstd", "message") => Compression::Message,
        _ => {
            return Err(bad(format!(
                "compression {format:?} by {mode:?} is not read (zstd by file or message)"
            )))
        }
    };
    let files = match info["relative_file_paths"].as_vec() {
        Some(list) => list
            .iter()
            .map(|f| f.as_str().map(|f| dir.join(f)))
            .collect::<Option<Vec<_>>>()
            .ok_or_else(|| {
                bad("relative_file_paths holds something other than file names".into())
            })?,
        None => Vec::new(),
    };
    Ok((files, compression))
}

/// Whether `dir` holds a `.db3` or `.mcap` file.
pub fn has_storage_files(dir: &Path) -> bool {
    listed_files(dir).is_ok_and(|files| !files.is_empty())
}

/// The storage files of a bag folder whose metadata lists none: its `.db3` or `.mcap`.
fn listed_files(dir: &Path) -> Result<Vec<PathBuf>, IoError> {
    let listing = std::fs::read_dir(dir).map_err(|e| IoError::read(dir, e))?;
    let mut files: Vec<_> = listing
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("db3" | "mcap")))
        .collect();
    files.sort();
    Ok(files)
}

/// Opens a ROS 2 bag folder through its storage files (several: read as one).
pub fn open_bag_folder(dir: &Path) -> Result<(Box<dyn Store>, Catalog), IoError> {
    let described = dir.join("metadata.yaml").is_file();
    let (mut files, compression) = if described {
        metadata(dir)?
    } else {
        (Vec::new(), Compression::None)
    };
    if files.is_empty() {
        files = listed_files(dir)?;
    }
    if files.is_empty() {
        return Err(IoError::invalid(dir, "a ROS 2 bag folder without storage files (metadata.yaml lists none, and there is no .db3 or .mcap)"));
    }
    let mut parts = Vec::with_capacity(files.len());
    for file in &files {
        crate::io::errors::check_exists(file, "storage file of the bag")?;
        parts.push(open_part(file, compression)?);
    }
    if !described {
        parts[0].1.warnings.push(format!(
            "{}: no metadata.yaml; its storage files are read as the bag, uncompressed",
            dir.display()
        ));
    }
    if parts.len() == 1 {
        return Ok(parts.pop().expect("one part"));
    }
    let mut stores = Vec::with_capacity(parts.len());
    let mut catalog: Option<Catalog> = None;
    for (index, (store, part)) in parts.into_iter().enumerate() {
        stores.push(store);
        match &mut catalog {
            None => catalog = Some(part.in_part(index)),
            Some(all) => all.absorb(part.in_part(index)),
        }
    }
    let mut catalog = catalog.expect("several parts");
    catalog.warnings.push(format!(
        "the bag is split into {} files, read as one",
        stores.len()
    ));
    Ok((Box::new(Parts(stores)), catalog))
}

/// Opens one storage file of a bag, decompressing it as the bag says.
fn open_part(file: &Path, compression: Compression) -> Result<(Box<dyn Store>, Catalog), IoError> {
    match compression {
        Compression::File => {
            let copy = Unpacked::decompress(file)?;
            let opened = open_file(&copy.path, Compression::None);
            let copy_path = copy.path.clone();
            // Removed as soon as it is open (the store reads the open file: SQLite's
            // connection, the MCAP map), so that a run killed later leaves nothing.
            drop(copy);
            let (store, mut catalog) = opened.map_err(|e| as_original(e, &copy_path, file))?;
            catalog.warnings.push(format!(
                "{} is compressed whole: decompressed into the temporary folder for reading (that copy is removed once open)",
                file.display(),
            ));
            let store = WithCopy {
                store,
                copy: copy_path,
                file: file.to_path_buf(),
            };
            Ok((Box::new(store), catalog))
        }
        _ => open_file(file, compression),
    }
}

fn open_file(file: &Path, compression: Compression) -> Result<(Box<dyn Store>, Catalog), IoError> {
    match file.extension().and_then(|e| e.to_str()) {
        Some("db3") => open_sqlite_with(file, compression),
        Some("mcap") => open_mcap_with(file, compression),
        _ => Err(IoError::invalid(
            file,
            "a bag's storage file that is neither .db3 nor .mcap",
        )),
    }
}

/// The storage files of a split bag as one store: a message of file `k` lies at
/// [`Location`] `(a, b | k << 48)`.
struct Parts(Vec<Box<dyn Store>>);

const PART_SHIFT: u32 = 48;

impl Catalog {
    /// The catalog of the `index`-th file of a split bag: its locations marked with it.
    fn in_part(mut self, index: usize) -> Self {
        for topic in &mut self.topics {
            for m in &mut topic.messages {
                m.at = Location(m.at.0, m.at.1 | ((index as u64) << PART_SHIFT));
            }
        }
        self
    }

    /// Adds the topics and messages of another file of the same bag.
    fn absorb(&mut self, other: Catalog) {
        for (index, count) in other.undecodable {
            let name = &other.topics[index].name;
            let mine = match self.topics.iter().position(|t| t.name == *name) {
                Some(i) => i,
                None => {
                    self.topics.push(super::Topic {
                        messages: Vec::new(),
                        ..other.topics[index].clone()
                    });
                    self.topics.len() - 1
                }
            };
            *self.undecodable.entry(mine).or_default() += count;
        }
        for topic in other.topics {
            match self.topics.iter_mut().find(|t| t.name == topic.name) {
                Some(t) => t.messages.extend(topic.messages),
                None => self.topics.push(topic),
            }
        }
        self.warnings.extend(other.warnings);
    }
}

impl Store for Parts {
    fn read(&self, at: Location) -> Result<Cow<'_, [u8]>, IoError> {
        let part = (at.1 >> PART_SHIFT) as usize;
        let inner = Location(at.0, at.1 & ((1u64 << PART_SHIFT) - 1));
        self.0[part].read(inner)
    }
}

/// A storage file compressed whole, decompressed into the temporary folder; removed
/// when dropped (a store opened on it reads on from the open file).
struct Unpacked {
    path: PathBuf,
}

impl Unpacked {
    fn decompress(file: &Path) -> Result<Self, IoError> {
        let name = file
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let Some(inner) = name.strip_suffix(".zstd") else {
            return Err(IoError::invalid(
                file,
                "the bag says its files are compressed, but this one does not end in .zstd",
            ));
        };
        let input = std::fs::File::open(file).map_err(|e| IoError::read(file, e))?;
        // A name of our own, created new (a file already there is never written over);
        // only once it is ours does dropping the copy remove it.
        static COPIES: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let (copy, mut output) = loop {
            let n = COPIES.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let path =
                std::env::temp_dir().join(format!("dopslam-{}-{n}-{inner}", std::process::id()));
            match std::fs::OpenOptions::new()
                .write(true)
                .create_new(true)
                .open(&path)
            {
                Ok(output) => break (Self { path }, output),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(source) => return Err(IoError::Write { path, source }),
            }
        };
        zstd::stream::copy_decode(input, &mut output)
            .map_err(|e| IoError::invalid(file, format!("not readable zstd data: {e}")))?;
        Ok(copy)
    }
}

impl Drop for Unpacked {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

/// A store read from a decompressed copy of `file` (removed from its folder once open,
/// at `copy`): its errors name the user's file.
struct WithCopy {
    store: Box<dyn Store>,
    copy: PathBuf,
    file: PathBuf,
}

impl Store for WithCopy {
    fn read(&self, at: Location) -> Result<Cow<'_, [u8]>, IoError> {
        self.store
            .read(at)
            .map_err(|e| as_original(e, &self.copy, &self.file))
    }
}

/// An error about the decompressed `copy` of `file`, as one about `file` (the copy's
/// temporary name means nothing to the user).
fn as_original(error: IoError, copy: &Path, file: &Path) -> IoError {
    match error {
        IoError::Invalid { path, message } if path == copy => IoError::Invalid {
            path: file.to_path_buf(),
            message: format!("{message} (in its decompressed content)"),
        },
        IoError::Read { path, source } if path == copy => IoError::Read {
            path: file.to_path_buf(),
            source,
        },
        other => other,
    }
}

/// A store whose messages are each zstd-compressed.
struct Decompressing {
    path: PathBuf,
    store: Box<dyn Store>,
}

impl Store for Decompressing {
    fn read(&self, at: Location) -> Result<Cow<'_, [u8]>, IoError> {
        let data = self.store.read(at)?;
        decompress_message(&data).map(Cow::Owned).map_err(|e| {
            IoError::invalid(
                &self.path,
                format!("message {at:?}: not readable zstd data: {e}"),
            )
        })
    }
}

/// The largest size a message's zstd frame may announce to be decompressed into one
/// buffer of that size; a frame that announces more (or no size) is decompressed as a
/// stream.
const MAX_ANNOUNCED_BYTES: u64 = 1 << 30;

/// One zstd-compressed message: into one buffer of the size its frame announces
/// (rosbag2's compressor writes it), not a stream's growing buffer, which copies the
/// image each time it grows.
fn decompress_message(data: &[u8]) -> std::io::Result<Vec<u8>> {
    match zstd::zstd_safe::get_frame_content_size(data) {
        Ok(Some(size)) if size <= MAX_ANNOUNCED_BYTES => {
            zstd::bulk::decompress(data, size as usize)
        }
        _ => zstd::decode_all(data),
    }
}

/// How many bytes of a message the scan looks at: its header, for the stamp.
const HEAD_BYTES: usize = 512;

/// The `data` of the `messages` row `rowid`, as an incremental blob: SQLite reads the
/// pages of the part read only (a query for the column reads all of an image's pages,
/// then copies it once more into the result).
fn open_blob(
    connection: &rusqlite::Connection,
    rowid: i64,
) -> rusqlite::Result<rusqlite::blob::Blob<'_>> {
    connection.blob_open(rusqlite::MAIN_DB, c"messages", c"data", rowid, true)
}

/// The first [`HEAD_BYTES`] of message `rowid`, or all of it with `whole` (a frame
/// read, or a compressed message, whose first block may be long); `blob`, once open,
/// is reopened on the row.
fn message_bytes<'c>(
    connection: &'c rusqlite::Connection,
    blob: &mut Option<rusqlite::blob::Blob<'c>>,
    rowid: i64,
    whole: bool,
) -> rusqlite::Result<Vec<u8>> {
    let blob = match blob {
        Some(open) => {
            open.reopen(rowid)?;
            open
        }
        None => blob.insert(open_blob(connection, rowid)?),
    };
    let length = if whole {
        blob.len()
    } else {
        blob.len().min(HEAD_BYTES)
    };
    let mut data = vec![0; length];
    blob.read_at_exact(&mut data, 0)?;
    Ok(data)
}

/// The first bytes of a message (enough for its header), decompressed when the bag
/// compresses messages; `None` when they do not decompress.
fn head(data: &[u8], compression: Compression) -> Option<std::borrow::Cow<'_, [u8]>> {
    if compression != Compression::Message {
        return Some(std::borrow::Cow::Borrowed(data));
    }
    let mut out = Vec::with_capacity(HEAD_BYTES);
    zstd::stream::read::Decoder::new(data)
        .ok()?
        .take(HEAD_BYTES as u64)
        .read_to_end(&mut out)
        .ok()?;
    Some(std::borrow::Cow::Owned(out))
}

/// `store` with its messages decompressed when the bag compresses them.
fn decompressed(path: &Path, store: Box<dyn Store>, compression: Compression) -> Box<dyn Store> {
    if compression == Compression::Message {
        Box::new(Decompressing {
            path: path.to_path_buf(),
            store,
        })
    } else {
        store
    }
}

/// Opens `path` read-only and immutable (SQLite's `immutable=1` URI): SQLite then takes
/// no lock and never creates the `-shm` and `-wal` files beside a bag in WAL mode
/// (rosbag2's old default, its `resilient` preset today), which a plain read-only open
/// of such a bag does, and which fails in a folder the user cannot write.
fn open_immutable(path: &Path) -> rusqlite::Result<rusqlite::Connection> {
    let flags = rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY
        | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX
        | rusqlite::OpenFlags::SQLITE_OPEN_URI;
    rusqlite::Connection::open_with_flags(sqlite_uri(path), flags)
}

/// The `file:` URI of `path` with `immutable=1`; every byte but the unreserved ones and
/// `/` percent-encoded (a `?`, `#` or `%` in a name would otherwise end or change it).
fn sqlite_uri(path: &Path) -> String {
    use std::os::unix::ffi::OsStrExt;
    let mut uri = String::from("file:");
    for &b in path.as_os_str().as_bytes() {
        match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'/' | b'.' | b'_' | b'-' | b'~' => {
                uri.push(b as char)
            }
            _ => uri.push_str(&format!("%{b:02X}")),
        }
    }
    uri.push_str("?immutable=1");
    uri
}

/// A warning when a `-wal` journal with content lies beside `path`: its writer did not
/// close the bag, and the messages only the journal holds are not read (an immutable
/// open reads the database file alone, and folding the journal in would write beside
/// the input).
fn unread_journal(path: &Path) -> Option<String> {
    let mut name = path.as_os_str().to_owned();
    name.push("-wal");
    let journal = PathBuf::from(name);
    let size = std::fs::metadata(&journal).ok()?.len();
    (size > 0).then(|| {
        format!(
            "{} ({size} bytes) lies beside the bag: its recorder did not close it, and the messages only that journal holds are not read (open a copy of both files once with `sqlite3 COPY.db3 'PRAGMA wal_checkpoint'` to fold them in)",
            journal.display()
        )
    })
}

/// A ROS 2 SQLite bag, opened read-only.
struct Sqlite {
    path: std::path::PathBuf,
    connection: Mutex<rusqlite::Connection>,
}

/// Opens a `.db3` file.
pub fn open_sqlite(path: &Path) -> Result<(Box<dyn Store>, Catalog), IoError> {
    open_sqlite_with(path, Compression::None)
}

fn open_sqlite_with(
    path: &Path,
    compression: Compression,
) -> Result<(Box<dyn Store>, Catalog), IoError> {
    let bad = |e: rusqlite::Error| {
        IoError::invalid(path, format!("not a readable ROS 2 SQLite bag: {e}"))
    };
    let connection = open_immutable(path).map_err(bad)?;
    let mut catalog = Catalog::new(Wire::Cdr);
    if let Some(note) = unread_journal(path) {
        catalog.warnings.push(note);
    }
    {
        let mut topics = connection
            .prepare("SELECT id, name, type, serialization_format FROM topics")
            .map_err(bad)?;
        let mut rows = topics.query([]).map_err(bad)?;
        while let Some(row) = rows.next().map_err(bad)? {
            let (id, name, msg_type, format): (i64, String, String, String) = (
                row.get(0).map_err(bad)?,
                row.get(1).map_err(bad)?,
                row.get(2).map_err(bad)?,
                row.get(3).map_err(bad)?,
            );
            if format != "cdr" {
                catalog.warnings.push(format!(
                    "topic {name} is serialised as {format:?}, not CDR: skipped"
                ));
                continue;
            }
            catalog.add_topic(id as u64, &name, &msg_type);
        }
        let mut messages = connection
            .prepare("SELECT rowid, topic_id, timestamp FROM messages ORDER BY timestamp, id")
            .map_err(bad)?;
        let mut rows = messages.query([]).map_err(bad)?;
        let mut blob = None;
        let whole = compression == Compression::Message;
        while let Some(row) = rows.next().map_err(bad)? {
            let (rowid, topic, time): (i64, i64, i64) = (
                row.get(0).map_err(bad)?,
                row.get(1).map_err(bad)?,
                row.get(2).map_err(bad)?,
            );
            let data = message_bytes(&connection, &mut blob, rowid, whole).map_err(bad)?;
            let data = head(&data, compression).unwrap_or_default();
            catalog.add_message(
                topic as u64,
                Location(rowid as u64, 0),
                &data,
                time as f64 / 1e9,
            );
        }
    }
    let store = Sqlite {
        path: path.to_path_buf(),
        connection: Mutex::new(connection),
    };
    Ok((decompressed(path, Box::new(store), compression), catalog))
}

impl Store for Sqlite {
    fn read(&self, at: Location) -> Result<Cow<'_, [u8]>, IoError> {
        let connection = self.connection.lock().unwrap_or_else(|p| p.into_inner());
        let bad =
            |e: rusqlite::Error| IoError::invalid(&self.path, format!("message {}: {e}", at.0));
        let data = message_bytes(&connection, &mut None, at.0 as i64, true);
        data.map(Cow::Owned).map_err(bad)
    }
}

/// An MCAP file, memory-mapped, read through its summary's chunk index.
struct Mcap {
    path: std::path::PathBuf,
    map: memmap2::Mmap,
    summary: mcap::read::Summary,
    /// The messages of the chunk read last (colour and depth usually share one).
    cache: Mutex<Option<(u64, ChunkMessages)>>,
}

/// One chunk's messages, in their order in the chunk: where they lie in the file when
/// the chunk is stored uncompressed ([`super::mcap_chunks`]), else decompressed by the
/// `mcap` crate (each with its channel and recording time).
enum ChunkMessages {
    InPlace(Vec<Span>),
    Decompressed(Vec<(u16, u64, Vec<u8>)>),
}

impl ChunkMessages {
    /// The messages of chunk `index` of the mapped file `map`.
    fn read(
        summary: &mcap::read::Summary,
        map: &[u8],
        index: &mcap::records::ChunkIndex,
    ) -> Result<Self, mcap::McapError> {
        if let Some(spans) = uncompressed_messages(map, index) {
            return Ok(Self::InPlace(spans?));
        }
        let messages = summary
            .stream_chunk(map, index)?
            .map(|m| m.map(|m| (m.channel.id, m.log_time, m.data.into_owned())))
            .collect::<Result<_, _>>()?;
        Ok(Self::Decompressed(messages))
    }

    /// Each message's channel, recording time (nanoseconds) and data.
    fn each<'a>(&'a self, map: &'a [u8]) -> Box<dyn Iterator<Item = (u16, u64, &'a [u8])> + 'a> {
        match self {
            Self::InPlace(spans) => Box::new(
                spans
                    .iter()
                    .map(|s| (s.channel, s.log_time, &map[s.data.clone()])),
            ),
            Self::Decompressed(all) => Box::new(all.iter().map(|(c, t, d)| (*c, *t, &d[..]))),
        }
    }

    /// The data of message `n`: where it lies in `map` for a chunk stored uncompressed
    /// (no copy), else a copy of the decompressed message.
    fn data<'m>(&self, map: &'m [u8], n: usize) -> Option<Cow<'m, [u8]>> {
        match self {
            Self::InPlace(spans) => spans.get(n).map(|s| Cow::Borrowed(&map[s.data.clone()])),
            Self::Decompressed(all) => all.get(n).map(|(_, _, d)| Cow::Owned(d.clone())),
        }
    }
}

/// Opens a `.mcap` file.
pub fn open_mcap(path: &Path) -> Result<(Box<dyn Store>, Catalog), IoError> {
    open_mcap_with(path, Compression::None)
}

fn open_mcap_with(
    path: &Path,
    compression: Compression,
) -> Result<(Box<dyn Store>, Catalog), IoError> {
    let map = mapped::map(path)?;
    let bad = |e: mcap::McapError| IoError::invalid(path, format!("not a readable MCAP file: {e}"));
    if map.starts_with(mcap::MAGIC) && !map.ends_with(mcap::MAGIC) {
        return Err(IoError::invalid(path, format!(
            "the MCAP file is cut short: its {} bytes do not end with MCAP's closing magic (its writer died, or the copy is partial); `mcap recover` rewrites what is whole into a new file",
            map.len()
        )));
    }
    check_summary(&map).map_err(|e| {
        IoError::invalid(
            path,
            format!("{e}; `mcap recover` rewrites the file from its records"),
        )
    })?;
    let summary = mcap::read::Summary::read(&map).map_err(bad)?.ok_or_else(|| {
        IoError::invalid(path, "the MCAP file has no summary (cut short, or its writer died): `mcap recover` it first")
    })?;
    if summary.chunk_indexes.is_empty()
        && summary.stats.as_ref().is_some_and(|s| s.message_count > 0)
    {
        return Err(IoError::invalid(
            path,
            "an MCAP file without chunks: only chunked files are read (rosbag2 writes chunks)",
        ));
    }
    let ros1 = summary
        .channels
        .values()
        .any(|c| c.message_encoding == "ros1");
    let mut catalog = Catalog::new(if ros1 { Wire::Ros1 } else { Wire::Cdr });
    let mut channels: Vec<_> = summary.channels.values().collect();
    channels.sort_by_key(|c| c.id);
    for channel in channels {
        let msg_type = channel.schema.as_ref().map_or("", |s| s.name.as_str());
        catalog.add_topic(channel.id, &channel.topic, msg_type);
    }
    for (i, index) in summary.chunk_indexes.iter().enumerate() {
        check_chunk_index(&map, i, index).map_err(|e| {
            IoError::invalid(
                path,
                format!("its summary lies: {e}; `mcap recover` rewrites the file from its records"),
            )
        })?;
    }
    for (i, index) in summary.chunk_indexes.iter().enumerate() {
        let messages = ChunkMessages::read(&summary, &map, index).map_err(bad)?;
        for (n, (channel, log_time, data)) in messages.each(&map).enumerate() {
            let data = head(data, compression).unwrap_or_default();
            let at = Location(i as u64, n as u64);
            catalog.add_message(channel, at, &data, log_time as f64 / 1e9);
        }
        release(&map, chunk_range(index));
    }
    let store = Mcap {
        path: path.to_path_buf(),
        map,
        summary,
        cache: Mutex::new(None),
    };
    Ok((decompressed(path, Box::new(store), compression), catalog))
}

/// Where chunk `index` lies in the file.
fn chunk_range(index: &mcap::records::ChunkIndex) -> std::ops::Range<usize> {
    let start = index.chunk_start_offset as usize;
    start..start.saturating_add(index.chunk_length as usize)
}

impl Store for Mcap {
    fn read(&self, at: Location) -> Result<Cow<'_, [u8]>, IoError> {
        let bad = |e: String| {
            IoError::invalid(&self.path, format!("chunk {} message {}: {e}", at.0, at.1))
        };
        let index_of = |chunk: u64| self.summary.chunk_indexes.get(chunk as usize);
        let mut cache = self.cache.lock().unwrap_or_else(|p| p.into_inner());
        if cache.as_ref().is_none_or(|(chunk, _)| *chunk != at.0) {
            let index = index_of(at.0).ok_or_else(|| bad("no such chunk".into()))?;
            let messages = ChunkMessages::read(&self.summary, &self.map, index)
                .map_err(|e| bad(e.to_string()))?;
            // The pages of the chunk read before are not needed again.
            if let Some((before, _)) = cache.as_ref() {
                release(
                    &self.map,
                    chunk_range(index_of(*before).expect("read before")),
                );
            }
            *cache = Some((at.0, messages));
        }
        let (_, messages) = cache.as_ref().expect("filled above");
        let data = messages.data(&self.map, at.1 as usize);
        data.ok_or_else(|| bad("no such message".into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_message_decompresses_whether_its_frame_announces_its_size_or_not() {
        let message: Vec<u8> = (0..300_000u32).map(|i| (i % 251) as u8).collect();
        let announced = zstd::bulk::compress(&message, 3).unwrap();
        assert!(zstd::zstd_safe::get_frame_content_size(&announced)
            .unwrap()
            .is_some());
        assert_eq!(decompress_message(&announced).unwrap(), message);
        // A stream's frame does not know its size.
        let mut streamed = Vec::new();
        let mut encoder = zstd::stream::write::Encoder::new(&mut streamed, 3).unwrap();
        std::io::Write::write_all(&mut encoder, &message).unwrap();
        encoder.finish().unwrap();
        assert_eq!(
            zstd::zstd_safe::get_frame_content_size(&streamed).unwrap(),
            None
        );
        assert_eq!(decompress_message(&streamed).unwrap(), message);
        // Cut short: an error, not a panic.
        assert!(decompress_message(&announced[..announced.len() / 2]).is_err());
        assert!(decompress_message(b"not zstd").is_err());
    }
}
