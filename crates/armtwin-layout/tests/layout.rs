//! The workspace's layout, read from its sources: the crates depend on each other only as the
//! layout allows, no crate's modules import each other in a circle, and inside the service's
//! `service/` every file imports only from the layers below its own.
//!
//! A test only: it reads every `crates/*/Cargo.toml` (its `[dependencies]`, target-specific ones
//! too; dev-dependencies are a test's business and left out) and every crate's `src/` as text,
//! comments left out. In the sources it resolves every path that starts with `crate::`,
//! `super::` or `self::` (a `use …::{…}` group's every item alike), or with a module the file
//! declares, so it sees every `use` and every fully qualified path of the crate's own.
#![allow(
    clippy::expect_used,
    reason = "a test, or a helper of one, that fails an expectation fails the test"
)]

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// What a crate must not reach, through its dependencies and theirs: workspace crates and the
/// external crates any crate on the way depends on directly.
const FORBIDDEN_REACH: &[(&str, &[&str])] = &[
    // The pure core: no other armtwin crate, no network, no runtime, no JSON, no command line.
    (
        "armtwin-core",
        &[
            "armtwin-codec",
            "armtwin-mesh",
            "armtwin-service",
            "zenoh",
            "tokio",
            "serde_json",
            "clap",
            "anyhow",
        ],
    ),
    // Codecs: bytes ⇄ core types, no network, no runtime.
    (
        "armtwin-codec",
        &["armtwin-mesh", "armtwin-service", "zenoh", "tokio"],
    ),
    // Session plumbing knows no twin, no door and no mode.
    (
        "armtwin-mesh",
        &[
            "armtwin-access",
            "armtwin-recorder",
            "armtwin-view",
            "armtwin-dashboard",
            "armtwin-gateway",
            "armtwin-offline",
            "armtwin-service",
            "axum",
            "mcap",
        ],
    ),
    // Who may do what knows nothing of what they reach.
    (
        "armtwin-access",
        &[
            "armtwin-recorder",
            "armtwin-view",
            "armtwin-dashboard",
            "armtwin-gateway",
            "armtwin-offline",
            "armtwin-service",
            "axum",
        ],
    ),
    // The flight recorder's rings and files: nothing networked, no service.
    (
        "armtwin-recorder",
        &[
            "armtwin-mesh",
            "armtwin-access",
            "armtwin-dashboard",
            "armtwin-service",
            "zenoh",
            "tokio",
            "axum",
        ],
    ),
    // What a running fleet shows its doors: no door, no service, no network of its own.
    (
        "armtwin-view",
        &["armtwin-dashboard", "armtwin-service", "zenoh", "axum"],
    ),
    // The dashboard defines what it reads; the service provides it, never the other way.
    (
        "armtwin-dashboard",
        &[
            "armtwin-service",
            "armtwin-recorder",
            "armtwin-offline",
            "armtwin-gateway",
            "mcap",
        ],
    ),
    // The RTDE gateway publishes on the mesh like any other gateway.
    (
        "armtwin-gateway",
        &[
            "armtwin-service",
            "armtwin-dashboard",
            "armtwin-offline",
            "armtwin-recorder",
            "axum",
        ],
    ),
    // Offline modes and `record` take the mesh, never the service's internals.
    (
        "armtwin-offline",
        &[
            "armtwin-service",
            "armtwin-dashboard",
            "armtwin-gateway",
            "axum",
        ],
    ),
    // The service knows the dashboard only through what it reads.
    (
        "armtwin-service",
        &[
            "armtwin-dashboard",
            "armtwin-offline",
            "armtwin-gateway",
            "axum",
        ],
    ),
    // The FMU is the core alone; the OPC UA server knows nothing of armtwin.
    (
        "armtwin-fmu",
        &["armtwin-codec", "armtwin-mesh", "zenoh", "tokio"],
    ),
    (
        "armtwin-opcua",
        &["armtwin-core", "armtwin-codec", "armtwin-mesh", "zenoh"],
    ),
];

/// External crates only these workspace crates may depend on directly: each door's own.
const ONLY_IN: &[(&str, &[&str])] = &[
    // The dashboard, and the router's bounded REST door.
    ("axum", &["armtwin-dashboard", "armtwin-router"]),
    ("prometheus-client", &["armtwin-dashboard"]),
    ("rusqlite", &["armtwin-offline"]),
    ("zip", &["armtwin-offline"]),
    ("async-opcua", &["armtwin-opcua"]),
    // The command lines: `armtwin` and the two other binaries.
    ("clap", &["armtwin-cli", "armtwin-bench", "armtwin-router"]),
    (
        "anyhow",
        &["armtwin-cli", "armtwin-bench", "armtwin-router"],
    ),
];

