//! A run's own temporary file for what would otherwise grow in memory: the TSDF
//! volume's blocks beyond its budget (`crate::dense::tsdf::TsdfVolume::spill_to`):
//! fixed-size records, one slot per block, written and read in place (`pwrite`/`pread`,
//! so that readers on several threads need no lock); the point cloud's voxel sums
//! (`crate::dense::cloud::CloudBuilder::spill_to`) and the tracked frames' observations
//! (`crate::map::record::FrameRecords`): records of any size appended at its end.
//! Each is created new (never one that exists), and removed when its owner is
//! dropped. A spill file can also be linked into a kept dense state
//! ([`SpillFile::keep_as`], `crate::dense::kept`), and laid over a kept file
//! ([`SpillFile::over`]): the kept bytes are read beneath it and never written.

use std::fs::{File, OpenOptions};
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

use crate::io::IoError;

/// A spill file of records of `record` bytes (or of any size: [`SpillFile::append`]).
#[derive(Debug)]
pub struct SpillFile {
    path: PathBuf,
    file: File,
    record: usize,
    /// Bytes written up to the end of the file (the kept file's beneath it included).
    len: u64,
    /// A kept file read beneath this one ([`SpillFile::over`]).
    base: Option<Base>,
}

/// A kept file beneath a spill file: its first `len` bytes are offsets `0..len`, and
/// the spill file's own bytes come after them.
#[derive(Debug)]
struct Base {
    path: PathBuf,
    file: File,
    len: u64,
}

impl SpillFile {
    /// Creates `dir/.dopslam-<kind>-spill-<pid>-<n>.tmp` (an error if it exists; `n`
    /// counts this process's spill files) for records of `record` bytes, and `dir`
    /// when it is new (an output folder not written yet).
    pub fn create(dir: &Path, kind: &str, record: usize) -> Result<Self, IoError> {
        std::fs::create_dir_all(dir).map_err(|source| IoError::Write {
            path: dir.to_path_buf(),
            source,
        })?;
        static CREATED: AtomicU32 = AtomicU32::new(0);
        let n = CREATED.fetch_add(1, Ordering::Relaxed);
        let name = format!(".dopslam-{kind}-spill-{}-{n}.tmp", std::process::id());
        let path = dir.join(name);
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(|source| IoError::Write {
                path: path.clone(),
                source,
            })?;
        Ok(Self {
            path,
            file,
            record,
            len: 0,
            base: None,
        })
    }

    /// A new spill file in `dir` (as [`SpillFile::create`]) laid over the first `len`
    /// bytes of the kept file `kept`, opened read-only: reads below `len` come from
    /// it, records written or appended go to the new file; writing below `len` is an
    /// error. An error too when `kept` is missing or shorter than `len` (cut short).
    pub fn over(
        kept: &Path,
        len: u64,
        dir: &Path,
        kind: &str,
        record: usize,
    ) -> Result<Self, IoError> {
        let file = File::open(kept).map_err(|e| IoError::read(kept, e))?;
        let size = file.metadata().map_err(|e| IoError::read(kept, e))?.len();
        if size < len {
            return Err(IoError::invalid(
                kept,
                format!("holds {size} bytes where its table needs {len}: the file was cut short"),
            ));
        }
        let mut spill = Self::create(dir, kind, record)?;
        spill.len = len;
        spill.base = Some(Base {
            path: kept.to_path_buf(),
            file,
            len,
        });
        Ok(spill)
    }

    /// Links the file at `path` too (copies it where a link cannot be made), so that it
    /// outlives this spill file: what was written so far is kept there. The caller
    /// writes nothing more into the records it keeps.
    pub fn keep_as(&self, path: &Path) -> Result<(), IoError> {
        let write_error = |source| IoError::Write {
            path: path.to_path_buf(),
            source,
        };
        if self.base.is_some() {
            return Err(IoError::invalid(
                path,
                "a spill file laid over a kept file is not kept again",
            ));
        }
        if std::fs::hard_link(&self.path, path).is_err() {
            std::fs::copy(&self.path, path).map_err(write_error)?;
        }
        Ok(())
    }

    /// Where the file is.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Bytes the file holds.
    pub fn bytes(&self) -> u64 {
        self.len
    }

    /// Writes `bytes` (one record) into `slot`, or into a new slot when `None`; the slot.
    pub fn write(&mut self, slot: Option<u32>, bytes: &[u8]) -> Result<u32, IoError> {
        debug_assert_eq!(bytes.len(), self.record);
        let slot = slot.unwrap_or((self.len / self.record as u64) as u32);
        self.write_at(self.offset(slot), bytes)?;
        Ok(slot)
    }

    /// Writes `bytes` (a record of any size) at the end of the file; where it went.
    pub fn append(&mut self, bytes: &[u8]) -> Result<u64, IoError> {
        let at = self.len;
        self.write_at(at, bytes)?;
        Ok(at)
    }

    /// Writes `bytes` over bytes appended before, at `at` (a record changed in place).
    pub fn overwrite(&mut self, at: u64, bytes: &[u8]) -> Result<(), IoError> {
        if at + bytes.len() as u64 > self.len {
            return Err(IoError::invalid(
                self.path.clone(),
                "a change in place reaches past the end of the spill file",
            ));
        }
        self.write_at(at, bytes)
    }

    fn write_at(&mut self, at: u64, bytes: &[u8]) -> Result<(), IoError> {
        let beneath = self.base.as_ref().map_or(0, |b| b.len);
        if at < beneath {
            let kept = self
                .base
                .as_ref()
                .map(|b| b.path.clone())
                .unwrap_or_default();
            return Err(IoError::invalid(kept, "a kept dense state is read only"));
        }
        self.file
            .write_all_at(bytes, at - beneath)
            .map_err(|source| IoError::Write {
                path: self.path.clone(),
                source,
            })?;
        self.len = self.len.max(at + bytes.len() as u64);
        Ok(())
    }

