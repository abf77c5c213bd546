//! The library's module graph, read from its sources: no import circle between its top-level
//! modules, and the edges the layout forbids stay absent.
//!
//! A test only: it reads `src/` as text, comments left out, and takes every `crate::<module>`
//! path and `use crate::{…}` group (`super::` stays within a module), so it sees every `use`
//! and every fully qualified path alike.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Edges the layout forbids: `(from, to)`.
const FORBIDDEN: &[(&str, &str)] = &[
    // The dashboard defines what it reads (`FleetSource`); the service implements it.
    ("dashboard", "service"),
    // Session plumbing knows no twin.
    ("mesh", "service"),
    ("mesh", "dashboard"),
    // Offline modes and benchmarks take the mesh, never the service's internals.
    ("replay", "service"),
    ("validate", "service"),
    ("calibrate", "service"),
    // Codecs know the core, not the network or the modes that use them.
    ("codec", "service"),
    ("codec", "mesh"),
    ("codec", "config"),
    ("codec", "dashboard"),
];

/// Every `.rs` file under `dir`.
fn sources(dir: &Path, files: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            sources(&path, files);
        } else if path.extension().is_some_and(|ext| ext == "rs") {
            files.push(path);
        }
    }
}

/// The top-level module a source file belongs to (`service/fleet.rs` → `service`).
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let relative = file.strip_prefix(src).ok()?;
    let first = relative.components().next()?.as_os_str().to_str()?;
    let name = first.strip_suffix(".rs").unwrap_or(first);
    (name != "lib" && name != "main").then(|| name.to_owned())
}

/// The top-level modules `text` names through `crate::`.
fn crate_paths(text: &str, modules: &BTreeSet<String>) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    for (at, _) in text.match_indices("crate::") {
        let rest = &text[at + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            // `use crate::{a, b::c, …}`: every first segment in the group.
            let inner = group.split('}').next().unwrap_or("");
            for item in inner.split(',') {
                let name: String = item
                    .trim()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if modules.contains(&name) {
                    found.insert(name);
                }
            }
        } else {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if modules.contains(&name) {
                found.insert(name);
            }
        }
    }
    found
}

/// The graph of top-level modules: `from → {to}`.
fn module_graph() -> BTreeMap<String, BTreeSet<String>> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let modules: BTreeSet<String> = files.iter().filter_map(|f| module_of(&src, f)).collect();
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for file in &files {
        let Some(from) = module_of(&src, file) else {
            continue;
        };
        if from == "module_graph" {
            continue;
        }
        let text = std::fs::read_to_string(file).unwrap_or_default();
        // Comments name modules without depending on them.
        let code: String = text
            .lines()
            .map(|line| line.split("//").next().unwrap_or(""))
            .collect::<Vec<_>>()
            .join("\n");
        let edges = graph.entry(from.clone()).or_default();
        for to in crate_paths(&code, &modules) {
            if to != from {
                edges.insert(to);
            }
        }
    }
    graph
}

/// A circle in `graph`, if it has one: the modules along it, the first repeated at the end.
fn find_circle(graph: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    #[derive(Clone, Copy, PartialEq)]
    enum Mark {
        Open,
        Done,
    }
    fn visit(
        node: &str,
        graph: &BTreeMap<String, BTreeSet<String>>,
        marks: &mut BTreeMap<String, Mark>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        match marks.get(node) {
            Some(Mark::Done) => return None,
            Some(Mark::Open) => {
                let start = path.iter().position(|n| n == node).unwrap_or(0);
                let mut circle = path[start..].to_vec();
                circle.push(node.to_owned());
                return Some(circle);
            }
            None => {}
        }
        marks.insert(node.to_owned(), Mark::Open);
        path.push(node.to_owned());
        for next in graph.get(node).into_iter().flatten() {
            if let Some(circle) = visit(next, graph, marks, path) {
                return Some(circle);
            }
        }
        path.pop();
        marks.insert(node.to_owned(), Mark::Done);
        None
    }
    let mut marks = BTreeMap::new();
    for node in graph.keys() {
        if let Some(circle) = visit(node, graph, &mut marks, &mut Vec::new()) {
            return Some(circle);
        }
    }
    None
}

#[test]
fn the_top_level_modules_import_no_circle() {
    let graph = module_graph();
    assert!(graph.len() > 5, "the sources were read: {graph:?}");
    if let Some(circle) = find_circle(&graph) {
        panic!("an import circle: {}", circle.join(" → "));
    }
}

#[test]
fn no_forbidden_edge() {
    let graph = module_graph();
    for (from, to) in FORBIDDEN {
        let edges = graph.get(*from);
        assert!(
            !edges.is_some_and(|edges| edges.contains(*to)),
            "{from} imports {to}"
        );
    }
}

#[test]
fn the_reader_sees_paths_groups_and_circles() {
    let modules: BTreeSet<String> = ["a", "b", "c"].iter().map(|m| (*m).to_owned()).collect();
    let text = "use crate::a::X;\nuse crate::{b, c::Y};\nfn f() { crate::zz::g() }";
    let expected: BTreeSet<String> = modules.clone();
    assert_eq!(crate_paths(text, &modules), expected);
    let graph: BTreeMap<String, BTreeSet<String>> =
        [("a", vec!["b"]), ("b", vec!["c"]), ("c", vec!["a"])]
            .into_iter()
            .map(|(k, v)| (k.to_owned(), v.into_iter().map(str::to_owned).collect()))
            .collect();
    assert_eq!(
        find_circle(&graph),
        Some(vec!["a".into(), "b".into(), "c".into(), "a".into()])
    );
    let mut acyclic = graph;
    acyclic.insert("c".to_owned(), BTreeSet::new());
    assert_eq!(find_circle(&acyclic), None);
}
