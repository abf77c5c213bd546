#!/usr/bin/env python3
"""Which residual-model terms pay on a real UR recording's currents (docs/load-twin.md quotes it).

Reads an RTDE recording in ur_rtde's CSV form with actual/target current, target_moment and
actual_qd (default: tests/data/ur3e_rad_program.csv) and prints, per joint, the RMS (N·m) of:
- currents × K_τ·101 − target_moment (the controller's model; armtwin's own matches it to
  ≤ 0.01 N·m RMS on this recording, `armtwin validate --dynamics`);
- that less friction fitted by non-negative least squares: Coulomb + viscous alike in both
  directions; then per direction with a Stribeck term (velocity scale 0.1 rad/s);
- measured − target current; with a per-joint gain on the target; with the target passed through
  a first-order lag of 10, 20, 40 ms (the drive's own dynamics).
Fits use the whole recording (an optimistic bound on what each term can give).

Usage: tools/load_twin_terms.py [RECORDING] [--model ur3e]   (numpy, scipy)
"""

import argparse
import csv

import numpy as np
from scipy.optimize import nnls

# K_τ · 101 per joint (N·m/A) from the e-Series joint sizes (docs: research/dynamics.md).
SIZE_FACTOR = {0: 0.035685, 1: 0.07695, 2: 0.10756, 3: 0.098322, 4: 0.11968}
SIZES = {"ur3e": (2, 2, 1, 0, 0, 0), "ur5e": (3, 3, 3, 1, 1, 1), "ur10e": (4, 4, 3, 2, 2, 2),
         "ur16e": (4, 4, 3, 2, 2, 2)}
MOVING_RAD_S = 0.05
STRIBECK_RAD_S = 0.1


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("recording", nargs="?", default="tests/data/ur3e_rad_program.csv")
    parser.add_argument("--model", default="ur3e")
    args = parser.parse_args()
    rows = list(csv.DictReader(open(args.recording)))
    group = lambda name: np.array([[float(r[f"{name}_{k}"]) for k in range(6)] for r in rows])
    current, target_current = group("actual_current"), group("target_current")
    moment, qd = group("target_moment"), group("actual_qd")
    stamps = np.array([float(r["timestamp"]) for r in rows])
    factor = np.array([SIZE_FACTOR[s] * 101 for s in SIZES[args.model]])
    rms = lambda e: " ".join(f"{v:6.3f}" for v in np.sqrt((e ** 2).mean(axis=0)))

    model = current * factor - moment
    alike, per_direction = model.copy(), model.copy()
    for k in range(6):
        v, sign = qd[:, k], np.sign(qd[:, k])
        moving = np.abs(v) > MOVING_RAD_S
        basis = np.c_[sign, v][moving]
        alike[moving, k] -= basis @ nnls(basis, model[moving, k])[0]
        for direction in (1, -1):
            chosen = moving & (sign == direction)
            if chosen.sum() < 10:
                continue
            speed = np.abs(v[chosen])
            basis = np.c_[np.ones_like(speed), speed, np.exp(-speed / STRIBECK_RAD_S)]
            per_direction[chosen, k] -= direction * (basis @ nnls(basis, direction * model[chosen, k])[0])
    print(f"{args.recording}: {len(rows)} rows; RMS per joint 1-6 (N·m)")
    print(f"  currents − target_moment                     {rms(model)}")
    print(f"  … − friction (Coulomb + viscous, NNLS)       {rms(alike)}")
    print(f"  … − friction per direction with Stribeck     {rms(per_direction)}")
    drive = (current - target_current) * factor
    print(f"  currents − target current                    {rms(drive)}")
    gain = (target_current * current).sum(axis=0) / (target_current ** 2).sum(axis=0)
    print(f"  … with a gain per joint ({' '.join(f'{g:.3f}' for g in gain)})   "
          f"{rms((current - gain * target_current) * factor)}")
    dt = np.median(np.diff(stamps))
    for lag_s in (0.01, 0.02, 0.04):
        follow = dt / (lag_s + dt)
        lagged = target_current.copy()
        for i in range(1, len(lagged)):
            lagged[i] = lagged[i - 1] + follow * (target_current[i] - lagged[i - 1])
        print(f"  … target through a {lag_s * 1000:.0f}-ms lag                  "
              f"{rms((current - lagged) * factor)}")


if __name__ == "__main__":
    main()
