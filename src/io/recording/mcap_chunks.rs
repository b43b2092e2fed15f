//! The messages of an MCAP chunk stored uncompressed, found in place: where each one's
//! data lies in the file, without copying it.
//!
//! The `mcap` crate's chunk reader copies a chunk's records into a buffer of its own
//! and each message out of that (and checks the chunk's CRC over all of them), so a
//! frame's megabytes passed through memory three times before they were decoded, and
//! the catalog's scan, which needs only each message's header, read every byte of the
//! file. A chunk's records are a sequence of frames (opcode: 1 byte, length: u64
//! little-endian, then the record's body); walking the frames and parsing only the
//! message records' headers (with the crate's own `parse_record`) touches one page per
//! message. Compressed chunks are left to the crate, which decompresses them.
//!
//! What is not checked in place: the chunk's CRC (`uncompressed_crc`; the framing is,
//! and a record that runs past its chunk is an error). The Python `rosbags` reader
//! does not check it either.

use std::borrow::Cow;
use std::ops::Range;

use mcap::read::parse_record;
use mcap::records::{op, ChunkIndex, Record};
use mcap::{McapError, McapResult};

/// A message of an uncompressed chunk.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Span {
    /// Its channel.
    pub channel: u16,
    /// Its recording time (`log_time`), nanoseconds.
    pub log_time: u64,
    /// Where its data lies in the file.
    pub data: Range<usize>,
}

/// Bytes of a record's frame before its body: the opcode and the length.
const FRAME: usize = 9;

/// The messages of the chunk `index` points at in `file`, in their order in the chunk;
/// `None` when the chunk is compressed.
pub fn uncompressed_messages(file: &[u8], index: &ChunkIndex) -> Option<McapResult<Vec<Span>>> {
    index.compression.is_empty().then(|| walk(file, index))
}

/// The records of an uncompressed chunk, where they lie in `file`.
fn records<'a>(file: &'a [u8], index: &ChunkIndex) -> McapResult<&'a [u8]> {
    let start = usize::try_from(index.chunk_start_offset).map_err(|_| McapError::BadIndex)?;
    let end = usize::try_from(index.chunk_start_offset.saturating_add(index.chunk_length))
        .map_err(|_| McapError::BadIndex)?;
    let body = file
        .get(start.saturating_add(FRAME)..end)
        .ok_or(McapError::BadIndex)?;
    match parse_record(op::CHUNK, body)? {
        Record::Chunk {
            header,
            data: Cow::Borrowed(records),
        } if header.compression.is_empty() => Ok(records),
        _ => Err(McapError::BadIndex),
    }
}

/// The most bytes a compressed chunk may announce decompressed: the `mcap` crate sizes
/// its buffer from the chunk's header, so a larger claim is refused before it reads.
pub const MAX_CHUNK_BYTES: u64 = 1 << 30;

/// Checks chunk index `n` against `file` before the `mcap` crate is handed it (the crate
/// slices the file at the offsets the index gives, unchecked, and sizes its buffer from
/// the chunk's header): the chunk lies inside the file, starts with a chunk record of
/// the index's length, and announces at most [`MAX_CHUNK_BYTES`] decompressed. The error
/// names the index and the byte.
pub fn check_chunk_index(file: &[u8], n: usize, index: &ChunkIndex) -> Result<(), String> {
    let start = index.chunk_start_offset;
    let claim = || {
        format!(
            "chunk index {n} (a chunk at byte {start}, {} bytes long)",
            index.chunk_length
        )
    };
    let end = start
        .checked_add(index.chunk_length)
        .filter(|&end| end <= file.len() as u64 && start >= 8)
        .ok_or_else(|| format!("{} lies outside the file's {} bytes", claim(), file.len()))?;
    let frame = &file[start as usize..end as usize];
    let length = frame
        .get(1..FRAME)
        .map(|l| u64::from_le_bytes(l.try_into().expect("8 bytes")));
    if frame.first() != Some(&op::CHUNK) || length != Some(index.chunk_length - FRAME as u64) {
        return Err(format!("{}: no chunk record of that length there", claim()));
    }
    let header = match parse_record(op::CHUNK, &frame[FRAME..]) {
        Ok(Record::Chunk { header, .. }) => header,
        Ok(_) => return Err(format!("{}: no chunk record there", claim())),
        Err(e) => return Err(format!("{}: {e}", claim())),
    };
    let announced = header.uncompressed_size.max(index.uncompressed_size);
    if !header.compression.is_empty() && announced > MAX_CHUNK_BYTES {
        return Err(format!(
            "{} announces {announced} bytes decompressed, more than the {MAX_CHUNK_BYTES} a chunk may hold here",
            claim()
        ));
    }
    Ok(())
}

