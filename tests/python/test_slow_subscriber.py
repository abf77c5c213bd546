"""A slow subscriber must not stall the twin (docs/protocol/delivery.md, "Delivery").

Two robots stream joint messages (with embedded measured poses) into the real ``armtwin serve``
while one subscriber, in a process and session of its own on a link with a small receive buffer,
sleeps 8 s in its callback on robot ``a``'s poses and deviations. Another subscriber, in another
session, must still get the poses of both robots without a stall; the service must twin every
input (its final metrics pair every sample); the slow subscriber must have missed poses (so the
congestion really happened), be able to count them from the gaps in ``seq``, and get fresh poses
once it wakes.

Both robots are tracked (their liveliness tokens visible) before the subscribers are declared:
a robot's declarations are reliable Zenoh messages that wait for a congested link, and Zenoh
closes a link on which one waited longer than its ``wait_before_close``; the test is about the
poses, not about a robot appearing while a subscriber sleeps.

The sleeper runs in a process of its own, as a dashboard would: Zenoh's receive threads (two per
process) and Python's interpreter lock are shared by every session of a process, so a sleeper
beside the gateway held one of the gateway's two receive threads for the whole sleep; the gateway,
which also subscribes to the blocking metrics, was seen to fall behind until the service closed
its link after ``wait_before_close``, and the twin lost its input. It sleeps less than the lease
(10 s, Zenoh's default): a callback that holds its session's receive thread for a whole lease
makes that session itself close the link as expired, dropping what the link held; with a sleep of
exactly the lease that happened or not by a millisecond.

Run: ``.venv/bin/python -m pytest tests/python/test_slow_subscriber.py -q -s``.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time

import pytest
import zenoh

from support.process import ArmtwinProcess, wait_until
from support.twin_reference import joint_message, load_fmpy
from support.zenoh_clients import PREFIX, TwinClient, open_session

CONFIG = """\
[service]
metrics_period_ms = 50

[robots.default]
model = "ur10e"
"""
WATCHDOG_S = 180.0
# Less than the service's lease (10 s) with a margin; long enough for the link to fill (its
# receive buffer, the service's send buffer and Zenoh's queue hold a few seconds of poses).
SLEEP_S = 8.0
STREAM_S = 14.0
RATE_HZ = 1500  # per robot
ROBOTS = ("a", "b")
# A small receive buffer on the slow subscriber's side, so its link congests within the sleep
# rather than after the kernel has buffered tens of megabytes.
SLOW_RCVBUF = 16384
# And a bounded send buffer on the service's side of the sleeper's link alone (a listener of its
# own). Linux grows a socket's send buffer up to tcp_wmem's maximum while its peer does not
# read: the sleeper woke to megabytes of poses queued before it slept, which Python on a busy
# machine could not drain before the stream ended. The fast subscriber keeps the grown buffer,
# which carries it over its own process's pauses. The kernel doubles what is asked.
SERVICE_SNDBUF = 131072
# Poses the fast subscriber may miss: with the `drop` default a subscriber loses poses when its own
# process is starved of CPU (it shares a Python interpreter with the gateway), which is not a stall;
# a few percent with busy loops beside the test on 2 cores, none without them.
FAST_MISSED_MAX = 0.05
# Longest silence of the fast subscriber that is not a stall (s). With `pose_congestion = "block"`
# the twin waits for the full link until Zenoh's wait_before_close (5 s) disconnects the sleeper;
# the gateway's own pauses (Python, a shared machine) were measured at up to ~0.3 s.
STALL_S = 2.0


@pytest.fixture
def twin(armtwin_bin, tmp_path):
    proc = ArmtwinProcess(armtwin_bin, tmp_path, CONFIG, WATCHDOG_S, listen_options=f"so_sndbuf={SERVICE_SNDBUF}")
    proc.start()
    try:
        yield proc
    finally:
        code, _ = proc.stop()
    if proc.watchdog_fired:
        pytest.fail(f"watchdog: armtwin killed after {WATCHDOG_S} s\n{proc.logs()}")
    if code != 0:
        pytest.fail(f"armtwin exited with code {code} after SIGINT\n{proc.logs()}")


class PoseLog:
    """(arrival time, robot, seq) of every pose, from a Zenoh callback."""

    def __init__(self):
        self.lock = threading.Lock()
        self.items: list[tuple[float, str, int]] = []

    def __call__(self, sample: zenoh.Sample) -> None:
        _, stream, robot = str(sample.key_expr).split("/", 2)
        if stream != "pose":
            return
        seq = json.loads(sample.payload.to_bytes())["seq"]
        with self.lock:
            self.items.append((time.monotonic(), robot, seq))

    def of(self, robot: str) -> list[tuple[float, int]]:
        with self.lock:
            return [(at, seq) for at, r, seq in self.items if r == robot]


# The slow subscriber's process: subscribes to robot a's poses and deviations, sleeps SLEEP_S in
# whichever of its session's receiving threads calls first, prints "ready" once the service knows
# its subscribers, and on a line on stdin writes {"woke_at", "poses": [[at, seq], ...]} to a file
# (time.monotonic(): one clock for every process of the machine). Zenoh's log, if RUST_LOG asks for
# one, goes to its stdout too.
SLEEPER = """
import json, sys, threading, time
import zenoh

