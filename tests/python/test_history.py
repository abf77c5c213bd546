"""``get twin/history/<robot>?_time=…`` on the real binary while a Python gateway streams the
sample UR10e recording: every completed second equals the count, mean, RMS and maximum of the
position and angle deviations published for the pairs of that second, and ten seconds of them
add up to the window the state query reported over the same ten seconds.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_history.py -q``
"""

from __future__ import annotations

import json
import math

import zenoh

from support.gateway import Gateway, lasttest_rows
from support.process import ArmtwinProcess, wait_until
from support.zenoh_clients import TwinClient, get_json

ROBOT = "cell-1/ur10e-h"
# Stamps 1000 s + 2 ms a row: the last of 6000 rows is 1011.998, in the last 0.5-s slice of
# second 1011, so the 10-s window then holds seconds 1002 … 1011 whole.
ROWS = 6000
CONFIG = """\
[service]
metrics_period_ms = 50
pose_congestion = "block"

[recorder]
enabled = false
history_s = 60

[robots.default]
model = "ur10e"
"""
# The window's slices: 10 s in 20 (the defaults), so 2 slices a second.
SLICES_PER_S = 20 / 10.0


def second_of(stamp_s: float) -> int:
    """The history's second of a pair: that of the start of its window slice."""
    return math.floor(math.floor(stamp_s * SLICES_PER_S) / SLICES_PER_S)


def aggregate(deviations: list[dict]) -> dict:
    """Count, and mean, RMS and maximum of position and angle, of some deviation messages."""
    n = len(deviations)
    out = {"n": n}
    for metric in ("position", "angle"):
        values = [d[metric] for d in deviations]
        out[metric] = {
            "mae": sum(values) / n,
            "rmse": math.sqrt(sum(v * v for v in values) / n),
            "max": max(values),
        }
    return out


def combine(seconds: list[dict]) -> dict:
    """The statistics of the union of some seconds' pairs, from their rows."""
    n = sum(s["n"] for s in seconds)
    out = {"n": n}
    for metric in ("position", "angle"):
        out[metric] = {
            "mae": sum(s[metric]["mae"] * s["n"] for s in seconds) / n,
            "rmse": math.sqrt(sum(s[metric]["rmse"] ** 2 * s["n"] for s in seconds) / n),
            "max": max(s[metric]["max"] for s in seconds),
        }
    return out


def assert_agree(got: dict, expected: dict, what: str, rel: float = 1e-9) -> None:
    assert got["n"] == expected["n"], (what, got, expected)
    for metric in ("position", "angle"):
        assert got[metric]["max"] == expected[metric]["max"], (what, metric, got, expected)
        for stat in ("mae", "rmse"):
            assert math.isclose(got[metric][stat], expected[metric][stat], rel_tol=rel), (
                what, metric, stat, got, expected)


def test_history_seconds_agree_with_the_pairs_and_the_window(armtwin_bin, tmp_path, processes):
    service = ArmtwinProcess(armtwin_bin, tmp_path, CONFIG, watchdog_s=120.0).start()
    processes.append(service)
    client = TwinClient(service.endpoint)
    try:
        gateway = Gateway(client, ROBOT, rate_hz=2000.0, recording=True, rows=ROWS)
        gateway.start()
        gateway.join(timeout=60)
        assert gateway.sent == ROWS
        state = lambda: get_json(client.session, f"twin/state/{ROBOT}")[0][1]  # noqa: E731
        assert wait_until(lambda: state()["metrics"]["paired"] == ROWS, 30.0, 0.1), state()["metrics"]
        window = state()["metrics"]["window"]
        assert window["seconds"] == 10.0
        assert wait_until(lambda: client.collector.count("deviation", ROBOT) == ROWS, 20.0, 0.05), (
            client.collector.count("deviation", ROBOT))
        deviations = client.collector.messages("deviation", ROBOT)

        # Second 1011 is still open (the newest stamp lies in it): the history answers 1000 … 1010.
        answers = get_json(client.session, f"twin/history/{ROBOT}?_time=[now(-10m)..]")
        assert [key for key, _ in answers] == [f"twin/history/{ROBOT}"]
        history = answers[0][1]
        assert history["robot"] == ROBOT and history["history_s"] == 60
        assert history["t"] == 1000.0 + (ROWS - 1) * 0.002
        assert [row["t"] for row in history["seconds"]] == list(range(1000, 1011))
        by_second: dict[int, list[dict]] = {}
        for deviation in deviations:
            by_second.setdefault(second_of(deviation["t"]), []).append(deviation)
        for row in history["seconds"]:
            assert_agree(row, aggregate(by_second[row["t"]]), f"second {row['t']}")
        # A real error, and every second counted, 500 pairs a second (± the slices' rounding).
        assert history["seconds"][0]["position"]["mae"] > 1e-5
        assert sum(row["n"] for row in history["seconds"]) == sum(len(by_second[s]) for s in range(1000, 1011))

        # A joint sample half a second on closes second 1011; the ten seconds the window held at
        # 1011.998 add up to what it reported then.
        q, _ = lasttest_rows()[ROWS - 1]
        client.joints(ROBOT).put(json.dumps({"t": 1012.5, "q": q}))
        assert wait_until(lambda: state()["metrics"]["t"] == 1012.5, 20.0, 0.05)
        answers = get_json(client.session, f"twin/history/{ROBOT}?_time=[now(-10.5s)..now(-0.5s)]")
        seconds = answers[0][1]["seconds"]
        assert [row["t"] for row in seconds] == list(range(1002, 1012))
        assert_agree(combine(seconds), window, "the window at 1011.998", rel=1e-9)

        # An absolute range is source time since 1970; a malformed one is refused.
        answers = get_json(client.session, f"twin/history/{ROBOT}?_time=[1970-01-01T00:16:45Z..1970-01-01T00:16:47Z]")
        assert [row["t"] for row in answers[0][1]["seconds"]] == [1005, 1006, 1007]
        replies = list(client.session.get(f"twin/history/{ROBOT}?_time=yesterday", timeout=10.0))
        assert replies and replies[0].err is not None, replies
        assert "_time" in json.loads(replies[0].err.payload.to_bytes())["error"]
    finally:
        client.close()


