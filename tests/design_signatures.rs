//! `docs/design.md` quotes the passes' entry points in its `text` blocks, each with the
//! file that defines it (`dense_pass(&DensePass) -> DenseReport   run/dense_pass.rs`).
//! Each quote must match the code: the function is defined in that file, it takes as
//! many arguments as quoted (`..` stands for any), and it returns the type quoted.

use std::path::Path;

/// A quoted call: the function's name, its arguments (`None` for `..`), the returned
/// type's words, and the file.
struct Quote {
    line: String,
    name: String,
    arguments: Option<usize>,
    returns: Option<String>,
    file: String,
}

/// Splits `text` at its top-level commas (outside brackets).
fn top_level(text: &str) -> Vec<String> {
    let (mut parts, mut depth, mut current) = (Vec::new(), 0i32, String::new());
    for c in text.chars() {
        match c {
            '(' | '<' | '[' | '{' => depth += 1,
            ')' | '>' | ']' | '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(std::mem::take(&mut current));
                continue;
            }
            _ => {}
        }
        current.push(c);
    }
    parts.push(current);
    parts
        .into_iter()
        .map(|p| p.trim().to_string())
        .filter(|p| !p.is_empty())
        .collect()
}

/// The quotes of the `text` blocks: `NAME(ARGS)[ -> TYPE]  path/file.rs`.
fn quotes(design: &str) -> Vec<Quote> {
    let mut found = Vec::new();
    let mut in_text = false;
    for line in design.lines() {
        if line.starts_with("```") {
            in_text = line.trim() == "```text";
            continue;
        }
        if !in_text {
            continue;
        }
        let Some(file) = line
            .split_whitespace()
            .find(|w| w.ends_with(".rs") && w.contains('/'))
        else {
            continue;
        };
        let head = line.trim_start();
        let Some(open) = head.find('(') else { continue };
        let name_part = &head[..open];
        if name_part.contains(' ') || name_part.is_empty() {
            continue;
        }
        let mut depth = 0;
        let mut close = None;
        for (i, c) in head[open..].char_indices() {
            match c {
                '(' => depth += 1,
                ')' => {
                    depth -= 1;
                    if depth == 0 {
                        close = Some(open + i);
                        break;
                    }
                }
                _ => {}
            }
        }
        let Some(close) = close else { continue };
        let inside = &head[open + 1..close];
        let rest = head[close + 1..].trim_start();
        let returns = rest.strip_prefix("->").map(|r| {
            let r = r.trim_start();
            let end = r.find("  ").unwrap_or(r.len());
            r[..end].trim().to_string()
        });
        found.push(Quote {
            line: line.to_string(),
            name: name_part
                .rsplit(['.', ':'])
                .next()
                .unwrap_or(name_part)
                .to_string(),
            arguments: (inside.trim() != "..").then(|| top_level(inside).len()),
            returns,
            file: file.to_string(),
        });
    }
    found
}

/// The parameters (without `self`) and the return type of `fn name` in `source`.
fn signature(source: &str, name: &str) -> Option<(usize, String)> {
    let start = source
        .find(&format!("fn {name}("))
        .or_else(|| source.find(&format!("fn {name}<")))?;
    let open = start + source[start..].find('(')?;
    let mut depth = 0;
    let mut close = open;
    for (i, c) in source[open..].char_indices() {
        match c {
            '(' => depth += 1,
            ')' => {
                depth -= 1;
                if depth == 0 {
                    close = open + i;
                    break;
                }
            }
            _ => {}
        }
    }
    let parameters = top_level(&source[open + 1..close])
        .into_iter()
        .filter(|p| !p.ends_with("self") && !p.starts_with("self"))
        .count();
    let after = &source[close + 1..];
    let end = after.find(['{', ';']).unwrap_or(after.len());
    let returns = after[..end]
        .trim()
        .trim_start_matches("->")
        .trim()
        .to_string();
    Some((parameters, returns))
}

#[test]
fn the_signatures_design_md_quotes_exist() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let design = std::fs::read_to_string(root.join("docs/design.md")).unwrap();
    let quotes = quotes(&design);
    assert!(quotes.len() >= 10, "found only {} quotes", quotes.len());
    let mut wrong = Vec::new();
    for q in &quotes {
        let path = root.join("src").join(&q.file);
        let Ok(source) = std::fs::read_to_string(&path) else {
            wrong.push(format!("{}: no file src/{}", q.line.trim(), q.file));
            continue;
        };
        let Some((parameters, returns)) = signature(&source, &q.name) else {
            wrong.push(format!(
                "{}: no fn {} in src/{}",
                q.line.trim(),
                q.name,
                q.file
            ));
            continue;
        };
        if let Some(n) = q.arguments.filter(|&n| n != parameters) {
            wrong.push(format!(
                "{}: quoted with {n} argument(s), the code's takes {parameters}",
                q.line.trim()
            ));
        }
        if let Some(quoted) = &q.returns {
            let words = |t: &str| -> String { t.chars().filter(|c| c.is_alphanumeric()).collect() };
            if !words(&returns).contains(&words(quoted)) {
                wrong.push(format!(
                    "{}: quoted as returning {quoted}, the code's returns {returns}",
                    q.line.trim()
                ));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "docs/design.md quotes:\n{}",
        wrong.join("\n")
    );
}
