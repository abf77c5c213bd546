//! The library's module graph, read from its sources: no import circle between its top-level
//! modules, the edges the layout forbids stay absent, and inside `service/` every file imports
//! only from the layers below its own.
//!
//! A test only: it reads `src/` as text, comments left out, and resolves every path that starts
//! with `crate::`, `super::` or `self::` (a `use …::{…}` group's every item alike), so it sees
//! every `use` and every fully qualified path.

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
    ("record", "service"),
    ("validate", "service"),
    ("calibrate", "service"),
    // Codecs know the core, not the network or the modes that use them.
    ("codec", "service"),
    ("codec", "mesh"),
    ("codec", "config"),
    ("codec", "dashboard"),
    // The flight recorder's rings and files know no network and no service.
    ("recorder", "service"),
    ("recorder", "mesh"),
    ("recorder", "dashboard"),
];

/// The files of `service/`, lowest layer first: a file imports only from the layers below its
/// own, never from its own layer or one above. `mod` is `service/mod.rs`. A new file takes its
/// place here.
const SERVICE_LAYERS: &[(&str, &[&str])] = &[
    ("why the service stops", &["error"]),
    (
        "leaves: each knows the crate (and the error) alone",
        &[
            "calibration_slot",
            "events",
            "gateways",
            "memory",
            "peers",
            "publish",
            "recording",
            "requests",
            "shard",
            "time_range",
        ],
    ),
    ("a robot's results, onto `publish`", &["sink"]),
    (
        "the robots' directory and cells, and the lock order",
        &["fleet"],
    ),
    (
        "duties, each over the fleet",
        &[
            "controller",
            "opcua_view",
            "queries",
            "self_calibration",
            "snapshot",
            "view",
        ],
    ),
    (
        "what runs the duties: Zenoh's callbacks and the control thread",
        &["control", "intake"],
    ),
    ("`serve`, which wires them", &["mod"]),
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

/// The module path a source file holds, from the crate root: `service/fleet.rs` →
/// `[service, fleet]`, `service/mod.rs` → `[service]`, `lib.rs` → `[]`.
fn module_path_of(src: &Path, file: &Path) -> Option<Vec<String>> {
    let relative = file.strip_prefix(src).ok()?;
    let mut path: Vec<String> = relative
        .components()
        .map(|part| part.as_os_str().to_str().map(str::to_owned))
        .collect::<Option<_>>()?;
    let last = path.pop()?;
    let stem = last.strip_suffix(".rs").unwrap_or(&last);
    if !(path.is_empty() && (stem == "lib" || stem == "main")) && stem != "mod" {
        path.push(stem.to_owned());
    }
    Some(path)
}

fn is_ident(c: char) -> bool {
    c.is_alphanumeric() || c == '_'
}

/// The contents of the `{…}` group `text` opens, up to the brace that closes it.
fn group(text: &str) -> &str {
    let mut depth = 0_usize;
    for (at, c) in text.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => {
                depth = depth.saturating_sub(1);
                if depth == 0 {
                    return &text[1..at];
                }
            }
            _ => {}
        }
    }
    text.get(1..).unwrap_or("")
}

/// `items` split at its commas outside any inner group.
fn top_level_items(items: &str) -> Vec<&str> {
    let (mut found, mut depth, mut start) = (Vec::new(), 0_usize, 0);
    for (at, c) in items.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth = depth.saturating_sub(1),
            ',' if depth == 0 => {
                found.push(&items[start..at]);
                start = at + 1;
            }
            _ => {}
        }
    }
    found.push(&items[start..]);
    found
}

/// The paths `rest` (what follows an anchor's `::`) names, each cut to its first `depth`
/// segments: one path, or one per item of a `{…}` group (`self` and `*` name the module itself).
fn segments(rest: &str, depth: usize) -> Vec<Vec<String>> {
    let rest = rest.trim_start();
    if depth == 0 {
        return vec![Vec::new()];
    }
    if rest.starts_with('{') {
        return top_level_items(group(rest))
            .into_iter()
            .flat_map(|item| segments(item, depth))
            .collect();
    }
    let name: String = rest.chars().take_while(|c| is_ident(*c)).collect();
    if name.is_empty() || name == "self" {
        return vec![Vec::new()];
    }
    let tails = match rest[name.len()..].strip_prefix("::") {
        Some(after) => segments(after, depth - 1),
        None => vec![Vec::new()],
    };
    tails
        .into_iter()
        .map(|tail| std::iter::once(name.clone()).chain(tail).collect())
        .collect()
}

