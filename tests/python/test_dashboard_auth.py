"""The dashboard's HTTP behind TLS and tokens (`[http] tls_certificate`, `[[http.tokens]]`,
tokens made by `armtwin http-token`): plain HTTP clients and a real headless Chromium are refused
without a token and served with one, over TLS verified against the test's CA; a `metrics` token
reads `/metrics` only; `/healthz` stays open; a real Prometheus scrapes `/metrics` with its bearer
token (and is refused without); the service refuses to serve the fleet beyond loopback without
tokens, or tokens without TLS.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_dashboard_auth.py -q``
(after ``bash scripts/test-tools.sh``).
"""

from __future__ import annotations

import base64
import http.client
import socket
import ssl
import subprocess
import time
from pathlib import Path

import pytest
from playwright.sync_api import Error as PlaywrightError
from playwright.sync_api import sync_playwright

from support.dashboard import DashboardService, Prometheus, chromium_path, http_get, http_json
from support.gateway import Gateway
from support.pki import make_ca, make_https_cert
from support.process import wait_until

ROBOT = "cell-1/ur10e-a"
CONFIG = """\
[service]
metrics_period_ms = 50

[robots.default]
model = "ur10e"
"""


def new_token(armtwin_bin: Path, name: str, role: str) -> tuple[str, str]:
    """`armtwin http-token`: the token and its configuration entry."""
    result = subprocess.run([str(armtwin_bin), "http-token", name, "--role", role],
                            capture_output=True, text=True, timeout=30, check=True)
    token, entry = result.stdout.split("\n", 1)
    assert f'name = "{name}"' in entry and f'role = "{role}"' in entry and 'hash = "sha256:' in entry
    assert token not in entry, "the configuration holds a digest, never the token"
    return token, entry.strip()


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("http-pki")
    make_ca(folder, "ca")
    make_https_cert(folder, "dashboard-http")
    return folder


class SecuredDashboard(DashboardService):
    """The service with its dashboard over TLS, taking a viewer token and a metrics token."""

    def __init__(self, armtwin_bin: Path, workdir: Path, pki: Path):
        self.viewer, viewer_entry = new_token(armtwin_bin, "alice", "viewer")
        self.scraper, scraper_entry = new_token(armtwin_bin, "prometheus", "metrics")
        # These keys land in the [http] table DashboardService opens.
        http = (f'tls_certificate = "{pki / "dashboard-http.pem"}"\n'
                f'tls_private_key = "{pki / "dashboard-http.key"}"\n\n'
                f"{viewer_entry}\n\n{scraper_entry}\n\n")
        super().__init__(armtwin_bin, workdir, http + CONFIG)
        self.base = f"https://127.0.0.1:{self.http_port}"
        self.cafile = pki / "ca.pem"
        self.tls = ssl.create_default_context(cafile=str(self.cafile))

    def get(self, path: str, authorization: str | None = None) -> tuple[int, dict, bytes]:
        """(status, headers, body) of a GET over TLS verified against the test's CA."""
        connection = http.client.HTTPSConnection("127.0.0.1", self.http_port, context=self.tls, timeout=10)
        try:
            connection.request("GET", path, headers={"Authorization": authorization} if authorization else {})
            response = connection.getresponse()
            return response.status, dict(response.getheaders()), response.read()
        finally:
            connection.close()


def basic(user: str, secret: str) -> str:
    return "Basic " + base64.b64encode(f"{user}:{secret}".encode()).decode()


