"""armtwin fk / models checked against the independent numpy reference (ur_reference.py)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from support import ur_reference as ur
from support.fk_csv import GIMBAL_COS, POS_TOL, QW_AMBIGUOUS, check_poses, csv_input, parse_csv_output
from support.paths import DATA_DIR
from support.process import run_armtwin

POSE_KEYS = {"x", "y", "z", "roll", "pitch", "yaw", "qx", "qy", "qz", "qw"}
N_RANDOM = 2000

# A calibration.conf like a real robot's: huge delta_d on joints 2-4 that nearly cancel.
LARGE_DD_CAL = ur.Calibration(
    delta_theta=[1.2e-06, 0.31, -0.55, 0.24, -3.1e-06, 2.0e-06],
    delta_a=[2.5e-05, -0.0045, 0.0025, 8.6e-05, 5.9e-05, 0.0],
    delta_d=[0.00013, 154.6, -219.5, 64.9, -6.5e-05, 0.0002],
    delta_alpha=[-0.00022, 0.0005, 0.0024, 0.00056, 0.00054, 0.0],
)


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------

def seed_for(*parts) -> int:
    """Deterministic seed from strings/ints (not Python's randomised hash)."""
    return sum((i + 1) * 7919 * sum(map(ord, str(p))) for i, p in enumerate(parts)) % (2**32)


def random_joints(rng, n=N_RANDOM):
    return rng.uniform(-2 * math.pi, 2 * math.pi, size=(n, 6))


def random_tcp(rng):
    xyz = rng.uniform(-0.3, 0.3, 3)
    rotvec = rng.uniform(-2.0, 2.0, 3)
    return [float(v) for v in np.concatenate([xyz, rotvec])]


def random_small_calibration(rng, zero_last_a_alpha=False):
    cal = ur.Calibration(
        delta_theta=list(rng.normal(0, 2e-3, 6)),
        delta_a=list(rng.normal(0, 2e-3, 6)),
        delta_d=list(rng.normal(0, 2e-3, 6)),
        delta_alpha=list(rng.normal(0, 2e-3, 6)),
    )
    if zero_last_a_alpha:
        cal.delta_a[5] = 0.0
        cal.delta_alpha[5] = 0.0
    return cal


def tcp_arg(tcp):
    return "--tcp=" + ",".join(repr(float(v)) for v in tcp)


def ok(res):
    assert res.returncode == 0, (
        f"armtwin exited {res.returncode}\nstderr:\n{res.stderr[-3000:]}"
    )
    return res


def run_fk_csv(model, text, *extra):
    res = ok(run_armtwin("fk", "--model", model, *extra, "--csv", "-", input=text))
    return parse_csv_output(res.stdout)


def write_conf(tmp_path, cal, name="calibration.conf"):
    path = tmp_path / name
    path.write_text(ur.format_calibration_conf(cal))
    return path


# --------------------------------------------------------------------------
# the reference itself (no CLI)
# --------------------------------------------------------------------------

def test_reference_matches_recorded_ur10e():
    """Our ur10e reference vs the real controller's pose (rounded to 1 mm / 1e-3, uncalibrated)."""
    data = np.genfromtxt(DATA_DIR / "fmpy_inputs.csv", delimiter=",", names=True)
    q = np.stack([data[f"q{i}"] for i in range(1, 7)], axis=1)
    T = ur.fk("ur10e", q)
    rec = np.stack([data["x"], data["y"], data["z"]], axis=1)
    assert np.abs(T[:, :3, 3] - rec).max() < 3e-3
    rq = np.stack([data["qx"], data["qy"], data["qz"], data["qw"]], axis=1)
    rq /= np.linalg.norm(rq, axis=1, keepdims=True)
    dot = np.abs(np.sum(rq * ur.canonical_quat(T[:, :3, :3]), axis=1))
    angle = 2 * np.arccos(np.clip(dot, -1, 1))
    assert angle.max() < 0.01


def test_reference_dh_and_urdf_forms_agree():
    rng = np.random.default_rng(12345)
    for model in ur.MODEL_NAMES:
        for cal in (random_small_calibration(rng, zero_last_a_alpha=True), LARGE_DD_CAL):
            origins = ur.calibration_to_urdf_origins(model, cal)
            q = random_joints(rng, 200)
            diff = np.abs(ur.fk_urdf(origins, q) - ur.fk(model, q, calibration=cal)).max()
            assert diff < 1e-12, (model, diff)


def test_reference_conf_writer_roundtrip():
    rng = np.random.default_rng(7)
    cal = random_small_calibration(rng)
    back = ur.parse_calibration_conf(ur.format_calibration_conf(cal))
    for key in ("delta_theta", "delta_a", "delta_d", "delta_alpha"):
        assert getattr(back, key) == [float(v) for v in getattr(cal, key)]


# --------------------------------------------------------------------------
# models --json
# --------------------------------------------------------------------------

def test_models_json():
    res = ok(run_armtwin("models", "--json"))
    models = json.loads(res.stdout)
    assert isinstance(models, list)
    by_name = {m["name"]: m for m in models}
    missing = set(ur.MODEL_NAMES) - set(by_name)
    assert not missing, f"models missing from `armtwin models --json`: {sorted(missing)}"
    for name in ur.MODEL_NAMES:
        m = by_name[name]
        assert m["convention"] == "standard", name
        joints = m["joints"]
        assert len(joints) == 6, name
        ref = ur.dh_table(name)
        for i, j in enumerate(joints):
            assert set(j) >= {"a_m", "alpha_rad", "d_m", "theta_offset_rad", "min_rad", "max_rad"}, (name, i, j)
            assert abs(j["a_m"] - ref.a[i]) <= 1e-15, (name, i, "a", j["a_m"], ref.a[i])
            assert abs(j["d_m"] - ref.d[i]) <= 1e-15, (name, i, "d", j["d_m"], ref.d[i])
            assert abs(j["alpha_rad"] - ref.alpha[i]) <= 1e-15, (name, i, "alpha", j["alpha_rad"], ref.alpha[i])
            assert abs(j["theta_offset_rad"] - ref.theta_offset[i]) <= 1e-15, (name, i, "theta_offset")
            lo, hi = j["min_rad"], j["max_rad"]
            assert lo is None or isinstance(lo, (int, float)), (name, i, lo)
            assert hi is None or isinstance(hi, (int, float)), (name, i, hi)
            if lo is not None and hi is not None:
                assert lo < hi, (name, i, lo, hi)


# --------------------------------------------------------------------------
# CSV streaming
# --------------------------------------------------------------------------

VARIANTS = ["plain", "tcp", "base_link", "deg", "tcp_base_link_deg"]


@pytest.mark.parametrize("variant", VARIANTS)
@pytest.mark.parametrize("model", ur.MODEL_NAMES)
def test_csv_random(model, variant):
    rng = np.random.default_rng(seed_for(model, variant))
    q = random_joints(rng)
    times = 1000.0 + 0.002 * np.arange(len(q)) + rng.uniform(0, 1e-3, len(q))
    use_tcp = "tcp" in variant
    use_deg = "deg" in variant
    frame = "base_link" if "base_link" in variant else "base"

    args = []
    tcp = None
    if use_tcp:
        tcp = random_tcp(rng)
        args.append(tcp_arg(tcp))
    if frame != "base":
        args += ["--frame", frame]
    if use_deg:
        args.append("--deg")
        q_in = np.rad2deg(q)
        q_ref = np.deg2rad(q_in)
    else:
        q_in = q_ref = q

    out = run_fk_csv(model, csv_input(q_in, times), *args)
    assert out.shape[0] == len(q), f"{out.shape[0]} output rows for {len(q)} input rows"
    assert np.array_equal(out[:, 0], times), "time column not copied"
    T_ref = ur.fk(model, q_ref, tcp=tcp, frame=frame)
    check_poses(out[:, 1:], T_ref, q=q_in, ctx=f"{model}/{variant}")


@pytest.mark.parametrize("model", ur.MODEL_NAMES)
def test_csv_special_angles(model):
    """Multiples of pi/2: gimbal lock (|cos pitch| ~ 0) and half-turns (qw ~ 0) are common here."""
    rng = np.random.default_rng(seed_for(model, "special"))
    k = rng.integers(-4, 5, size=(400, 6))
    q = k * (math.pi / 2)
    q[:3] = 0.0  # include the zero pose
    out = run_fk_csv(model, csv_input(q, np.arange(len(q))))
    T_ref = ur.fk(model, q)
    assert ur.cos_pitch(T_ref[:, :3, :3]).min() < GIMBAL_COS, "test data should hit gimbal lock"
    check_poses(out[:, 1:], T_ref, q=q, ctx=f"{model}/special")

    # same in degrees, with a tool and the base_link frame
    tcp = [0.0, 0.0, 0.1, 0.0, 0.0, math.pi / 2]
    out = run_fk_csv(model, csv_input(k * 90.0, np.arange(len(q))), "--deg", tcp_arg(tcp), "--frame", "base_link")
    T_ref = ur.fk(model, np.deg2rad(k * 90.0), tcp=tcp, frame="base_link")
    check_poses(out[:, 1:], T_ref, q=k * 90.0, ctx=f"{model}/special-deg")


GIMBAL_NUDGES = {
    "exact": [0.0],  # |cos pitch| ~ 1e-16
    "near": [1e-12, 1e-9, 1e-7],  # still |cos pitch| < 1e-6: matrix comparison
    "boundary": [1e-6, 2e-6, 1e-5, 1e-3],  # mostly regular: roll/pitch/yaw comparison
}


@pytest.mark.parametrize("kind", list(GIMBAL_NUDGES))
@pytest.mark.parametrize("model", ur.MODEL_NAMES)
def test_csv_gimbal_lock(model, kind):
    """Generic (not axis-aligned) configurations at and near pitch = +-pi/2.

    q4 = +-pi/2 - q2 - q3 and q5 = +-pi/2 make the flange z axis vertical; the tool
    rotation Ry(pi/2) then makes the tool x axis vertical, i.e. ZYX gimbal lock,
    with ~1e-16 rounding noise in the matrix entries. ``near``/``boundary`` rows
    are nudged off the lock on q4.
    """
    rng = np.random.default_rng(seed_for(model, "gimbal", kind))
    n = 400
    q = rng.uniform(-2 * math.pi, 2 * math.pi, size=(n, 6))
    # wrapped to [-pi, pi) so that q4 stays inside the +-2 pi joint limits
    q[:, 3] = ur.wrap(rng.choice([-1.0, 1.0], n) * (math.pi / 2) - q[:, 1] - q[:, 2])
    q[:, 4] = rng.choice([-1.0, 1.0], n) * (math.pi / 2)
    q[:, 3] += rng.choice(GIMBAL_NUDGES[kind], n) * rng.choice([-1.0, 1.0], n)
    tcp = [0.0, 0.0, 0.05, 0.0, math.pi / 2, 0.0]
    for frame in ("base", "base_link"):
        out = run_fk_csv(model, csv_input(q, np.arange(n)), tcp_arg(tcp), "--frame", frame)
        T_ref = ur.fk(model, q, tcp=tcp, frame=frame)
        cp = ur.cos_pitch(T_ref[:, :3, :3])
        if kind == "exact":
            assert cp.max() < 1e-12
        elif kind == "near":
            assert cp.max() < GIMBAL_COS
        check_poses(out[:, 1:], T_ref, q=q, ctx=f"{model}/gimbal-{kind}/{frame}")


def test_csv_without_time_column():
    rng = np.random.default_rng(99)
    q = random_joints(rng, 300)
    out = run_fk_csv("ur5e", csv_input(q, header="q1,q2,q3,q4,q5,q6"))
    assert out.shape[0] == len(q)
    assert np.array_equal(out[:, 0], np.arange(len(q), dtype=float)), "time should be the 0-based row index"
    check_poses(out[:, 1:], ur.fk("ur5e", q), q=q, ctx="no-time")


def _fmpy():
    data = np.genfromtxt(DATA_DIR / "fmpy_inputs.csv", delimiter=",", names=True)
    q = np.stack([data[f"q{i}"] for i in range(1, 7)], axis=1)
    return data["time"], q


def test_csv_extra_columns_file():
    times, q = _fmpy()
    res = ok(run_armtwin("fk", "--model", "ur10e", "--csv", DATA_DIR / "fmpy_inputs.csv"))
    out = parse_csv_output(res.stdout)
    assert out.shape[0] == len(q)
    assert np.array_equal(out[:, 0], times)
    check_poses(out[:, 1:], ur.fk("ur10e", q), q=q, ctx="fmpy file")


def test_csv_extra_columns_stdin():
    times, q = _fmpy()
    text = (DATA_DIR / "fmpy_inputs.csv").read_text()
    out = run_fk_csv("ur10e", text)
    assert out.shape[0] == len(q)
    assert np.array_equal(out[:, 0], times)
    check_poses(out[:, 1:], ur.fk("ur10e", q), q=q, ctx="fmpy stdin")


# --------------------------------------------------------------------------
# single pose (JSON)
# --------------------------------------------------------------------------

def _single(args):
    res = ok(run_armtwin(*args))
    obj = json.loads(res.stdout)
    assert isinstance(obj, dict), obj
    return obj


def _pose_vals(obj):
    return [obj[k] for k in ("x", "y", "z", "roll", "pitch", "yaw", "qx", "qy", "qz", "qw")]


SINGLE_Q = [0.1, -0.5, 0.3, -1.2, 2.5, -3.0]


@pytest.mark.parametrize("separator", [True, False], ids=["with--", "without--"])
def test_single_pose_ur10e(separator):
    args = ["fk", "--model", "ur10e"] + (["--"] if separator else []) + [repr(v) for v in SINGLE_Q]
    obj = _single(args)
    assert set(obj) == POSE_KEYS, sorted(obj)
    check_poses(_pose_vals(obj), ur.fk("ur10e", SINGLE_Q), ctx="single")


@pytest.mark.parametrize("model", ur.MODEL_NAMES)
def test_single_pose_matrix(model):
    rng = np.random.default_rng(seed_for(model, "single"))
    q = random_joints(rng, 1)[0]
    tcp = random_tcp(rng)
    for frame in ("base", "base_link"):
        args = ["fk", "--model", model, "--matrix", "--frame", frame, tcp_arg(tcp), "--"]
        obj = _single(args + [repr(float(v)) for v in q])
        assert set(obj) == POSE_KEYS | {"matrix"}, sorted(obj)
        T_ref = ur.fk(model, q, tcp=tcp, frame=frame)[0]
        M = np.array(obj["matrix"], dtype=float)
        assert M.shape == (4, 4), obj["matrix"]
        err = np.abs(M - T_ref).max()
        assert err <= POS_TOL, f"{model}/{frame} matrix err {err:.3e}\n{M}\n{T_ref}"
        check_poses(_pose_vals(obj), T_ref, ctx=f"single {model}/{frame}")


def test_single_pose_deg():
    q_deg = [10.0, -95.5, 120.25, -30.0, 90.0, -181.0]
    obj = _single(["fk", "--model", "ur5", "--deg", "--"] + [repr(v) for v in q_deg])
    assert set(obj) == POSE_KEYS
    check_poses(_pose_vals(obj), ur.fk("ur5", np.deg2rad(q_deg)), ctx="single deg")


def test_single_pose_zero():
    obj = _single(["fk", "--model", "ur5", "0", "0", "0", "0", "0", "0"])
    check_poses(_pose_vals(obj), ur.fk("ur5", [0.0] * 6), ctx="single zero")


# --------------------------------------------------------------------------
# calibration
# --------------------------------------------------------------------------

@pytest.mark.parametrize("model", ur.MODEL_NAMES)
def test_calibration_conf_small(model, tmp_path):
    rng = np.random.default_rng(seed_for(model, "cal-small"))
    cal = random_small_calibration(rng)  # every delta non-zero, including a6 / alpha6
    conf = write_conf(tmp_path, cal)
    q = random_joints(rng)
    out = run_fk_csv(model, csv_input(q, np.arange(len(q))), "--calibration", conf)
    T_ref = ur.fk(model, q, calibration=cal)
    # make sure the calibration actually matters at this tolerance
    assert np.abs(T_ref[:, :3, 3] - ur.fk(model, q)[:, :3, 3]).max() > 1e-4
    check_poses(out[:, 1:], T_ref, q=q, ctx=f"{model}/conf-small")

    # with tool + base_link, single pose
    tcp = random_tcp(rng)
    obj = _single(
        ["fk", "--model", model, "--calibration", conf, tcp_arg(tcp), "--frame", "base_link", "--matrix", "--"]
        + [repr(float(v)) for v in q[0]]
    )
    T1 = ur.fk(model, q[0], tcp=tcp, frame="base_link", calibration=cal)
    assert np.abs(np.array(obj["matrix"]) - T1[0]).max() <= POS_TOL
    check_poses(_pose_vals(obj), T1, ctx=f"{model}/conf-small single")


@pytest.mark.parametrize("model", ["ur10e", "ur5", "ur30"])
def test_calibration_conf_large_cancelling_dd(model, tmp_path):
    rng = np.random.default_rng(seed_for(model, "cal-large"))
    conf = write_conf(tmp_path, LARGE_DD_CAL)
    q = random_joints(rng)
    out = run_fk_csv(model, csv_input(q, np.arange(len(q))), "--calibration", conf)
    T_ref = ur.fk(model, q, calibration=LARGE_DD_CAL)
    # rotations are unaffected by delta_d: keep their tolerances; positions cancel ~ 100s of m
    check_poses(out[:, 1:], T_ref, q=q, pos_tol=1e-9, ctx=f"{model}/conf-large")


def _yaml_case(model, cal, tmp_path, pos_tol):
    conf = write_conf(tmp_path, cal)
    origins = ur.calibration_to_urdf_origins(model, cal)
    yaml_path = tmp_path / "calibration.yaml"
    yaml_path.write_text(ur.format_calibration_yaml(origins))
    rng = np.random.default_rng(seed_for(model, "yaml", pos_tol))
    q = random_joints(rng)
    text = csv_input(q, np.arange(len(q)))
    out_conf = run_fk_csv(model, text, "--calibration", conf)
    out_yaml = run_fk_csv(model, text, "--calibration", yaml_path)

    # armtwin(YAML) == armtwin(conf) to 1e-9
    T_conf = ur.fk(model, q, calibration=cal)
    pos_diff = np.abs(out_yaml[:, 1:4] - out_conf[:, 1:4]).max()
    assert pos_diff <= 1e-9, f"YAML vs conf position differs by {pos_diff:.3e}"
    quat_diff = np.abs(out_yaml[:, 7:11] - out_conf[:, 7:11]).max(axis=1)
    quat_diff = np.where(np.abs(out_conf[:, 10]) < QW_AMBIGUOUS,
                         np.minimum(quat_diff, np.abs(out_yaml[:, 7:11] + out_conf[:, 7:11]).max(axis=1)),
                         quat_diff)
    assert quat_diff.max() <= 1e-9, f"YAML vs conf quaternion differs by {quat_diff.max():.3e}"
    regular = ur.cos_pitch(T_conf[:, :3, :3]) >= GIMBAL_COS
    rpy_diff = np.abs(ur.wrap(out_yaml[regular, 4:7] - out_conf[regular, 4:7])).max()
    assert rpy_diff <= 1e-9, f"YAML vs conf rpy differs by {rpy_diff:.3e}"

    # armtwin(YAML) == our URDF-form reference of that YAML, and == the DH reference
    check_poses(out_yaml[:, 1:], ur.fk_urdf(origins, q), q=q, pos_tol=pos_tol, ctx=f"{model}/yaml-urdf")
    check_poses(out_yaml[:, 1:], T_conf, q=q, pos_tol=pos_tol, ctx=f"{model}/yaml-dh")
    check_poses(out_conf[:, 1:], T_conf, q=q, pos_tol=pos_tol, ctx=f"{model}/conf-dh")


@pytest.mark.parametrize("model", ur.MODEL_NAMES)
def test_calibration_yaml_small(model, tmp_path):
    rng = np.random.default_rng(seed_for(model, "yaml-small"))
    cal = random_small_calibration(rng, zero_last_a_alpha=True)
    _yaml_case(model, cal, tmp_path, pos_tol=POS_TOL)


@pytest.mark.parametrize("model", ["ur10e", "ur3"])
def test_calibration_yaml_large_cancelling_dd(model, tmp_path):
    _yaml_case(model, LARGE_DD_CAL, tmp_path, pos_tol=1e-9)
