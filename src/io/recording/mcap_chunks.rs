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
    // The chunk's header: three u64, a u32 CRC, then the compression's name (its length
    // taken unchecked by the crate, as in the summary).
    if !fields_fit(&frame[FRAME..], &[Field::Fixed(28), Field::Sized]) {
        return Err(format!(
            "{}: its compression's name runs past the chunk",
            claim()
        ));
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

/// One field of a summary record, for [`check_summary`].
#[derive(Clone, Copy)]
enum Field {
    /// A fixed number of bytes.
    Fixed(usize),
    /// A string or byte array: a u32 length, then that many bytes.
    Sized,
    /// A map of strings to strings: a u32 byte length, then pairs of [`Field::Sized`].
    StringMap,
    /// A byte array with a u64 length.
    Sized64,
}

/// The fields of the records whose lengths the `mcap` crate takes unchecked (a summary
/// section may hold any record; the message and statistics records' other fields are
/// fixed).
fn layout(opcode: u8) -> &'static [Field] {
    use Field::{Fixed, Sized, Sized64, StringMap};
    match opcode {
        op::HEADER => &[Sized, Sized],
        op::SCHEMA => &[Fixed(2), Sized, Sized, Sized],
        op::CHUNK => &[Fixed(28), Sized, Sized64],
        op::MESSAGE_INDEX => &[Fixed(2), Sized],
        op::ATTACHMENT => &[Fixed(16), Sized, Sized, Sized64],
        op::METADATA => &[Sized, StringMap],
        op::CHANNEL => &[Fixed(4), Sized, Sized, StringMap],
        op::CHUNK_INDEX => &[Fixed(32), Sized, Fixed(8), Sized, Fixed(16)],
        op::ATTACHMENT_INDEX => &[Fixed(40), Sized, Sized],
        op::METADATA_INDEX => &[Fixed(16), Sized],
        op::STATISTICS => &[Fixed(42), Sized],
        _ => &[],
    }
}

/// The u32 length at the start of `body`, when the bytes it names follow in `body`;
/// the rest after them.
fn sized(body: &[u8]) -> Option<&[u8]> {
    let (length, rest) = body.split_first_chunk::<4>()?;
    rest.get(u32::from_le_bytes(*length) as usize..)
}

/// Whether every length-prefixed field of a summary record's `body` lies inside it.
fn fields_fit(mut body: &[u8], fields: &[Field]) -> bool {
    for field in fields {
        let rest = match field {
            Field::Fixed(n) => body.get(*n..),
            Field::Sized => sized(body),
            Field::Sized64 => body.split_first_chunk::<8>().and_then(|(length, rest)| {
                rest.get(usize::try_from(u64::from_le_bytes(*length)).ok()?..)
            }),
            Field::StringMap => body.split_first_chunk::<4>().and_then(|(length, rest)| {
                let mut pairs = rest.get(..u32::from_le_bytes(*length) as usize)?;
                while !pairs.is_empty() {
                    pairs = sized(sized(pairs)?)?;
                }
                rest.get(u32::from_le_bytes(*length) as usize..)
            }),
        };
        let Some(rest) = rest else {
            return false;
        };
        body = rest;
    }
    true
}

/// Checks the summary section of `file` before the `mcap` crate reads it: each record
/// lies inside the section, and each string, byte array and map of a schema, channel
/// or index record inside its record. The crate sizes a buffer from a string's length
/// before it reads the string, so a lying length (up to 4 GiB) would be allocated.
/// A file without a footer or summary is left to the crate, which says so.
pub fn check_summary(file: &[u8]) -> Result<(), String> {
    const FOOTER: usize = 9 + 20;
    let Some(footer_at) = file.len().checked_sub(mcap::MAGIC.len() + FOOTER) else {
        return Ok(());
    };
    let footer = &file[footer_at..footer_at + FOOTER];
    if footer[0] != op::FOOTER {
        return Ok(());
    }
    let start = u64::from_le_bytes(footer[9..17].try_into().expect("8 bytes"));
    if start == 0 {
        return Ok(());
    }
    let mut at = usize::try_from(start)
        .ok()
        .filter(|&s| s >= mcap::MAGIC.len() && s <= footer_at)
        .ok_or_else(|| format!("the footer puts the summary at byte {start}, outside the file"))?;
    while at < footer_at {
        let record = &file[at..footer_at];
        let (opcode, length) = match record.get(..FRAME) {
            Some(frame) => (
                frame[0],
                u64::from_le_bytes(frame[1..].try_into().expect("8 bytes")),
            ),
            None => {
                return Err(format!(
                    "the summary record at byte {at} is cut by the footer"
                ))
            }
        };
        let body = usize::try_from(length)
            .ok()
            .and_then(|length| record.get(FRAME..FRAME.checked_add(length)?))
            .ok_or_else(|| {
                format!("the summary record at byte {at} ({length} bytes) runs past the summary")
            })?;
        if !fields_fit(body, layout(opcode)) {
            return Err(format!(
                "the summary record at byte {at} (opcode {opcode:#04x}) has a field longer than the record"
            ));
        }
        at += FRAME + body.len();
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

    /// A summary record whose string claims more bytes than its record holds is named
    /// before the crate would size a buffer from it; an honest summary passes.
    #[test]
    fn a_summary_string_longer_than_its_record_is_refused() {
        let (mut file, _) = written(&messages(), None);
        check_summary(&file).unwrap();
        let footer = file.len() - mcap::MAGIC.len() - 29;
        let mut at = u64::from_le_bytes(file[footer + 9..footer + 17].try_into().unwrap()) as usize;
        while file[at] != op::CHANNEL {
            at += FRAME + u64::from_le_bytes(file[at + 1..at + 9].try_into().unwrap()) as usize;
        }
        // The channel's topic: after its frame and its two u16 ids.
        let topic = at + FRAME + 4;
        file[topic..topic + 4].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        let error = check_summary(&file).unwrap_err();
        assert!(
            error.contains(&format!("record at byte {at}"))
                && error.contains("longer than the record"),
            "{error}"
        );
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
