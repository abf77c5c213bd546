"""armtwin's inverse dynamics checked against Pinocchio (PyPI ``pin``), an independent implementation.

For every catalog model, and for custom arms in both DH conventions, the arm is built in Pinocchio
from its DH table (ur_reference.py) and the inertial parameters transcribed below from the sources
armtwin's tables cite; random states, payloads and mountings go through the core's example
``rnea_json`` (built by ``cargo test`` into target/debug/examples/) and through ``pin.rnea``,
``pin.crba``, ``pin.computeGeneralizedGravity`` and ``pin.computeCoriolisMatrix``.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from support import ur_reference as ur
from support.paths import armtwin_path
from support.ur_dynamics import (
    GEAR_RATIO,
    PARAMETERS,
    ROTOR_INERTIA_KG_M2,
    TOLERANCE_NM,
    TORQUE_CONSTANT_NM_PER_A,
    UR_GRAVITY_M_S2,
    pinocchio_arm,
    with_payload,
)

N_STATES = 200


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------

def rnea_json_path() -> Path:
    env = os.environ.get("ARMTWIN_RNEA_JSON")
    if env:
        return Path(env)
    return armtwin_path().parent / "examples" / "rnea_json"


@pytest.fixture(scope="module")
def rnea_json() -> Path:
    path = rnea_json_path()
    if not path.is_file():
        pytest.fail(f"{path} not found: cargo test -p armtwin-core builds it (or set ARMTWIN_RNEA_JSON)",
                    pytrace=False)
    return path


def random_payload(rng, max_mass):
    root = rng.normal(0.0, 0.05, (3, 3))
    inertia = root @ root.T  # positive semi-definite
    entries = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
    return (float(rng.uniform(0.0, max_mass)), rng.uniform(-0.2, 0.2, 3).tolist(), entries)


def random_gravity(rng):
    if rng.random() < 0.5:
        return [0.0, 0.0, -UR_GRAVITY_M_S2]
    direction = rng.normal(size=3)
    return (UR_GRAVITY_M_S2 * direction / np.linalg.norm(direction)).tolist()


def run_states(binary, arm, states):
    lines = []
    for q, qd, qdd, (mass, cog, inertia), gravity in states:
        numbers = [*q, *qd, *qdd, mass, *cog, *inertia, *gravity]
        lines.append(" ".join([str(arm)] + [repr(float(v)) for v in numbers]))
    result = subprocess.run([str(binary)], input="\n".join(lines) + "\n", capture_output=True, text=True,
                            timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    return [json.loads(line) for line in result.stdout.splitlines()]


def compare(binary, arm, model, flange_in_joint, rng, max_payload_kg):
    """Largest |armtwin − Pinocchio| per quantity over N_STATES random states."""
    n = model.nq
    states = []
    for _ in range(N_STATES):
        states.append((rng.uniform(-2 * math.pi, 2 * math.pi, n), rng.uniform(-math.pi, math.pi, n),
                       rng.uniform(-10.0, 10.0, n), random_payload(rng, max_payload_kg), random_gravity(rng)))
    outputs = run_states(binary, arm, states)
    assert len(outputs) == N_STATES
    worst = {"tau": 0.0, "gravity": 0.0, "mass_matrix": 0.0, "momentum": 0.0, "coriolis": 0.0,
             "coriolis_transpose_qd": 0.0}
    for (q, qd, qdd, payload, gravity), out in zip(states, outputs):
        loaded = with_payload(model, flange_in_joint, payload)
        loaded.gravity.linear = np.asarray(gravity)
        data = loaded.createData()
        expected = {"tau": pin.rnea(loaded, data, q, qd, qdd).copy(),
                    "gravity": pin.computeGeneralizedGravity(loaded, data, q).copy()}
        mass = pin.crba(loaded, data, q).copy()
        mass = np.triu(mass) + np.triu(mass, 1).T  # crba fills the upper triangle
        expected["mass_matrix"] = mass
        coriolis = pin.computeCoriolisMatrix(loaded, data, q, qd).copy()
        expected["momentum"] = mass @ qd
        expected["coriolis"] = coriolis @ qd
        expected["coriolis_transpose_qd"] = coriolis.T @ qd
        for key, value in expected.items():
            worst[key] = max(worst[key], float(np.max(np.abs(np.asarray(out[key]) - value))))
    return worst


def report(name, worst):
    print(f"{name}: " + ", ".join(f"{key} {value:.2e}" for key, value in worst.items()))
    assert all(value <= TOLERANCE_NM for value in worst.values()), (name, worst)


# --------------------------------------------------------------------------
# tests
# --------------------------------------------------------------------------

@pytest.mark.parametrize("model_name", ur.MODEL_NAMES)
def test_catalog_arm_matches_pinocchio(rnea_json, model_name):
    masses, coms, diagonals, sizes = PARAMETERS[model_name]
    links = [(masses[k], coms[k], [*diagonals[k], 0.0, 0.0, 0.0]) for k in range(6)]
    rotor = [ROTOR_INERTIA_KG_M2[s] * GEAR_RATIO**2 for s in sizes] if sizes else [0.0] * 6
    dh = ur.dh_table(model_name)
    model, flange = pinocchio_arm("standard", dh.a, dh.alpha, dh.d, dh.theta_offset, links, rotor)
    rng = np.random.default_rng(sum(map(ord, model_name)))
    report(model_name, compare(rnea_json, model_name, model, flange, rng, max_payload_kg=30.0))


def custom_arm(rng, convention, n):
    """A random arm of n joints with full inertia tensors, θ offsets and rotor inertia, and its TOML."""
    a = rng.uniform(-0.5, 0.5, n).tolist()
    alpha = rng.choice([0.0, math.pi / 2, -math.pi / 2, 0.3], n).tolist()
    d = rng.uniform(-0.3, 0.3, n).tolist()
    theta = rng.uniform(-1.0, 1.0, n).tolist()
    links, rotor = [], rng.uniform(0.0, 2.0, n).tolist()
    for _ in range(n):
        root = rng.normal(0.0, 0.1, (3, 3))
        inertia = root @ root.T
        links.append((float(rng.uniform(0.5, 10.0)), rng.uniform(-0.2, 0.2, 3).tolist(),
                      [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]))
    text = [f'name = "random-{convention}-{n}"', f'convention = "{convention}"']
    for k in range(n):
        text += ["[[joints]]", f"a = {a[k]!r}", f"alpha = {alpha[k]!r}", f"d = {d[k]!r}",
                 f"theta_offset = {theta[k]!r}"]
    for k, (mass, com, inertia) in enumerate(links):
        text += ["[[dynamics.links]]", f"mass = {mass!r}", f"com = [{', '.join(map(repr, com))}]",
                 f"inertia = [{', '.join(repr(float(v)) for v in inertia)}]",
                 f"rotor_inertia = {rotor[k]!r}"]
    model, flange = pinocchio_arm(convention, a, alpha, d, theta, links, rotor)
    return "\n".join(text) + "\n", model, flange


@pytest.mark.parametrize("convention,n", [("standard", 6), ("modified", 6), ("standard", 7), ("modified", 7)])
def test_custom_arm_matches_pinocchio(rnea_json, tmp_path, convention, n):
    rng = np.random.default_rng(1000 + 10 * n + (convention == "modified"))
    text, model, flange = custom_arm(rng, convention, n)
    path = tmp_path / "arm.toml"
    path.write_text(text)
    report(f"custom {convention} {n}", compare(rnea_json, path, model, flange, rng, max_payload_kg=5.0))


# --------------------------------------------------------------------------
# armtwin validate --dynamics on a UR RTDE recording generated with Pinocchio
# --------------------------------------------------------------------------

REST_POSES = 12
ROWS_PER_REST = 15


def rtde_recording(rng, configured, actual, with_target=True):
    """A UR10e RTDE recording (space-separated, as UR's RTDE example client `record.py` writes): a program-mode motion, the
    arm at rest in several poses, then freedrive. `target_moment` is Pinocchio's model with the
    configured payload, as the controller computes it; the currents carry the actual payload,
    Coulomb + viscous friction and noise. Returns the text and the truth per row."""
    masses, coms, diagonals, sizes = PARAMETERS["ur10e"]
    links = [(masses[k], coms[k], [*diagonals[k], 0.0, 0.0, 0.0]) for k in range(6)]
    rotor = [ROTOR_INERTIA_KG_M2[s] * GEAR_RATIO**2 for s in sizes]
    factors = np.array([TORQUE_CONSTANT_NM_PER_A[s] * GEAR_RATIO for s in sizes])
    dh = ur.dh_table("ur10e")
    model, flange = pinocchio_arm("standard", dh.a, dh.alpha, dh.d, dh.theta_offset, links, rotor)
    as_configured = with_payload(model, flange, (configured[0], configured[1], [0.0] * 6))
    as_carried = with_payload(model, flange, (actual[0], actual[1], [0.0] * 6))
    for m in (as_configured, as_carried):
        m.gravity.linear = np.array([0.0, 0.0, -UR_GRAVITY_M_S2])
    data_configured, data_carried = as_configured.createData(), as_carried.createData()
    coulomb, viscous = np.array([6.0, 6.0, 4.0, 1.5, 1.5, 1.5]), np.array([3.0, 3.0, 2.0, 0.5, 0.5, 0.5])

    states = []  # (t, q, qd, qdd, status bits)
    dt = 0.002
    amplitude, omega, phase = rng.uniform(0.3, 0.8, 6), rng.uniform(1.0, 3.0, 6), rng.uniform(0, 6.3, 6)
    centre = np.array([0.0, -1.2, 1.3, -1.6, -1.5, 0.0])
    for i in range(300):
        t = i * dt
        q = centre + amplitude * np.sin(omega * t + phase)
        qd = amplitude * omega * np.cos(omega * t + phase)
        qdd = -amplitude * omega**2 * np.sin(omega * t + phase)
        states.append((t, q, qd, qdd, 3))
    for pose in range(REST_POSES):
        q = centre + rng.uniform(-1.2, 1.2, 6)
        for _ in range(ROWS_PER_REST):
            states.append((states[-1][0] + dt, q, np.zeros(6), np.zeros(6), 3))
    for _ in range(40):
        q = centre + rng.uniform(-0.5, 0.5, 6)
        states.append((states[-1][0] + dt, q, np.zeros(6), np.zeros(6), 7))

    groups = ["actual_q", "actual_qd", "actual_current", "target_moment"]
    if with_target:
        groups = ["target_q", "target_qd", "target_qdd"] + groups
    header = ["timestamp"] + [f"{g}_{k}" for g in groups for k in range(6)]
    header += ["payload", "payload_cog_0", "payload_cog_1", "payload_cog_2", "robot_status_bits"]
    lines = [" ".join(header)]
    truth = []
    for t, q, qd, qdd, bits in states:
        if bits & 4:
            moment = pin.computeGeneralizedGravity(as_configured, data_configured, q).copy()
        else:
            moment = pin.rnea(as_configured, data_configured, q, qd, qdd).copy()
        carried = pin.rnea(as_carried, data_carried, q, qd, qdd).copy()
        current = (carried + coulomb * np.sign(qd) + viscous * qd) / factors + rng.normal(0.0, 0.03, 6)
        columns = {"target_q": q, "target_qd": qd, "target_qdd": qdd, "actual_q": q, "actual_qd": qd,
                   "actual_current": current, "target_moment": moment}
        values = [t] + [v for g in groups for v in columns[g]] + [configured[0], *configured[1], bits]
        lines.append(" ".join(repr(float(v)) for v in values))
        truth.append(moment)
    return "\n".join(lines) + "\n", truth


def validate_dynamics(tmp_path, text, *extra):
    recording = tmp_path / "rtde.csv"
    recording.write_text(text)
    out = tmp_path / "report"
    binary = armtwin_path()
    res = subprocess.run([str(binary), "validate", str(recording), "--model", "ur10e", "--dynamics", "--out",
                          str(out), *extra], capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr
    report = json.loads((out / "report.json").read_text())
    rows = (out / "dynamics.csv").read_text().splitlines()
    assert "## Dynamics" in (out / "report.md").read_text()
    # The plots: model and reference torque per joint, and their difference.
    torques = (out / "dynamics_torques.svg").read_text()
    residual = (out / "dynamics_residual.svg").read_text()
    for joint in range(1, 7):
        assert f'data-name="model {joint}"' in torques and f'data-name="measured {joint}"' in torques
        assert f'data-name="joint {joint}"' in residual
    return report["dynamics"], rows, res.stderr


def test_validate_dynamics_reproduces_target_moment_and_identifies_the_payload(tmp_path):
    rng = np.random.default_rng(26)
    configured = (2.0, [0.0, 0.0, 0.05])
    actual = (3.5, [0.01, -0.02, 0.09])
    text, truth = rtde_recording(rng, configured, actual)
    dynamics, rows, stderr = validate_dynamics(tmp_path, text)
    print(stderr)
    assert dynamics["state"] == "target"
    assert dynamics["modes"] == {"program": 300 + REST_POSES * ROWS_PER_REST, "freedrive": 40}
    assert dynamics["rows"] == len(truth) and dynamics["skipped"] == 0
    # Like with like: the model equals the controller's (here Pinocchio's) target_moment.
    worst = max(dynamics["model_vs_target_moment"]["max_nm"])
    print(f"validate --dynamics: model vs target_moment max {worst:.2e} N·m")
    assert worst <= TOLERANCE_NM
    # dynamics.csv: a header and a row per modelled row; its model torques are the truth.
    header = rows[0].split(",")
    assert header[:3] == ["t", "line", "mode"] and len(header) == 27
    assert len(rows) == 1 + len(truth)
    first = dict(zip(header, rows[1].split(",")))
    assert all(abs(float(first[f"tau_model_{k}"]) - truth[0][k]) <= TOLERANCE_NM for k in range(6))
    # The currents carry 3.5 kg where 2 kg was configured: the rows at rest identify it.
    payload = dynamics["payload"]
    assert payload["configured"] == {"mass_kg": 2.0, "cog_m": [0.0, 0.0, 0.05], "source": "recording"}
    identified = payload["identified"]
    assert identified["samples"] == REST_POSES * ROWS_PER_REST
    print(f"identified payload {identified['mass_kg']:.3f} ± {identified['mass_std_kg']:.3f} kg, "
          f"cog {identified['cog_m']}")
    assert abs(identified["mass_kg"] - actual[0]) <= 4 * identified["mass_std_kg"] + 1e-3
    assert identified["mass_std_kg"] < 0.1
    assert np.allclose(identified["cog_m"], actual[1], atol=0.02)


def test_validate_dynamics_without_targets_differentiates_the_actual_velocity(tmp_path):
    rng = np.random.default_rng(27)
    payload = (2.0, [0.0, 0.0, 0.05])
    text, truth = rtde_recording(rng, payload, payload, with_target=False)
    dynamics, rows, _ = validate_dynamics(tmp_path, text)
    assert dynamics["state"] == "actual"
    header = rows[0].split(",")
    model = np.array([[float(v) for v in line.split(",")[3:9]] for line in rows[1:]])
    assert header[3:9] == [f"tau_model_{k}" for k in range(6)]
    error = np.abs(model - np.array(truth))
    # Row 0 has only a one-sided difference, and the generated motion stops dead at row 300 (q̇
    # jumps to 0), which no difference can follow: rows 0, 299 and 300 are excluded. Elsewhere
    # central differences of a 500 Hz sinusoid follow q̈ closely, and rows at rest or in freedrive
    # are exact.
    smooth = np.ones(len(truth), dtype=bool)
    smooth[[0, 299, 300]] = False
    print(f"actual state: model vs target_moment max {error[smooth].max():.2e} N·m on smooth rows, "
          f"{error[~smooth].max():.2e} where the motion stops dead")
    assert error[smooth].max() < 1e-2
    assert error[300:][1:].max() <= TOLERANCE_NM
