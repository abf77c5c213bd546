"""``armtwin validate`` against an independent numpy/scipy computation.

The two real recordings (tests/data) and a synthetic UR RTDE recording made here from the
reference FK with a known calibration and tool: every figure in report.json and every row of
rows.csv is recomputed from the file with ur_reference.py, and the SVG plots are parsed back.

Run: ``.venv/bin/python -m pytest tests/python/test_validate.py -q -s`` (``-s`` prints figures).
"""

from __future__ import annotations

import csv
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from support import ur_reference as ur
from support.paths import DATA_DIR, REPO_ROOT
from support.process import run_armtwin

STATS = ("position", "x", "y", "z", "quat_distance", "angle", "roll", "pitch", "yaw")
TOL_POS = 1e-12
TOL_STATS = 1e-9
TOL_ANGLE = 1e-7  # the reference's arccos loses precision near 1
CALIBRATION = REPO_ROOT / "config" / "examples" / "calibration.conf"
SVG = "{http://www.w3.org/2000/svg}"


def validate(tmp_path: Path, *args, expect_code=0):
    out = tmp_path / "report"
    res = run_armtwin("validate", *args, "--out", out)
    assert res.returncode == expect_code, res.stderr
    report = json.loads((out / "report.json").read_text())
    with open(out / "rows.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return report, rows, out, res.stderr


def deviations(T_twin, mpos, mquat):
    """Twin minus measured for (N,4,4) twin poses and measured positions / quaternions (xyzw)."""
    mquat = np.asarray(mquat, float)
    mquat = mquat / np.linalg.norm(mquat, axis=1, keepdims=True)
    R = T_twin[:, :3, :3]
    tquat = ur.canonical_quat(R)
    d = T_twin[:, :3, 3] - np.asarray(mpos, float)
    dot = np.abs(np.sum(tquat * mquat, axis=1))
    drpy = ur.wrap(ur.rpy(R) - ur.rpy(Rotation.from_quat(mquat).as_matrix()))
    return {
        "position": np.linalg.norm(d, axis=1),
        "x": d[:, 0],
        "y": d[:, 1],
        "z": d[:, 2],
        "quat_distance": 1.0 - dot,
        "angle": 2.0 * np.arccos(np.minimum(dot, 1.0)),
        "roll": drpy[:, 0],
        "pitch": drpy[:, 1],
        "yaw": drpy[:, 2],
    }


def stats(dev):
    out = {}
    for name in STATS:
        a = np.abs(dev[name])
        out[name] = {"mae": a.mean(), "rmse": math.sqrt(np.mean(a * a)), "max": a.max()}
    return out


def check_report_stats(report, dev, label):
    ref = stats(dev)
    cum = report["cumulative"]
    assert cum["n"] == len(dev["position"]), label
    for name in STATS:
        tol = TOL_ANGLE if name == "angle" else TOL_STATS
        for stat in ("mae", "rmse", "max"):
            got, want = cum[name][stat], ref[name][stat]
            assert abs(got - want) <= tol, f"{label}: {name}.{stat} = {got}, reference {want}"
    print(
        f"\n{label}: position MAE {ref['position']['mae'] * 1e3:.4f} mm, RMSE "
        f"{ref['position']['rmse'] * 1e3:.4f} mm, max {ref['position']['max'] * 1e3:.4f} mm; "
        f"quaternion distance MAE {ref['quat_distance']['mae']:.3e}, max {ref['quat_distance']['max']:.3e}; "
        f"rotation angle MAE {ref['angle']['mae'] * 1e3:.4f} mrad"
    )


def column(rows, name):
    return np.array([float(r[name]) for r in rows])


def check_rows(rows, T_twin, dev, label):
    """rows.csv (paired rows only, in order) against the reference."""
    for k, axis in enumerate("xyz"):
        err = np.abs(column(rows, f"twin_{axis}") - T_twin[:, k, 3]).max()
        assert err <= TOL_POS, f"{label}: twin_{axis} off by {err}"
    quat = np.stack([column(rows, f"twin_q{c}") for c in "xyzw"], axis=1)
    err = np.abs(quat - ur.canonical_quat(T_twin[:, :3, :3])).max()
    assert err <= TOL_POS, f"{label}: twin quaternion off by {err}"
    for name, col in (("x", "dx_m"), ("y", "dy_m"), ("z", "dz_m"), ("position", "position_error_m")):
        err = np.abs(column(rows, col) - dev[name]).max()
        assert err <= TOL_STATS, f"{label}: {col} off by {err}"
    err = np.abs(column(rows, "quat_distance") - dev["quat_distance"]).max()
    assert err <= TOL_STATS, f"{label}: quat_distance off by {err}"


def test_fmpy_inputs_against_reference(tmp_path):
    with open(DATA_DIR / "fmpy_inputs.csv", newline="") as f:
        data = list(csv.DictReader(f))
    q = np.array([[float(r[f"q{i}"]) for i in range(1, 7)] for r in data])
    mpos = np.array([[float(r[k]) for k in ("x", "y", "z")] for r in data])
    mquat = np.array([[float(r[k]) for k in ("qx", "qy", "qz", "qw")] for r in data])
    report, rows, _, stderr = validate(tmp_path, DATA_DIR / "fmpy_inputs.csv", "--period", "0.1")
    assert "FMPy input form" in stderr
    assert (report["rows"], report["poses"], report["paired"], report["rejected"]) == (54, 54, 54, 0)
    T = ur.fk("ur10e", q)
    dev = deviations(T, mpos, mquat)
    check_report_stats(report, dev, "fmpy_inputs.csv")
    check_rows(rows, T, dev, "fmpy_inputs.csv")
    assert np.allclose(column(rows, "t"), np.arange(54) * 0.1, atol=1e-12)


def test_lasttest_against_reference(tmp_path):
    lines = (DATA_DIR / "ur10e_lasttest.csv").read_text().splitlines()
    header = lines[0].split(",")
    good, bad_lines = [], []
    for number, line in enumerate(lines[1:], start=2):
        cells = line.split(",")
        if len(cells) == len(header):
            good.append(dict(zip(header, (float(c) for c in cells))))
        else:
            bad_lines.append(number)
    joints = [
        f"{j}_joint.position" for j in ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
    ]
    q = np.array([[r[j] for j in joints] for r in good])
    mpos = np.array([[r[f"tcp_pose.position.{a}"] for a in "xyz"] for r in good])
    mquat = np.array([[r[f"tcp_pose.orientation.{a}"] for a in "xyzw"] for r in good])
    report, rows, _, stderr = validate(tmp_path, DATA_DIR / "ur10e_lasttest.csv")
    assert "ROS 2 export" in stderr
    assert len(bad_lines) == 7
    assert report["malformed"]["lines"] == bad_lines
    assert [r["line"] for r in report["rejections"]] == bad_lines
    assert (report["rows"], report["poses"], report["paired"], report["rejected"]) == (
        len(lines) - 1,
        len(good),
        len(good),
        7,
    )
    T = ur.fk("ur10e", q)
    dev = deviations(T, mpos, mquat)
    check_report_stats(report, dev, "ur10e_lasttest.csv")
    paired = [r for r in rows if r["position_error_m"] != ""]
    assert [int(r["line"]) for r in rows if r["rejected"]] == bad_lines
    check_rows(paired, T, dev, "ur10e_lasttest.csv")


def write_rtde(path: Path, q, T):
    """A UR RTDE recording (space-separated, many columns) of joints q and TCP poses T."""
    names = (
        ["timestamp"]
        + [f"target_q_{i}" for i in range(6)]
        + [f"actual_q_{i}" for i in range(6)]
        + [f"actual_qd_{i}" for i in range(6)]
        + [f"actual_TCP_pose_{i}" for i in range(6)]
        + [f"actual_TCP_force_{i}" for i in range(6)]
        + ["robot_mode", "safety_mode"]
    )
    rotvec = Rotation.from_matrix(T[:, :3, :3]).as_rotvec()
    with open(path, "w") as f:
        f.write(" ".join(names) + "\n")
        for k in range(len(q)):
            values = (
                [1700000000.0 + k * 0.002]
                + list(q[k] + 1e-4)
                + list(q[k])
                + [0.01] * 6
                + list(T[k, :3, 3])
                + list(rotvec[k])
                + [0.5] * 6
                + [7, 1]
            )
            f.write(" ".join(repr(float(v)) for v in values) + "\n")


def test_synthetic_rtde_with_calibration_and_tool(tmp_path):
    rng = np.random.default_rng(20261122)
    q = rng.uniform(-math.pi, math.pi, size=(400, 6))
    cal = ur.parse_calibration_conf(CALIBRATION.read_text())
    tcp = (0.012, -0.034, 0.156, 0.1, -0.2, 0.3)
    T = ur.fk("ur10e", q, tcp=tcp, calibration=cal)
    recording = tmp_path / "rtde.txt"
    write_rtde(recording, q, T)
    tcp_arg = "--tcp=" + ",".join(repr(v) for v in tcp)

    # The same calibration and tool: the twin is the robot.
    report, rows, _, stderr = validate(tmp_path, recording, "--calibration", CALIBRATION, tcp_arg)
    assert "UR RTDE recording" in stderr
    assert report["paired"] == 400 and report["rejected"] == 0
    assert report["robot"]["calibration"] == str(CALIBRATION)
    assert report["cumulative"]["position"]["max"] < 1e-9, report["cumulative"]["position"]
    assert report["cumulative"]["angle"]["max"] < 1e-9, report["cumulative"]["angle"]
    print(
        f"\nsynthetic RTDE, same calibration and tool: max position error "
        f"{report['cumulative']['position']['max']:.3e} m, max angle {report['cumulative']['angle']['max']:.3e} rad"
    )

    # Without the calibration: exactly the error the reference predicts.
    report, _, _, _ = validate(tmp_path, recording, tcp_arg)
    dev = deviations(ur.fk("ur10e", q, tcp=tcp), T[:, :3, 3], ur.canonical_quat(T[:, :3, :3]))
    check_report_stats(report, dev, "synthetic RTDE without calibration")
    assert report["cumulative"]["position"]["mae"] > 1e-3

    # Without the tool: likewise.
    report, _, _, _ = validate(tmp_path, recording, "--calibration", CALIBRATION)
    dev = deviations(ur.fk("ur10e", q, calibration=cal), T[:, :3, 3], ur.canonical_quat(T[:, :3, :3]))
    check_report_stats(report, dev, "synthetic RTDE without tool")


def plot_area(root):
    g = root.find(f".//{SVG}g[@class='plot']")
    assert g is not None
    return {k: float(g.get(f"data-{k}")) for k in ("x-min", "x-max", "y-min", "y-max", "left", "right", "top", "bottom")}, g


def series(g):
    out = {}
    for line in g.findall(f"{SVG}polyline[@class='series']"):
        pts = np.array([[float(v) for v in p.split(",")] for p in line.get("points").split()])
        out[line.get("data-name")] = pts
    return out


def to_data(area, pts):
    x = area["x-min"] + (pts[:, 0] - area["left"]) / (area["right"] - area["left"]) * (area["x-max"] - area["x-min"])
    y = area["y-min"] + (area["bottom"] - pts[:, 1]) / (area["bottom"] - area["top"]) * (area["y-max"] - area["y-min"])
    return x, y


def test_svg_plots_contain_the_series(tmp_path):
    report, rows, out, _ = validate(tmp_path, DATA_DIR / "ur10e_lasttest.csv")
    paired = [r for r in rows if r["position_error_m"] != ""]
    t0 = float(rows[0]["t"])
    t_span = float(paired[-1]["t"]) - t0
    # One pixel of each axis, in data units, bounds the rounding of the plotted coordinates.
    def px(area, axis):
        lo, hi = (area["x-min"], area["x-max"]) if axis == "x" else (area["y-min"], area["y-max"])
        a, b = (area["left"], area["right"]) if axis == "x" else (area["top"], area["bottom"])
        return (hi - lo) / (b - a)

    root = ET.parse(out / "position.svg").getroot()
    area, g = plot_area(root)
    lines = series(g)
    assert set(lines) == {f"{w} {a}" for w in ("twin", "measured") for a in "xyz"}
    for k, a in enumerate("xyz"):
        x, y = to_data(area, lines[f"measured {a}"])
        measured = column(paired, f"measured_{a}")
        assert abs(y.max() - measured.max()) <= px(area, "y") and abs(y.min() - measured.min()) <= px(area, "y")
        assert abs(x.max() - t_span) <= px(area, "x") and abs(x.min()) <= px(area, "x")

    root = ET.parse(out / "position_error.svg").getroot()
    area, g = plot_area(root)
    (pts,) = series(g).values()
    _, y = to_data(area, pts)
    assert abs(y.max() - report["cumulative"]["position"]["max"] * 1e3) <= px(area, "y")
    assert len(pts) >= 500  # thinned, not reduced to a few points

    root = ET.parse(out / "quaternion_distance.svg").getroot()
    area, g = plot_area(root)
    _, y = to_data(area, series(g)["quaternion distance"])
    assert abs(y.max() - report["cumulative"]["quat_distance"]["max"]) <= px(area, "y")

    root = ET.parse(out / "position_error_histogram.svg").getroot()
    _, g = plot_area(root)
    bars = g.findall(f"{SVG}rect[@class='bar']")
    assert sum(int(b.get("data-count")) for b in bars) == report["paired"]
    errors_mm = column(paired, "position_error_m") * 1e3
    for b in bars[:5]:
        lo, hi = float(b.get("data-from")), float(b.get("data-to"))
        inside = np.count_nonzero((errors_mm >= lo) & (errors_mm < hi))
        assert abs(inside - int(b.get("data-count"))) <= 1, (lo, hi)
