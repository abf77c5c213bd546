#!/usr/bin/env bash
# Runs every armtwin test from a fresh clone: Rust (format, lints, unit, integration and doc tests,
# every workspace member under crates/; a short fuzzing pass of every decoder) and the Python
# tests (independent numpy/scipy reference, the FMU in FMPy), in a virtualenv this script creates.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n== %s\n' "$*"; }

step "cargo fmt --check"
cargo fmt --all -- --check
cargo fmt --manifest-path fuzz/Cargo.toml -- --check

step "cargo clippy (pedantic, warnings are errors)"
cargo clippy --locked --workspace --all-targets -- -D warnings

step "cargo test"
cargo test --locked --workspace

step "fuzz every decoder briefly (scripts/fuzz.sh: cargo-fuzz cached under .cache/)"
bash scripts/fuzz.sh short

step "Python virtualenv (.venv) from tests/python/requirements.txt"
venv=.venv
[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
want=$(sha256sum tests/python/requirements.txt | cut -d' ' -f1)
if [ "$(cat "$venv/.requirements.sha256" 2>/dev/null)" != "$want" ]; then
  "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r tests/python/requirements.txt
  echo "$want" > "$venv/.requirements.sha256"
fi

step "test tools (Debian's chromium; Prometheus unpacked into .cache/)"
eval "$(bash scripts/test-tools.sh)"
export ARMTWIN_CHROMIUM ARMTWIN_PROMETHEUS

step "pytest tests/python"
# The armtwin binary, the FMU library beside it and the core's `examples/rnea_json` (the dynamics
# reference test's route into the core), from the build `cargo test` just made: the
# same targets with the same feature set (dev-dependencies included), so nothing is compiled
# again; only the FMU's cdylib is copied up to target/debug/.
cargo build --locked --workspace --lib --bins --tests
ARMTWIN_BIN="$PWD/target/debug/armtwin" "$venv/bin/python" -m pytest tests/python -q
