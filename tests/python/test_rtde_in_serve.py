"""Three UR arms in one file: ``serve`` streams each robot whose section names its controller
(``rtde = "HOST:PORT"``) on its own session, with the links of ``armtwin gateway rtde``.

The file is docs/ur-rtde.md's ``plant.toml`` with the addresses of three stand-in controllers,
each with a tool and a serial number of its own, twinned by one process: each twin's tool, serial
and model come from its controller, and its pose is forward kinematics with that tool by an
independent implementation. A controller whose model disagrees with the configuration is said in
an event, in its own words.

No real controller runs here: the stand-in (rtde_server.py) serves rows of the project's UR10e
recording. Every process binds loopback only, ports are picked free, scouting is off, every wait is
bounded.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from support import rtde_recording, ur_reference
from support.paths import DATA_DIR
from support.dashboard import http_get
from support.process import free_port, wait_until
from support.rtde_processes import StandIn, doc_plant, serving
from support.zenoh_clients import get_json

# Each controller's tool (what its pendant's installation sets), serial number and dashboard model.
ARMS = {
    "cell-1/ur10e": ([0.0, 0.0, 0.12, 0.0, 0.0, 0.0], "20235500011", "UR10"),
    "cell-2/ur10e": ([0.01, -0.02, 0.15, 0.1, -0.2, 0.3], "20235500012", "UR10"),
    # An e-Series UR5 under [robots.default]'s ur10e: the robot names no model of its own, so
    # its twin takes the controller's.
    "cell-3/ur10e": ([0.0, 0.05, 0.08, 0.0, 0.3, 0.0], "20235500013", "UR5"),
}
# The model each twin computes with: the one the controller says.
TWINNED = {"cell-1/ur10e": "ur10e", "cell-2/ur10e": "ur10e", "cell-3/ur10e": "ur5e"}
TIMEOUT_S = 30.0


@pytest.fixture
def recordings(tmp_path):
    rows = rtde_recording.rtde_rows(DATA_DIR / "ur10e_lasttest.csv", limit=3000)
    header = list(rtde_recording.HEADER) + [f"tcp_offset_{j}" for j in range(6)]
    return {robot: rtde_recording.write([[*row, *tcp] for row in rows], tmp_path / f"rows-{i}.csv", header)
            for i, (robot, (tcp, _, _)) in enumerate(ARMS.items())}


def test_one_file_twins_three_controllers_with_their_own_tools(armtwin_bin, tmp_path, recordings, processes):
    # The controllers come up after the service: its links wait for them, as for a controller
    # that reboots, and every event they cause is heard.
    ports = {robot: (free_port(), free_port()) for robot in ARMS}
    http_port = free_port()
    plant = doc_plant(ports) + f'\n[http]\nlisten = "127.0.0.1:{http_port}"\n'
    with serving(armtwin_bin, tmp_path, plant) as service:
        def gauges(name: str) -> dict[str, float]:
            status, body = http_get(f"http://127.0.0.1:{http_port}/metrics")
            assert status == 200, body
            return {robot: float(value) for robot, value in
                    re.findall(rf'^{name}{{robot="([^"]+)"}} (\S+)$', body.decode(), re.M)}

        # Before any controller answers: every robot expected, every link waiting.
        assert wait_until(lambda: gauges("armtwin_gateway_streaming") == {r: 0.0 for r in ARMS}, TIMEOUT_S), (
            gauges("armtwin_gateway_streaming"))
        assert gauges("armtwin_robot_expected") == {r: 1.0 for r in ARMS}

        for robot, (tcp, serial, model) in ARMS.items():
            port, dashboard_port = ports[robot]
            processes.append(StandIn(recordings[robot], "--port", port, "--dashboard-port", dashboard_port,
                                     "--model", model, "--serial", serial, workdir=tmp_path, ports=0))

        def state(robot: str) -> dict:
            answers = get_json(service.session, f"twin/state/{robot}", timeout=5.0)
            return answers[0][1] if answers else {}

        def facts_shown(robot: str) -> bool:
            controller = state(robot).get("controller") or {}
            return controller.get("serial") == ARMS[robot][1] and controller.get("tcp_offset") is not None

        assert wait_until(lambda: all(facts_shown(r) for r in ARMS), TIMEOUT_S, 0.1), (
            {r: state(r) for r in ARMS}, service.logs())
        for robot, (tcp, serial, model) in ARMS.items():
            answer = state(robot)
            assert answer["controller"]["tcp_offset"] == tcp, robot
            assert answer["tool"] == pytest.approx(tcp, abs=1e-15), robot
            assert answer["controller"]["model"] == model, robot
            assert answer["model"] == TWINNED[robot], (robot, answer["model"])
            # The twin pose is FK with this controller's TCP, by an independent implementation.
            assert answer["joints"]["t"] == answer["twin"]["t"]
            transform = ur_reference.fk(TWINNED[robot], np.array(answer["joints"]["q"]), tcp=tcp)[0]
            twin = answer["twin"]
            assert [twin["x"], twin["y"], twin["z"]] == pytest.approx(transform[:3, 3], abs=1e-9), robot
            quaternion = ur_reference.canonical_quat(transform[:3, :3])[0]
            assert [twin["qx"], twin["qy"], twin["qz"], twin["qw"]] == pytest.approx(quaternion, abs=1e-9), robot

        assert wait_until(lambda: gauges("armtwin_gateway_streaming") == {r: 1.0 for r in ARMS}, TIMEOUT_S), (
            gauges("armtwin_gateway_streaming"))
        # Each link holds the gateway's streaming token, as `armtwin gateway rtde` does.
        replies = service.session.liveliness().get("twin/gateway/streaming/**", timeout=5.0)
        streaming = sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)
        assert streaming == [f"twin/gateway/streaming/{r}" for r in ARMS], streaming

        model_events = [e for e in service.events
                        if e.get("kind") == "controller" and e["detail"].get("fact") == "model"]
        assert [(e["robot"], e["detail"]) for e in model_events] == [
            ("cell-3/ur10e", {"fact": "model", "configured": "ur10e", "controller": "ur5e",
                              "serial": ARMS["cell-3/ur10e"][1], "in_use": True})
        ], service.events
        assert "the twin computes with ur5e" in model_events[0]["reason"], model_events
        stopped = service.stop()
        assert stopped.code == 0, service.logs()
        assert service.logs(limit=10**9).count("streaming the robot's controller over RTDE") == 3


@pytest.mark.parametrize("section, words", [
    ('[robots.default]\nrtde = "10.0.0.5"\n', "robots.default.rtde"),
    ('[robots."cell-1/ur10e"]\nrtde = "10.0.0.5:99999"\n', "is not a controller's address"),
    ('[robots."cell-1/ur10e"]\nrtde_dashboard_port = 29999\n', 'robots."cell-1/ur10e".rtde'),
])
def test_a_controller_badly_named_stops_the_start(armtwin_bin, tmp_path, section, words):
    from support.process import run_armtwin

    config = tmp_path / "plant.toml"
    config.write_text('[robots.default]\nmodel = "ur10e"\n' + section
                      if "robots.default" not in section else section)
    result = run_armtwin("serve", "-c", config, "-l", "tcp/127.0.0.1:0")
    assert result.returncode != 0, result.stdout + result.stderr
    assert words in result.stderr, result.stderr
