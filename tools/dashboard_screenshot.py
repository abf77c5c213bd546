"""Makes docs/img/dashboard.png, the README's picture: the fleet page of a service twinning a few
robots from the sample recording (one of them configured as the wrong arm, so that its row shows
an alarm), taken in the headless Chromium the dashboard tests drive (Debian's `chromium`,
`$ARMTWIN_CHROMIUM`, through Playwright).

    ARMTWIN_BIN=target/debug/armtwin .venv/bin/python tools/dashboard_screenshot.py

Loopback ports chosen free, multicast off; every process is stopped before it exits.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "python"))

from playwright.sync_api import sync_playwright  # noqa: E402

from support.dashboard import chromium_path  # noqa: E402
from support.process import Process, free_port  # noqa: E402

ROBOTS = ["plant-a/cell-1/ur10e-01", "plant-a/cell-1/ur10e-02", "plant-a/cell-2/ur10e-03",
          "plant-b/cell-7/ur10e-11", "plant-b/cell-7/ur10e-12"]
# A UR10e twinned as a UR5e: centimetres off, so its row turns red.
CONFIG = '[robots."plant-a/cell-2/ur10e-03"]\nmodel = "ur5e"\n'


def main() -> None:
    binary = Path(os.environ.get("ARMTWIN_BIN", REPO / "target" / "debug" / "armtwin"))
    out = REPO / "docs" / "img" / "dashboard.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as scratch:
        workdir = Path(scratch)
        (workdir / "armtwin.toml").write_text(CONFIG)
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        http_port = free_port()
        serve = Process("serve", [binary, "serve", "-c", workdir / "armtwin.toml", "-l", endpoint,
                                  "--http", f"127.0.0.1:{http_port}"], workdir).start()
        replays = []
        try:
            serve.wait_port(http_port, "serve its dashboard")
            for index, robot in enumerate(ROBOTS):
                replays.append(Process(f"replay{index}", [
                    binary, "replay", REPO / "tests" / "data" / "ur10e_lasttest.csv", "--robot", robot,
                    "--speed", str(4 + index), "-e", endpoint], workdir).start())
            time.sleep(12)
            with sync_playwright() as playwright:
                browser = playwright.chromium.launch(executable_path=chromium_path(), args=["--no-sandbox"])
                page = browser.new_page(viewport={"width": 1280, "height": 390}, device_scale_factor=1)
                page.goto(f"http://127.0.0.1:{http_port}/")
                # Rows are grouped by the levels of each id: wait until the last robot's name shows.
                page.wait_for_selector(f"text={ROBOTS[-1].rsplit('/', 1)[-1]}", timeout=15000)
                time.sleep(2)
                page.screenshot(path=str(out))
                browser.close()
        finally:
            for process in [*replays, serve]:
                process.stop()
    print(out)


if __name__ == "__main__":
    main()
