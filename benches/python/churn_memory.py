"""Memory of ``armtwin serve`` while waves of never-seen robot ids come (one JSON sample each) and
are retired (``[service] forget_after_s``): RSS at the baseline, with each wave tracked, and after
it is retired; with gdb on the machine also glibc's own count of the heap in use (``malloc_stats``),
which tells memory the service still holds from memory the allocator keeps. A measurement, not a
test (README.md beside it, "Robots that come and go").

Run: ``.venv/bin/python benches/python/churn_memory.py target/release/armtwin [--waves 3] [--ids 40000]``.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import zenoh

# The shared test support (tests/python/support) is imported from beside the tests.
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "python"))
from support.process import free_port, port_accepts, wait_until  # noqa: E402

Q = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("armtwin", type=Path)
    parser.add_argument("--waves", type=int, default=3)
    parser.add_argument("--ids", type=int, default=40000)
    parser.add_argument("--forget-after", type=float, default=20.0)
    args = parser.parse_args()

    workdir = Path(tempfile.mkdtemp(prefix="armtwin-churn-"))
    zenoh_port, http_port = free_port(), free_port()
    config = workdir / "armtwin.toml"
    config.write_text(
        f'[http]\nlisten = "127.0.0.1:{http_port}"\n\n[service]\nmax_robots = {args.ids + 10}\n'
        f'forget_after_s = {args.forget_after}\n\n[robots.default]\nmodel = "ur10e"\n'
    )
    log = open(workdir / "armtwin.log", "wb")
    service = subprocess.Popen(
        [args.armtwin, "serve", "-c", config, "-l", f"tcp/127.0.0.1:{zenoh_port}"], stdout=log, stderr=log
    )

    def rss_mib() -> float:
        status = Path(f"/proc/{service.pid}/status").read_text()
        return int(re.search(r"VmRSS:\s+(\d+)", status).group(1)) / 1024

    def tracked() -> int:
        url = f"http://127.0.0.1:{http_port}/api/fleet?limit=1"
        with urllib.request.urlopen(url, timeout=60) as response:
            return int(json.loads(response.read())["service"]["robots"])

    def heap_in_use_mib() -> str:
        if shutil.which("gdb") is None:
            return "n/a (no gdb)"
        subprocess.run(
            ["gdb", "-p", str(service.pid), "-batch", "-ex", "call (void)malloc_stats()"],
            capture_output=True, timeout=120,
        )
        time.sleep(0.5)
        totals = re.findall(r"Total \(incl\. mmap\):\s+system bytes\s+=\s+(\d+)\s+in use bytes\s+=\s+(\d+)",
                            (workdir / "armtwin.log").read_text(errors="replace"))
        return f"{int(totals[-1][1]) / 2**20:.1f} MiB in use of {int(totals[-1][0]) / 2**20:.1f}" if totals else "n/a"

    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{zenoh_port}"]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    if not wait_until(lambda: port_accepts(http_port), 30):
        print(f"armtwin did not start: {workdir / 'armtwin.log'}", file=sys.stderr)
        return 1
    session = zenoh.open(conf)
    try:
        time.sleep(1)
        print(f"baseline (no robot): RSS {rss_mib():.1f} MiB, heap {heap_in_use_mib()}", flush=True)
        for wave in range(args.waves):
            started = time.monotonic()
            for i in range(args.ids):
                session.put(f"twin/joints/wave{wave}/{i}", json.dumps({"t": 1.0, "q": Q}),
                            congestion_control=zenoh.CongestionControl.BLOCK)
            wait_until(lambda: tracked() >= args.ids, 600, interval=0.2)
            print(f"wave {wave}: {tracked()} tracked after {time.monotonic() - started:.1f} s, RSS {rss_mib():.1f} MiB",
                  flush=True)
            started = time.monotonic()
            wait_until(lambda: tracked() == 0, args.forget_after * 4 + 60, interval=0.5)
            time.sleep(2)
            print(f"wave {wave}: retired after {time.monotonic() - started:.1f} s ({tracked()} tracked), "
                  f"RSS {rss_mib():.1f} MiB, heap {heap_in_use_mib()}", flush=True)
    finally:
        session.close()
        service.terminate()
        service.wait(30)
    return 0


if __name__ == "__main__":
    sys.exit(main())