endpoint, prefix, sleep_s, result_path = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
zenoh.init_log_from_env_or("error")
conf = zenoh.Config()
conf.insert_json5("mode", '"peer"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("listen/endpoints", "[]")
conf.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(conf)
lock = threading.Lock()
poses, slept, woke = [], [False], threading.Event()
woke_at = [None]

def on_sample(sample):
    with lock:
        sleep, slept[0] = not slept[0], True
    if sleep:
        time.sleep(sleep_s)
        woke_at[0] = time.monotonic()
        woke.set()
    _, stream, _ = str(sample.key_expr).split("/", 2)
    if stream == "pose":
        seq = json.loads(sample.payload.to_bytes())["seq"]
        with lock:
            poses.append((time.monotonic(), seq))

subs = [session.declare_subscriber(f"{prefix}/{stream}/a", on_sample) for stream in ("pose", "deviation")]
list(session.get(f"{prefix}/state/**", timeout=10))
print("ready", flush=True)
sys.stdin.readline()
woke.wait(30)
time.sleep(1.0)  # what its link still holds
for sub in subs:
    sub.undeclare()
with lock:
    result = {"woke_at": woke_at[0], "poses": poses}
session.close()
with open(result_path, "w") as f:
    json.dump(result, f)
"""


class Sleeper:
    """The slow subscriber's process; its output read as it comes, so its log never blocks it."""

    def __init__(self, endpoint: str, workdir):
        self.result_path = workdir / "sleeper.json"
        self.proc = subprocess.Popen(
            [sys.executable, "-c", SLEEPER, endpoint, PREFIX, str(SLEEP_S), str(self.result_path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self.ready = threading.Event()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line)
            if line.strip() == "ready":
                self.ready.set()

    def output(self) -> str:
        return "".join(self.lines)

    def wait_ready(self, timeout: float) -> None:
        """Until the service knows its subscribers."""
        if not self.ready.wait(timeout):
            self.kill()
            raise RuntimeError(f"the slow subscriber's process did not get ready:\n{self.output()}")

    def result(self) -> tuple[float | None, list[tuple[float, int]]]:
        """When it woke, and (arrival time, seq) of each pose of robot a it got."""
        self.proc.stdin.write("stop\n")
        self.proc.stdin.close()
        code = self.proc.wait(60)
        self.reader.join(10)
        if code != 0 or not self.result_path.exists():
            raise RuntimeError(f"the slow subscriber's process exited with {code}:\n{self.output()}")
        result = json.loads(self.result_path.read_text())
        return result["woke_at"], [(at, seq) for at, seq in result["poses"]]

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def test_a_subscriber_asleep_in_its_callback_stalls_nothing(twin, tmp_path):
    gateway = TwinClient(twin.endpoint)  # also the fast subscriber's session: twin/** minus inputs
    fast_session = open_session(twin.endpoint)
    sleeper = None
    try:
        q, meas = load_fmpy()
        pubs = {r: gateway.joints(r) for r in ROBOTS}
        gateway.ready(ROBOTS)
        # Sample 0 of each robot makes it tracked; the stream goes on from sample 1.
        for r in ROBOTS:
            gateway.put_json(pubs[r], joint_message(0.0, q[0], meas[0]))
        alive = lambda: {  # noqa: E731
            str(reply.ok.key_expr)
            for reply in gateway.session.liveliness().get(f"{PREFIX}/alive/**", timeout=5)
            if reply.ok
        }
        assert wait_until(lambda: alive() == {f"{PREFIX}/alive/{r}" for r in ROBOTS}, 30), alive()

        fast = PoseLog()
        sleeper = Sleeper(f"{twin.option_endpoint}#so_rcvbuf={SLOW_RCVBUF}", tmp_path)
        sleeper.wait_ready(30)
        fast_sub = fast_session.declare_subscriber(f"{PREFIX}/pose/*", fast)
        # A session's subscriber is known to the service once a query from it came back.
        list(fast_session.get(f"{PREFIX}/state/**", timeout=10))

        sent = 1
        started = time.monotonic()
        put_at = [started]
        sent_by = [(started, 1)]  # (time, samples sent before it) at each burst
        while (elapsed := time.monotonic() - started) < STREAM_S:
            due = int(elapsed * RATE_HZ)
            if sent < due:
                put_at.append(time.monotonic())
                sent_by.append((put_at[-1], sent))
            while sent < due:
                row = sent % len(q)
                for r in ROBOTS:
                    gateway.put_json(pubs[r], joint_message(sent * 0.001, q[row], meas[row]))
                sent += 1
            time.sleep(0.002)
        stream_s = time.monotonic() - started

        done = lambda r: lambda m: m.get("paired") == sent  # noqa: E731
        finals = {r: gateway.collector.wait_message("metrics", r, done(r), 60) for r in ROBOTS}
        last_seq = lambda r: max((seq for _, seq in fast.of(r)), default=None)  # noqa: E731
        wait_until(lambda: all(last_seq(r) == sent - 1 for r in ROBOTS), 30)
        woke_at, slow_poses = sleeper.result()
        fast_sub.undeclare()
    finally:
        if sleeper is not None:
            sleeper.kill()
        fast_session.close()
        gateway.close()

    failures = []
    paused = max(b - a for a, b in zip(put_at, put_at[1:]))
    print(f"\ngateway: longest pause between bursts {paused * 1e3:.0f} ms")
    for r in ROBOTS:
        if finals[r] is None:
            failures.append(f"{r}: the service did not pair all {sent} samples: {gateway.collector.last('metrics', r)}")
        got = fast.of(r)
        seqs = [s for _, s in got]
        streamed = range(1, sent)
        missing = sorted(set(streamed) - set(seqs))
        if seqs != sorted(set(seqs)) or not set(seqs) <= set(streamed):
            failures.append(f"{r}: fast subscriber's seq not increasing or out of 1..{sent - 1}")
        if len(missing) > FAST_MISSED_MAX * len(streamed):
            failures.append(f"{r}: fast subscriber got {len(seqs)} of {len(streamed)} poses; missing {missing[:10]}")
        gaps = [b[0] - a[0] for a, b in zip(got, got[1:])]
        worst = max(gaps, default=0.0)
        print(
            f"\n[{r}] fast subscriber: {len(seqs)} poses, missed {len(missing)}, longest silence {worst * 1e3:.0f} ms"
        )
        if worst > STALL_S:
            failures.append(f"{r}: the fast subscriber waited {worst:.2f} s between two poses: the twin stalled")
    slow_seqs = [s for _, s in slow_poses]
    missed = (slow_seqs[-1] - len(slow_seqs)) if slow_seqs else sent - 1
    print(
        f"[a] slow subscriber: {len(slow_seqs)} poses, missed {missed} (from the gaps in seq); "
        f"{sent - 1} samples per robot streamed in {stream_s:.1f} s"
    )
    if slow_seqs != sorted(set(slow_seqs)):
        failures.append("slow subscriber: seq not increasing")
    if missed <= 0:
        failures.append("slow subscriber missed nothing: its link never congested, the test proved nothing")
    # Still connected after its sleep: it gets poses published after it woke (how many depends on
    # how fast this machine lets it drain its backlog; those it cannot take are dropped for it).
    woke_at = woke_at if woke_at is not None else float("inf")
    sent_when_woke = max(n for at, n in sent_by if at <= woke_at)
    if not slow_seqs or slow_seqs[-1] < sent_when_woke:
        failures.append(
            f"slow subscriber got nothing published after it woke (last seq {slow_seqs[-1:]}, "
            f"{sent_when_woke} sent when it woke, of {sent})"
        )
    (tmp_path / "sleeper.out").write_text(sleeper.output())
    assert not failures, "\n".join(failures) + "\n" + twin.logs() + "\nslow subscriber's process:\n" + sleeper.output()
