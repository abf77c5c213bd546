#!/usr/bin/env bash
# Coverage-guided fuzzing of every decoder of untrusted bytes (the targets in fuzz/fuzz_targets/),
# with cargo-fuzz and libFuzzer on the stable toolchain (`-s none`: no sanitizer, which would
# need nightly; Rust's own bounds and overflow checks still turn bad memory use into a panic).
#
#   scripts/fuzz.sh SECONDS [TARGET…]        each target (all by default) SECONDS from its
#                                            committed corpus, new inputs to a scratch folder:
#                                            the pass before a release (`short` is the same)
#   scripts/fuzz.sh long SECONDS [TARGET…]   each target (all by default) SECONDS, one at a time,
#                                            then the inputs that add coverage merged into
#                                            fuzz/corpus/<target>/
#   scripts/fuzz.sh cmin [TARGET…]           minimise the committed corpora
#   scripts/fuzz.sh build                    only build every target
#
# The test command does not fuzz: `cargo test` runs every committed corpus and regression input
# (fuzz/regressions/<target>/) through the same checks (crates/armtwin-fuzz-checks), without
# this instrumented build.
#
# cargo-fuzz is installed once into $ARMTWIN_CACHE/cargo-fuzz-<version>/ (~/.cache/armtwin unless
# set, shared by every clone on the machine). A finding stops the script
# with the input under fuzz/artifacts/<target>/; `cargo fuzz run -s none <target> <file>`
# (from fuzz/) replays it. Once fixed, the input goes to fuzz/regressions/<target>/, where
# `cargo test` keeps it fixed.
set -euo pipefail
cd "$(dirname "$0")/.."

cargo_fuzz_version=0.13.2
cache=${ARMTWIN_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/armtwin}
mkdir -p "$cache"
dir="$(cd "$cache" && pwd)/cargo-fuzz-$cargo_fuzz_version"
if [ "$(cargo fuzz --version 2>/dev/null)" != "cargo-fuzz $cargo_fuzz_version" ]; then
  if [ ! -x "$dir/bin/cargo-fuzz" ]; then
    rm -rf "$dir.partial"
    # A debug build: the tool only drives cargo and libFuzzer, and builds in a third of the time.
    cargo install --quiet --locked --debug --root "$dir.partial" cargo-fuzz --version "$cargo_fuzz_version" >&2
    rm -rf "$dir"
    mv "$dir.partial" "$dir"
  fi
  PATH="$dir/bin:$PATH"
fi

mode=${1:-short}
shift || true
if [[ "$mode" =~ ^[0-9]+$ ]]; then
  set -- "$mode" "$@"
  mode=short
fi
case "$mode" in
  short) seconds=${1:-15}; shift || true ;;
  long) seconds=${1:?"usage: scripts/fuzz.sh long SECONDS [TARGET…]"}; shift ;;
  cmin | build) ;;
  *) echo "usage: scripts/fuzz.sh SECONDS [TARGET…] | long SECONDS [TARGET…] | cmin [TARGET…] | build" >&2; exit 2 ;;
esac
targets=("$@")
cd fuzz
if [ ${#targets[@]} -eq 0 ]; then
  mapfile -t targets < <(cargo fuzz list)
fi

# Every flag that is not libFuzzer's own default: an input that runs 10 s is a hang, and a
# decoder must never need 2 GB.
libfuzzer_flags=(-timeout=10 -rss_limit_mb=2048 -print_final_stats=1)

cargo fuzz build -s none
[ "$mode" != build ] || exit 0
scratch=$(mktemp -d)
trap 'rm -rf "$scratch"' EXIT
for target in "${targets[@]}"; do
  corpus="corpus/$target"
  mkdir -p "$corpus"
  case "$mode" in
    short | long)
      printf '\n== fuzz %s for %s s\n' "$target" "$seconds"
      mkdir -p "$scratch/$target"
      cargo fuzz run -s none "$target" "$scratch/$target" "$corpus" -- \
        "${libfuzzer_flags[@]}" -max_total_time="$seconds"
      if [ "$mode" = long ]; then
        cargo fuzz run -s none "$target" "$corpus" "$scratch/$target" -- -merge=1
      fi
      ;;
    cmin)
      # Edges only, not their hit counts: the fewest inputs that reach every branch, so the
      # committed corpora stay small (tens of kilobytes).
      cargo fuzz cmin -s none "$target" "$corpus" -- -use_counters=0
      ;;
  esac
done
