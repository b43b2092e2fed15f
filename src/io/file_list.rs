//! TUM-style timestamped file lists (`rgb.txt`, `depth.txt`, association files) and
//! the greedy timestamp association of TUM's `associate.py`.

use std::path::Path;

use super::errors::{read_text, IoError};

/// One line of a file list: a timestamp (seconds) and the fields after it.
#[derive(Debug, Clone, PartialEq)]
pub struct ListEntry {
    /// The line's first column, seconds.
    pub timestamp: f64,
    /// The other columns.
    pub fields: Vec<String>,
    /// The line number in the file (1-based), for error messages.
    pub line: usize,
}

/// The lines of a text file that hold data, trimmed, with their 1-based numbers:
/// blank lines and `#` comments are skipped.
pub fn content_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .filter_map(|(index, raw)| Some((index + 1, content(raw)?)))
}

/// A line trimmed, when it holds data (not blank, not a `#` comment).
pub fn content(raw: &str) -> Option<&str> {
    let line = raw.trim();
    (!line.is_empty() && !line.starts_with('#')).then_some(line)
}

/// Splits a line as TUM's scripts do: commas and tabs count as spaces.
pub fn split_fields(line: &str) -> impl Iterator<Item = &str> {
    line.split([' ', ',', '\t']).filter(|s| !s.is_empty())
}

/// Parses exactly `expected` finite numbers from a line, naming file, line and format on failure.
pub fn parse_numbers(
    path: &Path,
    line_number: usize,
    line: &str,
    expected: usize,
    format: &str,
) -> Result<Vec<f64>, IoError> {
    let fields: Vec<&str> = split_fields(line).collect();
    if fields.len() != expected {
        return Err(IoError::parse(
            path,
            line_number,
            format!(
                "expected {expected} numbers ({format}), found {}",
                fields.len()
            ),
        ));
    }
    fields
        .iter()
        .map(|field| {
            field
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    IoError::parse(
                        path,
                        line_number,
                        format!("{field:?} is not a finite number ({format})"),
                    )
                })
        })
        .collect()
}

/// Reads a file list such as `rgb.txt`: lines starting with `#` and blank lines are
/// skipped; every other line is a timestamp followed by at least `min_fields` fields.
/// The entries come back sorted by timestamp; a line repeated word for word is kept
/// once, and one timestamp with different files is an error naming both lines.
pub fn read_file_list(path: &Path, min_fields: usize) -> Result<Vec<ListEntry>, IoError> {
    let text = read_text(path)?;
    let mut entries = Vec::new();
    for (line_number, line) in content_lines(&text) {
        let mut fields = split_fields(line);
        let first = fields.next().unwrap_or_default();
        let timestamp: f64 = first
            .parse()
            .ok()
            .filter(|t: &f64| t.is_finite())
            .ok_or_else(|| {
                IoError::parse(
                    path,
                    line_number,
                    format!("expected a timestamp, found {first:?}"),
                )
            })?;
        let fields: Vec<String> = fields.map(str::to_owned).collect();
        if fields.len() < min_fields {
            return Err(IoError::parse(
                path,
                line_number,
                format!(
                    "expected a timestamp and {min_fields} more field(s), found {}",
                    fields.len()
                ),
            ));
        }
        entries.push(ListEntry {
            timestamp,
            fields,
            line: line_number,
        });
    }
    let backwards: Vec<String> = entries
        .windows(2)
        .filter(|pair| pair[1].timestamp < pair[0].timestamp)
        .map(|pair| pair[1].line.to_string())
        .collect();
    if !backwards.is_empty() {
        eprintln!(
            "warning: {}: timestamps go backwards on line(s) {}: the entries are taken in time order",
            path.display(),
            backwards.join(", ")
        );
    }
    entries.sort_by(|a, b| a.timestamp.total_cmp(&b.timestamp));
    let mut deduplicated: Vec<ListEntry> = Vec::with_capacity(entries.len());
    for entry in entries {
        match deduplicated.last_mut() {
            Some(last) if last.timestamp == entry.timestamp => {
                if last.fields != entry.fields {
                    let (first, second) = (last.line.min(entry.line), last.line.max(entry.line));
                    return Err(IoError::parse(
                        path,
                        second,
                        format!(
                            "timestamp {} is on line {first} too, with other files: which frame is it?",
                            entry.timestamp
                        ),
                    ));
                }
            }
            _ => deduplicated.push(entry),
        }
    }
    Ok(deduplicated)
}