/// Every path in `code`, written in module `here`, that starts with `crate::`, `super::` (once or
/// more), `self::` or one of `children` (the modules `here` declares), resolved from the crate
/// root and cut to its first two segments.
fn paths_in(code: &str, here: &[String], children: &BTreeSet<String>) -> Vec<Vec<String>> {
    const DEPTH: usize = 2;
    let mut found = Vec::new();
    let mut at = 0;
    while let Some(rest) = code.get(at..).filter(|rest| !rest.is_empty()) {
        let starts_path = code[..at]
            .chars()
            .next_back()
            .is_none_or(|c| !is_ident(c) && c != ':');
        let child = children.iter().find(|child| {
            rest.strip_prefix(child.as_str())
                .is_some_and(|r| r.starts_with("::"))
        });
        let anchored: Option<(Vec<String>, &str)> = if !starts_path {
            None
        } else if let Some(after) = rest.strip_prefix("crate::") {
            Some((Vec::new(), after))
        } else if let Some(after) = rest.strip_prefix("self::") {
            Some((here.to_vec(), after))
        } else if rest.starts_with("super::") {
            let mut after = rest;
            let mut base = here.to_vec();
            while let Some(next) = after.strip_prefix("super::") {
                after = next;
                base.pop();
            }
            Some((base, after))
        } else {
            child.map(|child| {
                let base = here.iter().chain([child]).cloned().collect();
                (base, &rest[child.len() + "::".len()..])
            })
        };
        match anchored {
            Some((base, after)) => {
                for tail in segments(after, DEPTH) {
                    let mut path = base.clone();
                    path.extend(tail);
                    path.truncate(DEPTH);
                    found.push(path);
                }
                at = code.len() - after.len();
            }
            None => at += rest.chars().next().map_or(1, char::len_utf8),
        }
    }
    found
}

/// Every source file's module path and the paths its code names, resolved: a file's inline
/// `mod tests` (from its `mod tests` line on) is read as the module it is.
fn resolved_sources() -> Vec<(Vec<String>, Vec<Vec<String>>)> {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    files.sort();
    let mut resolved = Vec::new();
    for file in &files {
        let Some(here) = module_path_of(&src, file) else {
            continue;
        };
        if here.first().is_some_and(|first| first == "module_graph") {
            continue;
        }
        let text = std::fs::read_to_string(file).unwrap_or_default();
        // Comments name modules without depending on them.
        let code: String = text
            .lines()
            .map(|line| line.split("//").next().unwrap_or(""))
            .collect::<Vec<_>>()
            .join("\n");
        let children: BTreeSet<String> = code
            .lines()
            .filter_map(|line| {
                let line = line.trim_start();
                let line = line.strip_prefix("pub ").unwrap_or(line);
                let name = line.strip_prefix("mod ")?.strip_suffix(';')?;
                Some(name.trim().to_owned())
            })
            .collect();
        let (body, tests) = match code.find("\nmod tests") {
            Some(at) => code.split_at(at),
            None => (code.as_str(), ""),
        };
        let mut paths = paths_in(body, &here, &children);
        let in_tests: Vec<String> = here.iter().cloned().chain(["tests".to_owned()]).collect();
        paths.extend(paths_in(tests, &in_tests, &BTreeSet::new()));
        resolved.push((here, paths));
    }
    resolved
}

/// The graph of top-level modules: `from → {to}`.
fn module_graph() -> BTreeMap<String, BTreeSet<String>> {
    let resolved = resolved_sources();
    let modules: BTreeSet<String> = resolved
        .iter()
        .filter_map(|(here, _)| here.first().cloned())
        .collect();
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (here, paths) in resolved {
        let Some(from) = here.first() else {
            continue;
        };
        let edges = graph.entry(from.clone()).or_default();
        for to in paths.iter().filter_map(|path| path.first()) {
            if to != from && modules.contains(to) {
                edges.insert(to.clone());
            }
        }
    }
    graph
}

