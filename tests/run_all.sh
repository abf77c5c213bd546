#!/usr/bin/env bash
# Runs every armtwin test from a fresh clone: Rust (format, lints, unit, integration and doc tests,
# every workspace member under crates/, every fuzz target's committed corpus and regression inputs
# through its decoder's checks) and the Python tests (independent numpy/scipy reference, the FMU in
# FMPy, real ROS 2 nodes through the real bridge), in virtualenvs this script creates. Ends with
# each step's seconds, passed or failed.
#
# One compilation serves the lints, `cargo test` and the Python tests: clippy-driver compiles the
# workspace's own crates (see `linted` below), so dependencies are built once and never checked
# a second time. What needs no CPU (apt, pip) runs beside it. The Python tests run in parallel
# workers, since they mostly wait on sockets and timers. Tools kept across clones (Prometheus)
# live in $ARMTWIN_CACHE (~/.cache/armtwin unless set), one folder per version. Fuzzing itself
# (an instrumented build of its own) is not part of this command: `scripts/fuzz.sh SECONDS`,
# docs/fuzzing.md.
set -euo pipefail
cd "$(dirname "$0")/.."
export ARMTWIN_CACHE="${ARMTWIN_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/armtwin}"
scratch=$(mktemp -d)
# The Python tests' parallel workers: they mostly wait, so more than the cores.
ARMTWIN_PYTEST_WORKERS=${ARMTWIN_PYTEST_WORKERS:-4}

# step NAME TITLE: NAME is the step's row in the closing table.
timings=()
step_name=
step_started_s=0
step() {
  end_step
  step_name=$1
  step_started_s=$SECONDS
  printf '\n== %s\n' "$2"
}
end_step() {
  if [ -n "$step_name" ]; then
    timings+=("$((SECONDS - step_started_s))|$step_name")
    step_name=
  fi
}
print_timings() {
  local status=$?
  end_step
  local name
  if [ "$status" != 0 ]; then
    # A step failed: stop what still runs beside it, but for apt, which must not stop half-way.
    for name in "${!beside_pids[@]}"; do
      [ "$name" = "test tools" ] || stop_tree "${beside_pids[$name]}"
    done
  fi
  wait || true
  for name in "${!beside_pids[@]}"; do
    if [ -z "${collected[$name]:-}" ] && [ -e "$scratch/$name.seconds" ]; then
      timings+=("$(cat "$scratch/$name.seconds")|  $name (beside, not waited for)")
    fi
  done
  printf '\n== seconds per step (%s)\n' "$([ "$status" = 0 ] && echo passed || echo "FAILED with exit $status")"
  local row
  for row in "${timings[@]}"; do
    printf '%6s  %s\n' "${row%%|*}" "${row#*|}"
  done
  printf '%6s  %s\n' "$SECONDS" "total (wall clock)"
  rm -rf "$scratch"
}
trap print_timings EXIT

# stop_tree PID: ends PID and every process below it, all at once so none starts another.
descendants() {
  local child
  for child in $(pgrep -P "$1"); do
    echo "$child"
    descendants "$child"
  done
}
stop_tree() {
  # shellcheck disable=SC2046
  kill "$1" $(descendants "$1") 2>/dev/null || true
}

# beside NAME COMMAND…: starts COMMAND now, beside the steps that follow, its output kept aside;
# `collect NAME` waits for it, prints that output and adds its seconds to the table.
declare -A beside_pids collected
beside() {
  local name=$1
  shift
  (
    started_s=$(date +%s)
    status=0
    "$@" >"$scratch/$name.log" 2>&1 || status=$?
    echo "$(($(date +%s) - started_s))" >"$scratch/$name.seconds"
    exit "$status"
  ) &
  beside_pids[$name]=$!
}
collect() {
  end_step
  local name=$1 status=0 waited_from_s=$SECONDS
  printf '\n== %s (ran beside the steps above)\n' "$name"
  wait "${beside_pids[$name]}" || status=$?
  collected[$name]=1
  cat "$scratch/$name.log"
  timings+=("$(cat "$scratch/$name.seconds")|  $name (beside; $((SECONDS - waited_from_s)) s waited for it)")
  return "$status"
}

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
venvs() {
  venv .venv tests/python/requirements.txt
  # Prebuilt wheels only (rclpy, rcl, Fast DDS), but for one pure-Python sdist.
  venv .venv-ros2 tests/python/requirements-ros2.txt --only-binary=:all: --no-binary=empy
}

