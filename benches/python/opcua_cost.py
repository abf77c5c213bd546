"""The OPC UA server's cost: ``armtwin serve``'s CPU and RSS with 1 000 robots exposed, with and
without ``[opcua]``, alternated, and with one client monitoring some of them (README.md beside it,
"OPC UA server").

    .venv/bin/python benches/python/opcua_cost.py target/release/armtwin target/release/armtwin-bench \\
        [--robots 1000] [--hz 10] [--seconds 20] [--idle-seconds 20] [--rounds 2] [--sampling-ms 100] \\
        [--monitored 100] [--publishing-ms 100] [--item-sampling-ms MS] [--queue-size 1] \\
        [--positions-only]

Each round starts a fresh service (peer, loopback, every robot a ``ur10e``, metrics at 10 Hz per
robot, binary), twins every robot with ``armtwin-bench load`` (embedded measured poses, stamped
with the Unix time at which each sample is sent: ``--clock-origin 0``), then reads its CPU time
from /proc while the load streams ``--hz`` per robot for ``--seconds`` (the first and last 3 s left
out), then while idle for ``--idle-seconds``, every robot still exposed, per thread too, and its
RSS once it has started (before any robot) and at the end. Three kinds of round, in this order in
each of ``--rounds``:

* ``off``: no ``[opcua]``;
* ``on``: ``[opcua]``, no client connected;
* ``client``: ``[opcua]`` and one asyncua client (this process, a thread of its own, anonymous,
  security None on loopback) connected before the load streams. It finds armtwin's namespace
  index in the server's namespace array and the robots by browsing DI's ``DeviceSet``, then
  monitors ``Twin/Position`` of ``--monitored`` robots in one subscription, publishing interval
  ``--publishing-ms``, sampling interval ``--item-sampling-ms`` (default: ``--sampling-ms``, the
  server's sampler's period), queue size ``--queue-size``; and, unless ``--positions-only``, their
  ``Twin/SourceTime`` too, for the latency: twice the monitored items. The robots are spread
  evenly over the fleet in id order, so that their samples' phases spread over a sample period
  (the load sends the robots in turn). Skipped with ``--monitored 0``.

Figures per round: the service's CPU (cores) streaming and idle, its RSS (MiB); in the client
round also this process's CPU while streaming (the client's, the main thread only sleeps),
the notifications per monitored item per second, and the latency from sample to notification.
At the end, medians over the rounds, and the bytes per exposed robot with no client:
(RSS ``on`` − RSS ``off``) / ``--robots``, which counts the server's fixed cost too (its imported
information models, tens of MiB: it dominates at a few robots), and the same less each round's
RSS at its start, which leaves that fixed cost out.

The latency: at each ``Twin/SourceTime`` notification received in the measured window, the
client's ``time.time()`` minus the value, which is the stamp of the newest sample the twin had
when the server's sampler read it, i.e. the Unix time at which the load sent it (one machine,
one clock). It includes the load's put, Zenoh over loopback, the service's intake and kinematics,
the wait for the sampler's next turn (the value's age at that turn: up to the shorter of one
sample period, 1 / ``--hz``, and the sampling interval), the wait from that turn to the
subscription's next publish (the phase between the sampler's clock and the publishing clock,
0 to ``--publishing-ms``, drifting slowly), the publish response over TCP, and asyncua's
decoding and dispatch to the handler. So at 10 Hz with both intervals 100 ms expect tens to
~200 ms, most of it the two intervals' quantisation; it does not say how fast the server is,
only what a client sees. A value sampled but unchanged since the
last turn is not notified (the robot sent nothing new), so notifications per item per second stay
at or below min(``--hz``, 1000 / ``--sampling-ms``). The sampler's turns and the subscription's
publishes run on clocks of their own at the same period, so some publishing intervals hold two
turns: with a queue of 1 the older value is dropped (the client sees the newest, as an HMI
wants), with a longer queue both are sent, the older one late; this shows in both figures.

Not a test: it prints figures.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

from asyncua import Client, ua

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

DI_URI = "http://opcfoundation.org/UA/DI/"
ARMTWIN_URI = "urn:armtwin:opcua"
DEVICE_SET = 5001  # DI's DeviceSet object, numeric id in DI's namespace (OPC 10000-100)
CLIENT_TIMEOUT_S = 60.0
KINDS = ("off", "on", "client")


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
    # Stamps in Unix seconds: the latency compares them with this process's clock, and the
    # warm-up's and the stream's stamps follow each other instead of both starting at 0.
    argv = [bench, "load", "-e", endpoint, "--target", "armtwin", "--sut-pid", str(pid),
            "--encoding", "zenoh-serialized", "--embedded", "--robots", str(robots),
            "--latency-rate", str(rate), "--latency-duration", str(seconds), "--clock-origin", "0"]
    return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)


class Monitor:
    """One asyncua client in a thread of its own, subscribed to robots' ``Twin/Position`` (and
    ``Twin/SourceTime``); records each notification's arrival. Its callbacks run on its event
    loop and only append to the lists, which the round reads meanwhile (list appends and
    iteration are atomic under CPython's lock)."""

    def __init__(self, url: str, monitored: int, interval_ms: float, publishing_ms: int, queue_size: int,
                 source_time: bool):
        self.url, self.monitored, self.source_time = url, monitored, source_time
        self.interval_ms, self.publishing_ms, self.queue_size = interval_ms, publishing_ms, queue_size
        self.ready, self.stopping = threading.Event(), threading.Event()
        self.error: BaseException | None = None
        self.kinds: dict = {}
        self.positions: list[float] = []  # monotonic arrival of each Position notification
        self.latencies: list[tuple[float, float]] = []  # (monotonic arrival, now - SourceTime) s
        self.items = 0
        self.robot_ids: list[str] = []
        self._thread = threading.Thread(target=self._main, name="opcua-client", daemon=True)

    def start(self) -> Monitor:
        self._thread.start()
        if not self.ready.wait(CLIENT_TIMEOUT_S) or self.error is not None:
            self.stop()
            raise RuntimeError(f"the OPC UA client did not subscribe: {self.error!r}")
        return self

    def stop(self) -> None:
        self.stopping.set()
        self._thread.join(CLIENT_TIMEOUT_S)

    def datachange_notification(self, node, value, data) -> None:
        arrived_s, arrived_mono = time.time(), time.monotonic()
        kind = self.kinds.get(node.nodeid)
        if kind == "position":
            self.positions.append(arrived_mono)
        elif kind == "source_time" and isinstance(value, float):
            self.latencies.append((arrived_mono, arrived_s - value))

    def _main(self) -> None:
        try:
            asyncio.run(self._session())
        except BaseException as error:  # noqa: BLE001 -- reported by start() or the round
            self.error = error
            self.ready.set()

    async def _session(self) -> None:
        async with Client(self.url, timeout=CLIENT_TIMEOUT_S) as client:
            nodes = await self._nodes(client)
            subscription = await client.create_subscription(self.publishing_ms, self)
            handles = await subscription.subscribe_data_change(
                nodes, queuesize=self.queue_size, sampling_interval=self.interval_ms)
            refused = [h for h in handles if isinstance(h, ua.StatusCode)]
            if refused:
                raise RuntimeError(f"{len(refused)} monitored items refused, e.g. {refused[0]}")
            self.items = len(handles)
            self.ready.set()
            while not self.stopping.is_set():
                await asyncio.sleep(0.1)
            await subscription.delete()

    async def _nodes(self, client: Client) -> list:
        """The monitored nodes: robots found under DeviceSet, their ids as docs/opcua.md states,
        checked against a browse of the first robot."""
        armtwin = await client.get_namespace_index(ARMTWIN_URI)
        device_set = client.get_node(ua.NodeId(DEVICE_SET, await client.get_namespace_index(DI_URI)))
        ids = sorted(child.nodeid.Identifier for child in await device_set.get_children()
                     if child.nodeid.NamespaceIndex == armtwin)
        if len(ids) < self.monitored:
            raise RuntimeError(f"{len(ids)} robots under DeviceSet, {self.monitored} to monitor")
        self.robot_ids = [ids[index * len(ids) // self.monitored] for index in range(self.monitored)]
        browsed = await client.get_node(ua.NodeId(self.robot_ids[0], armtwin)).get_child(
            [f"{armtwin}:Twin", f"{armtwin}:Position"])
        nodes = []
        for kind, path in (("position", "Twin/Position"), ("source_time", "Twin/SourceTime")):
            if kind == "source_time" and not self.source_time:
                continue
            for robot in self.robot_ids:
                node = client.get_node(ua.NodeId(f"{robot}#{path}", armtwin))
                self.kinds[node.nodeid] = kind
                nodes.append(node)
        if browsed.nodeid != nodes[0].nodeid:
            raise RuntimeError(f"Twin/Position browsed as {browsed.nodeid}, not {nodes[0].nodeid}")
        return nodes


def percentile(values: list[float], fraction: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(fraction * len(ordered)))]


def client_figures(monitor: Monitor, window: tuple[float, float]) -> dict:
    """What the client saw between the window's monotonic bounds."""
    start, end = window
    positions = sum(1 for at in monitor.positions if start <= at < end)
    latencies_ms = [lag * 1000 for at, lag in monitor.latencies if start <= at < end]
    figures = {"monitored_robots": len(monitor.robot_ids), "monitored_items": monitor.items,
               "position_notifications_per_item_s": positions / len(monitor.robot_ids) / (end - start)}
    if latencies_ms:
        figures |= {"latency_p50_ms": percentile(latencies_ms, 0.5),
                    "latency_p99_ms": percentile(latencies_ms, 0.99),
                    "latency_max_ms": max(latencies_ms), "latency_samples": len(latencies_ms)}
    return figures


def stream(args, service: ArmtwinProcess, loads: list, monitor: Monitor | None) -> dict:
    """Streams, then idles; CPU in each, and what the client saw while streaming."""
    pid = service.proc.pid
    rate = args.robots * args.hz
    streaming = load(args.bench, service.endpoint, pid, args.robots, rate, args.seconds)
    loads.append(streaming)
    time.sleep(3.0)
    cpu0, own0, t0 = cpu_s(pid), cpu_s(os.getpid()), time.monotonic()
    time.sleep(args.seconds - 6.0)
    t1 = time.monotonic()
    figures = {"stream_cores": (cpu_s(pid) - cpu0) / (t1 - t0)}
    if monitor is not None:
        figures["client_cores"] = (cpu_s(os.getpid()) - own0) / (t1 - t0)
        figures |= client_figures(monitor, (t0, t1))
    streaming.communicate(timeout=120)
    time.sleep(2.0)
    cpu0, threads0, t0 = cpu_s(pid), threads_cpu_s(pid), time.monotonic()
    time.sleep(args.idle_seconds)
    elapsed = time.monotonic() - t0
    figures["idle_cores"] = (cpu_s(pid) - cpu0) / elapsed
    threads = threads_cpu_s(pid)
    threads.subtract(threads0)
    figures["idle_threads_cores"] = {name: round(s / elapsed, 4) for name, s in threads.most_common(4)}
    figures["rss_mib"] = rss_mib(pid)
    return figures


def one_round(args, kind: str, work: Path) -> dict:
    text, opc_port = CONFIG, free_port()
    if kind != "off":
        text += OPCUA.format(port=opc_port, sampling_ms=args.sampling_ms, pki=work.parent / "pki")
    service = ArmtwinProcess(args.armtwin, work, text, 600.0).start()
    loads: list[subprocess.Popen] = []
    monitor = None
    try:
        if kind != "off":
            service.wait_port(opc_port, "serve OPC UA")
        pid = service.proc.pid
        start_mib = rss_mib(pid)
        loads.append(load(args.bench, service.endpoint, pid, args.robots, args.robots * args.hz, 3.0))
        loads[-1].communicate(timeout=120)
        if kind == "client":
            monitor = Monitor(f"opc.tcp://127.0.0.1:{opc_port}", args.monitored, args.item_sampling_ms,
                              args.publishing_ms, args.queue_size, not args.positions_only).start()
        figures = stream(args, service, loads, monitor)
        if monitor is not None and monitor.error is not None:
            raise RuntimeError(f"the OPC UA client failed: {monitor.error!r}")
        figures["rss_grown_mib"] = figures["rss_mib"] - start_mib
        return {"kind": kind, "rss_start_mib": start_mib} | figures
    finally:
        if monitor is not None:
            monitor.stop()
        for running in loads:
            running.kill()
            running.wait()
        service.stop()


def summary(args, results: list[dict]) -> None:
    """Medians over the rounds, per kind, and the bytes per exposed robot."""
    medians: dict[str, dict] = {}
    for kind in KINDS:
        rounds = [r for r in results if r["kind"] == kind]
        if not rounds:
            continue
        keys = [k for k, v in rounds[0].items() if isinstance(v, float)]
        medians[kind] = {k: statistics.median(r[k] for r in rounds) for k in keys}
        print(f"median of {len(rounds)} '{kind}':",
              {k: round(v, 4) for k, v in medians[kind].items()}, flush=True)
    if "off" in medians and "on" in medians:
        extra_mib = medians["on"]["rss_mib"] - medians["off"]["rss_mib"]
        print(f"RSS with OPC UA on, no client, minus off: {extra_mib:.1f} MiB, "
              f"{extra_mib * 1024 * 1024 / args.robots:.0f} B per exposed robot ({args.robots} robots)",
              flush=True)
        grown_mib = medians["on"]["rss_grown_mib"] - medians["off"]["rss_grown_mib"]
        print(f"the same, less each round's RSS at its start: {grown_mib:.1f} MiB, "
              f"{grown_mib * 1024 * 1024 / args.robots:.0f} B per exposed robot", flush=True)
    for kind in ("on", "client"):
        if kind in medians and "off" in medians:
            print(f"CPU streaming '{kind}' / 'off': "
                  f"{medians[kind]['stream_cores'] / medians['off']['stream_cores']:.3f}", flush=True)


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
    parser.add_argument("--monitored", type=int, default=100,
                        help="robots whose Twin/Position the client monitors; 0: no client round")
    parser.add_argument("--publishing-ms", type=int, default=100)
    parser.add_argument("--item-sampling-ms", type=float, default=None,
                        help="the monitored items' sampling interval (default: --sampling-ms)")
    parser.add_argument("--queue-size", type=int, default=1, help="each monitored item's queue")
    parser.add_argument("--positions-only", action="store_true",
                        help="monitor Twin/Position alone: no SourceTime items, no latency")
    args = parser.parse_args()
    if args.seconds <= 6.0:
        parser.error("--seconds must exceed the 6 s left out")
    if args.monitored > args.robots:
        parser.error("--monitored must not exceed --robots")
    if args.item_sampling_ms is None:
        args.item_sampling_ms = float(args.sampling_ms)
    args.armtwin, args.bench = args.armtwin.resolve(), args.bench.resolve()
    # asyncua warns of every revised request parameter (the session timeout): not a figure.
    logging.getLogger("asyncua").setLevel(logging.ERROR)
    root = Path(tempfile.mkdtemp(prefix="opcua-cost-"))
    kinds = KINDS if args.monitored > 0 else KINDS[:2]
    print(f"load average before: {os.getloadavg()}", flush=True)
    results = []
    for index in range(args.rounds):
        for kind in kinds:
            work = root / f"{index}-{kind}"
            work.mkdir()
            results.append(one_round(args, kind, work))
            print(results[-1], f"load average {os.getloadavg()}", flush=True)
    summary(args, results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
