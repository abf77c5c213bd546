"""armtwin must fail (non-zero exit) with a useful stderr message on bad input."""

from __future__ import annotations

import re

import pytest

from support import ur_reference as ur
from support.process import run_armtwin

GOOD_CAL = ur.Calibration(
    delta_theta=[1.2e-06, 0.31, -0.55, 0.24, -3.1e-06, 2.0e-06],
    delta_a=[2.5e-05, -0.0045, 0.0025, 8.6e-05, 5.9e-05, 0.0],
    delta_d=[0.00013, 154.6, -219.5, 64.9, -6.5e-05, 0.0002],
    delta_alpha=[-0.00022, 0.0005, 0.0024, 0.00056, 0.00054, 0.0],
)

Q_OK = ["0.1", "-0.2", "0.3", "-0.4", "0.7", "-0.8"]


def standalone(number, text):
    """True if ``number`` appears in ``text`` as a number of its own (not inside 0.6, -6.5e-05, pytest-6...)."""
    return re.search(rf"(?<![\w.\-]){number}(?![\w.])", text) is not None


def fails(res, *needles, any_of=None):
    """Assert non-zero exit and that stderr contains every needle (case-insensitive)."""
    assert res.returncode != 0, f"expected failure, got exit 0\nstdout:\n{res.stdout[:2000]}"
    assert res.returncode > 0, f"armtwin was killed by a signal ({res.returncode}):\n{res.stderr}"
    err = res.stderr.lower()
    assert err.strip(), "stderr is empty"
    assert "panicked" not in err, f"armtwin panicked instead of reporting an error:\n{res.stderr}"
    for needle in needles:
        assert str(needle).lower() in err, f"stderr does not mention {needle!r}:\n{res.stderr}"
    if any_of:
        assert any(str(n).lower() in err for n in any_of), (
            f"stderr mentions none of {any_of!r}:\n{res.stderr}"
        )
    return res


def test_ok_baseline():
    """Sanity: the valid command used as a base below succeeds."""
    res = run_armtwin("fk", "--model", "ur5", "--", *Q_OK)
    assert res.returncode == 0, res.stderr


def test_wrong_joint_count():
    res = fails(run_armtwin("fk", "--model", "ur5", "--", "0.1", "-0.2", "0.3", "-0.4", "0.7"))
    assert standalone(6, res.stderr), f"stderr should mention the expected count 6:\n{res.stderr}"
    assert standalone(5, res.stderr), f"stderr should mention the given count 5:\n{res.stderr}"


def test_too_many_joints():
    res = fails(run_armtwin("fk", "--model", "ur5", "--", *Q_OK, "0.9"))
    assert standalone(6, res.stderr), f"stderr should mention the expected count 6:\n{res.stderr}"


@pytest.mark.parametrize("bad", ["nan", "NaN", "inf", "-inf", "infinity"])
def test_non_finite_angle(bad):
    args = list(Q_OK)
    args[2] = bad
    fails(run_armtwin("fk", "--model", "ur5", "--", *args), any_of=["nan", "inf", "finite"])


def test_non_finite_angle_in_csv():
    text = "time,q1,q2,q3,q4,q5,q6\n0,0.1,0.2,0.3,0.4,0.6,0.7\n1,0.1,nan,0.3,0.4,0.7,0.9\n"
    fails(run_armtwin("fk", "--model", "ur5", "--csv", "-", input=text), any_of=["nan", "finite"])


def test_unknown_model():
    fails(run_armtwin("fk", "--model", "ur99", "--", *Q_OK), "ur99")


def test_non_numeric_angle():
    args = list(Q_OK)
    args[1] = "abc"
    fails(run_armtwin("fk", "--model", "ur5", "--", *args), "abc")


def _conf_text(**overrides):
    text = ur.format_calibration_conf(GOOD_CAL)
    lines = []
    for ln in text.splitlines():
        key = ln.split("=")[0].strip()
        if key in overrides:
            if overrides[key] is None:
                continue
            ln = f"{key} = {overrides[key]}"
        lines.append(ln)
    return "\n".join(lines) + "\n"


def test_good_conf_accepted(tmp_path):
    path = tmp_path / "calibration.conf"
    path.write_text(_conf_text())
    res = run_armtwin("fk", "--model", "ur10e", "--calibration", path, "--", *Q_OK)
    assert res.returncode == 0, res.stderr


