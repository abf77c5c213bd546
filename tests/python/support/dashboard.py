"""What the dashboard tests share: the service with its HTTP side on, the tools (a real headless
Chromium, a real Prometheus) and bounded HTTP reads.

The tools come from ``scripts/test-tools.sh`` (``tests/run_all.sh`` runs it before pytest): the
tests fail, never skip, when one is missing.
"""

from __future__ import annotations

import json
import re
import os
import shutil
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from support.paths import REPO_ROOT
from support.process import ArmtwinProcess, Process, free_port, port_accepts, wait_until
from support.zenoh_clients import TwinClient

HTTP_TIMEOUT_S = 10.0


def chromium_path() -> str:
    path = os.environ.get("ARMTWIN_CHROMIUM") or shutil.which("chromium")
    if not path or not os.access(path, os.X_OK):
        pytest.fail("Chromium not found: run scripts/test-tools.sh (tests/run_all.sh does)", pytrace=False)
    return path


def prometheus_path() -> Path:
    env = os.environ.get("ARMTWIN_PROMETHEUS")
    found = [Path(env)] if env else sorted((REPO_ROOT / ".cache").glob("prometheus-*/usr/bin/prometheus"))
    if not found or not os.access(found[-1], os.X_OK):
        pytest.fail("Prometheus not found: run scripts/test-tools.sh (tests/run_all.sh does)", pytrace=False)
    return found[-1]


def http_get(url: str, timeout: float = HTTP_TIMEOUT_S) -> tuple[int, bytes]:
    """(status, body) of a GET, 4xx/5xx included."""
    try:
        with urllib.request.urlopen(url, timeout=timeout) as response:
            return response.status, response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


def exposed_names(exposition: str) -> set[str]:
    """The series names of a ``/metrics`` exposition."""
    return {line.split("{")[0].split(" ")[0] for line in exposition.splitlines() if line and not line.startswith("#")}


def http_json(url: str):
    status, body = http_get(url)
    assert status == 200, f"GET {url}: {status} {body[:200]!r}"
    return json.loads(body)


class DashboardService:
    """``armtwin serve`` with ``[http] listen`` on a free loopback port, and one client peer."""

    def __init__(self, binary: Path, workdir: Path, config_text: str, watchdog_s: float = 300.0,
                 stop_timeout_s: float = 15.0, clean_exit: bool = True):
        self.stop_timeout_s = stop_timeout_s
        self.clean_exit = clean_exit
        self.http_port = free_port()
        config = f'[http]\nlisten = "127.0.0.1:{self.http_port}"\n\n{config_text}'
        self.proc = ArmtwinProcess(binary, workdir, config, watchdog_s)
        self.client: TwinClient | None = None
        self.base = f"http://127.0.0.1:{self.http_port}"

    def __enter__(self) -> DashboardService:
        self.proc.start()
        if not wait_until(lambda: port_accepts(self.http_port), 30.0, 0.02):
            raise AssertionError(f"the dashboard never listened on {self.http_port}\n{self.proc.logs()}")
        self.client = TwinClient(self.proc.endpoint)
        return self

    def __exit__(self, *exc) -> None:
        code, _ = self.proc.stop(self.stop_timeout_s)
        if self.client is not None:
            self.client.close()
        if exc[0] is None and self.clean_exit:
            assert code == 0, f"armtwin exited with {code}\n{self.proc.logs()}"

    def url(self, path: str) -> str:
        return self.base + path

    def state(self, robot: str) -> dict:
        replies = self.client.get(f"twin/state/{robot}")
        values = [json.loads(r.ok.payload.to_string()) for r in replies if r.ok is not None]
        assert len(values) == 1, f"state of {robot}: {len(values)} replies"
        return values[0]


class Prometheus(Process):
    """A Prometheus scraping ``target`` every ``interval_s`` (its timeout too), its data in
    ``workdir``."""

    def __init__(self, workdir, target: str, job: str = "armtwin", rule_files: list[Path] = (),
                 interval_s: int = 1):
        self.binary = prometheus_path()
        self.port = free_port()
        self.config = workdir / "prometheus.yml"
        rules = "".join(f"  - {path}\n" for path in rule_files)
        self.config.write_text(
            f"global:\n  scrape_interval: {interval_s}s\n  evaluation_interval: {interval_s}s\n"
            + (f"rule_files:\n{rules}" if rules else "")
            + f"scrape_configs:\n  - job_name: {job}\n    static_configs:\n"
            f"      - targets: ['{target}']\n"
        )
        self.data = workdir / "prometheus-data"
        argv = [self.binary, f"--config.file={self.config}", f"--storage.tsdb.path={self.data}",
                f"--web.listen-address=127.0.0.1:{self.port}"]
        super().__init__("prometheus", argv, workdir)

    def __enter__(self) -> Prometheus:
        self.start()
        self.wait_port(self.port, f"listen on {self.port}")
        # It listens before its storage is open, and answers queries with 503 until then.
        ready = f"http://127.0.0.1:{self.port}/-/ready"
        if not wait_until(lambda: http_get(ready)[0] == 200, 60.0, 0.2):
            raise AssertionError(f"Prometheus never became ready\n{self.logs()}")
        return self

    def __exit__(self, *exc) -> None:
        self.stop()

    def query(self, expr: str) -> dict:
        url = f"http://127.0.0.1:{self.port}/api/v1/query?" + urllib.parse.urlencode({"query": expr})
        answer = http_json(url)
        assert answer["status"] == "success", answer
        return answer["data"]

    def value(self, expr: str) -> float | None:
        result = self.query(expr)["result"]
        return float(result[0]["value"][1]) if len(result) == 1 else None


def metric(port: int, name: str) -> float | None:
    """The value of the unlabelled series ``name`` on ``/metrics`` at ``port`` (loopback), or
    ``None`` when it is not there."""
    with urllib.request.urlopen(f"http://127.0.0.1:{port}/metrics", timeout=10) as response:
        body = response.read().decode()
    match = re.search(rf"^{re.escape(name)} (\S+)$", body, re.MULTILINE)
    return float(match.group(1)) if match else None
