"""The dashboard's figures (not a test: run by hand, prints them).

1. Fleet page load time at 10 000 tracked robots: from navigation to the first rows drawn, in a
   real headless Chromium, median of 5 loads.
2. The service's CPU cost of open pages at 1 000 robots: the same fixed stream (every robot's
   joints and measured pose at RATE_HZ for STREAM_S seconds) with no page open, with 10 fleet
   pages and with 10 robot pages, each twice, interleaved; CPU seconds of the armtwin process
   from /proc/PID/stat. ``--no-load`` skips the first figure.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python benches/python/dashboard_cost.py``
(after ``bash scripts/test-tools.sh``).
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from pathlib import Path


from playwright.sync_api import sync_playwright

# The shared test support (tests/python/support) is imported from beside the tests.
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "python"))
from support.dashboard import DashboardService, chromium_path, http_json  # noqa: E402
from support.gateway import lasttest_rows  # noqa: E402
from support.paths import armtwin_path  # noqa: E402
from support.process import cpu_s, wait_until  # noqa: E402

CONFIG = """\
[service]
metrics_period_ms = 100

[robots.default]
model = "ur10e"
"""
MEASURED_KEYS = ("x", "y", "z", "qx", "qy", "qz", "qw")
RATE_HZ = 2.0
STREAM_S = 20.0


def robots(n: int) -> list[str]:
    return [f"plant-{i // 1000}/cell-{i // 100 % 10}/ur10e-{i:05d}" for i in range(n)]


def stream(service: DashboardService, ids: list[str], rows: list, seconds: float, rate_hz: float, start: int = 0) -> int:
    pubs = [service.client.joints(robot) for robot in ids]
    ticks = int(seconds * rate_hz)
    began = time.monotonic()
    for tick in range(ticks):
        q, measured = rows[(start + tick) % len(rows)]
        message = json.dumps({"t": 1000.0 + (start + tick) / rate_hz, "q": q, "measured": dict(zip(MEASURED_KEYS, measured))})
        for pub in pubs:
            pub.put(message)
        pause = began + (tick + 1) / rate_hz - time.monotonic()
        if pause > 0:
            time.sleep(pause)
    return start + ticks


def wait_declared(service: DashboardService, last: str, timeout_s: float) -> None:
    """Until the service has declared every robot's outputs (its control thread logs each): the
    figures are of a steady service, not of one still declaring a fleet."""
    needle = f'tracking robot robot="{last}"'
    assert wait_until(lambda: needle in service.proc.logs(limit=10**9), timeout_s, 0.5), \
        f"{last} never declared"


def fleet_load_time(binary: Path, workdir: Path, browser) -> list[float]:
    ids = robots(10_000)
    with DashboardService(binary, workdir, CONFIG, watchdog_s=1200, stop_timeout_s=300,
                          # Its exit is not the figure: a debug build undeclaring 10 000 robots
                          # takes longer than the teardown's bound.
                          clean_exit=False) as service:
        service.client.ready(ids[:1])
        rows = lasttest_rows()
        stream(service, ids, rows, 2.0, 1.0)
        assert wait_until(lambda: http_json(service.url("/api/fleet?limit=1"))["service"]["robots"] == 10_000, 60)
        wait_declared(service, ids[-1], 600)
        loads = []
        for _ in range(5):
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            began = time.monotonic()
            page.goto(service.url("/"))
            page.wait_for_selector("tr[data-robot]", timeout=30_000)
            loads.append(time.monotonic() - began)
            assert page.locator("tr[data-robot]").count() == 100
            page.close()
        print(f"fleet page load at 10 000 robots: median {statistics.median(loads) * 1000:.0f} ms "
              f"(min {min(loads) * 1000:.0f}, max {max(loads) * 1000:.0f}, 5 loads)", flush=True)
        return loads


def page_cost(binary: Path, workdir: Path, browser, pages: str) -> float:
    ids = robots(1000)
    with DashboardService(binary, workdir, CONFIG, watchdog_s=1200, stop_timeout_s=300,
                          # Its exit is not the figure: a debug build undeclaring 10 000 robots
                          # takes longer than the teardown's bound.
                          clean_exit=False) as service:
        service.client.ready(ids[:1])
        rows = lasttest_rows()
        position = stream(service, ids, rows, 2.0, RATE_HZ)
        wait_declared(service, ids[-1], 300)
        opened = []
        for i in range(10 if pages != "none" else 0):
            page = browser.new_page(viewport={"width": 1280, "height": 900})
            page.goto(service.url("/" if pages == "fleet" else "/robot/" + ids[i * 97]))
            opened.append(page)
        time.sleep(2.0)
        pid = service.proc.proc.pid
        before = cpu_s(pid)
        end = stream(service, ids, rows, STREAM_S, RATE_HZ, position)
        # Until the service has taken the whole stream (one query of ready() besides): a loaded
        # service may still be working through it.
        expected = end * len(ids) + 1
        assert wait_until(
            lambda: http_json(service.url("/api/fleet?limit=1"))["service"]["inputs"] >= expected, 120, 0.2
        ), "the service never took the whole stream"
        used = cpu_s(pid) - before
        for page in opened:
            page.close()
        return used


def main() -> None:
    binary = armtwin_path()
    with sync_playwright() as playwright, tempfile.TemporaryDirectory() as tmp:
        browser = playwright.chromium.launch(executable_path=chromium_path(), args=["--no-sandbox"])
        (Path(tmp) / "load").mkdir()
        if "--no-load" not in sys.argv:
            fleet_load_time(binary, Path(tmp) / "load", browser)
        # Interleaved and repeated: the machine's other load drifts.
        for pages in ("none", "fleet", "robot") * 2:
            workdir = Path(tmp) / f"cost-{pages}-{time.monotonic_ns()}"
            workdir.mkdir()
            used = page_cost(binary, workdir, browser, pages)
            print(f"1 000 robots x {RATE_HZ:.0f} Hz for {STREAM_S:.0f} s, {pages} pages"
                  f"{'' if pages == 'none' else ' x 10'}: armtwin CPU {used:.2f} s", flush=True)
        browser.close()


if __name__ == "__main__":
    main()