def test_conf_list_of_five(tmp_path):
    path = tmp_path / "calibration.conf"
    path.write_text(_conf_text(delta_d="[ 0.00013, 154.6, -219.5, 64.9, -6.5e-05 ]"))
    res = fails(run_armtwin("fk", "--model", "ur10e", "--calibration", path, "--", *Q_OK), str(path), "delta_d")
    assert standalone(6, res.stderr.replace(str(path), "")), f"stderr should mention 6 values:\n{res.stderr}"


def test_conf_missing_delta_alpha(tmp_path):
    path = tmp_path / "calibration.conf"
    path.write_text(_conf_text(delta_alpha=None))
    fails(run_armtwin("fk", "--model", "ur10e", "--calibration", path, "--", *Q_OK), str(path), "delta_alpha")


def test_conf_non_numeric_value(tmp_path):
    path = tmp_path / "calibration.conf"
    path.write_text(_conf_text(delta_a="[ 2.5e-05, -0.0045, oops, 8.6e-05, 5.9e-05, 0 ]"))
    fails(
        run_armtwin("fk", "--model", "ur10e", "--calibration", path, "--", *Q_OK),
        str(path),
        any_of=["delta_a", "oops"],
    )


def test_missing_calibration_file(tmp_path):
    path = tmp_path / "does_not_exist.conf"
    fails(run_armtwin("fk", "--model", "ur10e", "--calibration", path, "--", *Q_OK), str(path))


def _yaml_text(drop=None):
    origins = ur.calibration_to_urdf_origins("ur10e", GOOD_CAL)
    text = ur.format_calibration_yaml(origins)
    if drop is None:
        return text
    out, skipping = [], False
    for ln in text.splitlines():
        if ln.startswith("  ") and not ln.startswith("    "):
            skipping = ln.strip() == f"{drop}:"
        if not skipping:
            out.append(ln)
    return "\n".join(out) + "\n"


def test_good_yaml_accepted(tmp_path):
    path = tmp_path / "calibration.yaml"
    path.write_text(_yaml_text())
    res = run_armtwin("fk", "--model", "ur10e", "--calibration", path, "--", *Q_OK)
    assert res.returncode == 0, res.stderr


def test_yaml_missing_wrist_2(tmp_path):
    path = tmp_path / "calibration.yaml"
    text = _yaml_text(drop="wrist_2")
    assert "wrist_2" not in text and "wrist_3" in text
    path.write_text(text)
    fails(run_armtwin("fk", "--model", "ur10e", "--calibration", path, "--", *Q_OK), str(path), "wrist_2")


@pytest.mark.parametrize("tcp", ["0,0,0.1,0,0", "0,0,0.1,0,0,x"], ids=["five", "non-numeric"])
def test_malformed_tcp(tcp):
    fails(run_armtwin("fk", "--model", "ur5", f"--tcp={tcp}", "--", *Q_OK), "tcp")


def test_unknown_frame():
    fails(run_armtwin("fk", "--model", "ur5", "--frame", "world", "--", *Q_OK), "world")


CSV_BAD = (
    "time,q1,q2,q3,q4,q5,q6\n"        # line 1
    "0,0.1,0.2,0.3,0.4,0.7,0.9\n"     # line 2
    "1,0.1,0.2,0.3,0.4,0.7,0.9\n"     # line 3
    "2,0.1,0.2,0.3,0.4,0.7,0.9\n"     # line 4
    "3,0.1,0.2,0.3,0.4,0.7,0.9\n"     # line 5
    "4,0.1,0.2,0.3,0.4,0.7,0.9\n"     # line 6
    "6,0.1,0.2,0.3,0.4,0.7,0.9\n"     # line 7
    "7,0.1,0.2,zz,0.4,0.7,0.9\n"      # line 8  <- bad
    "8,0.1,0.2,0.3,0.4,0.7,0.9\n"     # line 9
)


def _mentions_line_8(stderr):
    err = stderr.lower()
    return re.search(r"line\D{0,5}8(?![\w.])", err) is not None or ":8:" in err


def test_csv_non_numeric_stdin():
    res = fails(run_armtwin("fk", "--model", "ur5", "--csv", "-", input=CSV_BAD))
    assert _mentions_line_8(res.stderr), f"stderr should name line 8:\n{res.stderr}"


def test_csv_non_numeric_file(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text(CSV_BAD)
    res = fails(run_armtwin("fk", "--model", "ur5", "--csv", path))
    assert _mentions_line_8(res.stderr), f"stderr should name line 8:\n{res.stderr}"


def test_csv_missing_joint_column():
    text = "time,q1,q2,q3,q4,q5\n0,0.1,0.2,0.3,0.4,0.7\n"
    fails(run_armtwin("fk", "--model", "ur5", "--csv", "-", input=text), "q6")
