"""The FMI 2.0 FMU from `armtwin fmu build`, run in FMPy: valid, and equal to `armtwin fk`.

How FMPy's co-simulation loop lines up with `armtwin fk` (fmpy.simulation.simulateCS): inputs
interpolated at t_0 are applied in initialization mode and the outputs recorded at t_0; then at
each communication point t_k the inputs at t_k are applied, fmi2DoStep(t_k, h) runs, and the
outputs are recorded at t_{k+1}. So recorded row k+1 holds FK(q_k) and row 0 holds FK(q_0).
The input signal's times are k * 0.1 computed exactly as FMPy computes its communication points
(start + k * h with start 0), so FMPy's linear interpolation sits on a sample (weights 0 and 1)
and hands the FMU the CSV's values bit for bit; the test checks that too (it records q1..q6).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import zipfile
from ctypes import byref
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.logging import addLoggerProxy
from fmpy.validation import validate_fmu

from support import ur_reference as ur
from support.fk_csv import check_poses, csv_input, parse_csv_output
from support.paths import DATA_DIR, REPO_ROOT, armtwin_path
from support.process import run_armtwin

STEP_S = 0.1
OUTPUTS = ["x", "y", "z", "roll", "pitch", "yaw", "qx", "qy", "qz", "qw"]
JOINTS = [f"q{i}" for i in range(1, 7)]
VELOCITIES = [f"qd{i}" for i in range(1, 7)]
ACCELERATIONS = [f"qdd{i}" for i in range(1, 7)]
TORQUES = [f"tau{i}" for i in range(1, 7)]
PAYLOAD = ["payload_mass", "payload_cog_x", "payload_cog_y", "payload_cog_z"]
CALIBRATION = REPO_ROOT / "config" / "examples" / "calibration.conf"
TCP = [0.012, -0.034, 0.156, 0.11, -0.22, 1.3]
# The calibrated robot, as `armtwin fmu build` and `armtwin fk` options.
CALIBRATED = (
    "--model", "ur10e",
    "--calibration", CALIBRATION,
    "--tcp=" + ",".join(repr(v) for v in TCP),
    "--frame", "base_link",
)


def build_fmu(out: Path, *args) -> Path:
    res = run_armtwin("fmu", "build", "--out", out, *args)
    assert res.returncode == 0, res.stderr
    assert out.is_file()
    return out


def recorded_joints() -> np.ndarray:
    data = np.genfromtxt(DATA_DIR / "fmpy_inputs.csv", delimiter=",", names=True)
    return np.stack([data[name] for name in JOINTS], axis=1)


def fk_csv(q: np.ndarray, *extra) -> np.ndarray:
    """`armtwin fk --csv` of the joint rows q: (N, 10) outputs."""
    res = run_armtwin("fk", *extra, "--csv", "-", input=csv_input(q, header=",".join(JOINTS)))
    assert res.returncode == 0, res.stderr
    return parse_csv_output(res.stdout)[:, 1:]


def input_signal(q: np.ndarray) -> np.ndarray:
    """FMPy's structured input signal: time k * STEP_S and the joint columns."""
    signal = np.zeros(len(q), dtype=[("time", float)] + [(name, float) for name in JOINTS])
    signal["time"] = np.arange(len(q)) * STEP_S
    for i, name in enumerate(JOINTS):
        signal[name] = q[:, i]
    return signal


def simulate(fmu: Path, q: np.ndarray) -> np.ndarray:
    result = simulate_fmu(
        str(fmu),
        start_time=0.0,
        stop_time=len(q) * STEP_S,
        step_size=STEP_S,
        output_interval=STEP_S,
        input=input_signal(q),
        output=JOINTS + OUTPUTS,
    )
    assert len(result) == len(q) + 1, len(result)
    return result


def outputs_of(result: np.ndarray) -> np.ndarray:
    return np.stack([result[name] for name in OUTPUTS], axis=1)


def numpy_differences(outputs: np.ndarray, reference: np.ndarray) -> str:
    """Max |difference| of position and (canonical) quaternion against the numpy reference."""
    position = np.abs(outputs[:, 0:3] - reference[:, :3, 3]).max()
    quaternion = np.abs(outputs[:, 6:10] - ur.canonical_quat(reference[:, :3, :3])).max()
    return f"position {position:.3e} m, quaternion {quaternion:.3e}"


