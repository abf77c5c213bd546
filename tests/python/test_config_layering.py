"""A configuration file is layered over the built-in one: a file holding only a robot's section
serves where the built-in configuration says (tcp/127.0.0.1:7447) and a client there gets the
robot's poses; `armtwin config show` prints the effective configuration, every default filled in;
`serve` warns when nothing can reach it."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from support.paths import REPO_ROOT
from support.process import Process, port_accepts, run_armtwin
from support.zenoh_clients import TwinClient

DEFAULT_PORT = 7447
ROBOTS_ONLY = '[robots."r1"]\nmodel = "ur5e"\n'
Q = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]


def show(config: Path | None = None) -> dict:
    args = ["config", "show"] + (["-c", str(config)] if config else [])
    result = run_armtwin(*args)
    assert result.returncode == 0, result.stderr
    return tomllib.loads(result.stdout)


def test_config_show_fills_every_default_and_completes_each_robot(tmp_path):
    builtin = tomllib.loads((REPO_ROOT / "config" / "armtwin.toml").read_text())
    assert show() == builtin
    config = tmp_path / "armtwin.toml"
    config.write_text(ROBOTS_ONLY + "[align]\nmax_gap_s = 0.1\n")
    effective = show(config)
    assert effective["zenoh"] == builtin["zenoh"]
    assert effective["align"] == {**builtin["align"], "max_gap_s": 0.1}
    assert effective["robots"]["default"] == builtin["robots"]["default"]
    # r1 keeps its own model and takes every other key from [robots.default].
    assert effective["robots"]["r1"] == {**builtin["robots"]["default"], "model": "ur5e"}
    # What it prints is itself a configuration with the same effect.
    again = tmp_path / "again.toml"
    again.write_text(run_armtwin("config", "show", "-c", config).stdout)
    assert show(again) == effective


def test_config_show_refuses_a_bad_file_naming_the_field(tmp_path):
    config = tmp_path / "armtwin.toml"
    config.write_text('[service]\nwindow_s = -1.0\n')
    result = run_armtwin("config", "show", "-c", config)
    assert result.returncode != 0
    assert "service.window_s" in result.stderr and str(config) in result.stderr


def test_a_file_with_only_a_robot_serves_on_the_default_endpoint(tmp_path, armtwin_bin, processes):
    if port_accepts(DEFAULT_PORT):
        pytest.skip(f"127.0.0.1:{DEFAULT_PORT}, the built-in endpoint under test, is taken by another process")
    config = tmp_path / "armtwin.toml"
    config.write_text(ROBOTS_ONLY)
    serve = Process("armtwin", [armtwin_bin, "serve", "-c", config], tmp_path,
                    {"RUST_LOG": "armtwin=info"})
    processes.append(serve.start())
    serve.wait_port(DEFAULT_PORT, f"listen on the built-in endpoint 127.0.0.1:{DEFAULT_PORT}")
    assert "listening nowhere" not in serve.logs()
    client = TwinClient(f"tcp/127.0.0.1:{DEFAULT_PORT}")
    try:
        client.ready(["r1"])
        joints = client.joints("r1")
        for seq in range(20):
            client.put_json(joints, {"t": 1.0 + seq * 0.01, "q": Q, "seq": seq})
        assert client.collector.wait_count("pose", "r1", 20, timeout=10), serve.logs()
        pose = client.collector.last("pose", "r1")
        # The robot's own section applies: a UR5e, not the default UR10e.
        ur5e = run_armtwin("fk", "--model", "ur5e", "--", *map(str, Q))
        assert ur5e.returncode == 0, ur5e.stderr
        expected = json.loads(ur5e.stdout)
        assert [pose[axis] for axis in "xyz"] == pytest.approx(
            [expected[axis] for axis in "xyz"], abs=1e-9)
    finally:
        client.close()


def test_serve_warns_when_nothing_can_reach_it(tmp_path, armtwin_bin, processes):
    config = tmp_path / "armtwin.toml"
    config.write_text('[zenoh]\nmode = "client"\n')
    serve = Process("armtwin", [armtwin_bin, "serve", "-c", config], tmp_path,
                    {"RUST_LOG": "armtwin=info"})
    processes.append(serve.start())
    assert serve.wait_log("listening nowhere and connecting nowhere"), serve.logs()
