"""Recordings in ur_rtde's CSV form (a header of RTDE names, one row per data package), derived
from the project's real UR10e data for the stand-in controller (rtde_server.py).

``ur10e_lasttest.csv`` is a ROS 2 export at 500 Hz (tests/data/README.md): its rows become
``timestamp`` (row index × 2 ms, the README's faithful pacing), ``actual_q_0..5`` and
``actual_TCP_pose_0..5`` (position, then the quaternion as a rotation vector, scipy's
``as_rotvec``: axis · angle, angle in [0, π]). Rows that do not parse (the file's 7
locale-formatted rows) are left out: a controller sends numbers, never text; their 2 ms slots
stay empty. Numbers are written in Python's shortest round-trip form.
"""

from __future__ import annotations

import csv
from pathlib import Path

from scipy.spatial.transform import Rotation

HEADER = (
    ["timestamp"]
    + [f"actual_q_{j}" for j in range(6)]
    + [f"actual_TCP_pose_{j}" for j in range(6)]
)
PERIOD_S = 0.002


def rtde_rows(ros2_export: Path, limit: int | None = None) -> list[list[float]]:
    """The export's parsable rows as ``timestamp, q0..q5, x, y, z, rx, ry, rz``."""
    out = []
    with open(ros2_export, newline="") as handle:
        reader = csv.reader(handle)
        next(reader)
        for index, cells in enumerate(reader):
            if limit is not None and index >= limit:
                break
            try:
                numbers = [float(cell) for cell in cells[1:14]]
            except ValueError:
                continue
            if len(numbers) != 13:
                continue
            q, position, quaternion = numbers[:6], numbers[6:9], numbers[9:13]
            rotvec = Rotation.from_quat(quaternion).as_rotvec()
            out.append([round(index * PERIOD_S, 6), *q, *position, *(float(r) for r in rotvec)])
    return out


def write(rows: list[list[float]], path: Path, header: list[str] = HEADER) -> Path:
    with open(path, "w", newline="") as handle:
        handle.write(",".join(header) + "\n")
        for row in rows:
            handle.write(",".join(repr(v) for v in row) + "\n")
    return path