def check_simulation_equals_fk(result: np.ndarray, q: np.ndarray, fk: np.ndarray) -> float:
    """Row 0 = FK(q_0), row k+1 = FK(q_k), inputs exact; returns the max |difference|."""
    held = np.stack([result[name] for name in JOINTS], axis=1)
    assert np.array_equal(held[0], q[0])
    assert np.array_equal(held[1:], q), "FMPy must hand the FMU the CSV's values exactly"
    outputs = outputs_of(result)
    expected = np.vstack([fk[:1], fk])
    difference = float(np.abs(outputs - expected).max())
    assert difference <= 1e-12, difference
    return difference


@pytest.fixture(scope="module")
def nominal_fmu(tmp_path_factory) -> Path:
    return build_fmu(tmp_path_factory.mktemp("fmu") / "UR10e_FK.fmu", "--model", "ur10e")


@pytest.fixture(scope="module")
def calibrated_fmu(tmp_path_factory) -> Path:
    return build_fmu(tmp_path_factory.mktemp("fmu") / "UR10e_calibrated.fmu", *CALIBRATED)


def test_fmpy_validation_finds_no_problem(nominal_fmu, calibrated_fmu):
    for fmu in (nominal_fmu, calibrated_fmu):
        assert validate_fmu(str(fmu)) == []


def test_interface_is_the_reports_with_units_and_tool_parameters(calibrated_fmu):
    md = read_model_description(str(calibrated_fmu))
    variables = {v.name: v for v in md.modelVariables}
    for vr, name in enumerate(JOINTS):
        v = variables[name]
        assert (v.valueReference, v.causality, v.unit) == (vr, "input", "rad")
    for vr, name in enumerate(OUTPUTS, start=6):
        v = variables[name]
        assert (v.valueReference, v.causality) == (vr, "output")
    for vr, (name, value) in enumerate(zip(["tcp_x", "tcp_y", "tcp_z", "tcp_rx", "tcp_ry", "tcp_rz"], TCP), start=16):
        v = variables[name]
        assert (v.valueReference, v.causality, v.variability) == (vr, "parameter", "tunable")
        assert float(v.start) == value
    assert [variables[n].unit for n in OUTPUTS] == ["m"] * 3 + ["rad"] * 3 + [None] * 4
    for vr, name in enumerate(VELOCITIES + ACCELERATIONS, start=22):
        v = variables[name]
        assert (v.valueReference, v.causality, v.unit) == (vr, "input", "rad/s" if vr < 28 else "rad/s2")
    for vr, name in enumerate(TORQUES, start=34):
        v = variables[name]
        assert (v.valueReference, v.causality, v.unit) == (vr, "output", "N.m")
    for vr, name in enumerate(PAYLOAD, start=40):
        v = variables[name]
        assert (v.valueReference, v.causality, v.variability, float(v.start)) == (vr, "parameter", "tunable", 0.0)
    # ModelStructure: 1-based ScalarVariable indices (x is the 7th variable); the pose depends on
    # the angles, the torques on the angles, velocities and accelerations.
    assert [u.variable.name for u in md.outputs] == OUTPUTS + TORQUES
    assert all([d.name for d in u.dependencies] == JOINTS for u in md.outputs[:10])
    assert all([d.name for d in u.dependencies] == JOINTS + VELOCITIES + ACCELERATIONS for u in md.outputs[10:])
    with zipfile.ZipFile(calibrated_fmu) as archive:
        names = set(archive.namelist())
        assert f"binaries/linux64/{md.coSimulation.modelIdentifier}.so" in names
        assert archive.read("resources/calibration.conf") == CALIBRATION.read_bytes()


def test_simulation_equals_armtwin_fk_and_the_numpy_reference(nominal_fmu):
    q = recorded_joints()
    result = simulate(nominal_fmu, q)
    difference = check_simulation_equals_fk(result, q, fk_csv(q, "--model", "ur10e"))
    reference = ur.fk("ur10e", q)
    check_poses(outputs_of(result)[1:], reference, q=q, ctx="fmu vs numpy")
    print(f"\nnominal UR10e: max |FMU - armtwin fk| = {difference:.3e}; vs numpy: "
          f"{numpy_differences(outputs_of(result)[1:], reference)}")


