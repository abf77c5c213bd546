"""End-to-end tests of ``armtwin serve`` over Zenoh, against the protocol (docs/protocol/).

Each test starts the real binary on a private loopback port, connects one Python Zenoh peer,
streams real UR10e recordings (tests/data) and checks every output against an independent
numpy/scipy computation (ur_reference.py). Expected values never come from armtwin itself.

Run: ``.venv/bin/python -m pytest tests/python/test_service.py -q`` (``-s`` shows the figures).
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from support.checks import Checks
from support.process import ArmtwinProcess, wait_until
from support.twin_reference import (
    MEASURED_KEYS,
    MODEL,
    STAT_NAMES,
    TOL_EULER,
    TOL_POS,
    TOL_QUAT,
    check_deviations,
    check_metrics,
    check_poses,
    joint_message,
    load_fmpy,
    load_lasttest_naive,
    measured_arrays,
    reference_deviations,
    reference_poses,
    reference_stats,
)
from support.zenoh_clients import PREFIX, TwinClient, reply_payloads

CONFIG = """\
[service]
metrics_period_ms = 50
# Every pose is counted: a test client that falls behind must slow the twin, not miss poses.
pose_congestion = "block"

[robots.default]
model = "ur10e"
"""
WATCHDOG_S = 420.0  # hard limit per test: the process is killed, every blocked call returns


# ----------------------------------------------------------------------------------------------
# fixture
# ----------------------------------------------------------------------------------------------


class Twin:
    def __init__(self, proc: ArmtwinProcess, client: TwinClient):
        self.proc = proc
        self.client = client
        self.collector = client.collector


@pytest.fixture
def twin(armtwin_bin, tmp_path):
    proc = ArmtwinProcess(armtwin_bin, tmp_path, CONFIG, WATCHDOG_S)
    proc.start()
    client = None
    try:
        client = TwinClient(proc.endpoint)
        yield Twin(proc, client)
    finally:
        code, took = proc.stop()
        if client is not None:
            client.close()
    if proc.watchdog_fired:
        pytest.fail(f"watchdog: armtwin killed after {WATCHDOG_S} s\n{proc.logs()}")
    if took is None and proc.sigint_at is not None and code is None:
        pytest.fail(f"armtwin did not exit within 15 s of SIGINT (killed)\n{proc.logs()}")
    if code != 0:
        pytest.fail(f"armtwin exited with code {code} after SIGINT\n{proc.logs()}")


# ----------------------------------------------------------------------------------------------
# waits
# ----------------------------------------------------------------------------------------------


def final_metrics(tw: Twin, robot, predicate, timeout=10.0):
    """The metrics message satisfying ``predicate``; if none comes within ``timeout``, SIGINT the
    service and take the last metrics message it published (its final metrics)."""
    msg = tw.collector.wait_message("metrics", robot, predicate, timeout)
    if msg is not None:
        return msg, "periodic"
    tw.proc.stop()
    time.sleep(0.2)
    return tw.collector.last("metrics", robot), "after SIGINT"


def wait_outputs(tw: Twin, robot, poses, devs, events=0, timeout=60.0, quiet_s=3.0):
    """Wait until the expected counts arrive, or nothing new arrives for ``quiet_s`` s (so a
    shortfall is reported quickly), bounded by ``timeout``."""
    c = tw.collector
    deadline = time.monotonic() + timeout
    last_total, last_change = -1, time.monotonic()
    while time.monotonic() < deadline:
        counts = (c.count("pose", robot), c.count("deviation", robot), c.count("events", robot))
        if counts[0] >= poses and counts[1] >= devs and counts[2] >= events:
            time.sleep(0.3)  # let any surplus arrive, so "exactly" is meaningful
            return
        total = sum(counts)
        if total != last_total:
            last_total, last_change = total, time.monotonic()
        elif time.monotonic() - last_change > quiet_s:
            return
        time.sleep(0.02)


# ----------------------------------------------------------------------------------------------
# 1. fmpy_inputs.csv with embedded measured poses
# ----------------------------------------------------------------------------------------------


def test_fmpy_inputs_stream(twin):
    robot = "fmpy"
    q, meas = load_fmpy()
    n = len(q)
    assert n == 54
    t = [i * 0.1 for i in range(n)]
    client = twin.client
    client.ready([robot])
    pub = client.joints(robot)
    for i in range(n):
        client.put_json(pub, joint_message(t[i], q[i], meas[i]))
    wait_outputs(twin, robot, n, n, timeout=60)

    checks = Checks()
    poses = twin.collector.messages("pose", robot)
    devs = twin.collector.messages("deviation", robot)
    check_poses(checks, poses, robot, t, q, "fmpy")
    check_deviations(checks, devs, robot, t, q, meas, "fmpy")
    events = twin.collector.messages("events", robot)
    checks.equal([e.get("kind") for e in events], [], "fmpy: events")

    ref = reference_deviations(q, meas)
    stats = reference_stats(ref)
    metrics, how = final_metrics(twin, robot, lambda m: m.get("paired") == n and m.get("t") == t[-1])
    check_metrics(checks, metrics, robot, n, 0, stats, f"fmpy ({how} metrics)", t=t[-1])

    p, qd = stats["position"], stats["quat_distance"]
    print(
        f"\n[fmpy_inputs.csv] {n} rows: position MAE {p['mae'] * 1e3:.4f} mm, RMSE {p['rmse'] * 1e3:.4f} mm, "
        f"max {p['max'] * 1e3:.4f} mm; quat distance MAE {qd['mae']:.3e}, RMSE {qd['rmse']:.3e}, "
        f"max {qd['max']:.3e}; final metrics: {how}"
    )
    checks.done(twin.proc.logs())


# ----------------------------------------------------------------------------------------------
# 2. ur10e_lasttest.csv through a naive gateway (7 corrupted rows)
# ----------------------------------------------------------------------------------------------


def test_lasttest_naive_gateway(twin):
    robot = "lasttest"
    rows = load_lasttest_naive()
    n = len(rows)
    assert n == 29061
    t = [i * 0.002 for i in range(n)]
    assert all(b > a for a, b in zip(t, t[1:]))
    q = [r[1:7] for r in rows]
    assert all(isinstance(v, float) for qq in q for v in qq), "every joint field parses"
    meas = [r[7:14] for r in rows]
    bad = [i for i, m in enumerate(meas) if any(isinstance(v, str) for v in m)]
    assert len(bad) == 7
    bad_fields = [[k for k, v in zip(MEASURED_KEYS, meas[i]) if isinstance(v, str)] for i in bad]
    assert all(len(f) == 1 for f in bad_fields)
    good = [i for i in range(n) if i not in set(bad)]

    client = twin.client
    client.ready([robot])
    pub = client.joints(robot)
    payloads = [json.dumps(joint_message(t[i], q[i], meas[i])) for i in range(n)]
    start = time.monotonic()
    for payload in payloads:
        pub.put(payload)
    sent = time.monotonic()
    wait_outputs(twin, robot, n, len(good), events=7, timeout=300, quiet_s=5.0)
    c = twin.collector
    pose_items = c.items("pose", robot)
    last_out = max((i.at for i in c.items(robot=robot) if i.stream in ("pose", "deviation", "events")), default=sent)
    put_s = sent - start
    e2e_s = last_out - start
    print(
        f"\n[ur10e_lasttest.csv] {n} joint messages published in {put_s:.2f} s ({n / put_s:,.0f} msg/s); "
        f"last output received {e2e_s:.2f} s after the first put ({n / e2e_s:,.0f} msg/s end to end); "
        f"received {len(pose_items)} poses, {c.count('deviation', robot)} deviations, "
        f"{c.count('events', robot)} events"
    )

    checks = Checks()
    q_arr = np.array(q, float)
    poses = [i.json() for i in pose_items]
    check_poses(checks, poses, robot, t, q_arr, "lasttest")

    events = c.messages("events", robot)
    rejected = [e for e in events if e.get("kind") == "rejected"]
    checks.equal(len(rejected), 7, "lasttest: number of rejected events")
    others = sorted({e.get("kind") for e in events} - {"rejected", "alarm", "recovered"})
    checks.equal(others, [], "lasttest: unexpected event kinds")
    for j, e in enumerate(rejected[:7]):
        field = f"measured.{bad_fields[j][0]}"
        checks.equal((e.get("detail") or {}).get("cause"), "wrong_type", f"lasttest: rejected #{j} cause")
        checks.equal(e.get("key"), f"{PREFIX}/joints/{robot}", f"lasttest: rejected #{j} key")
        checks.equal(e.get("robot"), robot, f"lasttest: rejected #{j} robot")
        checks.true(field in json.dumps(e), f"lasttest: rejected #{j} (row {bad[j]}) names {field}: {e}")

    meas_good = np.array([meas[i] for i in good], float)
    q_good = q_arr[good]
    t_good = [t[i] for i in good]
    devs = c.messages("deviation", robot)
    check_deviations(checks, devs, robot, t_good, q_good, meas_good, "lasttest")

    stats = reference_stats(reference_deviations(q_good, meas_good))
    metrics, how = final_metrics(
        twin,
        robot,
        lambda m: m.get("paired") == len(good) and m.get("rejected") == 7 and m.get("t") == t[-1],
    )
    check_metrics(checks, metrics, robot, len(good), 7, stats, f"lasttest ({how} metrics)", t=t[-1])
    p, qd = stats["position"], stats["quat_distance"]
    print(
        f"[ur10e_lasttest.csv] reference over {len(good)} valid rows: position MAE {p['mae'] * 1e3:.4f} mm, "
        f"RMSE {p['rmse'] * 1e3:.4f} mm, max {p['max'] * 1e3:.4f} mm; quat distance MAE {qd['mae']:.3e}, "
        f"RMSE {qd['rmse']:.3e}, max {qd['max']:.3e}; final metrics: {how}"
    )
    checks.done(twin.proc.logs())


# ----------------------------------------------------------------------------------------------
# 3. bad input over the wire
# ----------------------------------------------------------------------------------------------


def test_bad_input_interleaved(twin):
    robot = "bad"
    q, meas = load_fmpy()
    client = twin.client
    client.ready([robot], measured=True)
    jp, mp = client.joints(robot), client.measured(robot)
    jkey, mkey = f"{PREFIX}/joints/{robot}", f"{PREFIX}/measured/{robot}"

    def jmsg(i, t):
        return {"t": t, "q": [float(v) for v in q[i]]}

    def mmsg(i, t, **extra):
        m = {"t": t, **{k: float(v) for k, v in zip(MEASURED_KEYS, meas[i])}}
        m.update(extra)
        return m

    quat = meas[2, 3:7] / np.linalg.norm(meas[2, 3:7]) * 1.2
    rpy_fields = dict(zip(("roll", "pitch", "yaw"), measured_arrays(meas[2:3])[2][0].tolist()))
    # (publisher, payload, expected: "pose" | "deviation" | (cause, key))
    # Causes: not_json, joint_count, out_of_order, duplicate_stamp are named in
    # docs/protocol/messages.md;
    # the doc's cause list ends in "…" and does not name the quaternion-norm and two-forms causes:
    # quaternion_norm / orientation_forms are the names armtwin reports (kind() in codec/wire.rs).
    plan = [
        (jp, jmsg(0, 0.0), "pose"),
        (jp, b"this is { not JSON", ("not_json", jkey)),
        (jp, jmsg(1, 0.1), "pose"),
        (jp, {"t": 0.15, "q": [float(v) for v in q[1][:5]]}, ("joint_count", jkey)),
        (jp, jmsg(2, 0.2), "pose"),
        (mp, mmsg(2, 0.2, **dict(zip(("qx", "qy", "qz", "qw"), quat.tolist()))), ("quaternion_norm", mkey)),
        (mp, mmsg(2, 0.2, **rpy_fields), ("orientation_forms", mkey)),
        (mp, mmsg(2, 0.2), "deviation"),
        (jp, jmsg(3, 0.3), "pose"),
        (jp, jmsg(4, 0.25), ("out_of_order", jkey)),
        (jp, jmsg(4, 0.4), "pose"),
        (jp, jmsg(5, 0.4), ("duplicate_stamp", jkey)),
        (jp, jmsg(5, 0.5), "pose"),
    ]
    for pub, payload, _ in plan:
        pub.put(payload if isinstance(payload, bytes) else json.dumps(payload))
    want_rejects = [e for _, _, e in plan if isinstance(e, tuple)]
    want_poses = [p["t"] for _, p, e in plan if e == "pose"]
    wait_outputs(twin, robot, len(want_poses), 1, events=len(want_rejects), timeout=30)

    checks = Checks()
    poses = twin.collector.messages("pose", robot)
    check_poses(checks, poses, robot, want_poses, q[[0, 1, 2, 3, 4, 5]], "bad input")
    devs = twin.collector.messages("deviation", robot)
    check_deviations(checks, devs, robot, [0.2], q[[2]], meas[[2]], "bad input")
    events = twin.collector.messages("events", robot)
    got = sorted(
        ((e.get("detail") or {}).get("cause"), e.get("key")) for e in events if e.get("kind") == "rejected"
    )
    checks.equal(got, sorted(want_rejects), "bad input: rejected events (cause, key)")
    checks.equal(
        [e.get("kind") for e in events if e.get("kind") != "rejected"], [], "bad input: other events"
    )
    metrics, how = final_metrics(
        twin,
        robot,
        # Every field at its final value: a periodic message can fall between the last rejection
        # and the last pose, so counts alone may still be one sample behind.
        lambda m: m.get("rejected") == len(want_rejects)
        and m.get("paired") == 1
        and m.get("t") == max(want_poses),
    )
    if checks.true(metrics is not None, "bad input: no metrics"):
        checks.equal(metrics.get("rejected"), len(want_rejects), f"bad input: metrics rejected ({how})")
        checks.equal(metrics.get("paired"), 1, f"bad input: metrics paired ({how})")
        checks.equal(metrics.get("t"), max(want_poses), f"bad input: metrics t (newest source time, {how})")
    checks.done(twin.proc.logs())


# ----------------------------------------------------------------------------------------------
# 4. queries
# ----------------------------------------------------------------------------------------------


def test_queries(twin):
    robots = ("r1", "plant-a/cell-3/ur10e-07")
    q, meas = load_fmpy()
    n = 20
    client = twin.client
    client.ready(robots)
    for r in robots:
        pub = client.joints(r)
        for i in range(n):
            client.put_json(pub, joint_message(i * 0.1, q[i], meas[i]))
    for r in robots:
        wait_outputs(twin, r, n, n, timeout=30)
    for r in robots:
        assert twin.collector.wait_message("metrics", r, lambda m: m.get("paired") == n, 10), r
    checks = Checks()
    stats = reference_stats(reference_deviations(q[:n], meas[:n]))
    last_pos, last_quat, last_rpy = reference_poses(q[n - 1 : n])

    # state of every robot
    oks, errs = reply_payloads(client.get(f"{PREFIX}/state/**"))
    checks.equal(errs, [], "get twin/state/**: error replies")
    checks.equal(sorted(k for k, _ in oks), sorted(f"{PREFIX}/state/{r}" for r in robots), "get twin/state/**: reply keys")
    for key, st in oks:
        r = key.split("/", 2)[2]
        checks.equal(st.get("robot"), r, f"state {r}: robot")
        checks.equal(st.get("model"), MODEL, f"state {r}: model")
        checks.equal(st.get("calibration"), None, f"state {r}: calibration")
        checks.equal(st.get("tool"), [0.0] * 6, f"state {r}: tool")
        checks.equal(st.get("frame"), "base", f"state {r}: frame")
        checks.equal(st.get("joints"), {"t": (n - 1) * 0.1, "q": q[n - 1].tolist()}, f"state {r}: joints")
        tw = st.get("twin") or {}
        checks.equal(tw.get("t"), (n - 1) * 0.1, f"state {r}: twin.t")
        checks.close([tw.get(k, np.nan) for k in ("x", "y", "z")], last_pos[0], TOL_POS, f"state {r}: twin position")
        checks.close([tw.get(k, np.nan) for k in ("qx", "qy", "qz", "qw")], last_quat[0], TOL_QUAT, f"state {r}: twin quat")
        ms = st.get("measured") or {}
        checks.equal(ms.get("t"), (n - 1) * 0.1, f"state {r}: measured.t")
        checks.close([ms.get(k, np.nan) for k in ("x", "y", "z")], meas[n - 1, :3], TOL_POS, f"state {r}: measured position")
        check_metrics(checks, st.get("metrics"), r, n, 0, stats, f"state {r}: metrics", t=(n - 1) * 0.1)

    # a site's robots only
    oks, _ = reply_payloads(client.get(f"{PREFIX}/state/plant-a/**"))
    checks.equal([k for k, _ in oks], [f"{PREFIX}/state/plant-a/cell-3/ur10e-07"], "get twin/state/plant-a/**")

    # liveliness tokens
    alive = sorted(str(r.ok.key_expr) for r in client.session.liveliness().get(f"{PREFIX}/alive/**", timeout=10) if r.ok)
    checks.equal(alive, sorted(f"{PREFIX}/alive/{r}" for r in robots), "liveliness twin/alive/**")

    # FK on demand
    qfk = [0.3, -1.2, 1.1, -0.4, 1.0, 2.5]
    pos, quat, rpy = reference_poses([qfk])
    for r in robots:
        for label, body in (("rad", {"q": qfk}), ("deg", {"q": np.degrees(qfk).tolist(), "unit": "deg"})):
            oks, errs = reply_payloads(client.get(f"{PREFIX}/fk/{r}", payload=json.dumps(body)))
            checks.equal(errs, [], f"fk {r} ({label}): error replies")
            if checks.equal(len(oks), 1, f"fk {r} ({label}): replies"):
                p = oks[0][1]
                checks.equal(p.get("seq"), 0, f"fk {r} ({label}): seq")
                checks.equal(p.get("robot"), r, f"fk {r} ({label}): robot")
                checks.equal(p.get("frame"), "base", f"fk {r} ({label}): frame")
                tol = TOL_POS if label == "rad" else 1e-12
                checks.close([p.get(k, np.nan) for k in ("x", "y", "z")], pos[0], tol, f"fk {r} ({label}): position")
                checks.close([p.get(k, np.nan) for k in ("qx", "qy", "qz", "qw")], quat[0], TOL_QUAT, f"fk {r} ({label}): quat")
                checks.angles_close([p.get(k, np.nan) for k in ("roll", "pitch", "yaw")], rpy[0], TOL_EULER, f"fk {r} ({label}): rpy")
    oks, errs = reply_payloads(client.get(f"{PREFIX}/fk/r1", payload=json.dumps({"q": qfk[:5]})))
    checks.equal(len(oks), 0, "fk with 5 joints: ok replies")
    checks.true(len(errs) == 1 and isinstance(errs[0].get("error"), str), f"fk with 5 joints: one {{'error'}} reply, got {errs}")

    # reset
    before = twin.collector.count("metrics", "r1")
    oks, errs = reply_payloads(client.get(f"{PREFIX}/admin/reset/r1"))
    checks.equal(errs, [], "reset r1: error replies")
    if checks.equal(len(oks), 1, "reset r1: replies"):
        final = oks[0][1]
        check_metrics(checks, final, "r1", n, 0, stats, "reset r1: reply (final metrics)", t=(n - 1) * 0.1)
        published = twin.collector.wait_message(
            "metrics", "r1", lambda m: m == final, 5.0
        ) if wait_until(lambda: twin.collector.count("metrics", "r1") > before, 5.0) else None
        checks.true(published is not None, "reset r1: the final metrics are also published on twin/metrics/r1")
    oks, _ = reply_payloads(client.get(f"{PREFIX}/state/r1"))
    if checks.equal(len(oks), 1, "state r1 after reset: replies"):
        m = oks[0][1].get("metrics") or {}
        checks.equal(m.get("paired"), 0, "state r1 after reset: metrics.paired")
        checks.equal(m.get("rejected"), 0, "state r1 after reset: metrics.rejected")
        cum = m.get("cumulative") or {}
        checks.equal(cum.get("n"), 0, "state r1 after reset: cumulative.n")
        checks.true(
            all(cum.get(s, {}).get(k) == 0 for s in STAT_NAMES for k in ("mae", "rmse", "max")),
            f"state r1 after reset: every statistic 0, got {cum}",
        )
    oks, _ = reply_payloads(client.get(f"{PREFIX}/state/plant-a/cell-3/ur10e-07"))
    if checks.equal(len(oks), 1, "state of the other robot after reset r1: replies"):
        checks.equal((oks[0][1].get("metrics") or {}).get("paired"), n, "other robot keeps its metrics")
    checks.done(twin.proc.logs())


# ----------------------------------------------------------------------------------------------
# 5. shutdown
# ----------------------------------------------------------------------------------------------


def test_shutdown_final_metrics(twin):
    robots = ("s1", "site/s2")
    q, meas = load_fmpy()
    n = 10
    client = twin.client
    client.ready(robots)
    for r in robots:
        pub = client.joints(r)
        for i in range(n):
            client.put_json(pub, joint_message(i * 0.1, q[i], meas[i]))
    for r in robots:
        assert twin.collector.wait_message("metrics", r, lambda m: m.get("paired") == n, 15), r
    time.sleep(0.3)
    stats = reference_stats(reference_deviations(q[:n], meas[:n]))
    code, took = twin.proc.stop(timeout=15.0)
    checks = Checks()
    checks.true(took is not None, f"armtwin exits within 15 s of SIGINT (exit code {code}, took {took})")
    checks.equal(code, 0, "exit code after SIGINT")
    time.sleep(0.3)
    sigint_at = twin.proc.sigint_at
    for r in robots:
        after = [i.json() for i in twin.collector.items("metrics", r) if i.at >= sigint_at]
        if checks.true(after, f"{r}: a final metrics message after SIGINT"):
            check_metrics(checks, after[-1], r, n, 0, stats, f"{r}: final metrics", t=(n - 1) * 0.1)
    print(f"\n[shutdown] exit code {code} {took:.3f} s after SIGINT" if took is not None else "")
    checks.done(twin.proc.logs())