    /// Reads `bytes.len()` bytes at `at` (where [`SpillFile::append`] put them).
    pub fn read_at(&self, at: u64, bytes: &mut [u8]) -> Result<(), IoError> {
        match &self.base {
            Some(base) if at < base.len => (base.file)
                .read_exact_at(bytes, at)
                .map_err(|e| IoError::read(&base.path, e)),
            _ => {
                let beneath = self.base.as_ref().map_or(0, |b| b.len);
                (self.file)
                    .read_exact_at(bytes, at - beneath)
                    .map_err(|e| IoError::read(&self.path, e))
            }
        }
    }

    /// Reads the record in `slot` into `bytes`.
    pub fn read(&self, slot: u32, bytes: &mut [u8]) -> Result<(), IoError> {
        debug_assert_eq!(bytes.len(), self.record);
        self.read_part(slot, 0, bytes)
    }

    /// Reads `bytes.len()` bytes at `at` within the record in `slot`.
    pub fn read_part(&self, slot: u32, at: usize, bytes: &mut [u8]) -> Result<(), IoError> {
        debug_assert!(at + bytes.len() <= self.record);
        self.read_at(self.offset(slot) + at as u64, bytes)
    }

    fn offset(&self, slot: u32) -> u64 {
        slot as u64 * self.record as u64
    }

    /// Reads the whole file from its start, as a stream (records appended one after
    /// another, read back in order).
    pub fn reader(&self) -> SpillReader<'_> {
        SpillReader { file: self, at: 0 }
    }
}

/// A spill file read in order from its start ([`SpillFile::reader`]).
#[derive(Debug)]
pub struct SpillReader<'a> {
    file: &'a SpillFile,
    at: u64,
}

impl std::io::Read for SpillReader<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = (self.file.len - self.at).min(buf.len() as u64) as usize;
        self.file
            .read_at(self.at, &mut buf[..n])
            .map_err(std::io::Error::other)?;
        self.at += n as u64;
        Ok(n)
    }
}

/// Writes a kept state's table (`bytes`) to `path`.
pub fn write_table(path: &Path, bytes: &[u8]) -> Result<(), IoError> {
    std::fs::write(path, bytes).map_err(|source| IoError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// Reads a kept state's table of `len` bytes from `path`: an error when it holds
/// another number of bytes.
pub fn read_table(path: &Path, len: usize) -> Result<Vec<u8>, IoError> {
    let bytes = std::fs::read(path).map_err(|e| IoError::read(path, e))?;
    if bytes.len() != len {
        return Err(IoError::invalid(
            path,
            format!(
                "holds {} bytes where the state says {len}: cut short or changed",
                bytes.len()
            ),
        ));
    }
    Ok(bytes)
}

impl Drop for SpillFile {
    fn drop(&mut self) {
        // Ours alone (created new); nothing else reads it.
        let _ = std::fs::remove_file(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_come_back_as_written_and_the_file_goes_with_it() {
        let dir = std::env::temp_dir().join(format!("dopslam-spill-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut file = SpillFile::create(&dir, "test", 4).unwrap();
        let a = file.write(None, &[1, 2, 3, 4]).unwrap();
        let b = file.write(None, &[5, 6, 7, 8]).unwrap();
        assert_eq!(file.write(Some(a), &[9, 9, 9, 9]).unwrap(), a);
        let mut back = [0; 4];
        file.read(b, &mut back).unwrap();
        assert_eq!(back, [5, 6, 7, 8]);
        file.read(a, &mut back).unwrap();
        assert_eq!(back, [9; 4]);
        let mut part = [0; 2];
        file.read_part(b, 2, &mut part).unwrap();
        assert_eq!(part, [7, 8]);
        assert_eq!(file.bytes(), 8);
        let name = file.path().file_name().unwrap().to_string_lossy();
        assert!(name.starts_with(&format!(".dopslam-test-spill-{}-", std::process::id())));
        let mut log = SpillFile::create(&dir, "log", 1).unwrap();
        let first = log.append(&[1, 2, 3]).unwrap();
        let second = log.append(&[4, 5]).unwrap();
        assert_eq!((first, second, log.bytes()), (0, 3, 5));
        let mut back = [0; 2];
        log.read_at(second, &mut back).unwrap();
        assert_eq!(back, [4, 5]);
        // Kept, then laid under a new spill file: read beneath, never written.
        let kept = dir.join("kept.bin");
        log.keep_as(&kept).unwrap();
        drop(log);
        let mut over = SpillFile::over(&kept, 5, &dir, "over", 1).unwrap();
        assert!(
            over.write_at(4, &[0]).is_err(),
            "the kept bytes are read only"
        );
        assert_eq!(over.append(&[6, 7]).unwrap(), 5);
        let mut all = [0; 7];
        over.read_at(0, &mut all[..5]).unwrap();
        over.read_at(5, &mut all[5..]).unwrap();
        assert_eq!(all, [1, 2, 3, 4, 5, 6, 7]);
        drop(over);
        assert_eq!(std::fs::read(&kept).unwrap(), [1, 2, 3, 4, 5]);
        let short = SpillFile::over(&kept, 6, &dir, "over", 1).unwrap_err();
        assert!(short.to_string().contains("cut short"), "{short}");
        std::fs::remove_file(&kept).unwrap();
        let path = file.path().to_path_buf();
        assert!(path.exists());
        drop(file);
        assert!(!path.exists());
        std::fs::remove_dir(&dir).unwrap();
    }
}
