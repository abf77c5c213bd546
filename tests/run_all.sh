#!/usr/bin/env bash
# Runs every armtwin test from a fresh clone: Rust (format, lints, unit, integration and doc tests,
# every workspace member under crates/; a short fuzzing pass of every decoder) and the Python
# tests (independent numpy/scipy reference, the FMU in FMPy, real ROS 2 nodes through the real
# bridge), in virtualenvs this script creates.
set -euo pipefail
cd "$(dirname "$0")/.."

step() { printf '\n== %s\n' "$*"; }

# venv DIR REQUIREMENTS [PIP OPTIONS…]: the virtualenv DIR with REQUIREMENTS installed, remade
# only when the requirements file changed.
venv() {
  local dir=$1 requirements=$2
  shift 2
  [ -x "$dir/bin/python" ] || python3 -m venv "$dir"
  local want
  want=$(sha256sum "$requirements" | cut -d' ' -f1)
  if [ "$(cat "$dir/.requirements.sha256" 2>/dev/null)" != "$want" ]; then
    "$dir/bin/python" -m pip install --quiet --disable-pip-version-check "$@" -r "$requirements"
    echo "$want" > "$dir/.requirements.sha256"
  fi
}

step "cargo fmt --check"
cargo fmt --all -- --check
cargo fmt --manifest-path fuzz/Cargo.toml -- --check

step "test tools (iproute2, cmake and libclang, Debian's chromium; Prometheus unpacked into .cache/)"
eval "$(bash scripts/test-tools.sh)"
export ARMTWIN_CHROMIUM ARMTWIN_PROMETHEUS

step "cargo clippy (pedantic, warnings are errors; armtwin-router with and without the ROS 2 bridge)"
cargo clippy --locked --workspace --all-targets -- -D warnings
cargo clippy --locked -p armtwin-router --features ros2dds --all-targets -- -D warnings

step "cargo test"
cargo test --locked --workspace

step "fuzz every decoder briefly (scripts/fuzz.sh: cargo-fuzz cached under .cache/)"
bash scripts/fuzz.sh short

step "Python virtualenvs: .venv (tests/python/requirements.txt), .venv-ros2 (ROS 2 Jazzy's rclpy)"
venv .venv tests/python/requirements.txt
# Prebuilt wheels only (rclpy, rcl, Fast DDS), but for one pure-Python sdist.
venv .venv-ros2 tests/python/requirements-ros2.txt --only-binary=:all: --no-binary=empy

step "build for pytest"
# The armtwin binary, the FMU library beside it and the core's `examples/rnea_json` (the dynamics
# reference test's route into the core), from the build `cargo test` just made: the
# same targets with the same feature set (dev-dependencies included), so nothing is compiled
# again; only the FMU's cdylib is copied up to target/debug/. Then armtwin-router with the ROS 2
# bridge (its CycloneDDS compiled once, then cached in target/ like every other crate).
cargo build --locked --workspace --lib --bins --tests
cargo build --locked -p armtwin-router --features ros2dds
export ARMTWIN_BIN="$PWD/target/debug/armtwin"

step "pytest tests/python"
.venv/bin/python -m pytest tests/python -q --ignore=tests/python/test_ros2_real.py

step "pytest tests/python/test_ros2_real.py: rclpy through the bridge, in a private network namespace"
# DDS discovers by multicast: nothing of it leaves this namespace, whose only interface is loopback.
unshare -n sh -c 'ip link set lo up && ip link set lo multicast on &&
  exec .venv/bin/python -m pytest tests/python/test_ros2_real.py -q'
