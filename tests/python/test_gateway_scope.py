"""Gateways scoped to their own robots by the access control `armtwin acl` generates from
config/fleet.toml (g1 speaks for r1, g2 for r2): on the shipped secured router, g1's joints of r1
are twinned, g1's joints of r2 are dropped at the router (its log names the denial) and g2's are
twinned; the generator prints the section the shipped configuration holds."""

from __future__ import annotations

import json
import subprocess
import time

from support.gateway import Gateway
from support.paths import REPO_ROOT
from support.process import wait_until
from support.secured_fleet import ROUTER_CONFIG, denied, secured_fleet, send, stream_until_paired
from support.zenoh_clients import get_json


def test_a_gateway_puts_its_own_robots_joints_only(tmp_path, certs, armtwin_bin):
    with secured_fleet(tmp_path, certs, armtwin_bin, ["g1", "g2", "dashboard"]) as (router, sessions, _):
        g1, g2, dashboard = sessions["g1"], sessions["g2"], sessions["dashboard"]
        stream_until_paired(Gateway(g1, "r1"), router, dashboard, "r1")
        send(Gateway(g1, "r2"))
        assert wait_until(lambda: denied(router, "g1", "Put (ingress) on", "twin/joints/r2"), 10), router.logs()
        time.sleep(1.0)
        assert get_json(dashboard, "twin/state/r2", timeout=3.0) == [], "g1 cannot speak for r2"

        # r2's own gateway can.
        stream_until_paired(Gateway(g2, "r2"), router, dashboard, "r2", at_least=10)
        assert not denied(router, "g2", "Put (ingress) on", "twin/joints/r2")
        assert not denied(router, "g1", "Put (ingress) on", "twin/joints/r1")


def test_the_generator_prints_the_shipped_section(armtwin_bin):
    result = subprocess.run(
        [str(armtwin_bin), "acl", str(REPO_ROOT / "config" / "fleet.toml")],
        capture_output=True, text=True, timeout=60, check=True,
    )
    section = json.loads(result.stdout)
    shipped = ROUTER_CONFIG.read_text()
    begin = shipped.index("access_control: ", shipped.index("// BEGIN access_control"))
    end = shipped.index("// END access_control")
    body = shipped[begin + len("access_control: "):end].rstrip().rstrip(",")
    assert json.loads(body) == section
    subjects = {s["id"]: s["cert_common_names"] for s in section["subjects"]}
    assert subjects["gateway:g1"] == ["g1"] and subjects["dashboards"] == ["dashboard", "rest"]
