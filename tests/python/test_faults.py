"""Faults around the twin, with real processes: the snapshot's disk filling up mid-run (a real
tmpfs, full for real), the router armtwin uses dying while a second one carries on, and a
gateway's network blackholed for 30 s. Each time the twin keeps twinning, says what happened and
takes the robot back without locking it out.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_faults.py -q -s``
(``-s`` prints the measured figures).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import socket
import threading
import time
from pathlib import Path

import pytest

from support.gateway import Gateway
from support.process import Armtwin, Router, free_port, wait_until
from support.zenoh_clients import Poses, get_json, open_client, wait_matched, wait_queryable
from support.dashboard import metric

TWIN_CONFIG = """
[service]
metrics_period_ms = 100
{extra}

[robots.default]
model = "ur10e"
"""

# The network is gone for this long: three times Zenoh's default lease (10 s), so both ends
# give the link up and the gateway must connect anew.
BLACKHOLE_S = 30.0



def paired(session, robot: str) -> int:
    replies = get_json(session, f"twin/state/{robot}")
    return replies[0][1]["metrics"]["paired"] if replies else 0


def events_of(session, robot: str) -> list[dict]:
    events: list[dict] = []
    session.declare_subscriber(f"twin/events/{robot}", lambda s: events.append(json.loads(s.payload.to_bytes())))
    return events


def lost_upstream(events: list[dict]) -> int:
    """Samples the twin never saw, from its `gap` events (`got` − `expected` of the seq)."""
    return sum(e["detail"]["got"] - e["detail"]["expected"] for e in events if e["kind"] == "gap" and "expected" in e["detail"])


def test_a_full_snapshot_disk_is_counted_and_twinning_goes_on(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    """armtwin in a mount namespace of its own with its state_dir on a 256 KiB tmpfs; the test
    fills that tmpfs (through /proc/<pid>/root) mid-stream: writes fail with ENOSPC, each one
    counted in armtwin_snapshot_failures_total and the first logged, twinning goes on; freed, the
    next period writes the snapshot again, with every sample since."""
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("a tmpfs of its own needs root and unshare (CI has both)")
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    http_port = free_port()
    config = TWIN_CONFIG.format(
        extra=f'state_dir = "{state_dir}"\nsnapshot_period_s = 0.2\n\n[http]\nlisten = "127.0.0.1:{http_port}"'
    )
    mount = f'mount -t tmpfs -o size=256k armtwin-state "{state_dir}" && exec "$@"'
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    twin = Armtwin(
        armtwin_bin, tmp_path, "twin", config, router.endpoint, wrapper=["unshare", "-m", "sh", "-c", mount, "sh"]
    ).start()
    processes.append(twin)
    client = open_client(router.endpoint)
    sessions.append(client)
    inside = Path(f"/proc/{twin.proc.pid}/root") / str(state_dir).lstrip("/")
    snapshot = inside / "twin-state.json"
    assert wait_queryable(client, "twin/state/**")
    gateway = Gateway(client, "r1", rate_hz=100.0)
    wait_matched(gateway.pub)
    gateway.start()
    try:
        assert wait_until(lambda: snapshot.exists() and "r1" in snapshot.read_text(), 20), twin.logs()
        filler = inside / "filler"
        with open(filler, "wb", buffering=0) as out:
            with pytest.raises(OSError) as full:
                while True:
                    out.write(b"\0" * 65536)
        assert full.value.errno == errno.ENOSPC
        assert wait_until(lambda: (metric(http_port, "armtwin_snapshot_failures_total") or 0) >= 5, 20), twin.logs()
        during = paired(client, "r1")
        assert wait_until(lambda: paired(client, "r1") >= during + 100, 10), "twinning stopped with the disk full"
        filler.unlink()
        freed_at = paired(client, "r1")
        assert wait_until(lambda: "snapshot written again" in twin.logs(limit=10**9), 10), twin.logs()
        assert wait_until(
            lambda: json.loads(snapshot.read_text())["robots"][0]["paired"] >= freed_at, 10
        )
    finally:
        gateway.stop()
    log = twin.logs(limit=10**9)
    assert log.count("snapshot not written") == 1, "the first failure is logged, the rest counted"
    failures = metric(http_port, "armtwin_snapshot_failures_total")
    assert twin.stop().code == 0
    print(f"snapshot disk full: {failures:.0f} failed writes counted, twinning went on, written again once freed")


def test_the_router_armtwin_uses_dies_and_it_resumes_through_the_other(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    """Routers A and B linked; armtwin a client of both, connected to A (B is started after);
    the gateway and the dashboard on B. A is killed mid-stream: armtwin connects to B and the
    poses resume, the samples lost in between reported as gaps."""
    router_a = Router(router_bin, tmp_path).start()
    processes.append(router_a)
    port_b = free_port()
    twin = Armtwin(
        armtwin_bin, tmp_path, "twin", TWIN_CONFIG.format(extra=""), router_a.endpoint,
        extra=["-e", f"tcp/127.0.0.1:{port_b}"],
    ).start()
    processes.append(twin)
    router_b = Router(router_bin, tmp_path, port=port_b, connect=[router_a.endpoint]).start()
    processes.append(router_b)
    gateway_session, dashboard = open_client(router_b.endpoint), open_client(router_b.endpoint)
    sessions += [gateway_session, dashboard]
    poses = Poses(dashboard, "r1")
    events = events_of(dashboard, "r1")
    assert wait_queryable(dashboard, "twin/state/**")
    gateway = Gateway(gateway_session, "r1", rate_hz=200.0)
    wait_matched(gateway.pub)
    # Matching is known at B before the route through A is complete: samples until the first
    # pose comes back may be lost with no seq before them to show it.
    assert wait_until(lambda: gateway.send_one() or poses.items, 10, interval=0.05)
    time.sleep(0.2)  # the last of those samples taken too
    unheard = gateway.seq - paired(dashboard, "r1")
    gateway.start()
    try:
        assert wait_until(lambda: len(poses.items) >= 200, 20), router_b.logs()
        router_a.kill()
        killed_at = time.monotonic()
        assert wait_until(lambda: poses.items[-1][0] > killed_at + 0.05, 30), (
            f"no pose after router A died\n{twin.logs()}"
        )
        resumed_at = next(at for at, _ in poses.items if at > killed_at)
        time.sleep(1.0)
    finally:
        gateway.stop()
    time.sleep(0.5)
    sent = gateway.seq
    lost = lost_upstream(events)
    assert paired(dashboard, "r1") + lost == sent - unheard, (paired(dashboard, "r1"), lost, sent, unheard)
    assert not [e for e in events if e["kind"] in ("rejected", "restart")], events[-5:]
    print(f"router failover: first pose {resumed_at - killed_at:.3f} s after router A died, {lost} of {sent} samples lost")


class BlackholeProxy:
    """A TCP relay to ``target_port`` that can drop every byte both ways, as a network that is
    gone does (no reset, no close), and come back: the links of before are then closed, as
    their peers would have given them up, and new ones relay again."""

    def __init__(self, target_port: int):
        self.target_port = target_port
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self.blackholed = threading.Event()
        self.closed = threading.Event()
        self.links: list[socket.socket] = []
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while not self.closed.is_set():
            try:
                near, _ = self.listener.accept()
                far = socket.create_connection(("127.0.0.1", self.target_port), timeout=5)
            except OSError:
                continue
            with self.lock:
                self.links += [near, far]
            for src, dst in ((near, far), (far, near)):
                threading.Thread(target=self._pump, args=(src, dst), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket) -> None:
        try:
            while data := src.recv(65536):
                if not self.blackholed.is_set():
                    dst.sendall(data)
        except OSError:
            pass
        for sock in (src, dst):
            try:
                sock.close()
            except OSError:
                pass

    def cut(self) -> None:
        self.blackholed.set()

    def restore(self) -> None:
        with self.lock:
            links, self.links = self.links, []
        for sock in links:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self.blackholed.clear()

    def close(self) -> None:
        self.closed.set()
        self.listener.close()
        self.restore()


def test_a_gateway_whose_network_drops_for_30_s_is_taken_back_with_the_gap_reported(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    twin = Armtwin(armtwin_bin, tmp_path, "twin", TWIN_CONFIG.format(extra=""), router.endpoint).start()
    processes.append(twin)
    proxy = BlackholeProxy(router.port)
    dashboard = open_client(router.endpoint)
    gateway_session = open_client(f"tcp/127.0.0.1:{proxy.port}")
    sessions += [dashboard, gateway_session]
    poses = Poses(dashboard, "r1")
    events = events_of(dashboard, "r1")
    assert wait_queryable(dashboard, "twin/state/**")
    gateway = Gateway(gateway_session, "r1", rate_hz=100.0)
    wait_matched(gateway.pub)
    gateway.start()
    try:
        assert wait_until(lambda: len(poses.items) >= 100, 20), twin.logs()
        proxy.cut()
        time.sleep(BLACKHOLE_S)
        proxy.restore()
        restored_at = time.monotonic()
        assert wait_until(lambda: poses.items[-1][0] > restored_at, 60), (
            f"no pose after the network came back\n{router.logs()}"
        )
        resumed_at = next(at for at, _ in poses.items if at > restored_at)
        time.sleep(1.0)
        gateway.stop()
        # The last samples the gateway put cross the proxy before it closes: closing it at once
        # could cut them off, and a lost last sample is no gap (nothing after it shows it).
        wait_until(lambda: paired(dashboard, "r1") + lost_upstream(events) >= gateway.seq, 10, interval=0.2)
    finally:
        gateway.stop()
        proxy.close()
    sent = gateway.seq
    lost = lost_upstream(events)
    assert lost >= BLACKHOLE_S * 100 * 0.9, f"the blackhole's samples are a gap: {lost}"
    assert paired(dashboard, "r1") + lost == sent, (paired(dashboard, "r1"), lost, sent)
    assert not [e for e in events if e["kind"] in ("rejected", "restart")], "taken back as it is, not refused"
    print(
        f"network blackholed {BLACKHOLE_S:.0f} s: first pose {resumed_at - restored_at:.2f} s after it came back, "
        f"{lost} of {sent} samples lost as gaps"
    )
