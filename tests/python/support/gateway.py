"""The one gateway of the tests: joint messages, each with its measured pose, for one robot or
several, at a fixed rate on a thread of its own (``start``/``stop``) or one at a time
(``send_one``), counting what it sent.

What it sends:

* by default one fixed arm pose, its measured pose 1 cm off (so metrics and the position alarm
  have something to show), stamped from ``start_t`` on at the rate's period and numbered from
  ``start_seq`` on; it streams until stopped, and a put that fails (a router away) still moves the
  stamp and the seq on;
* with ``recording=True``, the rows of the sample UR10e recording (tests/data/ur10e_lasttest.csv)
  row after row, stamped 1000 s + 2 ms a row, each robot's measured pose moved by its
  ``measured_offset_m`` along x; it ends after ``rows`` rows (all of them by default).
"""

from __future__ import annotations

import csv
import json
import threading
import time

import zenoh

from support.paths import DATA_DIR
from support.zenoh_clients import TwinClient

MEASURED_KEYS = ("x", "y", "z", "qx", "qy", "qz", "qw")


def lasttest_rows() -> list[tuple[list[float], list[float]]]:
    """The sample UR10e recording's (q, measured x y z qx qy qz qw) rows."""
    with open(DATA_DIR / "ur10e_lasttest.csv", newline="") as f:
        reader = csv.reader(f)
        next(reader)
        rows = []
        for fields in reader:
            values = [float(v) for v in fields[1:14]]
            rows.append((values[:6], values[6:13]))
    return rows


class Gateway:
    """Streams joint messages for ``robots`` (one name or several) through ``session``: a Zenoh
    session, or a :class:`TwinClient`, whose publishers it uses once armtwin matched them."""

    Q = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]
    MEASURED = {"x": -0.807, "y": 0.436, "z": 0.42, "qx": -0.408, "qy": -0.9, "qz": -0.014, "qw": 0.152}

    def __init__(self, session: zenoh.Session | TwinClient, robots, rate_hz: float = 200.0, *,
                 start_seq: int = 0, start_t: float = 0.0, recording: bool = False, rows: int | None = None,
                 measured_offset_m: dict[str, float] | None = None):
        self.robots = [robots] if isinstance(robots, str) else list(robots)
        self.period_s = 1.0 / rate_hz
        self.seq = start_seq
        self.t = start_t
        self.sent = 0  # messages sent to each robot
        self.sent_at: list[tuple[float, int]] = []  # (monotonic, seq)
        self.data = lasttest_rows() if recording else None
        # Messages per robot before it stops by itself: ``rows``, at most the recording's length.
        self.rows = rows if self.data is None else len(self.data) if rows is None else min(rows, len(self.data))
        self.offsets = measured_offset_m or {}
        if isinstance(session, TwinClient):
            self.publishers = {robot: session.joints(robot) for robot in self.robots}
            session.ready(self.robots)
        else:
            self.publishers = {
                robot: session.declare_publisher(f"twin/joints/{robot}", congestion_control=zenoh.CongestionControl.BLOCK)
                for robot in self.robots
            }
        self.pub = self.publishers[self.robots[0]]  # the publisher, for a gateway of one robot
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def send_one(self) -> None:
        """The next message to every robot."""
        for robot, pub in self.publishers.items():
            if self.data is None:
                body = {"t": round(self.t, 6), "q": self.Q, "seq": self.seq, "measured": self.MEASURED}
                pub.put(json.dumps(body), encoding=zenoh.Encoding.APPLICATION_JSON)
            else:
                q, measured = self.data[self.sent]
                pose = list(measured)
                pose[0] += self.offsets.get(robot, 0.0)
                body = {"t": 1000.0 + self.sent * 0.002, "q": q, "measured": dict(zip(MEASURED_KEYS, pose))}
                pub.put(json.dumps(body))
        self.sent_at.append((time.monotonic(), self.seq))
        self._move_on()

    def _move_on(self) -> None:
        self.sent += 1
        self.seq += 1
        self.t += self.period_s

    def finished(self) -> bool:
        return self.rows is not None and self.sent >= self.rows

    def start(self) -> Gateway:
        def run():
            next_at = time.monotonic()
            while not self._stop.is_set() and not self.finished():
                try:
                    self.send_one()
                except Exception:  # a put while the router is away may fail: the seq still moves on
                    self._move_on()
                next_at += self.period_s
                delay = next_at - time.monotonic()
                if delay > 0:
                    time.sleep(delay)

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()
        return self

    def is_alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout=timeout)

    def stop(self) -> None:
        self._stop.set()
        self.join(timeout=10)
