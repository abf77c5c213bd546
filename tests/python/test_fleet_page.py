"""One page for a fleet: two armtwin shards behind a real router (armtwin-router), each with its
dashboard on; either shard's fleet API and fleet page (in a real headless Chromium) list every
robot of the fleet with the shard that twins it, while each shard's ``/metrics`` keeps to its own
robots."""

from __future__ import annotations

import re

from playwright.sync_api import sync_playwright

from support.dashboard import chromium_path, http_get, http_json
from support.gateway import Gateway
from support.process import Armtwin, Router, free_port, port_accepts, wait_until
from support.zenoh_clients import get_json, open_client, wait_matched

CONFIG = """
[service]
robots = "{robots}"
metrics_period_ms = 100

[robots.default]
model = "ur10e"
alarm_position_m = 0.0005
alarm_hold_s = 0.0
"""
FLEET = {"site-a/r1": "site-a/**", "site-a/r2": "site-a/**", "site-b/r1": "site-b/**"}


def shard(armtwin_bin, tmp_path, name: str, robots: str, router: Router) -> tuple[Armtwin, str]:
    port = free_port()
    twin = Armtwin(armtwin_bin, tmp_path, name, CONFIG.format(robots=robots), router.endpoint,
                   extra=["--http", f"127.0.0.1:{port}"]).start()
    assert wait_until(lambda: port_accepts(port), 30.0, 0.02), twin.logs()
    return twin, f"http://127.0.0.1:{port}"


def test_every_shards_robots_show_on_one_page(tmp_path, armtwin_bin, router_bin, processes, sessions):
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    shard_a, page_a = shard(armtwin_bin, tmp_path, "shard-a", "site-a/**", router)
    processes.append(shard_a)
    shard_b, page_b = shard(armtwin_bin, tmp_path, "shard-b", "site-b/**", router)
    processes.append(shard_b)
    client = open_client(router.endpoint)
    sessions.append(client)
    for robot in FLEET:
        gateway = Gateway(client, robot)
        wait_matched(gateway.pub)
        for _ in range(20):
            gateway.send_one()
    assert wait_until(lambda: len(get_json(client, "twin/state/**")) == 3, 15)

    def rows(base: str) -> dict[str, dict]:
        return {row["robot"]: row for row in http_json(base + "/api/fleet")["rows"]}

    for base, own in ((page_a, "site-a/**"), (page_b, "site-b/**")):
        assert wait_until(lambda: set(rows(base)) == set(FLEET), 15, 0.1), rows(base)
        assert wait_until(lambda: all(row["paired"] == 20 for row in rows(base).values()), 15, 0.1), rows(base)
        page = http_json(base + "/api/fleet")
        assert page["shard"] == own and page["matched"] == 3 and not page["fleet_truncated"], page
        for robot, row in rows(base).items():
            assert row["shard"] == FLEET[robot], row
            assert row["local"] == (FLEET[robot] == own), row
            # The gateway's measured pose is ~1 mm off the twin: both shards' alarms show.
            assert row["alarm"]["position"] and row["position_m"] > 0.0005, row
        # A filter and a sort across shards.
        filtered = http_json(base + "/api/fleet?filter=*/r1&sort=shard&order=desc")
        assert [row["robot"] for row in filtered["rows"]] == ["site-b/r1", "site-a/r1"], filtered
        # Each shard exports its own robots on /metrics (Prometheus scrapes every shard).
        status, body = http_get(base + "/metrics")
        assert status == 200
        exported = set(re.findall(r'armtwin_poses_total\{robot="([^"]+)"\}', body.decode()))
        assert exported == {robot for robot, owner in FLEET.items() if owner == own}, exported

    # The fleet page of shard b, in a browser: every robot, each with its shard; only its own
    # robot links to a robot page here.
    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=chromium_path(), args=["--no-sandbox"])
        try:
            page = browser.new_page()
            page.goto(page_b + "/")
            for robot in FLEET:
                page.wait_for_selector(f'tr[data-robot="{robot}"]', timeout=15_000)
            shards = page.eval_on_selector_all(
                "tr[data-robot]", "rows => rows.map(row => [row.dataset.robot, row.querySelector('td.shard').textContent,"
                " row.querySelector('a') !== null])")
            assert shards == [[robot, owner, owner == "site-b/**"] for robot, owner in FLEET.items()], shards
            page.screenshot(path=str(tmp_path / "fleet-two-shards.png"), full_page=True)
        finally:
            browser.close()
