"""``armtwin validate --dynamics`` on a real UR3e's currents (tests/data/ur3e_rad_program.csv, RTDE at
25 Hz, normal program motion, 1.07 kg configured): the payload it identifies is physical and within
0.3 kg of the configured one, or it says the motion does not identify one; measured less target
current leaves far less than measured less the model.
"""

from __future__ import annotations

import json
import subprocess

from support.paths import DATA_DIR, armtwin_path

CONFIGURED_KG = 1.07


def test_validate_dynamics_on_real_currents(tmp_path):
    out = tmp_path / "report"
    res = subprocess.run([str(armtwin_path()), "validate", str(DATA_DIR / "ur3e_rad_program.csv"),
                          "--model", "ur3e", "--dynamics", "--out", str(out)],
                         capture_output=True, text=True, timeout=120, check=False)
    assert res.returncode == 0, res.stderr
    print(res.stderr)
    dynamics = json.loads((out / "report.json").read_text())["dynamics"]
    assert dynamics["state"] == "target" and dynamics["rows"] == 888
    payload = dynamics["payload"]
    assert payload["configured"]["mass_kg"] == CONFIGURED_KG
    identified = payload["identified"]
    if identified is None:
        assert payload["not_identifiable"] in ("too_few_poses", "poses_alike", "unphysical")
    else:
        assert payload["not_identifiable"] is None
        assert 0.0 <= identified["mass_kg"] and abs(identified["mass_kg"] - CONFIGURED_KG) <= 0.3, identified
    model = dynamics["model_vs_currents"]["rms_nm"]
    target = dynamics["currents_vs_target_current"]["rms_nm"]
    # Joints 1–4 move most: the controller's target current explains most of what our model
    # (without friction) leaves.
    assert all(target[k] < 0.5 * model[k] for k in range(4)), (model, target)
    assert "currents − target current" in (out / "report.md").read_text()
