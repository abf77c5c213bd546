"""The OPC UA server's cost: ``armtwin serve``'s CPU and RSS with 1 000 robots exposed, with and
without ``[opcua]``, alternated (README.md beside it, "OPC UA server").

    .venv/bin/python benches/python/opcua_cost.py target/release/armtwin target/release/armtwin-bench \\
        [--robots 1000] [--hz 10] [--seconds 20] [--idle-seconds 20] [--rounds 2] [--sampling-ms 100]

Each round starts a fresh service (peer, loopback, every robot a ``ur10e``, metrics at 10 Hz per
robot, binary), twins every robot with ``armtwin-bench load`` (embedded measured poses), then
reads its CPU time from /proc while the load streams ``--hz`` per robot for ``--seconds`` (the
first and last 3 s left out), then while idle for ``--idle-seconds``, every robot still exposed,
and its RSS at the end, per thread too. No OPC UA client connects: the sampler copies every
robot's state into its nodes whether or not anyone reads them. Not a test: it prints figures.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "python"))
from support.process import ArmtwinProcess, cpu_s, free_port  # noqa: E402

CONFIG = """\
[zenoh]
mode = "peer"
multicast_scouting = false

[service]
key_prefix = "twin"
metrics_period_ms = 100
window_s = 10.0
pose_congestion = "block"
encoding = "zenoh-serialized"

[align]
max_gap_s = 3600.0

[robots.default]
model = "ur10e"
"""

OPCUA = """
[opcua]
endpoint = "opc.tcp://127.0.0.1:{port}"
sampling_interval_ms = {sampling_ms}
anonymous = true
pki_dir = "{pki}"
"""


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


def threads_cpu_s(pid: int) -> Counter:
    """CPU seconds per thread name (threads of one name summed)."""
    by_name: Counter = Counter()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            comm = (task / "comm").read_text().strip()
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        by_name[comm] += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return by_name


def load(bench: Path, endpoint: str, pid: int, robots: int, rate: float, seconds: float) -> subprocess.Popen:
    argv = [bench, "load", "-e", endpoint, "--target", "armtwin", "--sut-pid", str(pid),
            "--encoding", "zenoh-serialized", "--embedded", "--robots", str(robots),
            "--latency-rate", str(rate), "--latency-duration", str(seconds)]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


def one_round(args, opcua: bool, work: Path) -> dict:
    text, opc_port = CONFIG, free_port()
    if opcua:
        text += OPCUA.format(port=opc_port, sampling_ms=args.sampling_ms, pki=work.parent / "pki")
    service = ArmtwinProcess(args.armtwin, work, text, 600.0).start()
    loads: list[subprocess.Popen] = []
    try:
        if opcua:
            service.wait_port(opc_port, "serve OPC UA")
        pid = service.proc.pid
        rate = args.robots * args.hz
        loads.append(load(args.bench, service.endpoint, pid, args.robots, rate, 3.0))
        loads[-1].communicate(timeout=120)
        streaming = load(args.bench, service.endpoint, pid, args.robots, rate, args.seconds)
        loads.append(streaming)
        time.sleep(3.0)
        cpu0, t0 = cpu_s(pid), time.monotonic()
        time.sleep(args.seconds - 6.0)
        stream_cores = (cpu_s(pid) - cpu0) / (time.monotonic() - t0)
        streaming.communicate(timeout=120)
        time.sleep(2.0)
        cpu0, threads0, t0 = cpu_s(pid), threads_cpu_s(pid), time.monotonic()
        time.sleep(args.idle_seconds)
        elapsed = time.monotonic() - t0
        idle_cores = (cpu_s(pid) - cpu0) / elapsed
        threads = threads_cpu_s(pid)
        threads.subtract(threads0)
        busiest = {name: round(s / elapsed, 4) for name, s in threads.most_common(4)}
        return {"opcua": opcua, "stream_cores": stream_cores, "idle_cores": idle_cores,
                "rss_mib": rss_mib(pid), "idle_threads_cores": busiest}
    finally:
        for running in loads:
            running.kill()
            running.wait()
        service.stop()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("armtwin", type=Path)
    parser.add_argument("bench", type=Path)
    parser.add_argument("--robots", type=int, default=1000)
    parser.add_argument("--hz", type=float, default=10.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--idle-seconds", type=float, default=20.0)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--sampling-ms", type=int, default=100)
    args = parser.parse_args()
    args.armtwin, args.bench = args.armtwin.resolve(), args.bench.resolve()
    root = Path(tempfile.mkdtemp(prefix="opcua-cost-"))
    print(f"load average before: {os.getloadavg()}", flush=True)
    for index in range(args.rounds):
        for opcua in (False, True):
            work = root / f"{index}-{'on' if opcua else 'off'}"
            work.mkdir()
            result = one_round(args, opcua, work)
            print(result, f"load average {os.getloadavg()}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
