"""Alerts out of the box: config/prometheus/alerts.yml passes ``promtool check rules`` and its unit
tests (``promtool test rules``), config/prometheus.yml loads it, and the per-robot gauges the rules
read follow a real ``armtwin gateway rtde`` on a real service's ``/metrics``: waiting for its
controller → ``armtwin_gateway_streaming`` 0, and the robot, named in the configuration, is
``armtwin_robot_expected`` with no sample age (what ``ArmtwinRobotNotSeen`` reads); streaming → 1 and ``armtwin_robot_last_sample_age_seconds``
small; stopped → 0 and the age grows. Every metric the rules name is one that ``/metrics`` exposes.

promtool is the one beside the Prometheus scripts/test-tools.sh unpacks.
"""

from __future__ import annotations

import re
import subprocess
import sys
import time

from support import rtde_recording
from support.dashboard import DashboardService, exposed_names, http_get, prometheus_path
from support.paths import DATA_DIR, REPO_ROOT, SUPPORT_DIR
from support.process import Process, free_port, wait_until

RULES = REPO_ROOT / "config" / "prometheus" / "alerts.yml"
RULE_TESTS = REPO_ROOT / "config" / "prometheus" / "alerts_test.yml"
ROBOT = "cell-1/ur10e"
# Effort watched: the collision and payload gauges the rules read exist. The robot is named:
# expected from the start.
CONFIG = f"""\
[robots.default]
model = "ur10e"
effort = true

[robots."{ROBOT}"]
"""
TIMEOUT_S = 60.0


def promtool(*args) -> subprocess.CompletedProcess:
    tool = prometheus_path().with_name("promtool")
    return subprocess.run([str(tool), *map(str, args)], capture_output=True, text=True, timeout=60)


def test_the_rules_pass_promtool_and_their_unit_tests():
    every_alert = set(re.findall(r"^\s+- alert: (\w+)$", RULES.read_text(), re.M))
    checked = promtool("check", "rules", RULES)
    assert checked.returncode == 0, checked.stdout + checked.stderr
    assert f"SUCCESS: {len(every_alert)} rules found" in checked.stdout, checked.stdout
    tested = promtool("test", "rules", RULE_TESTS)
    assert tested.returncode == 0, tested.stdout + tested.stderr
    # The shipped scrape configuration loads the rules.
    config = promtool("check", "config", REPO_ROOT / "config" / "prometheus.yml")
    assert config.returncode == 0, config.stdout + config.stderr
    assert "1 rule files found" in config.stdout, config.stdout
    assert every_alert == set(re.findall(r"alertname: (\w+)$", RULE_TESTS.read_text(), re.M)), (
        "an alert without a unit test")


def gauge(exposition: str, name: str) -> float | None:
    found = re.search(rf'^{name}\{{robot="{re.escape(ROBOT)}"\}} (\S+)$', exposition, re.M)
    return float(found.group(1)) if found else None


class StandIn(Process):
    """rtde_server.py serving the UR10e recording at 500 Hz on ``port``."""

    def __init__(self, workdir, port: int):
        recording = rtde_recording.write(rtde_recording.rtde_rows(DATA_DIR / "ur10e_lasttest.csv"),
                                         workdir / "rows.csv")
        argv = [sys.executable, SUPPORT_DIR / "rtde_server.py", "--recording", recording, "--port", port]
        super().__init__("rtde_server", argv, workdir)


def test_the_gauges_follow_a_real_gateway(armtwin_bin, tmp_path):
    controller_port = free_port()
    with DashboardService(armtwin_bin, tmp_path, CONFIG) as service:
        def metrics() -> str:
            status, body = http_get(service.url("/metrics"))
            assert status == 200, body
            return body.decode()

        gateway = Process("gateway", [armtwin_bin, "gateway", "rtde", "-e", service.proc.endpoint,
                                      "--host", "127.0.0.1", "--port", controller_port, "--robot", ROBOT],
                          tmp_path)
        stand_in = StandIn(tmp_path, controller_port)
        try:
            gateway.start()
            # No controller yet: the gateway waits, and the robot is expected but not tracked.
            assert wait_until(lambda: gauge(metrics(), "armtwin_gateway_streaming") == 0.0, TIMEOUT_S, 0.1), (
                metrics(), gateway.logs())
            assert gauge(metrics(), "armtwin_robot_last_sample_age_seconds") is None
            assert gauge(metrics(), "armtwin_robot_expected") == 1.0, metrics()

            stand_in.start()
            assert wait_until(lambda: gauge(metrics(), "armtwin_gateway_streaming") == 1.0, TIMEOUT_S, 0.1), (
                metrics(), gateway.logs(), stand_in.logs())
            assert wait_until(
                lambda: (gauge(metrics(), "armtwin_robot_last_sample_age_seconds") or 99.0) < 0.5, TIMEOUT_S, 0.05
            ), metrics()
            # One bad input: `armtwin_rejected_total` has a series once a robot has a rejection.
            service.client.joints(ROBOT).put("{not json")
            assert wait_until(lambda: "armtwin_rejected_total{" in metrics(), 15.0, 0.05), metrics()
            exposition = metrics()
            used = set(re.findall(r"\b(armtwin_[a-z_]+|up)\b", RULES.read_text())) - {"armtwin"}
            assert used - {"up"} <= exposed_names(exposition), sorted(used - exposed_names(exposition))

            assert gateway.stop().code == 0, gateway.logs()
            assert wait_until(lambda: gauge(metrics(), "armtwin_gateway_streaming") == 0.0, 15.0, 0.05), metrics()
            first = gauge(metrics(), "armtwin_robot_last_sample_age_seconds")
            time.sleep(1.5)
            later = gauge(metrics(), "armtwin_robot_last_sample_age_seconds")
            assert first is not None and later is not None and later - first >= 1.4, (first, later)
        finally:
            gateway.stop()
            stand_in.stop()
