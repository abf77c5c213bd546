"""The robot page's per-second error history in a real headless Chromium (Playwright driving
Debian's chromium) against the real service, after a Python gateway streamed five seconds of the
sample UR10e recording, its measured poses 1 cm off: ``/api/robot/history`` answers what
``get twin/history/<robot>`` answers, and the page draws one point per completed second, the
highest where the error was largest, and the position alarm as a mark at its source time. And the
page's list of the robot's flight-recorder files: ``/api/robot/recordings`` lists what is on disk,
``/api/robot/recording`` hands out exactly those bytes and nothing it does not list.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_dashboard_history.py -q``
(after ``bash scripts/test-tools.sh``).
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from urllib.parse import quote

from playwright.sync_api import sync_playwright

from support.dashboard import DashboardService, chromium_path, http_get, http_json
from support.gateway import Gateway
from support.mcap_files import read_mcap
from support.process import wait_until
from support.zenoh_clients import get_json

CONFIG = """\
[service]
metrics_period_ms = 50

[recorder]
enabled = false

[robots.default]
model = "ur10e"
alarm_position_m = 0.005
alarm_hold_s = 0.2
"""
ROBOT = "plant-a/cell-1/ur10e-history"
# Stamps 1000 s + 2 ms a row: 3000 rows end at 1005.998, in second 1005, still open.
ROWS = 3000
COMPLETED = list(range(1000, 1005))


def path_points(d: str) -> list[tuple[str, float, float]]:
    """An SVG path's commands and points (the page writes only M and L)."""
    return [(c, float(x), float(y)) for c, x, y in re.findall(r"([ML])(-?[\d.]+),(-?[\d.]+)", d)]


def test_the_robot_page_draws_the_seconds_the_service_keeps(armtwin_bin, tmp_path):
    with DashboardService(armtwin_bin, tmp_path, CONFIG) as service:
        gateway = Gateway(service.client, ROBOT, rate_hz=2000.0, recording=True, rows=ROWS,
                          measured_offset_m={ROBOT: 0.01})
        gateway.start()
        gateway.join(timeout=60)
        assert wait_until(lambda: service.state(ROBOT)["metrics"]["paired"] == ROWS, 30.0, 0.1)

        history = http_json(service.url("/api/robot/history?id=" + ROBOT))
        assert history["robot"] == ROBOT and history["history_s"] == 3600
        assert [s["t"] for s in history["seconds"]] == COMPLETED
        [(_, over_zenoh)] = get_json(service.client.session, f"twin/history/{ROBOT}")
        assert over_zenoh == history
        assert http_get(service.url("/api/robot/history?id=no/such/robot"))[0] == 404, "an unknown robot's history"

        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium_path(), args=["--no-sandbox"])
            try:
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                page.goto(service.url("/robot/" + ROBOT))
                page.wait_for_function(
                    f"() => document.getElementById('history').dataset.seconds === '{len(COMPLETED)}'",
                    timeout=15_000)
                assert page.get_attribute("#history", "data-last") == str(COMPLETED[-1])
                mae = path_points(page.get_attribute('#history path[data-series="position-mae"]', "d"))
                top = path_points(page.get_attribute('#history path[data-series="position-max"]', "d"))
                # One point per second, joined (the seconds follow each other), left to right.
                assert [c for c, _, _ in mae] == ["M"] + ["L"] * (len(COMPLETED) - 1)
                assert [x for _, x, _ in mae] == sorted(x for _, x, _ in mae)
                # SVG's y grows downwards: the largest MAE is drawn highest, and every maximum at
                # or above its mean.
                values = [s["position"]["mae"] for s in history["seconds"]]
                heights = [y for _, _, y in mae]
                assert heights.index(min(heights)) == values.index(max(values))
                assert all(y_max <= y_mae for (_, _, y_max), (_, _, y_mae) in zip(top, mae))
                assert "1000 … 1004" in page.inner_text("#history-span")
                # The alarm, raised 0.2 s of source time into the stream, between seconds 1000 and 1001.
                page.wait_for_function("() => Number(document.getElementById('history').dataset.marks) >= 1",
                                       timeout=15_000)
                [alarm_t] = [e["t"] for e in http_json(service.url("/api/robot?id=" + ROBOT))["events"]
                             if e["kind"] == "alarm"]
                assert 1000.0 < alarm_t < 1001.0, alarm_t
                mark_x = float(page.get_attribute('#history line[data-event="alarm"]', "x1"))
                assert mae[0][1] < mark_x < mae[1][1], (mark_x, mae[:2])
                page.screenshot(path=str(tmp_path / "robot-history.png"), full_page=True)
            finally:
                browser.close()


RECORDING_CONFIG = """\
[service]
metrics_period_ms = 50

[recorder]
dir = "recordings"

[robots.default]
model = "ur10e"
alarm_position_m = 1.0
"""
RECORDED = "plant-a/cell-2/ur10e-recorded"


def test_the_robot_page_lists_its_recordings_and_hands_them_out(armtwin_bin, tmp_path):
    with DashboardService(armtwin_bin, tmp_path, RECORDING_CONFIG) as service:
        gateway = Gateway(service.client, RECORDED, rate_hz=2000.0, recording=True, rows=1000)
        gateway.start()
        gateway.join(timeout=60)
        assert wait_until(lambda: service.state(RECORDED)["metrics"]["paired"] == 1000, 30.0, 0.1)
        listing = lambda: http_json(service.url("/api/robot/recordings?id=" + RECORDED))  # noqa: E731
        assert listing() == {"robot": RECORDED, "files": []}
        assert http_get(service.url("/api/robot/recordings?id=no/such/robot"))[0] == 404

        # An operator's record query (no access control on this peer) writes one file.
        [reply] = list(service.client.session.get(f"twin/admin/record/{RECORDED}?pre_s=1;post_s=0", timeout=10))
        path = Path(json.loads(reply.ok.payload.to_string())["path"])
        assert wait_until(lambda: len(listing()["files"]) == 1, 20.0, 0.1), (listing(), service.proc.logs())
        [listed] = listing()["files"]
        assert listed == {"name": path.name, "bytes": path.stat().st_size}

        status, body = http_get(service.url(f"/api/robot/recording?id={quote(RECORDED)}&name={quote(path.name)}"))
        assert status == 200 and body == path.read_bytes()
        downloaded = tmp_path / "downloaded.mcap"
        downloaded.write_bytes(body)
        channels, messages, metadata = read_mcap(downloaded)
        assert metadata["armtwin"]["robot"] == RECORDED and metadata["armtwin"]["trigger"] == "operator"
        assert len(messages["/joint_states"]) > 0
        # Only a listed name is handed out: no path of the request's own, no other robot's file.
        for name in ("../armtwin.toml", "../../armtwin.toml", path.name + "x", "recordings"):
            assert http_get(service.url(f"/api/robot/recording?id={quote(RECORDED)}&name={quote(name)}"))[0] == 404
        assert http_get(service.url(f"/api/robot/recording?id=other&name={quote(path.name)}"))[0] == 404

        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(executable_path=chromium_path(), args=["--no-sandbox"])
            try:
                page = browser.new_page(viewport={"width": 1280, "height": 900})
                page.goto(service.url("/robot/" + RECORDED))
                page.wait_for_function("() => document.getElementById('recordings').dataset.files === '1'",
                                       timeout=15_000)
                link = page.locator("#recordings a")
                assert link.inner_text() == path.name
                with page.expect_download() as download:
                    link.click()
                saved = tmp_path / "clicked.mcap"
                download.value.save_as(saved)
                assert saved.read_bytes() == path.read_bytes()
            finally:
                browser.close()
