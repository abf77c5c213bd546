"""A plant's fleet over time, against ``armtwin serve`` with its dashboard's ``/metrics``: a bounded
fleet that a flood of made-up robot ids cannot grow (``[service] max_robots``), and robots that went
silent retired after ``[service] forget_after_s``, their liveliness tokens gone and a later sample
starting them afresh.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_plant.py -q``.
"""

from __future__ import annotations

import json
import re

import zenoh

from support.dashboard import DashboardService, http_get
from support.process import wait_until
from support.zenoh_clients import PREFIX

Q = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]
CONFIGURED = "cell/r1"


def exposed(service: DashboardService, name: str) -> float | None:
    """The value of an unlabelled sample ``name`` on ``/metrics``."""
    status, body = http_get(service.url("/metrics"))
    assert status == 200
    match = re.search(rf"^{re.escape(name)} (\S+)$", body.decode(), re.MULTILINE)
    return float(match.group(1)) if match else None


def rss_kib(service: DashboardService) -> int:
    status = open(f"/proc/{service.proc.proc.pid}/status").read()
    return int(re.search(r"^VmRSS:\s+(\d+) kB$", status, re.MULTILINE).group(1))


def put_joints(session: zenoh.Session, robot: str, t: float) -> None:
    session.put(
        f"{PREFIX}/joints/{robot}",
        json.dumps({"t": t, "q": Q}),
        congestion_control=zenoh.CongestionControl.BLOCK,
        allowed_destination=zenoh.Locality.REMOTE,
    )


def tokens(session: zenoh.Session, robots: str) -> set[str]:
    # A channel that holds every token: the session hands the tokens it already knows to the
    # handler within `get` itself, and with the default channel (256) it would wait there forever
    # for a reader it has not yet returned.
    replies = session.liveliness().get(
        f"{PREFIX}/alive/{robots}", handler=zenoh.handlers.FifoChannel(65536), timeout=10
    )
    return {str(r.ok.key_expr) for r in replies if r.ok is not None}


def plant_config(service: str) -> str:
    """Unknown robots admitted as ur10e's, one configured robot, and ``service`` lines."""
    return (
        f"[service]\nmetrics_period_ms = 100\n{service}\n\n[robots.default]\nmodel = \"ur10e\"\n\n"
        f'[robots."{CONFIGURED}"]\nmodel = "ur10e"\n'
    )


FULL_CONFIG = plant_config("max_robots = 1000")


def test_a_flood_of_new_ids_fills_the_fleet_to_max_robots_and_no_further(armtwin_bin, tmp_path):
    """5 000 distinct ids, one sample each: 1 000 tracked (the configured robot among them), the
    4 000 others refused and counted, each refusal an event at most at the untracked robots' rate,
    memory within tens of MiB; the configured robot is still twinned afterwards."""
    with DashboardService(armtwin_bin, tmp_path, FULL_CONFIG) as service:
        session = service.client.session
        service.client.ready([CONFIGURED])
        put_joints(session, CONFIGURED, 1.0)
        assert wait_until(lambda: exposed(service, "armtwin_robots_tracked") == 1.0, 10)
        baseline_kib = rss_kib(service)
        for i in range(5000):
            put_joints(session, f"flood/{i}", 1.0)
        assert wait_until(lambda: (exposed(service, "armtwin_robots_refused_total") or 0) >= 4001, 60), (
            exposed(service, "armtwin_robots_refused_total"), service.proc.logs())
        tracked = exposed(service, "armtwin_robots_tracked")
        refused = exposed(service, "armtwin_robots_refused_total")
        assert tracked == 1000.0, tracked
        assert refused == 4001.0, refused
        assert exposed(service, "armtwin_robots_max") == 1000.0
        # The same totals in the instance's shard claim, for a mesh without HTTP.
        [claim] = [json.loads(r.ok.payload.to_bytes()) for r in session.get(f"{PREFIX}/shards/**", timeout=10) if r.ok]
        assert claim["service"]["robots"] == 1000 and claim["service"]["max_robots"] == 1000, claim
        assert claim["service"]["robots_refused"] == 4001, claim
        grown_mib = (rss_kib(service) - baseline_kib) / 1024
        assert grown_mib < 64, f"{grown_mib:.1f} MiB for 1 000 robots and 4 001 refused ids"
        # A configured robot always fits.
        put_joints(session, CONFIGURED, 2.0)
        assert wait_until(lambda: (service.state(CONFIGURED).get("joints") or {}).get("t") == 2.0, 10)
        logs = service.proc.logs(limit=10**9)
        assert logs.count("the fleet is full") == 1, "logged once, not per sample"