/// The graph of the files of `service/`: `from → {to}`, `mod` for `service/mod.rs` (and for what
/// it defines itself).
fn service_graph() -> BTreeMap<String, BTreeSet<String>> {
    const ROOT: &str = "mod";
    let unit_of = |path: &[String]| match path {
        [first, rest @ ..] if first == "service" => {
            Some(rest.first().cloned().unwrap_or_else(|| ROOT.to_owned()))
        }
        _ => None,
    };
    let resolved = resolved_sources();
    let files: BTreeSet<String> = resolved
        .iter()
        .filter_map(|(here, _)| unit_of(here))
        .collect();
    let mut graph: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (here, paths) in &resolved {
        let Some(from) = unit_of(here) else {
            continue;
        };
        let edges = graph.entry(from.clone()).or_default();
        for to in paths.iter().filter_map(|path| unit_of(path)) {
            // A name that is no file of the service is an item of `service/mod.rs`.
            let to = if files.contains(&to) {
                to
            } else {
                ROOT.to_owned()
            };
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

/// Fails on a circle in `graph` (the modules of `place`), once the sources were read.
fn assert_no_circle(graph: &BTreeMap<String, BTreeSet<String>>, place: &str) {
    assert!(
        graph.len() > 5,
        "the sources of {place} were read: {graph:?}"
    );
    if let Some(circle) = find_circle(graph) {
        panic!("an import circle in {place}: {}", circle.join(" → "));
    }
}

#[test]
fn the_top_level_modules_import_no_circle() {
    assert_no_circle(&module_graph(), "the crate");
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
fn the_service_files_import_no_circle() {
    assert_no_circle(&service_graph(), "service/");
}

#[test]
fn each_service_file_imports_only_from_the_layers_below_its_own() {
    let graph = service_graph();
    let layer_of: BTreeMap<&str, usize> = SERVICE_LAYERS
        .iter()
        .enumerate()
        .flat_map(|(layer, (_, files))| files.iter().map(move |file| (*file, layer)))
        .collect();
    let mut problems = Vec::new();
    for file in graph.keys() {
        if !layer_of.contains_key(file.as_str()) {
            problems.push(format!("service/{file}: no place in SERVICE_LAYERS"));
        }
    }
    for file in layer_of.keys() {
        if !graph.contains_key(*file) {
            problems.push(format!("SERVICE_LAYERS names {file}, which service/ lacks"));
        }
    }
    for (from, edges) in &graph {
        for to in edges {
            let (Some(&from_layer), Some(&to_layer)) =
                (layer_of.get(from.as_str()), layer_of.get(to.as_str()))
            else {
                continue;
            };
            if to_layer >= from_layer {
                problems.push(format!(
                    "{from} ({}) imports {to} ({}), which is not below it",
                    SERVICE_LAYERS[from_layer].0, SERVICE_LAYERS[to_layer].0
                ));
            }
        }
    }
    assert!(
        problems.is_empty(),
        "the service's layering:\n{}",
        problems.join("\n")
    );
}

#[test]
fn the_reader_resolves_paths_groups_and_anchors() {
    let strings = |paths: &[&[&str]]| -> Vec<Vec<String>> {
        paths
            .iter()
            .map(|path| path.iter().map(|s| (*s).to_owned()).collect())
            .collect()
    };
    // As in `service/mod.rs`, which declares `view`.
    let here = strings(&[&["service"]]).remove(0);
    let children: BTreeSet<String> = ["view".to_owned()].into();
    let code = "use crate::a::X;\nuse crate::{b, c::{Y, Z}};\nuse super::Error;\n\
                fn f() { crate::zz::g(); self::inner::h(); view::V::new(); my_view::w() }\n\
                pub(super) fn k() {}";
    assert_eq!(
        paths_in(code, &here, &children),
        strings(&[
            &["a", "X"],
            &["b"],
            &["c", "Y"],
            &["c", "Z"],
            &["Error"],
            &["zz", "g"],
            &["service", "inner"],
            &["service", "view"],
        ])
    );
    // In a file's tests, `super` is the file and `super::super` its parent.
    let in_tests = strings(&[&["service", "fleet", "tests"]]).remove(0);
    let code = "use super::{Fleet, Lookup};\nuse super::super::publish::P;";
    assert_eq!(
        paths_in(code, &in_tests, &BTreeSet::new()),
        strings(&[
            &["service", "fleet"],
            &["service", "fleet"],
            &["service", "publish"]
        ])
    );
}

#[test]
fn the_circle_finder_finds_a_circle_and_no_other() {
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
