"""``armtwin doctor`` finds each fault planted in a configuration, and passes docs/ur-rtde.md's
plant.toml against three stand-in controllers: a controller's port closed, a controller whose
dashboard server says another model, a robot without its calibration, a recorder folder that
cannot be written, and a Zenoh listener open to the network without access control. One line per
check, ``OK``, ``WARN`` or ``FAIL``; exit 1 on a failure.

The stand-ins (rtde_server.py) answer the dashboard server's commands as a UR controller's does
(checked by ur-rtde's ``DashboardClient`` in test_rtde_controller.py). Nothing is bound beyond
loopback: doctor reads the listener's address from the configuration, it does not open it.
"""

from __future__ import annotations

import re

import pytest

from support import rtde_recording
from support.dashboard import DashboardService, Prometheus
from support.paths import DATA_DIR, REPO_ROOT
from support.process import free_port, run_armtwin, wait_until
from support.rtde_processes import StandIn, doc_plant

CALIBRATION = REPO_ROOT / "config" / "examples" / "calibration.conf"
RULES = REPO_ROOT / "config" / "prometheus" / "alerts.yml"


@pytest.fixture
def recording(tmp_path):
    rows = rtde_recording.rtde_rows(DATA_DIR / "ur10e_lasttest.csv", limit=200)
    return rtde_recording.write(rows, tmp_path / "rows.csv")


@pytest.fixture
def stand_ins(tmp_path, recording):
    started = []

    def start(model: str = "UR10") -> StandIn:
        stand_in = StandIn(recording, "--dashboard-port", 0, "--model", model, workdir=tmp_path)
        started.append(stand_in)
        return stand_in

    yield start
    for stand_in in started:
        stand_in.stop()


def doctor(tmp_path, config_text: str):
    config = tmp_path / "plant.toml"
    config.write_text(config_text)
    result = run_armtwin("doctor", "-c", config)
    lines = result.stdout.splitlines()
    return result.returncode, lines, result


def line_of(lines: list[str], check: str) -> list[str]:
    return [line for line in lines if line.split(" ", 1)[1].lstrip().startswith(check + ":")]


def test_the_guides_plant_passes(tmp_path, stand_ins):
    robots = ["cell-1/ur10e", "cell-2/ur10e", "cell-3/ur10e"]
    started = {robot: stand_ins() for robot in robots}
    plant = doc_plant({robot: (s.ports[0], s.dashboard_ports[0]) for robot, s in started.items()})
    code, lines, result = doctor(tmp_path, plant)
    assert code == 0, result.stdout + result.stderr
    for robot in robots:
        [controller_ok] = [line for line in line_of(lines, f"controller of {robot}") if "dashboard" in line]
        assert controller_ok.startswith("OK ") and "a ur10e, as configured" in controller_ok, controller_ok
        [port_ok] = [line for line in line_of(lines, f"controller of {robot}") if "RTDE at" in line]
        assert port_ok.startswith("OK ") and "streams (controller software 5.21.0.9, protocol 2)" in port_ok, port_ok
        # The nominal twin against the controller's own pose: measured, in mm.
        [twin] = line_of(lines, f"twin of {robot}")
        assert re.search(r"\d+\.\d\d mm from the controller's own TCP pose", twin), twin
        # No calibration in the guide's file: said, not failed.
        [robot_line] = line_of(lines, f"robot {robot}")
        assert robot_line.startswith("WARN") and "without a calibration" in robot_line, robot_line
        assert line_of(lines, f"robot {robot} tool") == [f"OK   robot {robot} tool: its controller's (RTDE tcp_offset)"]
    assert not [line for line in lines if line.startswith("FAIL")], result.stdout
    [listen] = [line for line in lines if "zenoh listen" in line]
    assert listen.startswith("OK ") and "this host only" in listen, listen


