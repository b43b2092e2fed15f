//! ROS 2 bags: a folder with `metadata.yaml` and one storage file, SQLite 3 (`.db3`:
//! tables `topics` and `messages`, what `ros2 bag record` wrote until Iron and current
//! librealsense writes) or MCAP (`.mcap`, read with the `mcap` crate); messages are
//! CDR. A single `.db3` or `.mcap` file opens the same way.

use std::path::Path;
use std::sync::Mutex;

use super::{Catalog, Location, Store, Wire};
use crate::io::IoError;

/// Opens a ROS 2 bag folder through its one storage file.
pub fn open_bag_folder(dir: &Path) -> Result<(Box<dyn Store>, Catalog), IoError> {
    let listing = std::fs::read_dir(dir).map_err(|source| IoError::Read {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut files: Vec<_> = listing
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| matches!(p.extension().and_then(|e| e.to_str()), Some("db3" | "mcap")))
        .collect();
    files.sort();
    match files.as_slice() {
        [] => Err(IoError::invalid(
            dir,
            "a ROS 2 bag folder without a .db3 or .mcap file (compressed bags, .zstd files, are not read: `ros2 bag decompress` them)",
        )),
        [one] if one.extension().is_some_and(|e| e == "db3") => open_sqlite(one),
        [one] => open_mcap(one),
        many => Err(IoError::invalid(
            dir,
            format!("a bag split into {} files: only single-file bags are read (`ros2 bag convert` merges them)", many.len()),
        )),
    }
}

/// A ROS 2 SQLite bag, opened read-only.
struct Sqlite {
    path: std::path::PathBuf,
    connection: Mutex<rusqlite::Connection>,
}

/// Opens a `.db3` file.
pub fn open_sqlite(path: &Path) -> Result<(Box<dyn Store>, Catalog), IoError> {
    let bad = |e: rusqlite::Error| {
        IoError::invalid(path, format!("not a readable ROS 2 SQLite bag: {e}"))
    };
    let flags =
        rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX;
    let connection = rusqlite::Connection::open_with_flags(path, flags).map_err(bad)?;
    let mut catalog = Catalog::new(Wire::Cdr);
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
            .prepare("SELECT id, topic_id, timestamp, data FROM messages ORDER BY timestamp, id")
            .map_err(bad)?;
        let mut rows = messages.query([]).map_err(bad)?;
        while let Some(row) = rows.next().map_err(bad)? {
            let (id, topic, time): (i64, i64, i64) = (
                row.get(0).map_err(bad)?,
                row.get(1).map_err(bad)?,
                row.get(2).map_err(bad)?,
            );
            let data = row
                .get_ref(3)
                .map_err(bad)?
                .as_blob()
                .map_err(|e| bad(e.into()))?;
            catalog.add_message(
                topic as u64,
                Location(id as u64, 0),
                data,
                time as f64 / 1e9,
            );
        }
    }
    let store = Sqlite {
        path: path.to_path_buf(),
        connection: Mutex::new(connection),
    };
    Ok((Box::new(store), catalog))
}

impl Store for Sqlite {
    fn read(&self, at: Location) -> Result<Vec<u8>, IoError> {
        let connection = self.connection.lock().unwrap_or_else(|p| p.into_inner());
        let bad =
            |e: rusqlite::Error| IoError::invalid(&self.path, format!("message {}: {e}", at.0));
        // One prepared statement for every frame (cached by the connection).
        let mut statement = connection
            .prepare_cached("SELECT data FROM messages WHERE id = ?1")
            .map_err(bad)?;
        statement
            .query_row([at.0 as i64], |row| row.get(0))
            .map_err(bad)
    }
}

/// An MCAP file, memory-mapped, read through its summary's chunk index.
struct Mcap {
    path: std::path::PathBuf,
    map: memmap2::Mmap,
    summary: mcap::read::Summary,
    /// The messages of the chunk read last (colour and depth usually share one).
    cache: Mutex<Option<(u64, Vec<Vec<u8>>)>>,
}

/// Opens a `.mcap` file.
pub fn open_mcap(path: &Path) -> Result<(Box<dyn Store>, Catalog), IoError> {
    let file = std::fs::File::open(path).map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    // SAFETY: the file is opened read-only and is an input that the run never writes.
    let map = unsafe { memmap2::Mmap::map(&file) }.map_err(|source| IoError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    let bad = |e: mcap::McapError| IoError::invalid(path, format!("not a readable MCAP file: {e}"));
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
        for (n, message) in summary.stream_chunk(&map, index).map_err(bad)?.enumerate() {
            let message = message.map_err(bad)?;
            catalog.add_message(
                message.channel.id,
                Location(i as u64, n as u64),
                &message.data,
                message.log_time as f64 / 1e9,
            );
        }
        release(&map, index);
    }
    let store = Mcap {
        path: path.to_path_buf(),
        map,
        summary,
        cache: Mutex::new(None),
    };
    Ok((Box::new(store), catalog))
}

/// Drops the pages of chunk `index` from the process's memory (they are read again
/// from the file when needed), so that reading a recording of any size keeps the
/// memory of a few chunks, not of the file. The range reaches 64 KiB beyond the chunk
/// on both sides: the kernel maps pages around each one touched ("fault-around"), so
/// reading a chunk also maps the end of the one before it.
fn release(map: &memmap2::Mmap, index: &mcap::records::ChunkIndex) {
    const AROUND: usize = 64 * 1024;
    let start = (index.chunk_start_offset as usize).saturating_sub(AROUND);
    let end = (index.chunk_start_offset as usize)
        .saturating_add(index.chunk_length as usize)
        .saturating_add(AROUND)
        .min(map.len());
    if start < end {
        // SAFETY: a read-only mapping of a file: MADV_DONTNEED only drops pages, which
        // the next access reads again from the file; no borrow of them is alive here.
        let _ = unsafe {
            map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, start, end - start)
        };
    }
}

impl Store for Mcap {
    fn read(&self, at: Location) -> Result<Vec<u8>, IoError> {
        let bad = |e: String| {
            IoError::invalid(&self.path, format!("chunk {} message {}: {e}", at.0, at.1))
        };
        let mut cache = self.cache.lock().unwrap_or_else(|p| p.into_inner());
        if cache.as_ref().is_none_or(|(chunk, _)| *chunk != at.0) {
            let index = self
                .summary
                .chunk_indexes
                .get(at.0 as usize)
                .ok_or_else(|| bad("no such chunk".into()))?;
            let messages = self
                .summary
                .stream_chunk(&self.map, index)
                .map_err(|e| bad(e.to_string()))?
                .map(|m| m.map(|m| m.data.into_owned()))
                .collect::<Result<Vec<_>, _>>()
                .map_err(|e| bad(e.to_string()))?;
            release(&self.map, index);
            *cache = Some((at.0, messages));
        }
        let (_, messages) = cache.as_ref().expect("filled above");
        messages
            .get(at.1 as usize)
            .cloned()
            .ok_or_else(|| bad("no such message".into()))
    }
}
