"""The twin's outputs checked against the independent numpy/scipy reference (ur_reference.py),
the fields docs/protocol/messages.md gives them, and the recordings (tests/data) the service
tests stream.

Expected values never come from armtwin itself.
"""

from __future__ import annotations

import csv
import math

import numpy as np
from scipy.spatial.transform import Rotation

from support import ur_reference as ur
from support.checks import wrap_pi
from support.paths import DATA_DIR

MODEL = "ur10e"
MEASURED_KEYS = ("x", "y", "z", "qx", "qy", "qz", "qw")
STAT_NAMES = ("position", "x", "y", "z", "quat_distance", "angle", "roll", "pitch", "yaw")
TOL_POS = 1e-12
TOL_QUAT = 1e-12
TOL_EULER = 1e-9
TOL_STATS = 1e-9
TOL_ANGLE = 1e-7  # acos loses precision near 1


def reference_poses(q):
    """(pos (N,3), quat xyzw canonical (N,4), rpy (N,3)) of FK in the base frame, flange TCP."""
    T = ur.fk(MODEL, np.asarray(q, float))
    R = T[:, :3, :3]
    return T[:, :3, 3], ur.canonical_quat(R), ur.rpy(R)


def measured_arrays(meas):
    """meas (N,7) x,y,z,qx,qy,qz,qw → (pos, normalised quat, rpy from that quat)."""
    meas = np.asarray(meas, float)
    quat = meas[:, 3:7] / np.linalg.norm(meas[:, 3:7], axis=1, keepdims=True)
    R = Rotation.from_quat(quat).as_matrix()
    return meas[:, :3], quat, ur.rpy(R)


def reference_deviations(q, meas):
    """dict of (N,) arrays: dx dy dz position quat_distance angle droll dpitch dyaw."""
    tpos, tquat, trpy = reference_poses(q)
    mpos, mquat, mrpy = measured_arrays(meas)
    d = tpos - mpos
    dot = np.abs(np.sum(tquat * mquat, axis=1))
    de = wrap_pi(trpy - mrpy)
    return {
        "dx": d[:, 0],
        "dy": d[:, 1],
        "dz": d[:, 2],
        "position": np.linalg.norm(d, axis=1),
        "quat_distance": 1.0 - dot,
        "angle": 2.0 * np.arccos(np.minimum(dot, 1.0)),
        "droll": de[:, 0],
        "dpitch": de[:, 1],
        "dyaw": de[:, 2],
    }


def reference_stats(dev):
    """The cumulative metrics' statistics (over absolute values) of reference deviations."""
    series = {
        "position": dev["position"],
        "x": dev["dx"],
        "y": dev["dy"],
        "z": dev["dz"],
        "quat_distance": dev["quat_distance"],
        "angle": dev["angle"],
        "roll": dev["droll"],
        "pitch": dev["dpitch"],
        "yaw": dev["dyaw"],
    }
    out = {}
    for name, v in series.items():
        a = np.abs(np.asarray(v, float))
        out[name] = {
            "mae": float(a.mean()),
            "rmse": float(math.sqrt(np.mean(a * a))),
            "max": float(a.max()),
        }
    return out


def check_poses(checks, poses, robot, t_expected, q, label):
    """Twin poses in arrival order: seq 0..N-1, t, frame, and the reference FK."""
    n = len(q)
    checks.equal(len(poses), n, f"{label}: number of twin poses")
    checks.equal([p.get("seq") for p in poses], list(range(len(poses))), f"{label}: pose seq")
    checks.true(all(p.get("robot") == robot for p in poses), f"{label}: every pose names robot {robot!r}")
    checks.true(all(p.get("frame") == "base" for p in poses), f"{label}: every pose has frame 'base'")
    if len(poses) != n:
        # Compare what can be matched by stamp, so the report also says whether the values are right.
        by_t = {p["t"]: p for p in poses}
        idx = [i for i, t in enumerate(t_expected) if t in by_t]
        missing = [i for i in range(n) if t_expected[i] not in by_t]
        checks.true(not missing, f"{label}: no pose for rows {missing[:20]}{'…' if len(missing) > 20 else ''}")
        poses = [by_t[t_expected[i]] for i in idx]
    else:
        idx = list(range(n))
        checks.close([p["t"] for p in poses], [t_expected[i] for i in idx], 0.0, f"{label}: pose t")
    if not idx:
        return
    pos, quat, rpy = reference_poses(np.asarray(q)[idx])
    got = lambda keys: np.array([[p[k] for k in keys] for p in poses], float)  # noqa: E731
    checks.close(got(("x", "y", "z")), pos, TOL_POS, f"{label}: pose position vs reference FK")
    checks.close(got(("qx", "qy", "qz", "qw")), quat, TOL_QUAT, f"{label}: pose quaternion vs reference FK")
    checks.angles_close(got(("roll", "pitch", "yaw")), rpy, TOL_EULER, f"{label}: pose roll/pitch/yaw vs reference")


