"""The stand-in UR controller (rtde_server.py) and `armtwin gateway rtde` as test processes."""

from __future__ import annotations

import contextlib
import json
import re
import sys
import time
from pathlib import Path

from support.paths import REPO_ROOT, SUPPORT_DIR
from support.process import STARTUP_TIMEOUT_S, ArmtwinProcess, Process, wait_until
from support.zenoh_clients import open_session

WATCHDOG_S = 300.0


class StandIn(Process):
    """rtde_server.py in its own process; its ports (and dashboard server ports) once it listens."""

    def __init__(self, recording: Path, *args, workdir: Path, ports: int = 1):
        command = [sys.executable, SUPPORT_DIR / "rtde_server.py", "--recording", recording]
        command += ["--port", "0"] * ports + list(args)
        super().__init__(f"rtde_server-{time.monotonic_ns()}", command, workdir, watchdog_s=WATCHDOG_S)
        self.start()
        assert wait_until(lambda: self.listening() is not None or not self.running(), STARTUP_TIMEOUT_S), (
            f"stand-in did not start\n{self.logs()}")
        self.ports = self.listening()
        assert self.ports is not None, f"stand-in did not start\n{self.logs()}"
        self.dashboard_ports = self.printed("dashboard") or []

    def printed(self, word: str) -> list[int] | None:
        """The ports of its line starting with ``word``, once it printed one."""
        for line in self.logs(limit=10**9).splitlines():
            if line.startswith(word + " "):
                return [int(p) for p in line.split()[1:]]
        return None

    def listening(self) -> list[int] | None:
        """The ports of its ``listening`` line, once it printed one."""
        return self.printed("listening")


class Gateway(Process):
    """`armtwin gateway rtde …` connected to the service's endpoint."""

    def __init__(self, binary: Path, workdir: Path, endpoint: str, *args):
        argv = [binary, "gateway", "rtde", "-e", endpoint, *args]
        super().__init__(f"gateway-{time.monotonic_ns()}", argv, workdir, watchdog_s=WATCHDOG_S)
        self.start()

    def logs(self, limit: int = 10**9) -> str:
        """The whole log by default: the tests count what it says."""
        return super().logs(limit)


@contextlib.contextmanager
def serving(binary: Path, workdir: Path, config_text: str):
    """`armtwin serve` with a session on it (``.session``) and every event it publishes (``.events``)."""
    proc = ArmtwinProcess(binary, workdir, config_text, WATCHDOG_S)
    proc.start()
    session = open_session(proc.endpoint)
    events: list[dict] = []
    subscriber = session.declare_subscriber(
        "twin/events/**", lambda sample: events.append(json.loads(sample.payload.to_bytes()))
    )
    proc.events = events
    proc.session = session
    try:
        yield proc
    finally:
        subscriber.undeclare()
        session.close()
        proc.stop()


def doc_plant(controllers: dict[str, tuple[int, int]]) -> str:
    """docs/ur-rtde.md's ``plant.toml``, its robots those of ``controllers`` in order, each
    controller's address on loopback at its (RTDE port, dashboard server port)."""
    block = re.search(r"```toml\n# plant\.toml\n(.*?)```", (REPO_ROOT / "docs" / "ur-rtde.md").read_text(), re.S)
    assert block, "docs/ur-rtde.md has no plant.toml"
    text = block.group(1)
    assert re.findall(r'^\[robots\."([^"]+)"\]$', text, re.M) == list(controllers), text
    ports = iter(controllers.values())

    def address(_match) -> str:
        port, dashboard_port = next(ports)
        return f'rtde = "127.0.0.1:{port}"\nrtde_dashboard_port = {dashboard_port}'

    return re.sub(r'^rtde = "[^"]+"$', address, text, flags=re.M)
