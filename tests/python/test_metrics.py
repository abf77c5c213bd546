"""``/metrics`` scraped by a real Prometheus (Debian's package, unpacked by scripts/test-tools.sh)
while a Python gateway streams the sample UR10e recording: Prometheus' query API returns the
MAE ``get twin/state/<robot>`` answers, bit for bit, and parsed every scrape; ``promtool``
accepts config/prometheus.yml; every query of the Grafana dashboard in config/grafana/ runs in that
Prometheus and names only metrics ``/metrics`` exposes.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_metrics.py -q``
(after ``bash scripts/test-tools.sh``).
"""

from __future__ import annotations

import json
import re
import subprocess

from support.dashboard import DashboardService, Prometheus, exposed_names, http_get, http_json
from support.gateway import Gateway
from support.paths import REPO_ROOT
from support.process import wait_until

CONFIG = """\
[service]
metrics_period_ms = 50

[robots.default]
model = "ur10e"
effort = true
"""
ROBOTS = ("cell-1/ur10e-a", "cell-2/ur10e-b")
ROWS = 4000
DASHBOARD = REPO_ROOT / "config" / "grafana" / "dashboards" / "armtwin.json"


def dashboard_queries() -> list[str]:
    dashboard = json.loads(DASHBOARD.read_text())
    exprs = [target["expr"] for panel in dashboard["panels"] for target in panel["targets"]]
    assert exprs, "the dashboard has no queries"
    return exprs


def test_prometheus_scrapes_the_twin_and_agrees_with_the_state_query(armtwin_bin, tmp_path):
    with DashboardService(armtwin_bin, tmp_path, CONFIG) as service, \
            Prometheus(tmp_path, f"127.0.0.1:{service.http_port}") as prometheus:
        gateway = Gateway(service.client, ROBOTS, rate_hz=250.0, recording=True, rows=ROWS)
        # The token an `armtwin gateway rtde` holds while it streams: the dashboard's gateway panel.
        token = service.client.session.liveliness().declare_token(f"twin/gateway/streaming/{ROBOTS[0]}")
        gateway.start()
        # Scraped while the recording streams.
        assert wait_until(
            lambda: (prometheus.value(f'armtwin_paired_total{{robot="{ROBOTS[0]}"}}') or 0) > 0, 30.0, 0.2
        ), prometheus.logs(2000)
        assert gateway.is_alive(), "the recording ended before the first scrape"
        targets = http_json(f"http://127.0.0.1:{prometheus.port}/api/v1/targets")["data"]["activeTargets"]
        assert [t["health"] for t in targets] == ["up"], targets
        gateway.join(timeout=60)
        # Two bad inputs after the recording: counted by cause.
        service.client.joints(ROBOTS[0]).put("{not json")
        service.client.joints(ROBOTS[0]).put(json.dumps({"t": 5000.0, "q": [0.1, 0.2]}))
        assert wait_until(lambda: service.state(ROBOTS[1])["metrics"]["paired"] == ROWS, 30.0, 0.1)
        assert wait_until(lambda: service.state(ROBOTS[0])["metrics"]["rejected"] == 2, 30.0, 0.1)
        for cause in ("not_json", "joint_count"):
            expr = f'armtwin_rejected_total{{robot="{ROBOTS[0]}",cause="{cause}"}}'
            assert wait_until(lambda: prometheus.value(expr) == 1.0, 20.0, 0.25), (expr, prometheus.value(expr))

        for robot in ROBOTS:
            state = service.state(robot)["metrics"]
            checks = {
                f'armtwin_position_error_mae_meters{{robot="{robot}",scope="cumulative"}}': state["cumulative"]["position"]["mae"],
                f'armtwin_rotation_error_mae_radians{{robot="{robot}",scope="cumulative"}}': state["cumulative"]["angle"]["mae"],
                f'armtwin_position_error_max_meters{{robot="{robot}",scope="window"}}': state["window"]["position"]["max"],
                f'armtwin_paired_total{{robot="{robot}"}}': float(state["paired"]),
            }
            for expr, expected in checks.items():
                # The next scrapes after the stream ended carry the final values.
                assert wait_until(lambda: prometheus.value(expr) == expected, 20.0, 0.25), (
                    expr, prometheus.value(expr), expected)
        assert state["cumulative"]["position"]["mae"] > 1e-4  # a real error, not an empty one

        status, body = http_get(service.url("/metrics"))
        assert status == 200
        exposition = body.decode()
        # Prometheus parsed every scrape (OpenMetrics text): no error on the target.
        targets = http_json(f"http://127.0.0.1:{prometheus.port}/api/v1/targets")["data"]["activeTargets"]
        assert [(t["health"], t["lastError"]) for t in targets] == [("up", "")], targets
        promtool = prometheus.binary.with_name("promtool")
        config = subprocess.run([str(promtool), "check", "config", str(REPO_ROOT / "config" / "prometheus.yml")],
                                capture_output=True, text=True, timeout=30)
        assert config.returncode == 0, config.stdout + config.stderr

        # Every Grafana query names exposed metrics and runs in this Prometheus, with results.
        names = exposed_names(exposition)
        for expr in dashboard_queries():
            used = set(re.findall(r"\barmtwin_[a-z_]+", expr))
            assert used and used <= names, (expr, used - names)
            query = expr.replace("$robot", ".*")
            prometheus.query(query)  # a query Prometheus refuses fails here
            if "alarm_active" not in expr:
                # rate() needs two scrapes of a series.
                assert wait_until(lambda: prometheus.query(query)["result"], 10.0, 0.5), f"no series for {expr}"
        token.undeclare()


def test_grafana_dashboard_structure():
    dashboard = json.loads(DASHBOARD.read_text())
    ids = [panel["id"] for panel in dashboard["panels"]]
    assert len(ids) == len(set(ids))
    provisioned = (REPO_ROOT / "config" / "grafana" / "provisioning" / "datasources" / "armtwin.yaml").read_text()
    # Every query reads the Prometheus the `datasource` variable picks: the provisioned one by
    # default, any other once imported into a Grafana of one's own.
    variables = {v["name"]: v for v in dashboard["templating"]["list"]}
    source = variables["datasource"]
    assert (source["type"], source["query"]) == ("datasource", "prometheus"), source
    assert f"uid: {source['current']['value']}" in provisioned, source
    assert variables["robot"]["datasource"]["uid"] == "${datasource}"
    for panel in dashboard["panels"]:
        assert {"x", "y", "w", "h"} <= set(panel["gridPos"]), panel["title"]
        assert panel["datasource"]["uid"] == "${datasource}", panel["title"]
        for target in panel["targets"]:
            assert target["datasource"]["uid"] == "${datasource}", panel["title"]
    kinds = {panel["type"] for panel in dashboard["panels"]}
    assert {"heatmap", "table", "timeseries"} <= kinds
