//! The house stays a pipeline: every module of `src/` is read (test modules and
//! comments left out), its references to other modules (`crate::a::b`, `super::c`,
//! `use child::…`) resolved to the files that define them, and two rules checked:
//! 1. lower floors never import higher ones (the floors below, bottom first);
//! 2. no import circles: neither between top-level modules nor between the files of
//!    one folder (a child may use its parent, as an `impl` split over files does).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The floors of the crate, bottom first: a module may import its own floor and the
/// ones below.
const FLOORS: &[&[&str]] = &[
    &[
        "random",
        "checks",
        "interrupt",
        "memory",
        "threads",
        "pacing",
    ],
    &["geometry"],
    &["io", "features"],
    &["optim", "dop"],
    &["frame", "detect", "eval"],
    &["map", "bow", "dynamics"],
    &["mapping", "tracking"],
    &["global", "dense", "records", "view"],
    &["config"],
    &["system"],
    &["run", "synth", "demo"],
    &["batch"],
];

type Module = Vec<String>;

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// `src/a/b.rs` and `src/a/b/mod.rs` are module `a::b`.
fn module_of(src: &Path, file: &Path) -> Module {
    let relative = file.strip_prefix(src).unwrap().with_extension("");
    let mut parts: Module = relative
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if parts.last().is_some_and(|p| p == "mod") {
        parts.pop();
    }
    parts
}

/// The code of a file without its test module (`#[cfg(test)]` over `mod tests {`, of
/// any visibility) and comments.
fn code(text: &str) -> String {
    let mut kept = Vec::new();
    let mut lines = text.lines().peekable();
    while let Some(line) = lines.next() {
        let test_module = line.trim() == "#[cfg(test)]"
            && lines
                .peek()
                .is_some_and(|next| next.trim_end().ends_with("mod tests {"));
        if test_module {
            break;
        }
        kept.push(match line.find("//") {
            Some(i) => &line[..i],
            None => line,
        });
    }
    kept.join("\n")
}

/// The paths after each occurrence of `prefix` (`a::b::c` for `crate::a::b::c`).
fn paths_after(code: &str, prefix: &str) -> Vec<Vec<String>> {
    let mut found = Vec::new();
    let mut rest = code;
    while let Some(i) = rest.find(prefix) {
        let before = rest[..i].chars().last();
        rest = &rest[i + prefix.len()..];
        if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
            continue;
        }
        let end = rest
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == ':'))
            .unwrap_or(rest.len());
        let path: Vec<String> = rest[..end]
            .split("::")
            .filter(|s| !s.is_empty())
            .map(str::to_string)
            .collect();
        if !path.is_empty() {
            found.push(path);
        }
    }
    found
}

/// Every module's references to other modules (resolved to the longest module path
/// that exists).
fn references(src: &Path) -> BTreeMap<Module, BTreeSet<Module>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let modules: BTreeMap<Module, PathBuf> = files
        .into_iter()
        .map(|f| (module_of(src, &f), f))
        .filter(|(m, _)| m != &["lib"] && m != &["main"] && m.last().is_some_and(|l| l != "tests"))
        .collect();
    let resolve = |path: &[String]| -> Option<Module> {
        (1..=path.len())
            .rev()
            .map(|n| path[..n].to_vec())
            .find(|m| modules.contains_key(m))
    };
    let mut edges = BTreeMap::new();
    for (module, file) in &modules {
        let code = code(&std::fs::read_to_string(file).unwrap());
        let parent = &module[..module.len() - 1];
        let mut paths = paths_after(&code, "crate::");
        for path in paths_after(&code, "super::") {
            paths.push(parent.iter().cloned().chain(path).collect());
        }
        for path in paths_after(&code, "\nuse ") {
            // `use child::Item;` of a module's own child.
            paths.push(module.iter().cloned().chain(path).collect());
        }
        let targets: BTreeSet<Module> = paths
            .iter()
            .filter_map(|p| resolve(p))
            .filter(|t| t != module)
            .collect();
        edges.insert(module.clone(), targets);
    }
    edges
}

/// The circles of a directed graph (its strongly connected components of more than
/// one node), by repeated reachability (the graphs are small).
fn circles(graph: &BTreeMap<String, BTreeSet<String>>) -> Vec<BTreeSet<String>> {
    let reach = |from: &String| {
        let mut seen = BTreeSet::new();
        let mut stack = vec![from.clone()];
        while let Some(n) = stack.pop() {
            for m in graph.get(&n).into_iter().flatten() {
                if seen.insert(m.clone()) {
                    stack.push(m.clone());
                }
            }
        }
        seen
    };
    let reachable: BTreeMap<&String, BTreeSet<String>> =
        graph.keys().map(|n| (n, reach(n))).collect();
    let mut found: Vec<BTreeSet<String>> = Vec::new();
    for (n, from_n) in &reachable {
        if !from_n.contains(*n) {
            continue;
        }
        let component: BTreeSet<String> = from_n
            .iter()
            .filter(|m| reachable.get(m).is_some_and(|r| r.contains(*n)))
            .cloned()
            .collect();
        if !found.contains(&component) {
            found.push(component);
        }
    }
    found
}

