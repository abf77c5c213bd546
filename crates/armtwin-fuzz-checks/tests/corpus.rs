//! Every committed fuzz input through its decoder's check: the corpora under `fuzz/corpus/` (the
//! inputs that reach every branch the fuzzer found) and the regression inputs under
//! `fuzz/regressions/` (each a finding once, kept fixed). A decoder change that breaks one of them
//! fails here, in the ordinary test build, without the instrumented fuzz build.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};

use armtwin_fuzz_checks::CHECKS;

/// The workspace's `fuzz/` folder.
fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fuzz")
}

/// The files of `dir`, sorted; none when it does not exist.
fn inputs(dir: &Path) -> Vec<PathBuf> {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return Vec::new();
    };
    let mut files: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| path.is_file())
        .collect();
    files.sort();
    files
}

/// Runs `target`'s check on each of its inputs and fails naming every input that broke it.
fn run(target: &str) {
    let Some(&(_, check)) = CHECKS.iter().find(|(name, _)| *name == target) else {
        panic!("no check named {target}");
    };
    let corpus = inputs(&fuzz_dir().join("corpus").join(target));
    // An empty or misplaced corpus would make this test pass on nothing.
    assert!(
        !corpus.is_empty(),
        "no corpus for {target} under {}",
        fuzz_dir().display()
    );
    let regressions = inputs(&fuzz_dir().join("regressions").join(target));
    let mut broken = Vec::new();
    for path in corpus.iter().chain(&regressions) {
        let bytes =
            std::fs::read(path).unwrap_or_else(|error| panic!("{}: {error}", path.display()));
        if catch_unwind(AssertUnwindSafe(|| check(&bytes))).is_err() {
            broken.push(path.display().to_string());
        }
    }
    assert!(
        broken.is_empty(),
        "{} of {} {target} inputs broke the check (replay one with `cargo fuzz run -s none {target} FILE` from fuzz/):\n{}",
        broken.len(),
        corpus.len() + regressions.len(),
        broken.join("\n")
    );
}

/// The file stems of `dir`'s entries (file or folder), sorted.
fn names_in(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap_or_else(|error| panic!("{}: {error}", dir.display()))
        .filter_map(Result::ok)
        .filter_map(|entry| {
            let path = entry.path();
            path.file_stem()
                .map(|stem| stem.to_string_lossy().into_owned())
        })
        .collect();
    names.sort();
    names
}

#[test]
fn every_fuzz_target_has_a_check_a_corpus_and_a_test_here() {
    let checked: Vec<String> = CHECKS.iter().map(|(name, _)| (*name).to_owned()).collect();
    assert_eq!(names_in(&fuzz_dir().join("fuzz_targets")), checked);
    assert_eq!(names_in(&fuzz_dir().join("corpus")), checked);
    let source = include_str!("corpus.rs");
    for name in &checked {
        assert!(
            source.contains(&format!("run(\"{name}\")")),
            "no test runs the {name} corpus"
        );
    }
}

#[test]
fn calibration() {
    run("calibration");
}

#[test]
fn certificate_names() {
    run("certificate_names");
}

#[test]
fn cdr() {
    run("cdr");
}

#[test]
fn csv() {
    run("csv");
}

#[test]
fn fleet() {
    run("fleet");
}

#[test]
fn json() {
    run("json");
}

#[test]
fn ros2_attachment() {
    run("ros2_attachment");
}

#[test]
fn rtde() {
    run("rtde");
}

#[test]
fn snapshot() {
    run("snapshot");
}

#[test]
fn urdf() {
    run("urdf");
}

#[test]
fn zser() {
    run("zser");
}