def test_refusals_for_a_full_fleet_are_events_of_their_own(armtwin_bin, tmp_path):
    config = plant_config("max_robots = 2")
    with DashboardService(armtwin_bin, tmp_path, config) as service:
        session = service.client.session
        service.client.ready([CONFIGURED])
        put_joints(session, "a", 1.0)
        put_joints(session, "b", 1.0)
        c = service.client.collector
        assert wait_until(lambda: c.count("events", "b") >= 1, 10), service.proc.logs()
        [event] = c.messages("events", "b")
        assert event["detail"] == {"cause": "fleet_full"}, event
        assert "max_robots" in event["reason"], event
        assert exposed(service, "armtwin_robots_tracked") == 1.0
        assert c.count("pose", "a") == 1


RETIRE_CONFIG = plant_config("forget_after_s = 2.0")


def test_silent_robots_are_retired(armtwin_bin, tmp_path):
    """300 robots send, then fall silent: 6 s later none is tracked, their tokens are gone and each
    sent its final metrics; the configured robot, silent too, stays. One of them sending again is
    a new twin (its pose seq from 0)."""
    robots = [f"line/{i}" for i in range(300)]
    with DashboardService(armtwin_bin, tmp_path, RETIRE_CONFIG) as service:
        session = service.client.session
        service.client.ready([CONFIGURED])
        put_joints(session, CONFIGURED, 1.0)
        for t in (1.0, 1.01, 1.02):
            for robot in robots:
                put_joints(session, robot, t)
        assert wait_until(lambda: len(tokens(session, "line/**")) == 300, 20), len(tokens(session, "line/**"))
        assert exposed(service, "armtwin_robots_tracked") == 301.0
        assert wait_until(lambda: exposed(service, "armtwin_robots_tracked") == 1.0, 6), (
            exposed(service, "armtwin_robots_tracked"), service.proc.logs())
        # Tracked drops as the robots are taken out; their tokens go right after, one by one (a
        # debug build beside three other test workers has taken over 5 s for the 300).
        assert wait_until(lambda: tokens(session, "line/**") == set(), 15), len(tokens(session, "line/**"))
        assert tokens(session, CONFIGURED) == {f"{PREFIX}/alive/{CONFIGURED}"}, "listed robots stay"
        assert exposed(service, "armtwin_robots_retired_total") == 300.0
        c = service.client.collector
        assert all(c.count("metrics", robot) >= 1 for robot in robots), "each sent its final metrics"
        # A retired robot that sends again is tracked afresh.
        put_joints(session, robots[7], 5.0)
        assert wait_until(lambda: tokens(session, robots[7]) == {f"{PREFIX}/alive/{robots[7]}"}, 10)
        assert service.state(robots[7])["joints"]["t"] == 5.0
        assert wait_until(lambda: c.count("pose", robots[7]) == 4, 5)
        assert [p["seq"] for p in c.messages("pose", robots[7])] == [0, 1, 2, 0], "a new twin's poses"


def test_a_gateways_prefix_grant_fills_its_own_share_and_a_robot_granted_by_name_still_fits(armtwin_bin, tmp_path):
    """The fleet description grants `cell-a` the prefix site-a/** with max_robots = 20 and `g2`
    the robot r2; the service reads it (`[service] fleet`), max_robots = 30. 500 made-up ids under
    site-a: 20 tracked, the rest refused with fleet_full events that name the grant; r2, which
    arrives after the flood, is twinned (before: it was refused once the flood had filled the
    fleet's max_robots)."""
    (tmp_path / "fleet.toml").write_text(
        '[gateways]\ncell-a = { robots = ["site-a/**"], max_robots = 20 }\ng2 = ["r2"]\n')
    config = plant_config('max_robots = 30\nfleet = "fleet.toml"')
    with DashboardService(armtwin_bin, tmp_path, config) as service:
        session = service.client.session
        service.client.ready(["r2"])
        for i in range(500):
            put_joints(session, f"site-a/flood-{i}", 1.0)
        c = service.client.collector
        assert wait_until(lambda: (exposed(service, "armtwin_robots_refused_total") or 0) >= 480, 60), (
            exposed(service, "armtwin_robots_refused_total"), service.proc.logs())
        assert exposed(service, "armtwin_robots_tracked") == 20.0

        def flood_events() -> list[dict]:
            return [e for i in range(500) for e in c.messages("events", f"site-a/flood-{i}")]

        # The refusals' events follow the counter, at the untracked robots' event rate.
        assert wait_until(lambda: len(flood_events()) >= 20, 20), len(flood_events())
        refusals = flood_events()
        assert all(e["detail"] == {"cause": "fleet_full"} for e in refusals), refusals[:3]
        assert all("'site-a/**'" in e["reason"] and "its gateway's grant" in e["reason"] for e in refusals), refusals[0]
        put_joints(session, "r2", 1.0)
        assert wait_until(lambda: (service.state("r2").get("joints") or {}).get("t") == 1.0, 10), service.proc.logs()
        assert exposed(service, "armtwin_robots_tracked") == 21.0
