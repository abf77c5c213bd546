"""armtwin ik checked against an independent numeric solver on the numpy reference FK.

The reference finds solutions by damped least squares (scipy) from many random starts on the
FK of ur_reference.py: it knows nothing of the closed form. Every armtwin solution must
reproduce the target under the reference FK, and every distinct solution the reference finds
must be among armtwin's (so no branch is missed).
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from support import ur_reference as ur
from support.process import run_armtwin

POSES_PER_MODEL = 2
STARTS = 24
FK_TOL = 1e-9
SAME_SOLUTION_RAD = 1e-5


def residual(model, q, target, tcp):
    T = ur.fk(model, q, tcp=tcp)[0]
    dp = T[:3, 3] - target[:3, 3]
    dr = Rotation.from_matrix(target[:3, :3].T @ T[:3, :3]).as_rotvec()
    return np.concatenate([dp, dr])


def reference_solutions(model, target, tcp, rng):
    """Distinct solutions (wrapped to (-pi, pi]) found from random starts."""
    found = []
    for _ in range(STARTS):
        start = rng.uniform(-math.pi, math.pi, 6)
        fit = least_squares(
            lambda q: residual(model, q, target, tcp), start, xtol=1e-15, ftol=1e-15, gtol=1e-15
        )
        if np.linalg.norm(fit.fun) > 1e-10:
            continue
        q = np.array([ur.wrap(v) for v in fit.x])
        if not any(np.all(np.abs([ur.wrap(v) for v in q - other]) < SAME_SOLUTION_RAD) for other in found):
            found.append(q)
    return found


def armtwin_ik(model, target, tcp):
    quat = Rotation.from_matrix(target[:3, :3]).as_quat()  # x, y, z, w
    pose = ",".join(repr(float(v)) for v in (*target[:3, 3], *quat))
    args = ["ik", "--model", model, f"--pose={pose}"]
    if tcp is not None:
        args.append("--tcp=" + ",".join(repr(float(v)) for v in tcp))
    result = run_armtwin(*args)
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


@pytest.mark.parametrize("model", ur.MODEL_NAMES)
def test_ik_matches_an_independent_numeric_solver(model):
    rng = np.random.default_rng(ur.MODEL_NAMES.index(model) + 101)
    tcp = (0.0, 0.01, 0.12, 0.0, 0.0, 0.3)
    checked = 0
    while checked < POSES_PER_MODEL:
        q = rng.uniform(-math.pi, math.pi, 6)
        if abs(math.sin(q[4])) < 0.1 or abs(math.sin(q[2])) < 0.1:
            continue
        checked += 1
        target = ur.fk(model, q, tcp=tcp)[0]
        answer = armtwin_ik(model, target, tcp)
        ours = [np.array(s["q"]) for s in answer["solutions"]]
        assert ours, answer
        for solution in ours:
            assert np.linalg.norm(residual(model, solution, target, tcp)) < FK_TOL
        reference = reference_solutions(model, target, tcp, rng)
        assert reference, "the reference solver found nothing"
        for ref in reference:
            assert any(
                np.all(np.abs([ur.wrap(v) for v in ref - mine]) < SAME_SOLUTION_RAD) for mine in ours
            ), f"{model}: reference solution {ref} missing from armtwin's {ours}"
        assert any(
            np.all(np.abs([ur.wrap(v) for v in q - mine]) < 1e-7) for mine in ours
        ), f"{model}: generating q {q} missing"


def test_unreachable_pose_is_refused():
    result = run_armtwin("ik", "--model", "ur5e", "--pose", "2,0,0,0,0,0,1")
    assert result.returncode != 0
    assert "unreachable" in result.stderr