/// For each folder (and the crate), the graph between its direct children that the
/// references imply: a reference between two modules counts between the children of
/// their deepest common folder; one between a module and its own ancestor does not.
fn sibling_graphs(
    edges: &BTreeMap<Module, BTreeSet<Module>>,
) -> BTreeMap<Module, BTreeMap<String, BTreeSet<String>>> {
    let mut graphs: BTreeMap<Module, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for (from, targets) in edges {
        for to in targets {
            let common = from.iter().zip(to).take_while(|(a, b)| a == b).count();
            if common == from.len() || common == to.len() {
                continue;
            }
            graphs
                .entry(from[..common].to_vec())
                .or_default()
                .entry(from[common].clone())
                .or_default()
                .insert(to[common].clone());
        }
    }
    graphs
}

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

#[test]
fn lower_floors_never_import_higher_ones() {
    let floor_of: BTreeMap<&str, usize> = FLOORS
        .iter()
        .enumerate()
        .flat_map(|(n, names)| names.iter().map(move |m| (*m, n)))
        .collect();
    let edges = references(&src());
    let mut upward = Vec::new();
    for (from, targets) in &edges {
        // The binary's command modules stand on top of the library.
        if from[0] == "cli" {
            continue;
        }
        let own = *floor_of
            .get(from[0].as_str())
            .unwrap_or_else(|| panic!("module {} has no floor in tests/layers.rs", from[0]));
        for to in targets.iter().filter(|t| t[0] != from[0]) {
            let theirs = floor_of.get(to[0].as_str()).copied().unwrap_or(usize::MAX);
            if theirs > own {
                upward.push(format!("{} imports {}", from.join("::"), to.join("::")));
            }
        }
    }
    assert!(
        upward.is_empty(),
        "imports from a lower floor to a higher one:\n{}",
        upward.join("\n")
    );
}

#[test]
fn there_are_no_import_circles() {
    let edges = references(&src());
    // A sanity check that references are found at all.
    let pass: Module = vec!["run".into(), "tracking_pass".into()];
    assert!(
        edges[&pass].contains(&vec!["system".to_string()]),
        "{:?}",
        edges[&pass]
    );
    let mut found = Vec::new();
    for (folder, graph) in sibling_graphs(&edges) {
        for circle in circles(&graph) {
            let names: Vec<&str> = circle.iter().map(String::as_str).collect();
            found.push(format!("in {}: {}", folder.join("::"), names.join(" -> ")));
        }
    }
    assert!(found.is_empty(), "import circles:\n{}", found.join("\n"));
}

#[test]
fn a_circle_is_found() {
    let mut edges: BTreeMap<Module, BTreeSet<Module>> = BTreeMap::new();
    let m = |s: &str| -> Module { s.split("::").map(str::to_string).collect() };
    edges.entry(m("a::x")).or_default().insert(m("a::y"));
    edges.entry(m("a::y")).or_default().insert(m("a::z"));
    edges.entry(m("a::z")).or_default().insert(m("a::x"));
    // A child using its parent, and the parent its child: no circle between siblings.
    edges.entry(m("b::c")).or_default().insert(m("b"));
    edges.entry(m("b")).or_default().insert(m("b::c"));
    let graphs = sibling_graphs(&edges);
    let found: Vec<_> = graphs.values().flat_map(circles).collect();
    assert_eq!(found.len(), 1);
    assert_eq!(found[0].len(), 3);
}

/// Modules of one floor that never import each other in the named direction: the
/// global and dense passes are independent stages after tracking; local mapping and
/// the tracker meet only through the map and the system; the map knows nothing of the
/// DOP state over a run (the dynamics read and write the map, not the other way). One
/// pair across floors: the global pass takes the tracking pass's frames as the map's
/// [`FrameRecord`](dopslam::map::record::FrameRecord)s, not the tracker's types.
const NEVER: &[(&str, &str)] = &[
    ("global", "tracking"),
    ("global", "dense"),
    ("dense", "global"),
    ("mapping", "tracking"),
    ("tracking", "mapping"),
    ("map", "dynamics"),
];

/// The files of `run/` import their siblings, not their folder: what they share
/// (`RunError`, `RunOptions`) has a file of its own, so `run/mod.rs` is the top of the
/// folder and nothing points back up into it.
#[test]
fn the_files_of_run_never_import_their_folder() {
    let edges = references(&src());
    let run = vec!["run".to_string()];
    let back: Vec<String> = edges
        .iter()
        .filter(|(from, targets)| from.len() > 1 && from[0] == "run" && targets.contains(&run))
        .map(|(from, _)| from.join("::"))
        .collect();
    assert!(back.is_empty(), "these import run/mod.rs: {back:?}");
}

#[test]
fn modules_of_one_floor_keep_apart_where_they_must() {
    let edges = references(&src());
    let mut found = Vec::new();
    for (from, targets) in &edges {
        for to in targets {
            if NEVER.iter().any(|&(a, b)| from[0] == a && to[0] == b) {
                found.push(format!("{} imports {}", from.join("::"), to.join("::")));
            }
        }
    }
    assert!(
        found.is_empty(),
        "imports the layers forbid:\n{}",
        found.join("\n")
    );
}