# linted COMMAND…: COMMAND (cargo, perhaps behind nice) with clippy-driver compiling the
# workspace's own crates, the way `cargo clippy` runs it (RUSTC_WORKSPACE_WRAPPER, and CLIPPY_ARGS
# for what follows its `--`): each crate is linted, pedantic and with warnings as errors, while it
# is compiled for the tests. Dependencies are compiled by rustc as usual. Every cargo command
# below goes through here, so that all see the same compiler and nothing is compiled twice.
clippy_driver="$(rustc --print sysroot)/bin/clippy-driver"
linted() {
  RUSTC_WORKSPACE_WRAPPER="$clippy_driver" CLIPPY_ARGS="-D__CLIPPY_HACKERY__warnings__CLIPPY_HACKERY__" "$@"
}

step fmt "cargo fmt --check"
cargo fmt --all -- --check
cargo fmt --manifest-path fuzz/Cargo.toml -- --check
[ -x "$clippy_driver" ] || { echo "clippy-driver not found: rustup component add clippy" >&2; exit 1; }

# apt and pip wait on the network, beside the build.
beside "test tools" sh -c 'bash scripts/test-tools.sh > "$1"' sh "$scratch/tools.env"
beside "virtualenvs" venvs

step build "clippy and build, every target (pedantic, warnings are errors; no ROS 2 bridge)"
# The targets of `cargo clippy --all-targets`, compiled: lib, bins, tests, benches, examples.
linted cargo build --locked --workspace --all-targets

# iproute2, cmake and libclang, Debian's chromium; Prometheus unpacked into $ARMTWIN_CACHE
# (`cargo test`'s soak is scraped by it).
collect "test tools"
# shellcheck disable=SC1091
. "$scratch/tools.env"
export ARMTWIN_CHROMIUM ARMTWIN_PROMETHEUS
# The Rust tests run with nothing beside them: their services stream at full rate, and a
# compiler on the other core made them miss samples.

# cargo-nextest runs the test binaries side by side (a test waiting on its service no longer holds
# up the next binary); `cargo test` runs them one after the other. Both build nothing new but the
# doc tests.
if cargo nextest --version >/dev/null 2>&1; then
  step test "cargo nextest run, then the doc tests"
  linted cargo nextest run --locked --workspace
  linted cargo test --locked --workspace --doc
else
  step test "cargo test (compiles only the doc tests; cargo-nextest would run the binaries side by side)"
  linted cargo test --locked --workspace
fi

step bridge "clippy and build armtwin-router with the ROS 2 bridge"
# The same build with `ros2dds` on: only armtwin-router and the bridge's own crates (CycloneDDS,
# compiled by cmake) are new, since armtwin-router's `regex` keeps every other crate's features
# as they were. Leaves the bridge's router in target/debug for the Python tests.
linted cargo build --locked --workspace --all-targets --features armtwin-router/ros2dds
export ARMTWIN_BIN="$PWD/target/debug/armtwin"

collect "virtualenvs"

step pytest "pytest tests/python, $ARMTWIN_PYTEST_WORKERS workers"
# A test module's tests stay on one worker (they share its module-scoped services); each worker
# takes its ports from a block of its own (tests/python/support/process.py).
# The slowest tests are listed at the end: where the step's time goes, in every run's log.
.venv/bin/python -m pytest tests/python -q -n "$ARMTWIN_PYTEST_WORKERS" --dist loadfile \
  --durations=25 --ignore=tests/python/test_ros2_real.py

step ros2 "pytest tests/python/test_ros2_real.py: rclpy through the bridge, in a private network namespace"
# DDS discovers by multicast: nothing of it leaves this namespace, whose only interface is loopback.
unshare -n sh -c 'ip link set lo up && ip link set lo multicast on &&
  exec .venv/bin/python -m pytest tests/python/test_ros2_real.py -q'
end_step