/// The service crate's `service/` files, lowest layer first: a file imports only from the
/// layers below its own, never from its own layer or one above. `mod` is `service/mod.rs`. A
/// new file takes its place here.
const SERVICE_LAYERS: &[(&str, &[&str])] = &[
    ("why the service stops", &["error"]),
    (
        "leaves: each knows the crate (and the error) alone",
        &[
            "admin",
            "calibration_slot",
            "events",
            "gateways",
            "history_log",
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
            "description",
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

/// The crate that holds `service/`.
const SERVICE_CRATE: &str = "armtwin-service";

fn workspace() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// Every workspace crate under `crates/`: its folder by its package name.
fn crates() -> BTreeMap<String, PathBuf> {
    let mut found = BTreeMap::new();
    let Ok(entries) = std::fs::read_dir(workspace().join("crates")) else {
        return found;
    };
    for entry in entries.flatten() {
        let manifest = entry.path().join("Cargo.toml");
        let Ok(text) = std::fs::read_to_string(&manifest) else {
            continue;
        };
        let table: toml::Table = text.parse().expect("a valid Cargo.toml");
        if let Some(name) = table
            .get("package")
            .and_then(|package| package.get("name"))
            .and_then(toml::Value::as_str)
        {
            found.insert(name.to_owned(), entry.path());
        }
    }
    found
}

/// The normal dependencies a manifest names: `[dependencies]`, `[build-dependencies]` and every
/// `[target.….dependencies]`, by package name (a renamed one by its `package`).
fn dependencies_of(manifest: &toml::Table) -> BTreeSet<String> {
    let mut tables: Vec<&toml::Table> = ["dependencies", "build-dependencies"]
        .iter()
        .filter_map(|key| manifest.get(*key).and_then(toml::Value::as_table))
        .collect();
    if let Some(targets) = manifest.get("target").and_then(toml::Value::as_table) {
        for target in targets.values() {
            tables.extend(
                ["dependencies", "build-dependencies"]
                    .iter()
                    .filter_map(|key| target.get(*key).and_then(toml::Value::as_table)),
            );
        }
    }
    tables
        .into_iter()
        .flat_map(|table| {
            table.iter().map(|(name, spec)| {
                spec.get("package")
                    .and_then(toml::Value::as_str)
                    .unwrap_or(name)
                    .to_owned()
            })
        })
        .collect()
}

/// Each workspace crate's direct normal dependencies, workspace and external alike.
fn crate_graph() -> BTreeMap<String, BTreeSet<String>> {
    crates()
        .into_iter()
        .map(|(name, dir)| {
            let text = std::fs::read_to_string(dir.join("Cargo.toml")).unwrap_or_default();
            let manifest: toml::Table = text.parse().expect("a valid Cargo.toml");
            (name, dependencies_of(&manifest))
        })
        .collect()
}

/// What `from` reaches in `graph`: every crate on a dependency path from it (external ones
/// included, which have no edges of their own here).
fn reach(graph: &BTreeMap<String, BTreeSet<String>>, from: &str) -> BTreeSet<String> {
    let mut seen = BTreeSet::new();
    let mut next = vec![from.to_owned()];
    while let Some(name) = next.pop() {
        for to in graph.get(&name).into_iter().flatten() {
            if seen.insert(to.clone()) {
                next.push(to.clone());
            }
        }
    }
    seen
}

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
/// `[service, fleet]`, `service/mod.rs` → `[service]`, `lib.rs` → `[]`. A binary's other roots
/// (`src/bin/*.rs`) are left out: each is a crate of its own.
fn module_path_of(src: &Path, file: &Path) -> Option<Vec<String>> {
    let relative = file.strip_prefix(src).ok()?;
    let mut path: Vec<String> = relative
        .components()
        .map(|part| part.as_os_str().to_str().map(str::to_owned))
        .collect::<Option<_>>()?;
    if path.first().is_some_and(|first| first == "bin") {
        return None;
    }
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

/// How deep a resolved path is kept: deeper than any module nesting of the workspace.
const DEPTH: usize = 6;

/// Every path in `code`, written in module `here`, that starts with `crate::`, `super::` (once or
/// more), `self::` or one of `children` (the modules `here` declares), resolved from the crate
/// root and cut to its first [`DEPTH`] segments.
fn paths_in(code: &str, here: &[String], children: &BTreeSet<String>) -> Vec<Vec<String>> {
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

/// Every source file of the crate in `dir`: its module path and the paths its code names,
/// resolved. A file's inline `mod tests` (from its `mod tests` line on) is read as the module it
/// is.
fn resolved_sources(dir: &Path) -> Vec<(Vec<String>, Vec<Vec<String>>)> {
    let src = dir.join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    files.sort();
    let mut resolved = Vec::new();
    for file in &files {
        let Some(here) = module_path_of(&src, file) else {
            continue;
        };
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
                let line = line.strip_prefix("pub(crate) ").unwrap_or(line);
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

/// Each folder's graph of its modules, by the folder's module path: a node is one of its files
/// or subfolders (the folder's own `mod.rs` or `lib.rs` is the folder, not a node), and `a → b`
/// when anything under `a` names anything under `b`.
fn folder_graphs(
    resolved: &[(Vec<String>, Vec<Vec<String>>)],
) -> BTreeMap<Vec<String>, BTreeMap<String, BTreeSet<String>>> {
    let modules: BTreeSet<&[String]> = resolved.iter().map(|(here, _)| here.as_slice()).collect();
    let mut graphs: BTreeMap<Vec<String>, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
    for (here, _) in resolved {
        if let Some((last, folder)) = here.split_last() {
            graphs
                .entry(folder.to_vec())
                .or_default()
                .entry(last.clone())
                .or_default();
        }
    }
    for (here, paths) in resolved {
        for path in paths {
            // The folder both lie in, and the child of it each is under.
            let shared = here.iter().zip(path).take_while(|(a, b)| a == b).count();
            let (Some(from), Some(to)) = (here.get(shared), path.get(shared)) else {
                continue;
            };
            let folder = &here[..shared];
            let to_path: Vec<String> = folder.iter().chain([to]).cloned().collect();
            if !modules.iter().any(|module| module.starts_with(&to_path)) {
                continue;
            }
            graphs
                .entry(folder.to_vec())
                .or_default()
                .entry(from.clone())
                .or_default()
                .insert(to.clone());
        }
    }
    graphs
}

/// The graph of the files of the service crate's `service/`: `from → {to}`, `mod` for
/// `service/mod.rs` (and for what it defines itself).
fn service_graph() -> BTreeMap<String, BTreeSet<String>> {
    const ROOT: &str = "mod";
    let unit_of = |path: &[String]| match path {
        [first, rest @ ..] if first == "service" => {
            Some(rest.first().cloned().unwrap_or_else(|| ROOT.to_owned()))
        }
        _ => None,
    };
    let dir = crates()
        .remove(SERVICE_CRATE)
        .expect("the service crate exists");
    let resolved = resolved_sources(&dir);
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

#[test]
fn no_crate_imports_a_circle_between_its_modules() {
    let crates = crates();
    assert!(crates.len() > 10, "the crates were found: {crates:?}");
    let mut circles = Vec::new();
    let mut folders = 0;
    for (name, dir) in &crates {
        for (folder, graph) in folder_graphs(&resolved_sources(dir)) {
            folders += 1;
            if let Some(circle) = find_circle(&graph) {
                let place = if folder.is_empty() {
                    "src/".to_owned()
                } else {
                    format!("src/{}/", folder.join("/"))
                };
                circles.push(format!("{name} {place}: {}", circle.join(" → ")));
            }
        }
    }
    assert!(folders > 25, "the sources were read: {folders} folders");
    assert!(
        circles.is_empty(),
        "import circles:\n{}",
        circles.join("\n")
    );
}

#[test]
fn no_crate_reaches_what_the_layout_forbids() {
    let graph = crate_graph();
    let mut problems = Vec::new();
    for (from, forbidden) in FORBIDDEN_REACH {
        assert!(graph.contains_key(*from), "{from} is a workspace crate");
        let reached = reach(&graph, from);
        for to in *forbidden {
            if reached.contains(*to) {
                problems.push(format!("{from} reaches {to}"));
            }
        }
    }
    for (external, owners) in ONLY_IN {
        for (name, dependencies) in &graph {
            if dependencies.contains(*external) && !owners.contains(&name.as_str()) {
                problems.push(format!(
                    "{name} depends on {external}, which is {owners:?}'s"
                ));
            }
        }
    }
    assert!(
        problems.is_empty(),
        "the crate graph:\n{}",
        problems.join("\n")
    );
}

#[test]
fn the_service_files_import_no_circle() {
    let graph = service_graph();
    assert!(
        graph.len() > 5,
        "the service's sources were read: {graph:?}"
    );
    if let Some(circle) = find_circle(&graph) {
        panic!("an import circle in service/: {}", circle.join(" → "));
    }
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

fn strings(paths: &[&[&str]]) -> Vec<Vec<String>> {
    paths
        .iter()
        .map(|path| path.iter().map(|s| (*s).to_owned()).collect())
        .collect()
}

#[test]
fn the_reader_resolves_paths_groups_and_anchors() {
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
            &["service", "inner", "h"],
            &["service", "view", "V", "new"],
        ])
    );
    // In a file's tests, `super` is the file and `super::super` its parent.
    let in_tests = strings(&[&["service", "fleet", "tests"]]).remove(0);
    let code = "use super::{Fleet, Lookup};\nuse super::super::publish::P;";
    assert_eq!(
        paths_in(code, &in_tests, &BTreeSet::new()),
        strings(&[
            &["service", "fleet", "Fleet"],
            &["service", "fleet", "Lookup"],
            &["service", "publish", "P"]
        ])
    );
}

#[test]
fn a_folder_graph_joins_siblings_and_leaves_the_parent_out() {
    // `a/mod.rs` uses its child `x`, `x` uses its sibling `y` (through the parent's path) and an
    // item of the parent; `y` uses the crate's `b`, whose child uses `a/x`.
    let resolved = vec![
        (strings(&[&["a"]]).remove(0), strings(&[&["a", "x", "X"]])),
        (
            strings(&[&["a", "x"]]).remove(0),
            strings(&[&["a", "y", "Y"], &["a", "Item"]]),
        ),
        (strings(&[&["a", "y"]]).remove(0), strings(&[&["b", "B"]])),
        (
            strings(&[&["b", "z"]]).remove(0),
            strings(&[&["a", "x", "X"]]),
        ),
    ];
    let graphs = folder_graphs(&resolved);
    let edges = |folder: &[&str], from: &str| -> Vec<String> {
        let folder: Vec<String> = folder.iter().map(|s| (*s).to_owned()).collect();
        graphs[&folder][from].iter().cloned().collect()
    };
    assert_eq!(edges(&[], "a"), ["b"]);
    assert_eq!(edges(&[], "b"), ["a"]);
    assert_eq!(edges(&["a"], "x"), ["y"]);
    assert!(edges(&["a"], "y").is_empty());
    assert_eq!(
        find_circle(&graphs[&Vec::new()]),
        Some(vec!["a".into(), "b".into(), "a".into()])
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

#[test]
fn reach_follows_dependencies_of_dependencies() {
    let graph: BTreeMap<String, BTreeSet<String>> = [
        ("service", vec!["view", "tokio"]),
        ("view", vec!["core"]),
        ("core", vec!["nalgebra"]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_owned(), v.into_iter().map(str::to_owned).collect()))
    .collect();
    let reached: Vec<String> = reach(&graph, "service").into_iter().collect();
    assert_eq!(reached, ["core", "nalgebra", "tokio", "view"]);
}

#[test]
fn the_layout_checks_from_outside_the_graph() {
    // It reads every crate without an edge to any (dev-dependencies included), so that a change
    // to it recompiles nothing else and it cannot shape what it checks.
    let mut problems = Vec::new();
    for (name, dir) in crates() {
        let text = std::fs::read_to_string(dir.join("Cargo.toml")).unwrap_or_default();
        let manifest: toml::Table = text.parse().expect("a valid Cargo.toml");
        let mut names = dependencies_of(&manifest);
        if let Some(dev) = manifest
            .get("dev-dependencies")
            .and_then(toml::Value::as_table)
        {
            names.extend(dev.keys().cloned());
        }
        if name == "armtwin-layout" {
            problems.extend(
                names
                    .iter()
                    .filter(|dependency| dependency.starts_with("armtwin"))
                    .map(|dependency| format!("armtwin-layout depends on {dependency}")),
            );
        } else if names.contains("armtwin-layout") {
            problems.push(format!("{name} depends on armtwin-layout"));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}