/// TUM's `associate.py` rule: every pair \((a, b)\) with \(|a - (b + \text{offset})| <\)
/// `max_difference` is a candidate; candidates are taken greedily in order of increasing
/// difference (ties by `a`, then `b`), each timestamp at most once. Returns index pairs
/// into the two sorted slices, sorted by the first index.
///
/// Runs in \(O((n + m)\log(n + m) + k\log k)\) for \(k\) candidates instead of the
/// script's \(O(nm)\), with the same result.
pub fn associate_greedy(
    first: &[f64],
    second: &[f64],
    offset: f64,
    max_difference: f64,
) -> Vec<(usize, usize)> {
    debug_assert!(
        first.windows(2).all(|w| w[0] <= w[1]) && second.windows(2).all(|w| w[0] <= w[1])
    );
    let mut candidates = Vec::new();
    for (i, &a) in first.iter().enumerate() {
        // Candidates b with b + offset in (a - max, a + max); widen by one on each side
        // and keep the script's exact test so rounding cannot change the set.
        let low = second
            .partition_point(|&b| b + offset < a - max_difference)
            .saturating_sub(1);
        for (j, &b) in second.iter().enumerate().skip(low) {
            let difference = (a - (b + offset)).abs();
            if difference < max_difference {
                candidates.push((difference, i, j));
            } else if b + offset > a + max_difference {
                break;
            }
        }
    }
    candidates.sort_by(|x, y| x.0.total_cmp(&y.0).then(x.1.cmp(&y.1)).then(x.2.cmp(&y.2)));
    let mut first_used = vec![false; first.len()];
    let mut second_used = vec![false; second.len()];
    let mut matches = Vec::new();
    for (_, i, j) in candidates {
        if !first_used[i] && !second_used[j] {
            first_used[i] = true;
            second_used[j] = true;
            matches.push((i, j));
        }
    }
    matches.sort_unstable();
    matches
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// The script's own quadratic algorithm, as a reference.
    fn associate_reference(
        first: &[f64],
        second: &[f64],
        offset: f64,
        max: f64,
    ) -> Vec<(usize, usize)> {
        let mut potential = Vec::new();
        for (i, &a) in first.iter().enumerate() {
            for (j, &b) in second.iter().enumerate() {
                if (a - (b + offset)).abs() < max {
                    potential.push(((a - (b + offset)).abs(), i, j));
                }
            }
        }
        potential.sort_by(|x, y| x.partial_cmp(y).unwrap());
        let (mut fu, mut su) = (vec![false; first.len()], vec![false; second.len()]);
        let mut out = Vec::new();
        for (_, i, j) in potential {
            if !fu[i] && !su[j] {
                fu[i] = true;
                su[j] = true;
                out.push((i, j));
            }
        }
        out.sort();
        out
    }

    proptest! {
        #[test]
        fn greedy_equals_quadratic_reference(
            mut a in prop::collection::vec(0.0..3.0f64, 0..60),
            mut b in prop::collection::vec(0.0..3.0f64, 0..60),
            offset in -0.05..0.05f64,
        ) {
            a.sort_by(f64::total_cmp);
            b.sort_by(f64::total_cmp);
            prop_assert_eq!(associate_greedy(&a, &b, offset, 0.02), associate_reference(&a, &b, offset, 0.02));
        }
    }

    #[test]
    fn reads_comments_commas_and_duplicates() {
        let dir = std::env::temp_dir().join(format!("dopslam-list-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("rgb.txt");
        std::fs::write(
            &path,
            "# color images\n2.0 rgb/2.png\n1.0,rgb/1.png\n\n2.0\trgb/2.png\n",
        )
        .unwrap();
        let entries = read_file_list(&path, 1).unwrap();
        assert_eq!(entries.len(), 2);
        assert_eq!(entries[0].fields, vec!["rgb/1.png"]);
        assert_eq!(entries[1].fields, vec!["rgb/2.png"]);
        std::fs::write(&path, "2.0 rgb/2.png\n1.0 rgb/1.png\n2.0 rgb/2b.png\n").unwrap();
        let message = read_file_list(&path, 1).unwrap_err().to_string();
        assert!(
            message.contains("rgb.txt:3") && message.contains("line 1"),
            "{message}"
        );
        std::fs::write(&path, "1.0 a.png\nabc b.png\n").unwrap();
        let message = read_file_list(&path, 1).unwrap_err().to_string();
        assert!(message.contains("rgb.txt:2"), "{message}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