def test_each_planted_fault_is_found(tmp_path, stand_ins):
    healthy, other_model = stand_ins("UR10"), stand_ins("UR5")
    closed_port, closed_dashboard = free_port(), free_port()
    not_a_folder = tmp_path / "a-file"
    not_a_folder.write_text("")
    config = f"""\
[zenoh]
listen = ["tcp/0.0.0.0:{free_port()}"]

[recorder]
dir = "{not_a_folder}/recordings"

[robots.default]
model = "ur10e"

[robots."cell-1/ur10e"]
calibration = "{CALIBRATION}"
rtde = "127.0.0.1:{healthy.ports[0]}"
rtde_dashboard_port = {healthy.dashboard_ports[0]}

[robots."cell-2/ur10e"]
rtde = "127.0.0.1:{other_model.ports[0]}"
rtde_dashboard_port = {other_model.dashboard_ports[0]}

[robots."cell-3/ur10e"]
tcp = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0]
rtde = "127.0.0.1:{closed_port}"
rtde_dashboard_port = {closed_dashboard}
"""
    code, lines, result = doctor(tmp_path, config)
    assert code == 1, result.stdout + result.stderr
    failed = [line for line in lines if line.startswith("FAIL")]

    # A reachable arm, the model it says, with a calibration...
    assert line_of(lines, "robot cell-1/ur10e") == ["OK   robot cell-1/ur10e: ur10e with its calibration"]
    cell_1 = line_of(lines, "controller of cell-1/ur10e")
    assert [line for line in cell_1 if line.startswith("OK ")] == [
        line for line in cell_1 if "RTDE at" in line or "dashboard server" in line], "\n".join(lines)
    # ... that is not this arm's (the synthetic example file): the twin measured
    # against the controller's own pose says so; the recorded arm's nominal model does not.
    [wrong] = line_of(lines, "twin of cell-1/ur10e")
    assert wrong.startswith("WARN") and "above the 5.0-mm alarm" in wrong, wrong
    [nominal] = line_of(lines, "twin of cell-2/ur10e")
    assert nominal.startswith("OK ") and "(alarm at 5.0 mm)" in nominal, nominal
    # A controller that is another arm, in its own words.
    [mismatch] = [line for line in failed if line.startswith("FAIL controller of cell-2/ur10e")]
    assert "'UR5'" in mismatch and "a ur5e, the configuration says ur10e" in mismatch, mismatch
    # A missing calibration, said for the robots without one.
    assert line_of(lines, "robot cell-2/ur10e")[0].startswith("WARN"), lines
    # A closed port: RTDE's and the dashboard server's.
    closed = [line for line in failed if line.startswith("FAIL controller of cell-3/ur10e")]
    assert any(f"RTDE at 127.0.0.1:{closed_port}: cannot connect" in line for line in closed), closed
    assert any("dashboard server" in line for line in closed), closed
    assert line_of(lines, "robot cell-3/ur10e tool") == ["OK   robot cell-3/ur10e tool: the configuration's tcp"]
    # A recorder folder that cannot be made.
    [recorder] = line_of(lines, "recorder")
    assert recorder.startswith("FAIL") and "cannot be written" in recorder, recorder
    # A door open to the network.
    [listen] = [line for line in lines if "zenoh listen tcp/0.0.0.0" in line]
    assert listen.startswith("FAIL") and "anyone on the network" in listen, listen
    assert lines[-1] == f"{len(failed)} failed, {sum(line.startswith('WARN') for line in lines)} to look at", lines


def test_a_configuration_that_does_not_load_fails_alone(tmp_path):
    code, lines, result = doctor(tmp_path, '[robots."cell-1/ur10e"]\nrtde = "10.0.0.5:0"\n')
    # The address is checked where the controller is: doctor says it, the rest goes on.
    assert code == 1, result.stdout
    assert any(line.startswith("FAIL controller of cell-1/ur10e") and "not a controller's address" in line
               for line in lines), lines
    code, lines, result = doctor(tmp_path, "[service]\nno_such_key = 1\n")
    assert code == 1 and lines[0].startswith("FAIL configuration:"), result.stdout


@pytest.mark.parametrize("job, rules", [("armtwin", True), ("robots", False)])
def test_a_prometheus_is_asked_for_its_job_and_rules(armtwin_bin, tmp_path, job, rules):
    """A real Prometheus scraping a real service: doctor finds the job that scrapes its /metrics
    and says when its name is not the one ArmtwinDown reads, and which shipped rules it lacks."""
    config = tmp_path / "site.toml"
    service = DashboardService(armtwin_bin, tmp_path, '[robots.default]\nmodel = "ur10e"\n')
    # Scraped every 5 s: a loaded machine's debug build answering /metrics in over a second would
    # be a target down, which doctor rightly fails.
    with service, Prometheus(tmp_path, f"127.0.0.1:{service.http_port}", job=job,
                             rule_files=[RULES] if rules else [], interval_s=5) as prometheus:
        config.write_text(f'[http]\nlisten = "127.0.0.1:{service.http_port}"\n')
        assert wait_until(lambda: prometheus.value(f'up{{job="{job}"}}') == 1.0, 30.0, 0.5)
        result = run_armtwin("doctor", "-c", config, "--prometheus", f"http://127.0.0.1:{prometheus.port}")
        lines = [line for line in result.stdout.splitlines() if "prometheus http://" in line]
        assert result.returncode == 0, (result.stdout + result.stderr, prometheus.logs())
        [scraped] = [line for line in lines if "scrapes" in line]
        [held] = [line for line in lines if "alerting rules" in line]
        every = len(re.findall(r"^\s+- alert: ", RULES.read_text(), re.M))
        if rules:
            assert scraped.startswith("OK ") and f"job 'armtwin' scrapes http://127.0.0.1:{service.http_port}/metrics" in scraped
            assert held.startswith("OK ") and f"holds armtwin's {every} alerting rules" in held, held
        else:
            assert scraped.startswith("WARN") and "job 'robots'" in scraped and 'up{job="armtwin"}' in scraped
            assert held.startswith("WARN") and f"lacks {every} of armtwin's {every}" in held, held
    # A Prometheus that is not there is a failure of its own.
    gone = run_armtwin("doctor", "-c", config, "--prometheus", f"http://127.0.0.1:{free_port()}")
    assert gone.returncode == 1 and "cannot read its targets" in gone.stdout, gone.stdout