def test_plain_clients_need_a_token_over_tls_and_healthz_is_open(armtwin_bin, tmp_path, pki):
    with SecuredDashboard(armtwin_bin, tmp_path, pki) as service:
        gateway = Gateway(service.client, [ROBOT], rate_hz=200.0, recording=True, rows=200)
        gateway.start()
        gateway.join(timeout=30)
        viewer, scraper = f"Bearer {service.viewer}", f"Bearer {service.scraper}"

        assert service.get("/healthz")[::2] == (200, b"ok\n")
        for path in ("/", "/api/fleet", "/metrics", f"/robot/{ROBOT}", "/assets/fleet.js", "/nowhere"):
            status, headers, _ = service.get(path)
            assert status == 401 and headers["www-authenticate"].startswith("Basic "), (path, status)
        assert service.get("/", "Bearer not-a-token")[0] == 401
        assert service.get("/", basic("prometheus", service.viewer))[0] == 401, "Basic needs the token's own name"

        status, _, page = service.get("/", viewer)
        assert status == 200 and b"<html" in page.lower()
        assert service.get(f"/robot/{ROBOT}", basic("alice", service.viewer))[0] == 200
        assert wait_until(lambda: ROBOT in service.get("/api/fleet", viewer)[2].decode(), 10)
        assert service.get("/metrics", viewer)[0] == 200

        # The scraper's token reads /metrics and nothing else.
        status, _, text = service.get("/metrics", scraper)
        assert status == 200 and f'robot="{ROBOT}"' in text.decode()
        for path in ("/", "/api/fleet", f"/robot/{ROBOT}"):
            assert service.get(path, scraper)[0] == 403, path

        # The port speaks TLS only: a plain HTTP request gets no page.
        plain = http.client.HTTPConnection("127.0.0.1", service.http_port, timeout=10)
        try:
            with pytest.raises((http.client.HTTPException, ConnectionError)):
                plain.request("GET", "/healthz")
                plain.getresponse().read()
        finally:
            plain.close()
        # And its certificate is checked: a client that trusts another CA refuses it.
        stranger = ssl.create_default_context()
        other = http.client.HTTPSConnection("127.0.0.1", service.http_port, context=stranger, timeout=10)
        with pytest.raises(ssl.SSLError):
            other.request("GET", "/healthz")
        other.close()


def test_a_browser_is_refused_without_credentials_and_served_with_them(armtwin_bin, tmp_path, pki):
    with SecuredDashboard(armtwin_bin, tmp_path, pki) as service, sync_playwright() as playwright:
        gateway = Gateway(service.client, [ROBOT], rate_hz=200.0, recording=True)
        gateway.start()
        chromium = playwright.chromium.launch(executable_path=chromium_path(), args=["--no-sandbox"])
        try:
            # Chromium cannot be handed the test's CA; Python's clients above check the chain.
            anonymous = chromium.new_context(ignore_https_errors=True)
            # Headless, the browser cannot ask for credentials: the navigation fails on the
            # challenge, and the same request from the browser's context shows the 401.
            with pytest.raises(PlaywrightError, match="ERR_INVALID_AUTH_CREDENTIALS"):
                anonymous.new_page().goto(service.url("/"))
            assert anonymous.request.get(service.url("/")).status == 401
            assert anonymous.request.get(service.url("/healthz")).status == 200
            anonymous.close()

            signed_in = chromium.new_context(
                ignore_https_errors=True, http_credentials={"username": "alice", "password": service.viewer}
            )
            page = signed_in.new_page()
            response = page.goto(service.url("/"))
            assert response.status == 200 and page.url.startswith("https://")
            # The live fleet table fills from its event stream, which the browser opens with the
            # same credentials.
            page.wait_for_selector(f'tr[data-robot="{ROBOT}"]', timeout=20_000)
            page.screenshot(path=str(tmp_path / "fleet-signed-in.png"))
            signed_in.close()
        finally:
            chromium.close()
            gateway.stop()


def test_prometheus_scrapes_metrics_with_its_token(armtwin_bin, tmp_path, pki):
    with SecuredDashboard(armtwin_bin, tmp_path, pki) as service:
        gateway = Gateway(service.client, [ROBOT], rate_hz=200.0, recording=True)
        gateway.start()
        prometheus = Prometheus(tmp_path, f"127.0.0.1:{service.http_port}")
        prometheus.config.write_text(
            "global:\n  scrape_interval: 1s\n  evaluation_interval: 1s\nscrape_configs:\n"
            "  - job_name: armtwin\n    scheme: https\n"
            f"    tls_config:\n      ca_file: {pki / 'ca.pem'}\n"
            f"    authorization:\n      credentials: {service.scraper}\n"
            f"    static_configs:\n      - targets: ['127.0.0.1:{service.http_port}']\n"
            "  - job_name: no-token\n    scheme: https\n"
            f"    tls_config:\n      ca_file: {pki / 'ca.pem'}\n"
            f"    static_configs:\n      - targets: ['127.0.0.1:{service.http_port}']\n"
        )
        try:
            with prometheus:
                # Its API answers 503 until its storage is open.
                ready = f"http://127.0.0.1:{prometheus.port}/-/ready"
                assert wait_until(lambda: http_get(ready)[0] == 200, 30.0, 0.2), prometheus.logs(2000)
                expr = f'armtwin_paired_total{{robot="{ROBOT}",job="armtwin"}}'
                assert wait_until(lambda: (prometheus.value(expr) or 0) > 0, 30.0, 0.2), \
                    prometheus.logs(2000)

                def targets() -> dict:
                    url = f"http://127.0.0.1:{prometheus.port}/api/v1/targets"
                    return {t["labels"]["job"]: t for t in http_json(url)["data"]["activeTargets"]}

                assert wait_until(lambda: targets()["no-token"]["health"] == "down", 15.0, 0.2)
                assert targets()["armtwin"]["health"] == "up"
                assert "401" in targets()["no-token"]["lastError"], targets()["no-token"]
        finally:
            gateway.stop()


