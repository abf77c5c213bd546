//! The example configuration (`config/armtwin.toml`, also the embedded default) documents every
//! key the parser reads, and no key it does not.
//!
//! The parser's keys come from the serde types themselves: every section refuses unknown fields
//! and names the ones it knows, so a probe key at each depth lists them. The documented keys come
//! from the file's lines, commented-out examples included. A section added to [`super::file`]
//! (with `deny_unknown_fields`, as every section has) and written up in the example passes with
//! no change here; one without it shows as a single undocumented key.

use std::collections::BTreeSet;

use serde::Deserialize;
use toml::{Table, Value};

use super::DEFAULT_CONFIG_TOML;
use super::file::File;

const PROBE: &str = "__probe__";

/// Keys read only to refuse them with the reason: documenting them would invite their use.
const RETIRED: &[&str] = &["service.window_max_samples"];

/// How a table-valued field holds its tables.
#[derive(Clone, Copy)]
enum Nesting {
    /// `[a.f]`: one table.
    Table,
    /// `[a.f."<name>"]`: tables by name (`robots`).
    Map,
    /// `[[a.f]]`: an array of tables (`sources`).
    Array,
}

/// The document holding the probe key under `path`, each step nested as it says.
fn probe_document(path: &[(String, Nesting)]) -> Value {
    let mut value = Value::Table(Table::from_iter([(PROBE.to_owned(), Value::Integer(1))]));
    for (name, nesting) in path.iter().rev() {
        value = match nesting {
            Nesting::Table => value,
            Nesting::Map => Value::Table(Table::from_iter([("x".to_owned(), value)])),
            Nesting::Array => Value::Array(vec![value]),
        };
        value = Value::Table(Table::from_iter([(name.clone(), value)]));
    }
    value
}

/// The fields of the struct the parser expects under `path`, or `None` when no struct is there.
fn fields_at(path: &[(String, Nesting)]) -> Option<Vec<String>> {
    let error = File::deserialize(probe_document(path)).err()?;
    let expected = error
        .message()
        .strip_prefix(&format!("unknown field `{PROBE}`, "))?
        .to_owned();
    Some(
        expected
            .split('`')
            .skip(1)
            .step_by(2)
            .map(str::to_owned)
            .collect(),
    )
}

/// The name of a path as both sides write it: map keys as `*`.
fn dotted(path: &[(String, Nesting)], leaf: &str) -> String {
    let mut parts = Vec::new();
    for (name, nesting) in path {
        parts.push(name.clone());
        if matches!(nesting, Nesting::Map) {
            parts.push("*".to_owned());
        }
    }
    parts.push(leaf.to_owned());
    parts.join(".")
}

/// Every leaf key the parser reads, and the paths whose next level is a map of tables.
fn parser_keys() -> (BTreeSet<String>, BTreeSet<String>) {
    let mut keys = BTreeSet::new();
    let mut maps = BTreeSet::new();
    let mut pending = vec![Vec::new()];
    while let Some(path) = pending.pop() {
        let fields = fields_at(&path).expect("a struct at every path visited");
        for field in fields {
            let nested = [Nesting::Table, Nesting::Map, Nesting::Array]
                .into_iter()
                .find(|&nesting| {
                    let mut deeper = path.clone();
                    deeper.push((field.clone(), nesting));
                    fields_at(&deeper).is_some()
                });
            match nested {
                Some(nesting) => {
                    if matches!(nesting, Nesting::Map) {
                        maps.insert(dotted(&path, &field));
                    }
                    let mut deeper = path.clone();
                    deeper.push((field, nesting));
                    pending.push(deeper);
                }
                None => {
                    keys.insert(dotted(&path, &field));
                }
            }
        }
    }
    (keys, maps)
}

/// A TOML header's dotted keys, quotes removed (`robots."a/b".sensors` → `robots`, `a/b`,
/// `sensors`).
fn header_keys(header: &str) -> Vec<String> {
    let mut keys = vec![String::new()];
    let mut quoted = false;
    for c in header.chars() {
        match c {
            '"' => quoted = !quoted,
            '.' if !quoted => keys.push(String::new()),
            c if quoted || !c.is_whitespace() => keys.last_mut().expect("one key").push(c),
            _ => {}
        }
    }
    keys
}

/// Every key the example writes or shows commented out, under its section, map keys as `*`.
fn documented_keys(text: &str, maps: &BTreeSet<String>) -> BTreeSet<String> {
    let mut section = String::new();
    let mut keys = BTreeSet::new();
    for line in text.lines() {
        let line = line.trim_start_matches('#').trim();
        if let Some(header) = line.strip_prefix('[') {
            let header = header.trim_start_matches('[');
            let Some((inside, after)) = header.split_once(']') else {
                continue;
            };
            let after = after.trim_start_matches(']').trim();
            // Prose that starts with a header's name ("[robots.default] gives it …") is not one.
            if !(after.is_empty() || after.starts_with('#')) {
                continue;
            }
            let mut parts: Vec<String> = Vec::new();
            for key in header_keys(inside) {
                let name = if maps.contains(&parts.join(".")) {
                    "*".to_owned()
                } else {
                    key
                };
                parts.push(name);
            }
            section = parts.join(".");
        } else if let Some((key, _)) = line.split_once('=') {
            let key = key.trim();
            let is_key = !key.is_empty()
                && key
                    .chars()
                    .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_');
            if is_key {
                keys.insert(if section.is_empty() {
                    key.to_owned()
                } else {
                    format!("{section}.{key}")
                });
            }
        }
    }
    keys
}

#[test]
fn the_example_configuration_documents_every_key_the_parser_reads_and_no_other() {
    let (parser, maps) = parser_keys();
    assert!(
        parser.contains("zenoh.listen") && parser.contains("robots.*.sensors.key_expr"),
        "the probe found the parser's keys: {parser:?}"
    );
    let documented = documented_keys(DEFAULT_CONFIG_TOML, &maps);
    let undocumented: Vec<_> = parser
        .iter()
        .filter(|key| !documented.contains(*key) && !RETIRED.contains(&key.as_str()))
        .collect();
    let unknown: Vec<_> = documented.difference(&parser).collect();
    assert!(
        undocumented.is_empty() && unknown.is_empty(),
        "config/armtwin.toml leaves out {undocumented:?} and documents keys the parser does not \
         read: {unknown:?}"
    );
}