def test_calibrated_fmu_equals_calibrated_fk(calibrated_fmu):
    q = recorded_joints()
    result = simulate(calibrated_fmu, q)
    fk = fk_csv(q, *CALIBRATED)
    difference = check_simulation_equals_fk(result, q, fk)
    calibration = ur.parse_calibration_conf(CALIBRATION.read_text())
    reference = ur.fk("ur10e", q, tcp=TCP, frame="base_link", calibration=calibration)
    # The reference's plain DH product loses digits to the ±200 m cancelling delta_d.
    check_poses(outputs_of(result)[1:], reference, q=q, pos_tol=1e-9, ctx="calibrated fmu vs numpy")
    nominal = fk_csv(q, "--model", "ur10e")
    assert np.abs(fk - nominal).max() > 1e-3, "the calibration and tool must matter"
    print(f"\ncalibrated UR10e: max |FMU - armtwin fk| = {difference:.3e}; vs numpy: "
          f"{numpy_differences(outputs_of(result)[1:], reference)}")


def test_torques_equal_pinocchio_with_a_payload_in_fmpy(nominal_fmu):
    """The torque outputs over a simulation, with the payload parameters set, against Pinocchio's
    rnea of the same UR10e (an independent implementation)."""
    import pinocchio as pin

    from support.ur_dynamics import (
        GEAR_RATIO,
        PARAMETERS,
        ROTOR_INERTIA_KG_M2,
        TOLERANCE_NM,
        UR_GRAVITY_M_S2,
        pinocchio_arm,
        with_payload,
    )

    masses, coms, diagonals, sizes = PARAMETERS["ur10e"]
    links = [(masses[k], coms[k], [*diagonals[k], 0.0, 0.0, 0.0]) for k in range(6)]
    rotor = [ROTOR_INERTIA_KG_M2[s] * GEAR_RATIO**2 for s in sizes]
    dh = ur.dh_table("ur10e")
    model, flange = pinocchio_arm("standard", dh.a, dh.alpha, dh.d, dh.theta_offset, links, rotor)
    payload = (3.5, [0.01, -0.02, 0.09])
    loaded = with_payload(model, flange, (payload[0], payload[1], [0.0] * 6))
    loaded.gravity.linear = np.array([0.0, 0.0, -UR_GRAVITY_M_S2])
    data = loaded.createData()

    rng = np.random.default_rng(9)
    rows = 40
    q = rng.uniform(-3.0, 3.0, (rows, 6))
    qd = rng.uniform(-2.0, 2.0, (rows, 6))
    qdd = rng.uniform(-5.0, 5.0, (rows, 6))
    names = JOINTS + VELOCITIES + ACCELERATIONS
    signal = np.zeros(rows, dtype=[("time", float)] + [(name, float) for name in names])
    signal["time"] = np.arange(rows) * STEP_S
    for i, column in enumerate(np.hstack([q, qd, qdd]).T):
        signal[names[i]] = column
    result = simulate_fmu(
        str(nominal_fmu),
        start_time=0.0,
        stop_time=rows * STEP_S,
        step_size=STEP_S,
        output_interval=STEP_S,
        input=signal,
        output=TORQUES,
        start_values=dict(zip(PAYLOAD, [payload[0], *payload[1]])),
    )
    torques = np.stack([result[name] for name in TORQUES], axis=1)[1:]
    expected = np.array([pin.rnea(loaded, data, q[k], qd[k], qdd[k]).copy() for k in range(rows)])
    worst = float(np.abs(torques - expected).max())
    print(f"FMU tau vs Pinocchio rnea over {rows} states with a 3.5 kg payload: max {worst:.2e} N·m")
    assert worst <= TOLERANCE_NM


def slave(unzipped: str, name: str) -> FMU2Slave:
    md = read_model_description(unzipped)
    fmu = FMU2Slave(
        guid=md.guid,
        unzipDirectory=unzipped,
        modelIdentifier=md.coSimulation.modelIdentifier,
        instanceName=name,
    )
    fmu.instantiate()
    return fmu


OUTPUT_VRS = list(range(6, 16))


def test_outputs_are_right_at_t0_before_any_step(calibrated_fmu):
    unzipped = extract(str(calibrated_fmu))
    try:
        fmu = slave(unzipped, "t0")
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        # Start values: every joint 0.
        assert fmu.getReal(OUTPUT_VRS) == fk_csv(np.zeros((1, 6)), *CALIBRATED)[0].tolist()
        q = recorded_joints()[7]
        fmu.setReal(list(range(6)), q.tolist())
        expected = fk_csv(q.reshape(1, 6), *CALIBRATED)[0].tolist()
        assert fmu.getReal(OUTPUT_VRS) == expected
        fmu.exitInitializationMode()
        assert fmu.getReal(OUTPUT_VRS) == expected
        fmu.terminate()
        fmu.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)


