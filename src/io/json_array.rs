//! A JSON array's items read one at a time from a file, for run files that grow with
//! the frames (`dynamic_keypoints.json`): a reader holds one item, never the array.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::marker::PhantomData;
use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;

use super::IoError;

/// Where the reader is in the array.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Place {
    Start,
    First,
    Rest,
    Done,
}

/// The items of the JSON array in a file, in order ([`JsonArrayItems::open`]); an
/// item that does not parse, or text that is not an array, is an error naming the
/// file, after which the reader ends.
pub struct JsonArrayItems<T> {
    path: PathBuf,
    reader: BufReader<File>,
    place: Place,
    item: PhantomData<fn() -> T>,
}

impl<T: DeserializeOwned> JsonArrayItems<T> {
    /// Opens the array in the file at `path`.
    pub fn open(path: &Path) -> Result<Self, IoError> {
        let file = File::open(path).map_err(|e| IoError::read(path, e))?;
        Ok(Self {
            path: path.to_path_buf(),
            reader: BufReader::with_capacity(1 << 16, file),
            place: Place::Start,
            item: PhantomData,
        })
    }

    /// The next byte that is not white space, not taken (`None` at the end).
    fn peek(&mut self) -> Result<Option<u8>, IoError> {
        loop {
            let buffer = self
                .reader
                .fill_buf()
                .map_err(|e| IoError::read(&self.path, e))?;
            let Some(&byte) = buffer.first() else {
                return Ok(None);
            };
            if !byte.is_ascii_whitespace() {
                return Ok(Some(byte));
            }
            self.reader.consume(1);
        }
    }

    fn malformed(&mut self, what: &str) -> IoError {
        self.place = Place::Done;
        IoError::invalid(&self.path, format!("malformed: {what}"))
    }

    fn step(&mut self) -> Result<Option<T>, IoError> {
        let byte = self.peek()?;
        match (self.place, byte) {
            (Place::Done, _) => Ok(None),
            (Place::Start, Some(b'[')) => {
                self.reader.consume(1);
                self.place = Place::First;
                self.step()
            }
            (Place::First | Place::Rest, Some(b']')) => {
                self.reader.consume(1);
                self.place = Place::Done;
                Ok(None)
            }
            (Place::Rest, Some(b',')) => {
                self.reader.consume(1);
                self.item()
            }
            (Place::First, Some(_)) => self.item(),
            (Place::Start, _) => Err(self.malformed("not a JSON array")),
            (_, None) => Err(self.malformed("the array ends before its `]` (cut short?)")),
            (Place::Rest, Some(_)) => Err(self.malformed("items not separated by `,`")),
        }
    }

    /// One item: an object or array, which the parser ends at its closing bracket
    /// without reading past it.
    fn item(&mut self) -> Result<Option<T>, IoError> {
        let mut parser = serde_json::Deserializer::from_reader(&mut self.reader);
        match T::deserialize(&mut parser) {
            Ok(item) => {
                self.place = Place::Rest;
                Ok(Some(item))
            }
            Err(e) => Err(self.malformed(&e.to_string())),
        }
    }
}

impl<T: DeserializeOwned> Iterator for JsonArrayItems<T> {
    type Item = Result<T, IoError>;

    fn next(&mut self) -> Option<Self::Item> {
        self.step().transpose()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, serde::Serialize, serde::Deserialize)]
    struct Item {
        t: f64,
        points: Vec<[f32; 3]>,
    }

    fn items_of(text: &str) -> Vec<Result<Item, String>> {
        let dir = std::env::temp_dir().join(format!("dopslam-json-array-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!(
            "{:x}.json",
            text.len() * 31 + text.bytes().map(usize::from).sum::<usize>()
        ));
        std::fs::write(&path, text).unwrap();
        let items = JsonArrayItems::<Item>::open(&path)
            .unwrap()
            .map(|i| i.map_err(|e| e.to_string()))
            .collect();
        std::fs::remove_file(&path).unwrap();
        items
    }

    #[test]
    fn items_come_one_by_one_as_serde_json_writes_them_and_bad_text_is_named() {
        let items: Vec<Item> = (0..50)
            .map(|i| Item {
                t: i as f64 / 3.0,
                points: (0..i % 4).map(|k| [k as f32 * 0.1, 2.5, -1.0e-3]).collect(),
            })
            .collect();
        for text in [
            serde_json::to_string(&items).unwrap(),
            serde_json::to_string_pretty(&items).unwrap(),
        ] {
            let back: Vec<Item> = items_of(&text).into_iter().map(Result::unwrap).collect();
            assert_eq!(back, items);
        }
        assert!(items_of("[]").is_empty());
        assert!(items_of(" [ ] ").is_empty());
        let cut = items_of(r#"[{"t": 1.0, "points": []}, {"t": 2.0, "poi"#);
        assert_eq!(cut.len(), 2);
        assert!(cut[0].is_ok());
        assert!(
            cut[1].as_ref().unwrap_err().contains("malformed"),
            "{cut:?}"
        );
        let cut = items_of(r#"[{"t": 1.0, "points": []}"#);
        assert!(
            cut[1].as_ref().unwrap_err().contains("cut short"),
            "{cut:?}"
        );
        let not = items_of(r#"{"t": 1.0}"#);
        assert!(not[0].as_ref().unwrap_err().contains("not a JSON array"));
    }
}
