#!/usr/bin/env bash
# Installs the tools the tests drive, idempotently: `ip` (iproute2), `curl`, `cmake` and libclang (which
# build the ROS 2 bridge's CycloneDDS into armtwin-router's feature `ros2dds`), Debian's `chromium`
# (a headless browser for the page tests) and Debian's `prometheus` unpacked into
# $ARMTWIN_CACHE/prometheus-<version>/ (no system install, no service started; the cache is
# ~/.cache/armtwin unless set, so every clone on the machine shares it). Prints the paths it
# settled on as shell assignments.
set -euo pipefail
cd "$(dirname "$0")/.."
cache=${ARMTWIN_CACHE:-${XDG_CACHE_HOME:-$HOME/.cache}/armtwin}
mkdir -p "$cache"
cache=$(cd "$cache" && pwd)

apt_updated=0
apt_update_once() {
  if [ "$apt_updated" = 0 ]; then
    apt-get update -qq >&2
    apt_updated=1
  fi
}

# `ip` brings up loopback in the private network namespace of the ur-rtde read-back test.
if ! command -v ip >/dev/null 2>&1; then
  apt_update_once
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends iproute2 >&2
fi

# The bridge's build script runs cmake on the C sources it bundles and bindgen, which loads libclang.
if ! command -v cmake >/dev/null 2>&1 || ! ls /usr/lib/llvm-*/lib/libclang.so* >/dev/null 2>&1; then
  apt_update_once
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends cmake libclang-dev >&2
fi

# The documentation's commands (tests/python/test_docs_commands.py) read HTTP with curl.
if ! command -v curl >/dev/null 2>&1; then
  apt_update_once
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends curl >&2
fi

if ! command -v chromium >/dev/null 2>&1; then
  apt_update_once
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends chromium >&2
fi

version=$(apt-cache policy prometheus 2>/dev/null | awk '/Candidate:/ {print $2}')
if [ -z "$version" ] || [ "$version" = "(none)" ]; then
  apt_update_once
  version=$(apt-cache policy prometheus | awk '/Candidate:/ {print $2}')
fi
dir="$cache/prometheus-${version//[:~]/_}"
if [ ! -x "$dir/usr/bin/prometheus" ]; then
  rm -rf "$dir.partial"
  mkdir -p "$dir.partial"
  (cd "$dir.partial" && apt-get download -qq "prometheus=$version" >&2 && dpkg -x prometheus_*.deb . && rm prometheus_*.deb)
  rm -rf "$dir"
  mv "$dir.partial" "$dir"
fi

printf 'ARMTWIN_CHROMIUM=%q\n' "$(command -v chromium)"
printf 'ARMTWIN_PROMETHEUS=%q\n' "$dir/usr/bin/prometheus"
