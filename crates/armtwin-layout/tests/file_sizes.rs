//! Files by concern: no Rust source of the workspace (every crate and `fuzz/`) is longer than
//! [`MAX_LINES`] lines before its inline tests.
//!
//! A test only: it reads the sources as text and counts a file's lines up to its first line that
//! opens with `#[cfg(test)]` at the top level (the inline `mod tests` at its end), or all of them
//! when it has none. Integration tests under `tests/` count whole.

use std::path::{Path, PathBuf};

/// The most lines a source may have before its inline tests.
const MAX_LINES: usize = 1000;

/// Every `.rs` file under `dir`, build output and hidden directories left out.
fn sources(dir: &Path, files: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let path = entry.path();
        let name = entry.file_name();
        let name = name.to_string_lossy();
        if path.is_dir() {
            if name != "target" && !name.starts_with('.') {
                sources(&path, files);
            }
        } else if path.extension().is_some_and(|ext| ext == "rs") {
            files.push(path);
        }
    }
}

/// Lines of `text` before its first top-level `#[cfg(test)]` line, or all of them.
fn lines_before_tests(text: &str) -> usize {
    text.lines()
        .take_while(|line| !line.starts_with("#[cfg(test)]"))
        .count()
}

#[test]
fn no_source_is_over_the_limit_before_its_tests() {
    let workspace = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut files = Vec::new();
    sources(&workspace.join("crates"), &mut files);
    sources(&workspace.join("fuzz"), &mut files);
    assert!(files.len() > 50, "the sources were read: {}", files.len());
    let mut over: Vec<(usize, String)> = files
        .iter()
        .filter_map(|file| {
            let text = std::fs::read_to_string(file).unwrap_or_default();
            let lines = lines_before_tests(&text);
            let shown = file.strip_prefix(&workspace).unwrap_or(file);
            (lines > MAX_LINES).then(|| (lines, shown.display().to_string()))
        })
        .collect();
    over.sort_unstable_by(|a, b| b.cmp(a));
    assert!(
        over.is_empty(),
        "over {MAX_LINES} lines before their tests (split them by concern): {over:?}"
    );
}

#[test]
fn the_count_stops_at_the_inline_tests() {
    let text =
        "//! A module.\nfn f() {}\n    #[cfg(test)]\n    fn g() {}\n#[cfg(test)]\nmod tests {}\n";
    assert_eq!(lines_before_tests(text), 4);
    assert_eq!(lines_before_tests("fn f() {}\nfn g() {}\n"), 2);
    assert_eq!(lines_before_tests(""), 0);
}
