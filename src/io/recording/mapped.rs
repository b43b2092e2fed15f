//! Recordings read through a read-only memory map (ROS 1 bags, MCAP files): a message
//! stored uncompressed is handed to its decoder where it lies in the file, with no
//! copy, and the pages of a chunk read are given back when the reader moves on, so
//! that a recording of any size is read with the memory of a few chunks.

use std::ops::Range;
use std::path::Path;

use memmap2::Mmap;

use crate::io::IoError;

/// Maps the file at `path`, read-only.
pub fn map(path: &Path) -> Result<Mmap, IoError> {
    let file = std::fs::File::open(path).map_err(|e| IoError::read(path, e))?;
    // SAFETY: the file is opened read-only and is an input that the run never writes.
    // (Another process cutting it while it is read would end the run with SIGBUS, as
    // for every memory-mapped reader; the readers check every offset against the
    // length the file had when it was mapped.)
    unsafe { Mmap::map(&file) }.map_err(|e| IoError::read(path, e))
}

/// Drops the pages of `range` of `map` from the process's memory (they are read again
/// from the file when touched: the contents stay valid, a borrowed slice of them
/// included). The range is widened by 64 KiB on both sides: the kernel maps pages
/// around each one touched ("fault-around"), so reading a chunk also maps the end of
/// the one before it.
pub fn release(map: &Mmap, range: Range<usize>) {
    const AROUND: usize = 64 * 1024;
    let start = range.start.saturating_sub(AROUND);
    let end = range.end.saturating_add(AROUND).min(map.len());
    if start < end {
        // SAFETY: a read-only, private mapping of a file that is never written:
        // MADV_DONTNEED only drops its pages, which the next access reads again from
        // the file, with the same bytes.
        let _ = unsafe {
            map.unchecked_advise_range(memmap2::UncheckedAdvice::DontNeed, start, end - start)
        };
    }
}