def check_deviations(checks, devs, robot, t_expected, q, meas, label):
    """Deviations (any order), matched to rows by their stamp."""
    n = len(t_expected)
    checks.equal(len(devs), n, f"{label}: number of deviations")
    checks.true(all(d.get("robot") == robot for d in devs), f"{label}: every deviation names robot {robot!r}")
    by_t = {}
    for d in devs:
        checks.true(d["t"] not in by_t, f"{label}: two deviations at t={d['t']}")
        by_t[d["t"]] = d
    unknown = sorted(set(by_t) - set(t_expected))
    checks.true(not unknown, f"{label}: deviations at unexpected stamps {unknown[:10]}")
    idx = [i for i, t in enumerate(t_expected) if t in by_t]
    missing = [t_expected[i] for i in range(n) if t_expected[i] not in by_t]
    checks.true(not missing, f"{label}: no deviation at stamps {missing[:10]}")
    if not idx:
        return
    ref = reference_deviations(np.asarray(q)[idx], np.asarray(meas)[idx])
    rows = [by_t[t_expected[i]] for i in idx]
    for key, tol in (
        ("dx", TOL_POS), ("dy", TOL_POS), ("dz", TOL_POS), ("position", TOL_POS),
        ("quat_distance", TOL_QUAT), ("angle", TOL_ANGLE),
        ("droll", TOL_EULER), ("dpitch", TOL_EULER), ("dyaw", TOL_EULER),
    ):
        checks.close([r[key] for r in rows], ref[key], tol, f"{label}: deviation {key}")


def check_metrics(checks, metrics, robot, paired, rejected, ref_stats, label, unpaired=0, t=None):
    """``t``: the newest source time sent for the robot (protocol: metrics ``t``)."""
    if not checks.true(metrics is not None, f"{label}: no final metrics message"):
        return
    checks.equal(metrics.get("robot"), robot, f"{label}: metrics robot")
    if t is not None:
        checks.equal(metrics.get("t"), t, f"{label}: metrics t (newest source time)")
    checks.equal(metrics.get("paired"), paired, f"{label}: metrics paired")
    checks.equal(metrics.get("unpaired"), unpaired, f"{label}: metrics unpaired")
    checks.equal(metrics.get("rejected"), rejected, f"{label}: metrics rejected")
    cum = metrics.get("cumulative") or {}
    checks.equal(cum.get("n"), paired, f"{label}: metrics cumulative.n")
    for name in STAT_NAMES:
        tol = TOL_ANGLE if name == "angle" else TOL_STATS
        got = cum.get(name)
        if not checks.true(isinstance(got, dict), f"{label}: metrics cumulative.{name} missing"):
            continue
        for s in ("mae", "rmse", "max"):
            checks.close(got.get(s, np.nan), ref_stats[name][s], tol, f"{label}: cumulative.{name}.{s}")


def load_fmpy():
    with open(DATA_DIR / "fmpy_inputs.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    q = np.array([[float(r[f"q{i}"]) for i in range(1, 7)] for r in rows])
    meas = np.array([[float(r[k]) for k in MEASURED_KEYS] for r in rows])
    return q, meas


def naive_field(text):
    try:
        return float(text)
    except ValueError:
        return text


def load_lasttest_naive():
    """What a naive gateway makes of each data line: comma split, float() where it parses."""
    lines = (DATA_DIR / "ur10e_lasttest.csv").read_text().splitlines()
    out = []
    for line in lines[1:]:
        fields = [naive_field(s) for s in line.split(",")][:14]
        out.append(fields)
    return out


def joint_message(t, q, meas):
    return {
        "t": t,
        "q": [float(v) for v in q],
        "measured": {k: (float(v) if not isinstance(v, str) else v) for k, v in zip(MEASURED_KEYS, meas)},
    }
