"""``armtwin fk --csv`` seen from outside: its input written, its output parsed, and its poses
checked against the numpy reference (ur_reference.py) at the tolerances the tests hold it to."""

from __future__ import annotations

import numpy as np

from support import ur_reference as ur

OUT_HEADER = "time,x,y,z,roll,pitch,yaw,qx,qy,qz,qw"

POS_TOL = 1e-12
QUAT_TOL = 1e-12
ANGLE_TOL = 1e-9
GIMBAL_COS = 1e-6
QW_AMBIGUOUS = 1e-9


def csv_input(q, times=None, header="time,q1,q2,q3,q4,q5,q6"):
    lines = [header]
    for i, row in enumerate(q):
        vals = [repr(float(v)) for v in row]
        if times is not None:
            vals = [repr(float(times[i]))] + vals
        lines.append(",".join(vals))
    return "\n".join(lines) + "\n"


def parse_csv_output(stdout: str):
    lines = [ln for ln in stdout.splitlines() if ln.strip() != ""]
    assert lines, "armtwin printed no CSV"
    assert lines[0].strip() == OUT_HEADER, f"unexpected header {lines[0]!r}"
    rows = []
    for k, ln in enumerate(lines[1:], start=2):
        fields = ln.strip().split(",")
        assert len(fields) == 11, f"output line {k} has {len(fields)} fields: {ln!r}"
        rows.append([float(f) for f in fields])
    return np.array(rows, dtype=float).reshape(-1, 11)


def _describe(i, q, what, got, exp):
    qs = "" if q is None else f" q={np.asarray(q[i]).tolist()}"
    return f"row {i}{qs}: {what} got {got} expected {exp}"


def check_poses(vals, T_ref, q=None, pos_tol=POS_TOL, quat_tol=QUAT_TOL, ang_tol=ANGLE_TOL, ctx=""):
    """vals: (N, 10) columns x, y, z, roll, pitch, yaw, qx, qy, qz, qw."""
    vals = np.asarray(vals, dtype=float).reshape(-1, 10)
    T_ref = np.asarray(T_ref).reshape(-1, 4, 4)
    assert vals.shape[0] == T_ref.shape[0], f"{ctx}: {vals.shape[0]} rows, expected {T_ref.shape[0]}"
    assert np.all(np.isfinite(vals)), f"{ctx}: non-finite output"
    R_ref = T_ref[:, :3, :3]

    # position
    perr = np.abs(vals[:, 0:3] - T_ref[:, :3, 3])
    i = int(np.argmax(perr.max(axis=1)))
    assert perr[i].max() <= pos_tol, ctx + " position " + _describe(
        i, q, f"(max err {perr[i].max():.3e})", vals[i, 0:3].tolist(), T_ref[i, :3, 3].tolist()
    )

    # quaternion (x, y, z, w), canonical w >= 0
    quat = vals[:, 6:10]
    qref = ur.canonical_quat(R_ref)
    bad_sign = np.where((quat[:, 3] < 0) & (np.abs(quat[:, 3]) >= QW_AMBIGUOUS))[0]
    assert bad_sign.size == 0, ctx + " quaternion not canonical (qw < 0) " + _describe(
        int(bad_sign[0]), q, "", quat[bad_sign[0]].tolist(), qref[bad_sign[0]].tolist()
    )
    qerr = np.abs(quat - qref).max(axis=1)
    ambiguous = np.abs(qref[:, 3]) < QW_AMBIGUOUS
    qerr = np.where(ambiguous, np.minimum(qerr, np.abs(quat + qref).max(axis=1)), qerr)
    i = int(np.argmax(qerr))
    assert qerr[i] <= quat_tol, ctx + " quaternion " + _describe(
        i, q, f"(max err {qerr[i]:.3e})", quat[i].tolist(), qref[i].tolist()
    )

    # roll, pitch, yaw
    rpy = vals[:, 3:6]
    cp = ur.cos_pitch(R_ref)
    regular = cp >= GIMBAL_COS
    if np.any(regular):
        ref_rpy = ur.rpy(R_ref[regular])
        aerr = np.abs(ur.wrap(rpy[regular] - ref_rpy)).max(axis=1)
        j = int(np.argmax(aerr))
        i = int(np.flatnonzero(regular)[j])
        assert aerr[j] <= ang_tol, ctx + " roll/pitch/yaw " + _describe(
            i, q, f"(max wrapped err {aerr[j]:.3e})", rpy[i].tolist(), ref_rpy[j].tolist()
        )
    if np.any(~regular):
        idx = np.flatnonzero(~regular)
        R_out = ur.rpy_matrix(rpy[idx, 0], rpy[idx, 1], rpy[idx, 2])
        merr = np.abs(R_out - R_ref[idx]).reshape(len(idx), -1).max(axis=1)
        j = int(np.argmax(merr))
        i = int(idx[j])
        assert merr[j] <= ang_tol, ctx + " gimbal-lock rpy->matrix " + _describe(
            i, q, f"(max err {merr[j]:.3e})", rpy[i].tolist(), R_ref[i].tolist()
        )
