"""Deploying a fleet, end to end with real processes: a Zenoh router (armtwin-router, REST linked
in), armtwin instances in client mode behind it splitting a fleet by key expression, gateways and
dashboards that reach armtwin only through the router, REST and SSE read with a real HTTP client,
the router killed and restarted mid-stream, armtwin killed with SIGKILL and restored from its
snapshot."""

from __future__ import annotations

import http.client
import json
import time
import urllib.request

from support.gateway import Gateway
from support.paths import REPO_ROOT
from support.process import Armtwin, Router, free_port, wait_until
from support.zenoh_clients import (
    Poses,
    description_publisher,
    get_json,
    open_client,
    paired_of,
    wait_matched,
    wait_queryable,
)

TWIN_CONFIG = """
[service]
robots = "{robots}"
pose_congestion = "block"
metrics_period_ms = 100
{extra}

[robots.default]
model = "ur10e"
alarm_position_m = 0.0005
alarm_hold_s = 0.0
"""


def twin_config(robots: str = "**", extra: str = "") -> str:
    return TWIN_CONFIG.format(robots=robots, extra=extra)



def test_clients_reach_armtwin_through_the_router(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    router = Router(router_bin, tmp_path, rest=True).start()
    processes.append(router)
    processes.append(Armtwin(armtwin_bin, tmp_path, "twin", twin_config(), router.endpoint).start())
    gateway_session, dashboard = open_client(router.endpoint), open_client(router.endpoint)
    sessions += [gateway_session, dashboard]
    poses = Poses(dashboard, "site/r1")
    assert wait_queryable(dashboard, "twin/state/**"), "armtwin's queryable never reached the dashboard"
    gateway = Gateway(gateway_session, "site/r1")
    wait_matched(gateway.pub)
    for _ in range(50):
        gateway.send_one()
        time.sleep(0.005)
    assert wait_until(lambda: len(poses.items) >= 50, 15), f"{len(poses.items)} poses\n{router.logs()}"
    assert poses.seqs() == list(range(50))
    [(key, state)] = get_json(dashboard, "twin/state/**")
    assert key == "twin/state/site/r1" and state["robot"] == "site/r1"

    # REST: a GET is a Zenoh query; the replies' application/json encoding makes them objects.
    url = f"http://127.0.0.1:{router.rest_port}/twin/state/**"
    with urllib.request.urlopen(url, timeout=10) as response:
        assert response.status == 200
        body = json.loads(response.read())
    assert [item["key"] for item in body] == ["twin/state/site/r1"]
    assert body[0]["encoding"] == "application/json"
    assert body[0]["value"]["robot"] == "site/r1" and body[0]["value"]["metrics"]["paired"] == 50

    # SSE: metrics streamed as `event: PUT` records while the gateway streams.
    connection = http.client.HTTPConnection("127.0.0.1", router.rest_port, timeout=10)
    connection.request("GET", "/twin/metrics/**", headers={"Accept": "text/event-stream"})
    response = connection.getresponse()
    assert response.status == 200 and response.getheader("Content-Type", "").startswith("text/event-stream")
    gateway.start()
    records = []
    deadline = time.monotonic() + 20
    try:
        while len(records) < 3 and time.monotonic() < deadline:
            line = response.fp.readline().decode().strip()
            if line.startswith("data: "):
                records.append(json.loads(line[len("data: "):]))
    finally:
        gateway.stop()
        connection.close()
    assert len(records) >= 3, records
    for record in records:
        assert record["key"] == "twin/metrics/site/r1" and record["encoding"] == "application/json"
        assert record["value"]["cumulative"]["n"] >= 50


def test_two_shards_split_a_fleet_and_an_overlap_is_refused(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    shard_a = Armtwin(armtwin_bin, tmp_path, "shard-a", twin_config("site-a/**"), router.endpoint).start()
    shard_b = Armtwin(armtwin_bin, tmp_path, "shard-b", twin_config("site-b/**"), router.endpoint).start()
    processes += [shard_a, shard_b]
    client = open_client(router.endpoint)
    sessions.append(client)
    fleet = ["site-a/r1", "site-a/r2", "site-b/r1"]
    gateways = [Gateway(client, robot) for robot in fleet]
    for gateway in gateways:
        wait_matched(gateway.pub)
        for _ in range(10):
            gateway.send_one()
    assert wait_until(lambda: len(get_json(client, "twin/state/**")) == 3, 15)
    time.sleep(0.5)
    replies = get_json(client, "twin/state/**")
    assert sorted(key for key, _ in replies) == [f"twin/state/{robot}" for robot in fleet], replies
    assert all(state["metrics"]["paired"] == 10 for _, state in replies)
    # Each shard tracks its own robots alone.
    assert "site-b" not in shard_a.logs(limit=10**9).split("robots claimed", 1)[1]
    assert "site-a/r1" in shard_a.logs(limit=10**9) and "site-a/r1" not in shard_b.logs(limit=10**9)
    claims = sorted(claim["robots"] for _, claim in get_json(client, "twin/shards/**"))
    assert claims == ["site-a/**", "site-b/**"]

    overlapping = Armtwin(armtwin_bin, tmp_path, "shard-ab", twin_config("*/r1"), router.endpoint)
    overlapping.start(ready=False)
    processes.append(overlapping)
    assert wait_until(lambda: not overlapping.running(), 30), overlapping.logs()
    assert overlapping.proc.returncode != 0
    log = overlapping.logs()
    assert "service.robots '*/r1' overlaps" in log and ("'site-a/**'" in log or "'site-b/**'" in log), log


def test_a_router_restart_mid_stream_is_survived(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    http_port = free_port()
    config = twin_config(extra=f'\n[http]\nlisten = "127.0.0.1:{http_port}"')
    twin = Armtwin(armtwin_bin, tmp_path, "twin", config, router.endpoint).start()
    processes.append(twin)
    gateway_session, dashboard = open_client(router.endpoint), open_client(router.endpoint)
    sessions += [gateway_session, dashboard]
    poses = Poses(dashboard, "r1")
    events = []
    dashboard.declare_subscriber("twin/events/r1", lambda s: events.append(json.loads(s.payload.to_bytes())))
    assert wait_queryable(dashboard, "twin/state/**")
    gateway = Gateway(gateway_session, "r1", rate_hz=200.0)
    wait_matched(gateway.pub)
    gateway.start()
    try:
        assert wait_until(lambda: len(poses.items) >= 200, 20), router.logs()
        router.kill()
        killed_at = time.monotonic()
        time.sleep(1.0)
        router = Router(router_bin, tmp_path, port=router.port)
        processes.append(router.start())
        restarted_at = time.monotonic()
        assert wait_until(lambda: poses.items and poses.items[-1][0] > restarted_at, 60), (
            f"no pose after the router restarted\n{twin.logs()}"
        )
        resumed_at = next(at for at, _ in poses.items if at > restarted_at)
        time.sleep(1.0)
    finally:
        gateway.stop()
    assert twin.running(), twin.logs()
    # The outage's first sample raises two gap events, the gateway's seq skipped and its stamp
    # (the gateway's clock moves one period per seq): each says how many samples were lost. Events
    # published while the dashboard's subscription is declared again on the new router can be lost
    # (one of them, or both), so the robot's recent events, which the service keeps, count as
    # well.
    with urllib.request.urlopen(f"http://127.0.0.1:{http_port}/api/robot?id=r1", timeout=10) as response:
        kept = json.loads(response.read())["events"]
    events = events + [e for e in kept if e not in events]
    seq_gaps = {e["t"]: e["detail"]["got"] - e["detail"]["expected"]
                for e in events if e["kind"] == "gap" and "expected" in e["detail"]}
    stamp_gaps = {e["t"]: round(e["detail"]["gap_s"] / gateway.period_s) - 1
                  for e in events if e["kind"] == "gap" and "gap_s" in e["detail"]}
    assert seq_gaps or stamp_gaps, f"no gap event: {events[-5:]}"
    lost = sum(seq_gaps.values()) + sum(n for t, n in stamp_gaps.items() if t not in seq_gaps)
    sent = gateway.seq
    [(_, state)] = get_json(dashboard, "twin/state/r1")
    # Every sample armtwin took yields one pose: those lost upstream are exactly the seq gaps.
    assert state["metrics"]["paired"] + lost == sent - 0, (state["metrics"]["paired"], lost, sent)
    print(
        f"router restart: down {restarted_at - killed_at:.2f} s, first pose "
        f"{resumed_at - restarted_at:.2f} s after the restart, {lost} of {sent} samples lost upstream"
    )


def twin_with_snapshots(tmp_path, armtwin_bin, router_bin, processes, sessions, period_s: float):
    """A router, armtwin behind it with snapshots every ``period_s`` in ``tmp_path/state``, and a
    client of the router: (state dir, armtwin's configuration, router, armtwin, client)."""
    state_dir = tmp_path / "state"
    config = twin_config(extra=f'state_dir = "{state_dir}"\nsnapshot_period_s = {period_s}')
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    twin = Armtwin(armtwin_bin, tmp_path, "twin", config, router.endpoint).start()
    processes.append(twin)
    client = open_client(router.endpoint)
    sessions.append(client)
    return state_dir, config, router, twin, client


def test_after_a_sigkill_the_twins_come_back_from_the_snapshot(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    state_dir, config, router, twin, client = twin_with_snapshots(
        tmp_path, armtwin_bin, router_bin, processes, sessions, 0.5
    )
    assert wait_queryable(client, "twin/state/**")
    gateway = Gateway(client, "r1")
    wait_matched(gateway.pub)
    for _ in range(300):
        gateway.send_one()
        time.sleep(0.002)
    assert wait_until(lambda: paired_of(client, "r1") == 300, 15)
    [(_, before)] = get_json(client, "twin/state/r1")
    assert before["alarms"]["position"], "the alarm is armed before the kill"
    time.sleep(1.2)  # at least two snapshot periods with the 300 samples in
    twin.kill()
    snapshot = json.loads((state_dir / "twin-state.json").read_text())
    assert [r["robot"] for r in snapshot["robots"]] == ["r1"]

    twin = Armtwin(armtwin_bin, tmp_path, "twin", config, router.endpoint).start()
    processes.append(twin)
    assert "twins restored from the snapshot" in twin.logs()
    assert wait_queryable(client, "twin/state/**")
    [(_, after)] = get_json(client, "twin/state/r1")
    assert after["metrics"]["paired"] == 300 and after["metrics"]["cumulative"] == before["metrics"]["cumulative"]
    assert after["alarms"]["position"] is True
    poses = Poses(client, "r1")
    events = []
    client.declare_subscriber("twin/events/r1", lambda s: events.append(json.loads(s.payload.to_bytes())))
    assert wait_queryable(client, "twin/state/**")
    gateway.send_one()
    assert wait_until(lambda: poses.items, 10)
    assert poses.seqs()[0] == 300, "the pose seq goes on from the snapshot"
    assert wait_until(lambda: paired_of(client, "r1") == 301, 10)


def test_a_twin_that_took_its_own_description_starts_afresh_the_others_come_back(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    """A snapshot record of a twin computing with another arm than its configured one (here a
    Panda's own description, taken by a robot under the default UR10e) cannot be restored onto
    the configured arm: after a restart that robot starts afresh, with a warning naming why, and
    every other robot's twin comes back from the same file."""
    state_dir = tmp_path / "state"
    # p1's own section names its chain's tip, not a model: it takes its description.
    config = twin_config(extra=f'state_dir = "{state_dir}"\n\n[robots."p1"]\ntip_link = "panda_hand_tcp"')
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    twin = Armtwin(armtwin_bin, tmp_path, "twin", config, router.endpoint).start()
    processes.append(twin)
    client = open_client(router.endpoint)
    sessions.append(client)
    assert wait_queryable(client, "twin/state/**")
    gateway = Gateway(client, "r1")
    wait_matched(gateway.pub)
    for _ in range(100):
        gateway.send_one()
    assert wait_until(lambda: paired_of(client, "r1") == 100, 15)
    events = []
    client.declare_subscriber("twin/events/p1", lambda s: events.append(json.loads(s.payload.to_bytes())))
    description_publisher(client, "p1").put((REPO_ROOT / "tests" / "data" / "urdf" / "panda.urdf").read_text())
    assert wait_until(lambda: any(e["kind"] == "description" for e in events), 15), events
    [taken] = [e for e in events if e["kind"] == "description"]
    assert taken["detail"]["in_use"] is True, taken
    assert twin.stop().code == 0
    snapshot = json.loads((state_dir / "twin-state.json").read_text())
    assert sorted(r["robot"] for r in snapshot["robots"]) == ["p1", "r1"], snapshot

    twin = Armtwin(armtwin_bin, tmp_path, "twin", config, router.endpoint).start()
    processes.append(twin)
    log = twin.logs()
    assert "snapshot refused" not in log, log
    assert "twin not restored: it starts afresh" in log and "'panda'" in log, log
    assert wait_queryable(client, "twin/state/**")
    [(_, after)] = get_json(client, "twin/state/r1")
    assert after["metrics"]["paired"] == 100, after["metrics"]
    assert get_json(client, "twin/state/p1") == []


def test_a_corrupt_snapshot_is_set_aside_and_the_service_starts_fresh(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    state_dir = tmp_path / "state"
    state_dir.mkdir()
    (state_dir / "twin-state.json").write_text('{"format": "armtwin-twin-state/v1", "robots": [')
    config = twin_config(extra=f'state_dir = "{state_dir}"')
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    twin = Armtwin(armtwin_bin, tmp_path, "twin", config, router.endpoint).start()
    processes.append(twin)
    log = twin.logs()
    assert "snapshot refused: starting fresh" in log and "not a readable snapshot" in log, log
    aside = list(state_dir.glob("twin-state.json.refused-*"))
    assert len(aside) == 1 and aside[0].read_text().endswith('"robots": [')
    client = open_client(router.endpoint)
    sessions.append(client)
    assert wait_queryable(client, "twin/state/**")
    assert get_json(client, "twin/state/**") == []
    assert twin.stop().code == 0
    # The clean shutdown writes a fresh snapshot in place of the refused one.
    assert json.loads((state_dir / "twin-state.json").read_text())["robots"] == []


def test_sigkill_mid_stream_loses_at_most_one_snapshot_period(
    tmp_path, armtwin_bin, router_bin, processes, sessions
):
    period_s, rate_hz = 0.5, 200.0
    state_dir, config, router, twin, client = twin_with_snapshots(
        tmp_path, armtwin_bin, router_bin, processes, sessions, period_s
    )
    metrics = []
    client.declare_subscriber(
        "twin/metrics/r1", lambda s: metrics.append(json.loads(s.payload.to_bytes())["paired"])
    )
    events = []
    client.declare_subscriber("twin/events/r1", lambda s: events.append(json.loads(s.payload.to_bytes())))
    assert wait_queryable(client, "twin/state/**")
    gateway = Gateway(client, "r1", rate_hz=rate_hz)
    wait_matched(gateway.pub)
    gateway.start()
    try:
        assert wait_until(lambda: metrics and metrics[-1] >= 600, 30), twin.logs()
        twin.kill()
        # Metrics go out every 100 ms: the last one seen is at most that much behind the kill.
        paired_at_kill = metrics[-1]
        twin = Armtwin(armtwin_bin, tmp_path, "twin", config, router.endpoint).start()
        processes.append(twin)
        assert "twins restored from the snapshot" in twin.logs(), twin.logs()
        assert wait_until(lambda: any(e["kind"] == "gap" and "expected" in e["detail"] for e in events), 20)
    finally:
        gateway.stop()
    gap = next(e["detail"] for e in events if e["kind"] == "gap" and "expected" in e["detail"])
    # The restored twin goes on from the gateway seq of its snapshot: the gap is what it lost,
    # samples taken after the snapshot plus those sent while it was down.
    restored = gap["expected"]
    assert paired_at_kill - rate_hz * (period_s + 0.2) <= restored <= paired_at_kill + rate_hz * 0.2, (
        restored, paired_at_kill
    )
    print(f"SIGKILL mid-stream: restored at sample {restored}, {paired_at_kill} seen before the kill")
