//! The workspace's layering: within each crate, no two source files import each other,
//! directly or around a circle (issue "One crate per concern"). Between crates cargo already
//! forbids cycles. A module file that re-exports or uses its children (`pub use write::…` in
//! `io/mod.rs`) depends on them, and a file that imports through it (`crate::io::Samples`)
//! depends on it: a façade is a file like any other.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Every `.rs` file under `dir`.
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

/// A file's module path in its crate: `a/mod.rs` and `a.rs` are `a`, `a/b.rs` is `a::b`, the
/// crate root is empty.
fn module_of(src: &Path, file: &Path) -> String {
    let relative = file.strip_prefix(src).unwrap().with_extension("");
    let mut parts: Vec<String> = relative
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts.join("::")
}

/// The paths a file's code names (`crate::…`, `super::…`, `self::…` and paths that start at a
/// child module: `write::…` in `io/mod.rs`), tests and comments left out, as lists of
/// segments from the crate root. A path that starts with any other name (`std::…`, a type's
/// `Map::new`) is the child path `module::name::…`, which names no file unless `name` is a
/// child module.
fn named_paths(module: &str, text: &str) -> Vec<Vec<String>> {
    // A file's tests may reach anywhere (and their `super` is the file itself).
    let code = text.split("#[cfg(test)]").next().unwrap_or("");
    let mut paths = Vec::new();
    for line in code.lines() {
        let line = line.split("//").next().unwrap_or("");
        // Each path: a name followed by `::`, not itself the middle of a path.
        for (start, _) in line.match_indices("::") {
            let head_start = line[..start]
                .rfind(|c: char| !(c.is_alphanumeric() || c == '_'))
                .map_or(0, |i| i + 1);
            if head_start == start || line[..head_start].ends_with("::") {
                continue; // `::std` or the middle of `a::b::c`
            }
            let tail: String = line[head_start..]
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':')
                .collect();
            let mut segments: Vec<String> = tail
                .split("::")
                .filter(|s| !s.is_empty())
                .map(str::to_string)
                .collect();
            let mut base: Vec<String> = if segments[0] == "crate" {
                Vec::new()
            } else {
                module
                    .split("::")
                    .filter(|s| !s.is_empty())
                    .map(str::to_string)
                    .collect()
            };
            if segments[0] == "self" {
                segments.remove(0);
            }
            while segments.first().is_some_and(|s| s == "super") {
                segments.remove(0);
                base.pop();
            }
            if segments.first().is_some_and(|s| s == "crate") {
                segments.remove(0);
            }
            base.extend(segments);
            paths.push(base);
        }
    }
    paths
}

/// Per crate (its `src` folder), the edges module → module it imports from.
fn import_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(src, &mut files);
    let modules: BTreeSet<String> = files.iter().map(|f| module_of(src, f)).collect();
    let mut graph = BTreeMap::new();
    for file in &files {
        let module = module_of(src, file);
        let text = std::fs::read_to_string(file).unwrap();
        let mut edges = BTreeSet::new();
        for path in named_paths(&module, &text) {
            // The longest prefix that is a file of the crate.
            let target = (1..=path.len())
                .rev()
                .map(|n| path[..n].join("::"))
                .find(|m| modules.contains(m));
            // The crate root only declares modules and re-exports: not a layer of its own.
            if let Some(target) = target.filter(|t| t != &module && !t.is_empty()) {
                edges.insert(target);
            }
        }
        if !module.is_empty() {
            graph.insert(module, edges);
        }
    }
    graph
}

/// A cycle of the graph, if it has one.
fn find_cycle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == node) {
            let mut cycle = path[i..].to_vec();
            cycle.push(node.to_string());
            return Some(cycle);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for next in graph.get(node).into_iter().flatten() {
            if let Some(c) = visit(next, graph, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    graph
        .keys()
        .find_map(|n| visit(n, graph, &mut Vec::new(), &mut done))
}

fn crate_sources() -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let mut sources = vec![root.join("src")];
    for group in ["crates", "examples"] {
        for entry in std::fs::read_dir(root.join(group)).unwrap() {
            let src = entry.unwrap().path().join("src");
            if src.is_dir() {
                sources.push(src);
            }
        }
    }
    sources
}

#[test]
fn the_checker_sees_a_circle_and_resolves_super() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c::d"]),
        ("c::d", vec!["a"]),
        ("e", vec![]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.into_iter().map(str::to_string).collect()))
    .collect();
    assert_eq!(find_cycle(&graph).unwrap(), ["a", "b", "c::d", "a"]);
    let paths = named_paths(
        "onnx::kernels",
        "use super::winograd;\nuse crate::map::Map; // crate::gone\n#[cfg(test)]\nuse super::x;",
    );
    assert_eq!(paths, [vec!["onnx", "winograd"], vec!["map", "Map"]]);
    // A module file's own children, re-exported or used, and other names as child paths.
    let paths = named_paths(
        "io",
        "pub use write::{retag, MaterialWriter};\nlet r = read::Reader::new(std::f32::MAX);",
    );
    assert_eq!(
        paths,
        [
            vec!["io", "write"],
            vec!["io", "read", "Reader", "new"],
            vec!["io", "std", "f32", "MAX"],
        ]
    );
}

#[test]
fn no_two_files_import_each_other() {
    let mut circles = Vec::new();
    for src in crate_sources() {
        if let Some(cycle) = find_cycle(&import_graph(&src)) {
            circles.push(format!("{}: {}", src.display(), cycle.join(" → ")));
        }
    }
    assert!(
        circles.is_empty(),
        "import circles:\n{}",
        circles.join("\n")
    );
}