def test_two_instances_in_one_process_do_not_share_state(nominal_fmu):
    # Both from one unpacked FMU: one shared library, loaded once, two instances.
    unzipped = extract(str(nominal_fmu))
    try:
        a, b = slave(unzipped, "a"), slave(unzipped, "b")
        for fmu in (a, b):
            fmu.setupExperiment(startTime=0.0)
            fmu.enterInitializationMode()
            fmu.exitInitializationMode()
        q = recorded_joints()
        fk = fk_csv(q, "--model", "ur10e")
        fk_longer_tool = fk_csv(q, "--model", "ur10e", "--tcp=0,0,0.25,0,0,0")
        b.setReal([18], [0.25])  # tcp_z, tunable
        n = len(q)
        for k in range(n):
            a.setReal(list(range(6)), q[k].tolist())
            b.setReal(list(range(6)), q[n - 1 - k].tolist())
            a.doStep(k * STEP_S, STEP_S)
            b.doStep(k * STEP_S, STEP_S)
            assert a.getReal(OUTPUT_VRS) == fk[k].tolist(), k
            assert b.getReal(OUTPUT_VRS) == fk_longer_tool[n - 1 - k].tolist(), k
        assert a.getReal([18]) == [0.0]
        a.terminate()
        a.freeInstance()
        b.doStep(n * STEP_S, STEP_S)
        assert b.getReal(OUTPUT_VRS) == fk_longer_tool[0].tolist()
        b.terminate()
        b.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)


def test_invalid_calls_fail_with_the_fmus_message(nominal_fmu):
    unzipped = extract(str(nominal_fmu))
    messages = []

    def logger(component_environment, instance_name, status, category, message):
        messages.append((status, category.decode(), message.decode()))

    try:
        md = read_model_description(unzipped)
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bad")
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(logger)
        addLoggerProxy(byref(callbacks))  # formats the "%s" argument as a C master would
        fmu.instantiate(callbacks=callbacks)
        with pytest.raises(FMICallException):
            fmu.doStep(0.0, STEP_S)
        assert messages[-1] == (3, "logStatusError", "fmi2DoStep: not allowed in state instantiated")
        fmu.reset()
        fmu.setupExperiment(startTime=0.0)
        fmu.enterInitializationMode()
        with pytest.raises(FMICallException):
            fmu.setReal([2], [7.0])
        assert messages[-1][2].startswith("fmi2SetReal: joint q3 = 7 rad is outside its limits")
        fmu.freeInstance()
    finally:
        shutil.rmtree(unzipped, ignore_errors=True)


def test_build_errors_are_armtwin_fks(tmp_path):
    out = tmp_path / "x.fmu"
    for args in (
        ["--model", "ur11"],
        ["--model", "ur10e", "--calibration", tmp_path / "missing.conf"],
        ["--model", "ur10e", "--tcp=1,2,3"],
    ):
        build = run_armtwin("fmu", "build", "--out", out, *args)
        fk = run_armtwin("fk", *args, "0", "0", "0", "0", "0", "0")
        assert build.returncode != 0 and fk.returncode != 0
        assert build.stderr.splitlines()[0] == fk.stderr.splitlines()[0]
        assert not out.exists()
    custom = run_armtwin("fmu", "build", "--out", out, "--model", REPO_ROOT / "config" / "examples" / "franka-panda.toml")
    assert custom.returncode != 0
    assert "catalog models only" in custom.stderr
    missing = run_armtwin("fmu", "build", "--out", out, "--library", tmp_path / "nope.so")
    assert missing.returncode != 0 and "nope.so: no such file" in missing.stderr


def test_build_without_the_library_says_how_to_build_it(tmp_path):
    # An armtwin executable alone in a folder: no libarmtwin_fmu.so beside it.
    lonely = tmp_path / "armtwin"
    try:
        os.link(armtwin_path(), lonely)
    except OSError:
        shutil.copy2(armtwin_path(), lonely)
    res = subprocess.run([str(lonely), "fmu", "build", "--out", str(tmp_path / "x.fmu")],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode != 0
    assert "cargo build --release -p armtwin-fmu" in res.stderr
    assert str(tmp_path) in res.stderr
