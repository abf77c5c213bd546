"""Baseline for benches/fk.rs: the UR10e FMU report's per-pose numpy FK (its model.py, rebuilt from
the report's listing), timed on this machine.
Run: .venv/bin/python crates/armtwin-bench/benches/report_numpy_fk.py"""

import math
import timeit

import numpy as np

D1, A2, A3, D4, D5, D6 = 0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655


def create_dh_transform_matrix(alpha, a, d, theta):
    return np.array([
        [math.cos(theta), -math.sin(theta) * math.cos(alpha), math.sin(theta) * math.sin(alpha), a * math.cos(theta)],
        [math.sin(theta), math.cos(theta) * math.cos(alpha), -math.cos(theta) * math.sin(alpha), a * math.sin(theta)],
        [0, math.sin(alpha), math.cos(alpha), d],
        [0, 0, 0, 1],
    ])


def matrix_to_rpy(t):
    sy = math.sqrt(t[0, 0] ** 2 + t[1, 0] ** 2)
    if sy > 1e-6:
        return math.atan2(t[2, 1], t[2, 2]), math.atan2(-t[2, 0], sy), math.atan2(t[1, 0], t[0, 0])
    return math.atan2(-t[1, 2], t[1, 1]), math.atan2(-t[2, 0], sy), 0.0


def matrix_to_quaternion(t):
    trace = t[0, 0] + t[1, 1] + t[2, 2]
    s = 0.5 / math.sqrt(trace + 1.0)
    return (t[2, 1] - t[1, 2]) * s, (t[0, 2] - t[2, 0]) * s, (t[1, 0] - t[0, 1]) * s, 0.25 / s


def forward_kinematics(q):
    dh_params = np.array([
        [math.pi / 2, 0, D1, 0], [0, A2, 0, 0], [0, A3, 0, 0],
        [math.pi / 2, 0, D4, 0], [-math.pi / 2, 0, D5, 0], [0, 0, D6, 0],
    ])
    t = np.eye(4)
    for i in range(6):
        alpha, a, d, theta_offset = dh_params[i]
        t = t @ create_dh_transform_matrix(alpha, a, d, q[i] + theta_offset)
    qx, qy, qz, qw = matrix_to_quaternion(t)
    if qw < 0.0:
        qx, qy, qz, qw = -qx, -qy, -qz, -qw
    return (t[0, 3], t[1, 3], t[2, 3], *matrix_to_rpy(t), qx, qy, qz, qw)


if __name__ == "__main__":
    q = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]
    runs = 20000
    best = min(timeit.repeat(lambda: forward_kinematics(q), number=runs, repeat=5)) / runs
    print(f"the report's numpy FK: {best * 1e6:.1f} us per pose (best of 5 x {runs})")
