"""The RTDE gateway's cost: CPU per controller at the controllers' pace, and the latency from a
controller's data package to the twin pose (README.md beside it,
"The RTDE gateway").

    .venv/bin/python benches/python/rtde_gateway_cost.py target/release/armtwin \\
        [--controllers 20] [--rate-hz 500] [--seconds 30]

Starts ``armtwin serve`` (peer, loopback), the stand-in controller (tests/python/support/rtde_server.py,
one port per controller, serving the UR10e recording at ``--rate-hz``) and one
``armtwin gateway rtde -c`` for all of them, and subscribes the twin poses. After a 5-s warm-up
it reads the gateway's and the service's CPU time from /proc over ``--seconds``, and each pose's
latency as its arrival (wall clock) minus its stamp. The gateway stamps a package with the
controller's clock plus an offset to wall time fixed at the connection's first package, so the
latency counts from when that package would have left on the first package's schedule: the
stand-in's send jitter and the path stand-in → gateway → service → subscriber. Not a test: it
prints figures and asserts nothing but that poses arrived.
"""

from __future__ import annotations

import argparse
import json
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

# The shared test support (tests/python/support) is imported from beside the tests.
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "python"))
from support import rtde_recording  # noqa: E402
from support.paths import DATA_DIR, SUPPORT_DIR  # noqa: E402
from support.process import ArmtwinProcess, cpu_s  # noqa: E402
from support.zenoh_clients import open_session  # noqa: E402

DATA = DATA_DIR / "ur10e_lasttest.csv"
CONFIG = """\
[service]
metrics_period_ms = 1000

[robots.default]
model = "ur10e"
"""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("armtwin", type=Path)
    parser.add_argument("--controllers", type=int, default=20)
    parser.add_argument("--rate-hz", type=float, default=500.0)
    parser.add_argument("--seconds", type=float, default=30.0)
    args = parser.parse_args()
    args.armtwin = args.armtwin.resolve()
    work = Path(tempfile.mkdtemp(prefix="rtde-cost-"))
    recording = rtde_recording.write(rtde_recording.rtde_rows(DATA), work / "rows.csv")
    service = ArmtwinProcess(args.armtwin, work, CONFIG, 600.0)
    service.start()
    server = subprocess.Popen(
        [sys.executable, str(SUPPORT_DIR / "rtde_server.py"), "--recording", str(recording),
         "--rate-hz", str(args.rate_hz), *["--port", "0"] * args.controllers],
        stdout=subprocess.PIPE, stderr=open(work / "server.log", "wb"), text=True, start_new_session=True,
    )
    ports = [int(p) for p in server.stdout.readline().split()[1:]]
    fleet = work / "gateways.toml"
    fleet.write_text("".join(
        f'[[controllers]]\nrobot = "cost/{k}"\nhost = "127.0.0.1"\nport = {port}\nfrequency = {args.rate_hz}\n\n'
        for k, port in enumerate(ports)
    ))
    latencies: list[float] = []
    lock = threading.Lock()
    measuring = threading.Event()

    def on_pose(sample: zenoh.Sample) -> None:
        arrival = time.time()
        if measuring.is_set():
            t = json.loads(sample.payload.to_bytes())["t"]
            with lock:
                latencies.append(arrival - t)

    session = open_session(service.endpoint)
    subscriber = session.declare_subscriber("twin/pose/cost/**", on_pose)
    gateway = subprocess.Popen(
        [str(args.armtwin), "gateway", "rtde", "-e", service.endpoint, "-c", str(fleet)],
        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=open(work / "gateway.log", "wb"),
        start_new_session=True,
    )
    try:
        time.sleep(5.0)
        gateway_0, service_0, wall_0 = cpu_s(gateway.pid), cpu_s(service.proc.pid), time.monotonic()
        measuring.set()
        time.sleep(args.seconds)
        measuring.clear()
        gateway_1, service_1, wall_1 = cpu_s(gateway.pid), cpu_s(service.proc.pid), time.monotonic()
    finally:
        gateway.send_signal(signal.SIGINT)
        gateway.wait(15)
        subscriber.undeclare()
        session.close()
        server.send_signal(signal.SIGTERM)
        server.wait(5)
        service.stop()
    wall = wall_1 - wall_0
    with lock:
        got = sorted(latencies)
    assert got, "no pose arrived"
    quantile = lambda q: got[min(len(got) - 1, int(q * len(got)))]  # noqa: E731
    gateway_core = (gateway_1 - gateway_0) / wall
    print(f"controllers {args.controllers} at {args.rate_hz:g} Hz, {wall:.1f} s: "
          f"{len(got) / wall:.0f} poses/s ({len(got) / wall / args.controllers:.1f} per robot)")
    print(f"gateway CPU {100 * gateway_core:.1f} % of a core, {100 * gateway_core / args.controllers:.2f} % per controller; "
          f"service {100 * (service_1 - service_0) / wall:.1f} %")
    print(f"latency package → twin pose: p50 {1e3 * statistics.median(got):.2f} ms, "
          f"p99 {1e3 * quantile(0.99):.2f} ms, max {1e3 * got[-1]:.2f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