/// Walks the records' frames of an uncompressed chunk; a frame that runs past the
/// chunk's end is an error.
fn walk(file: &[u8], index: &ChunkIndex) -> McapResult<Vec<Span>> {
    let records = records(file, index)?;
    // The records' offset in the file (a sub-slice of it).
    let base = records.as_ptr() as usize - file.as_ptr() as usize;
    let mut spans = Vec::new();
    let mut at = 0;
    while at < records.len() {
        let frame = records
            .get(at..at + FRAME)
            .ok_or(McapError::UnexpectedEoc)?;
        let length = u64::from_le_bytes(frame[1..].try_into().expect("8 bytes"));
        let body_start = at + FRAME;
        let body_end = usize::try_from(length)
            .ok()
            .and_then(|l| body_start.checked_add(l))
            .filter(|&end| end <= records.len())
            .ok_or(McapError::UnexpectedEoc)?;
        if frame[0] == op::MESSAGE {
            let body = &records[body_start..body_end];
            if let Record::Message { header, data } = parse_record(op::MESSAGE, body)? {
                let offset = base + body_end - data.len();
                spans.push(Span {
                    channel: header.channel_id,
                    log_time: header.log_time,
                    data: offset..offset + data.len(),
                });
            }
        }
        at = body_end;
    }
    Ok(spans)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcap::records::MessageHeader;
    use mcap::{WriteOptions, Writer};
    use std::collections::BTreeMap;
    use std::io::Cursor;

    /// An MCAP file of `messages` (channel 1 or 2, time, data) written by the `mcap`
    /// crate's writer with `compression`, and its summary.
    fn written(
        messages: &[(u16, u64, Vec<u8>)],
        compression: Option<mcap::Compression>,
    ) -> (Vec<u8>, mcap::read::Summary) {
        let mut out = Cursor::new(Vec::new());
        {
            let options = WriteOptions::new()
                .compression(compression)
                .chunk_size(Some(64));
            let mut writer = Writer::with_options(&mut out, options).unwrap();
            for id in [1u16, 2] {
                let added = writer
                    .add_channel(0, &format!("/topic{id}"), "cdr", &BTreeMap::new())
                    .unwrap();
                assert_eq!(added, id);
            }
            for (sequence, (channel, time, data)) in messages.iter().enumerate() {
                let header = MessageHeader {
                    channel_id: *channel,
                    sequence: sequence as u32,
                    log_time: *time,
                    publish_time: *time,
                };
                writer.write_to_known_channel(&header, data).unwrap();
            }
            writer.finish().unwrap();
        }
        let file = out.into_inner();
        let summary = mcap::read::Summary::read(&file).unwrap().unwrap();
        (file, summary)
    }

    fn messages() -> Vec<(u16, u64, Vec<u8>)> {
        (0..20u8)
            .map(|i| {
                (
                    1 + u16::from(i % 2),
                    1000 + u64::from(i),
                    vec![i; 10 + 7 * i as usize],
                )
            })
            .collect()
    }

    /// In place, an uncompressed file's messages are the crate's own, chunk by chunk.
    #[test]
    fn spans_in_place_are_the_messages_the_crate_reads() {
        let (file, summary) = written(&messages(), None);
        assert!(summary.chunk_indexes.len() > 1, "several chunks");
        let mut found = 0;
        for index in &summary.chunk_indexes {
            let spans = uncompressed_messages(&file, index).unwrap().unwrap();
            let crate_read: Vec<_> = summary
                .stream_chunk(&file, index)
                .unwrap()
                .map(|m| m.unwrap())
                .collect();
            assert_eq!(spans.len(), crate_read.len());
            for (span, message) in spans.iter().zip(&crate_read) {
                assert_eq!(span.channel, message.channel.id);
                assert_eq!(span.log_time, message.log_time);
                assert_eq!(&file[span.data.clone()], &message.data[..]);
            }
            found += spans.len();
        }
        assert_eq!(found, messages().len());
    }

    /// A compressed chunk is left to the crate; a chunk cut short is an error.
    #[test]
    fn compressed_chunks_are_left_and_cut_ones_refused() {
        let (file, summary) = written(&messages(), Some(mcap::Compression::Zstd));
        assert!(uncompressed_messages(&file, &summary.chunk_indexes[0]).is_none());
        let (file, summary) = written(&messages(), None);
        let mut index = summary.chunk_indexes[0].clone();
        index.chunk_length -= 5;
        assert!(uncompressed_messages(&file, &index).unwrap().is_err());
        let cut = &file[..index.chunk_start_offset as usize + 30];
        assert!(uncompressed_messages(cut, &summary.chunk_indexes[0])
            .unwrap()
            .is_err());
    }

    /// An index that lies (a chunk shorter than its frame, an offset near 2^64, one
    /// past the file's end, a huge decompressed size) is named, never handed on.
    #[test]
    fn a_lying_chunk_index_is_refused_by_name_and_byte() {
        for compression in [None, Some(mcap::Compression::Zstd)] {
            let (file, summary) = written(&messages(), compression);
            for (n, index) in summary.chunk_indexes.iter().enumerate() {
                check_chunk_index(&file, n, index).unwrap();
            }
            let honest = summary.chunk_indexes[1].clone();
            let lie = |change: &dyn Fn(&mut ChunkIndex)| {
                let mut index = honest.clone();
                change(&mut index);
                check_chunk_index(&file, 1, &index).unwrap_err()
            };
            let error = lie(&|i| i.chunk_length = 5);
            assert!(
                error.contains("chunk index 1") && error.contains("5 bytes long"),
                "{error}"
            );
            let error = lie(&|i| i.chunk_start_offset = u64::MAX - 255);
            assert!(error.contains("outside the file"), "{error}");
            let error = lie(&|i| i.chunk_start_offset = file.len() as u64 - 3);
            assert!(error.contains("outside the file"), "{error}");
            let error = lie(&|i| i.chunk_start_offset += 1);
            assert!(error.contains("no chunk record"), "{error}");
            if compression.is_some() {
                let error = lie(&|i| i.uncompressed_size = u64::MAX);
                assert!(error.contains("announces"), "{error}");
            }
        }
    }
}