def replies_of(client: TwinClient, selector: str) -> tuple[list[str], list[dict]]:
    """(the keys answered, the error replies' bodies) of one query."""
    keys, errors = [], []
    for reply in client.session.get(selector, timeout=20.0, consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is not None:
            keys.append(str(reply.ok.key_expr))
        else:
            errors.append(json.loads(reply.err.payload.to_bytes()))
    return keys, errors


def test_wildcard_reads_are_bounded_and_say_so(armtwin_bin, tmp_path, processes):
    """`get twin/history/**` over 70 robots answers the first 64 by id and then an error reply
    that names the bound; `state` answers all 70; a flood of such queries is answered or refused
    as busy, never left unanswered, while the twins go on taking samples."""
    config = CONFIG.replace('pose_congestion = "block"', 'pose_congestion = "drop"')
    service = ArmtwinProcess(armtwin_bin, tmp_path, config, watchdog_s=120.0).start()
    processes.append(service)
    # A gateway and an operator's queries, hearing none of the outputs: a Python subscriber to
    # 70 robots at 500 Hz falls behind, its metrics (which wait) hold the twins, and the puts
    # sharing its link wait past Zenoh's `wait_before_close`, which drops the link.
    client = TwinClient(service.endpoint, subscribe=False)
    robots = [f"cell-9/r{i:02d}" for i in range(70)]
    try:
        gateway = Gateway(client, robots, rate_hz=500.0, recording=True, rows=1200)
        gateway.start()
        gateway.join(timeout=90)
        assert gateway.sent == 1200
        def paired(robot: str) -> int | None:
            answers = get_json(client.session, f"twin/state/{robot}")
            return answers[0][1]["metrics"]["paired"] if answers else None

        assert wait_until(lambda: all(paired(r) == 1200 for r in robots[-3:]), 60.0, 0.2), [
            paired(r) for r in robots[-3:]]

        keys, errors = replies_of(client, "twin/history/cell-9/**")
        assert sorted(keys) == [f"twin/history/{r}" for r in robots[:64]], keys
        assert len(errors) == 1 and errors[0]["truncated"] is True, errors
        assert (errors[0]["answered"], errors[0]["matching"], errors[0]["max_robots"]) == (64, 70, 64), errors
        assert "ask for fewer robots" in errors[0]["error"]
        keys, errors = replies_of(client, "twin/state/cell-9/**")
        assert (len(keys), errors) == (70, []), (len(keys), errors)

        # A flood of wildcard reads while one robot streams on: every query gets an answer or a
        # refusal, and no sample of the robot is lost.
        extra = Gateway(client, robots[0], rate_hz=500.0, rows=1000, start_t=2000.0)
        extra.start()
        pending = [client.session.get("twin/history/cell-9/**", timeout=30.0,
                                       consolidation=zenoh.ConsolidationMode.NONE) for _ in range(200)]
        outcomes = {"answered": 0, "busy": 0}
        for replies in pending:
            errors = [json.loads(r.err.payload.to_bytes()) for r in replies if r.err is not None]
            assert len(errors) == 1, errors
            outcomes["busy" if errors[0]["error"].startswith("busy") else "answered"] += 1
        extra.join(timeout=60)
        assert outcomes["answered"] >= 1, outcomes
        assert wait_until(lambda: paired(robots[0]) == 2200, 30.0, 0.2), paired(robots[0])
        print(f"\n[wildcard reads] 200 queries at once: {outcomes}")
    finally:
        client.close()


def test_minutes_merge_their_seconds_and_survive_a_restart(armtwin_bin, tmp_path, processes):
    """Twenty minutes of source time (the recording's rows 0.2 s apart) with the default hour:
    the newest ten minutes answered second by second, every completed minute answered as the
    exact merge of its pairs and of its seconds; after a restart on the snapshot, the same
    minutes come back bit for bit and the seconds start afresh."""
    state_dir = tmp_path / "state"
    config = CONFIG.replace("history_s = 60\n", "").replace(
        "[service]\n", f"[service]\nstate_dir = '{state_dir}'\nsnapshot_period_s = 3600.0\n")
    service = ArmtwinProcess(armtwin_bin, tmp_path, config, watchdog_s=120.0).start()
    processes.append(service)
    client = TwinClient(service.endpoint)
    rows = lasttest_rows()[:6000]
    stamp = lambda i: 1000.0 + i * 0.2  # noqa: E731
    try:
        publisher = client.joints(ROBOT)
        client.ready([ROBOT])
        for i, (q, measured) in enumerate(rows):
            body = {"t": stamp(i), "q": q, "measured": dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), measured))}
            publisher.put(json.dumps(body))
        state = lambda: get_json(client.session, f"twin/state/{ROBOT}")[0][1]  # noqa: E731
        assert wait_until(lambda: state()["metrics"]["paired"] == len(rows), 30.0, 0.1), state()["metrics"]
        assert wait_until(lambda: client.collector.count("deviation", ROBOT) == len(rows), 20.0, 0.05)
        deviations = client.collector.messages("deviation", ROBOT)

        history = get_json(client.session, f"twin/history/{ROBOT}")[0][1]
        assert (history["history_s"], history["seconds_s"]) == (3600, 600)
        # The newest second, 2199, is open: the seconds kept are 1600 … 2198.
        assert [row["t"] for row in history["seconds"]] == list(range(1600, 2199))
        assert all(row["n"] == 5 for row in history["seconds"])
        # Minutes 960 (holding 1000 … 1019) to 2100; 2160's is open.
        minutes = history["minutes"]
        assert [row["t"] for row in minutes] == list(range(960, 2160, 60))
        for row in minutes:
            of_minute = [d for d in deviations if row["t"] <= second_of(d["t"]) < row["t"] + 60]
            assert_agree(row, aggregate(of_minute), f"minute {row['t']}")
            seconds = [s for s in history["seconds"] if row["t"] <= s["t"] < row["t"] + 60]
            if len(seconds) == 60:
                assert_agree(combine(seconds), row, f"the seconds of minute {row['t']}", rel=1e-12)
        # `_time` picks minutes by their first second.
        ranged = get_json(client.session, f"twin/history/{ROBOT}?_time=[now(-10m)..]")[0][1]
        assert [row["t"] for row in ranged["minutes"]] == list(range(1620, 2160, 60))
        assert [row["t"] for row in ranged["seconds"]] == list(range(1600, 2199))
    finally:
        client.close()
    assert service.stop().code == 0

    again = ArmtwinProcess(armtwin_bin, tmp_path, config, watchdog_s=120.0).start()
    processes.append(again)
    client = TwinClient(again.endpoint)
    try:
        # The snapshot kept the open minute too: once a sample of a later minute completes it,
        # it is answered with its pairs of before the restart.
        q, measured = rows[-1]
        body = {"t": 2222.0, "q": q, "measured": dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), measured))}
        publisher = client.joints(ROBOT)
        client.ready([ROBOT])
        publisher.put(json.dumps(body))
        restored = lambda: get_json(client.session, f"twin/history/{ROBOT}")[0][1]  # noqa: E731
        assert wait_until(lambda: restored()["t"] == 2222.0, 20.0, 0.05), restored()
        after = restored()
        assert after["minutes"][: len(minutes)] == minutes, "the minutes come back bit for bit"
        opened = [d for d in deviations if second_of(d["t"]) >= 2160]
        assert_agree(after["minutes"][len(minutes)], aggregate(opened), "the minute open at the stop")
        assert after["seconds"] == [], "the seconds start afresh"
    finally:
        client.close()
