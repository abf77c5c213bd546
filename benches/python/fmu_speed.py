"""How many co-simulation steps per second FMPy achieves driving armtwin's FMU.

Usage: python benches/python/fmu_speed.py [FMU]
Without FMU, builds one with `$ARMTWIN_BIN fmu build --model ur10e` (default
target/release/armtwin) into a temporary folder. Input: the real UR10e recording
tests/data/ur10e_lasttest.csv (29 061 joint samples), one step per sample at 500 Hz.
Prints steps per second for (1) fmpy.simulate_fmu with the recording as input signal and
(2) a bare FMU2Slave loop (setReal of 6 joints, doStep, getReal of 10 outputs per step).
Not a test: it asserts nothing about time.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from fmpy import extract, read_model_description, simulate_fmu
from fmpy.fmi2 import FMU2Slave

REPO_ROOT = Path(__file__).resolve().parents[2]
STEP_S = 0.002
JOINT_COLUMNS = [f"{joint}_joint.position" for joint in
                 ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")]
OUTPUTS = ["x", "y", "z", "roll", "pitch", "yaw", "qx", "qy", "qz", "qw"]


def recording() -> np.ndarray:
    with warnings.catch_warnings():
        # The recording's 7 corrupted rows (tests/data/README.md) are skipped, not reported.
        warnings.simplefilter("ignore")
        data = np.genfromtxt(REPO_ROOT / "tests" / "data" / "ur10e_lasttest.csv", delimiter=",",
                             names=True, invalid_raise=False, deletechars="")
    q = np.stack([data[name] for name in JOINT_COLUMNS], axis=1)
    return q[np.all(np.isfinite(q), axis=1)]


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        if len(sys.argv) > 1:
            fmu = sys.argv[1]
        else:
            armtwin = os.environ.get("ARMTWIN_BIN", str(REPO_ROOT / "target" / "release" / "armtwin"))
            fmu = str(Path(tmp) / "UR10e_FK.fmu")
            subprocess.run([armtwin, "fmu", "build", "--model", "ur10e", "--out", fmu], check=True)
        q = recording()
        n = len(q)
        signal = np.zeros(n, dtype=[("time", float)] + [(f"q{i}", float) for i in range(1, 7)])
        signal["time"] = np.arange(n) * STEP_S
        for i in range(6):
            signal[f"q{i + 1}"] = q[:, i]

        start = time.perf_counter()
        result = simulate_fmu(fmu, start_time=0.0, stop_time=n * STEP_S, step_size=STEP_S,
                              output_interval=STEP_S, input=signal, output=OUTPUTS)
        elapsed = time.perf_counter() - start
        print(f"simulate_fmu: {len(result) - 1} steps in {elapsed:.2f} s = "
              f"{(len(result) - 1) / elapsed:,.0f} steps/s (includes unpacking and instantiation)")

        unzipped = extract(fmu)
        md = read_model_description(unzipped)
        slave = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                          modelIdentifier=md.coSimulation.modelIdentifier, instanceName="speed")
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        joints, outputs = list(range(6)), list(range(6, 16))
        rows = q.tolist()
        start = time.perf_counter()
        for k, row in enumerate(rows):
            slave.setReal(joints, row)
            slave.doStep(k * STEP_S, STEP_S)
            slave.getReal(outputs)
        elapsed = time.perf_counter() - start
        print(f"FMU2Slave loop (setReal 6, doStep, getReal 10): {n} steps in {elapsed:.2f} s = "
              f"{n / elapsed:,.0f} steps/s")
        slave.terminate()
        slave.freeInstance()


if __name__ == "__main__":
    main()