@pytest.mark.parametrize(
    ("http_section", "reason"),
    [
        ('listen = "0.0.0.0:{port}"', "anonymous = true"),
        ('listen = "0.0.0.0:{port}"\n{viewer}', "tls_certificate and tls_private_key"),
        ('listen = "127.0.0.1:{port}"\ntls_certificate = "{pki}/dashboard-http.pem"', "go together"),
        ('listen = "127.0.0.1:{port}"\nanonymous = true\n{viewer}', "which one is meant"),
    ],
)
def test_the_service_refuses_to_expose_the_fleet_by_accident(armtwin_bin, tmp_path, pki, http_section, reason):
    _, viewer = new_token(armtwin_bin, "alice", "viewer")
    config = tmp_path / "armtwin.toml"
    config.write_text("[http]\n" + http_section.format(port=0, pki=pki, viewer=viewer) + "\n")
    result = subprocess.run([str(armtwin_bin), "serve", "-c", str(config)],
                            capture_output=True, text=True, timeout=30)
    assert result.returncode != 0 and reason in result.stderr, result.stderr



def idle_connections(port: int, count: int, source: str = "127.0.0.1") -> list[socket.socket]:
    """`count` TCP connections to the dashboard from `source` that send nothing."""
    held = []
    for _ in range(count):
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.bind((source, 0))
        s.settimeout(20)
        s.connect(("127.0.0.1", port))
        held.append(s)
    return held


def closed_by_server(s: socket.socket, within_s: float) -> bool:
    """Whether the server closes `s` (EOF or reset) within `within_s`."""
    s.settimeout(within_s)
    try:
        return s.recv(1) == b""
    except ConnectionResetError:
        return True
    except (TimeoutError, socket.timeout):
        return False


def test_connections_before_login_are_bounded(armtwin_bin, tmp_path, pki):
    """A stranger who opens connections and sends nothing (no TLS hello, no request) holds no
    one else up: one address keeps 32 connections at most, a silent one is closed after the
    10-s deadline, and another address is served at once meanwhile."""
    with SecuredDashboard(armtwin_bin, tmp_path, pki) as service:
        opened = time.monotonic()
        # 64 silent connections from one address: past its share, the server closes them as
        # they come; the first 32 stay open until the deadline.
        held = idle_connections(service.http_port, 64)
        over = [s for s in held[32:] if closed_by_server(s, 3.0)]
        assert len(over) == 32, f"{len(over)} of the 32 over the share were closed"

        # Another address is served at once, over TLS, though 32 silent handshakes are pending.
        before = time.monotonic()
        status, body = curl_healthz(service, source="127.0.0.2")
        served_s = time.monotonic() - before
        assert (status, body) == (200, "ok\n"), (status, body)
        assert served_s < 3.0, f"another address waited {served_s:.1f} s for /healthz"

        # The silent ones are closed by the deadline (10 s), not left to hold their slots.
        closed = [s for s in held[:32] if closed_by_server(s, max(0.1, opened + 15.0 - time.monotonic()))]
        assert len(closed) == 32, f"{len(closed)} of 32 silent connections closed within 15 s"
        closed_s = time.monotonic() - opened
        assert closed_s > 8.0, f"closed after {closed_s:.1f} s: before the deadline"
        for s in held:
            s.close()

        # A connection that sent its TLS hello and then nothing more is closed by the request
        # deadline too, and the address's share is whole again: 32 served at once.
        tls = service.tls.wrap_socket(socket.create_connection(("127.0.0.1", service.http_port), 10),
                                      server_hostname="127.0.0.1")
        assert closed_by_server(tls, 15.0), "a TLS connection without a request stays open"
        tls.close()
        statuses = [service.get("/healthz")[0] for _ in range(32)]
        assert statuses == [200] * 32


def curl_healthz(service: SecuredDashboard, source: str) -> tuple[int, str]:
    """`/healthz` through curl from the source address `source`, over TLS against the test CA."""
    out = subprocess.run(
        ["curl", "-sS", "--max-time", "10", "--interface", source, "--cacert", str(service.cafile),
         "-w", "\n%{http_code}", f"https://127.0.0.1:{service.http_port}/healthz"],
        capture_output=True, text=True, timeout=20)
    body, _, code = out.stdout.rpartition("\n")
    return int(code or 0), body
