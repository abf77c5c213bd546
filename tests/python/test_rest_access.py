"""The router's REST API behind the same access control as every Zenoh session: with the shipped
secured configuration (config/router-tls-acl.json5, REST speaking as the certificate `rest`, a
dashboard in config/fleet.toml) an anonymous HTTP client reads, but can neither reset a twin nor
forge a sample; armtwin-router refuses REST beside access control without an identity, and a bare
--rest-http-port binds loopback only."""

from __future__ import annotations

import http.client
import json
import subprocess
import time
import urllib.request
from pathlib import Path

from support.gateway import Gateway
from support.paths import router_path
from support.process import Router, free_port, wait_until
from support.secured_fleet import ROUTER_CONFIG, denied, secured_fleet, stream_until_paired
from support.zenoh_clients import get_json, paired_of


# REST on a loopback port, speaking as the certificate `rest` (a dashboard in config/fleet.toml).
REST_IDENTITY = ["--rest-certificate", "certs/rest.pem", "--rest-private-key", "certs/rest.key"]


def rest(router: Router, method: str, path: str, body: bytes | None = None,
         timeout: float = 20.0) -> tuple[int, bytes]:
    """An anonymous HTTP request to the router's REST API: status and body."""
    connection = http.client.HTTPConnection("127.0.0.1", router.rest_port, timeout=timeout)
    try:
        headers = {"Content-Type": "application/json"} if body is not None else {}
        connection.request(method, path, body=body, headers=headers)
        response = connection.getresponse()
        return response.status, response.read()
    finally:
        connection.close()


def test_an_anonymous_rest_client_reads_but_can_neither_reset_nor_forge(tmp_path, certs, armtwin_bin):
    with secured_fleet(tmp_path, certs, armtwin_bin, ["g1", "dashboard"], rest=REST_IDENTITY) as (router, sessions, _):
        dashboard = sessions["dashboard"]
        paired = stream_until_paired(Gateway(sessions["g1"], "r1"), router, dashboard, "r1")

        # REST reads, as a dashboard does.
        status, body = rest(router, "GET", "/twin/state/r1")
        assert status == 200, body
        [answer] = json.loads(body)
        assert answer["key"] == "twin/state/r1" and answer["value"]["metrics"]["paired"] == paired, answer

        # A reset through REST: refused by REST itself (test_rest_bounds.py), and a query REST
        # could send there would still be dropped by the router's access control.
        status, body = rest(router, "GET", "/twin/admin/reset/r1")
        assert status == 403, (status, body)
        status, body = rest(router, "GET", "/twin/calibrate/r1")
        assert status == 200, (status, body)
        assert paired_of(dashboard, "r1") == paired, "the twin was not reset"

        # The forged sample: the plugin's own session takes the put (200), the router
        # drops it, and armtwin never twins r2.
        sample = {"t": 0.0, "q": Gateway.Q, "seq": 0}
        for seq in range(5):
            sample["seq"], sample["t"] = seq, seq * 0.005
            status, body = rest(router, "PUT", "/twin/joints/r2", json.dumps(sample).encode())
            assert status == 200, body
        assert wait_until(lambda: denied(router, "rest", "Put (ingress) on", "twin/joints/r2"), 10), router.logs()
        time.sleep(1.0)
        assert get_json(dashboard, "twin/state/r2", timeout=3.0) == [], "r2 was never twinned"
        # Nor may REST forge an output.
        rest(router, "PUT", "/twin/pose/r1", json.dumps({"robot": "r1", "seq": -1}).encode())
        assert wait_until(lambda: denied(router, "rest", "Put (ingress) on", "twin/pose/r1"), 10), router.logs()
        [(_, state)] = get_json(dashboard, "twin/state/r1")
        assert state["metrics"]["paired"] == paired


def run_router(armtwin_bin: Path, workdir: Path, *args: str) -> subprocess.CompletedProcess:
    """armtwin-router with the shipped secured configuration and ``args``, expected to stop."""
    return subprocess.run(
        [str(router_path(armtwin_bin)), "-c", str(ROUTER_CONFIG), "-l", f"tls/localhost:{free_port()}", *args],
        cwd=workdir, capture_output=True, text=True, timeout=30,
    )


def test_the_router_refuses_rest_beside_access_control_without_an_identity(tmp_path, certs, armtwin_bin):
    (tmp_path / "certs").symlink_to(certs)
    port = str(free_port())
    for args, reason in [
        (["--rest-http-port", port], "--rest-certificate FILE --rest-private-key FILE"),
        (["--rest-http-port", f"0.0.0.0:{port}"], "--rest-certificate FILE --rest-private-key FILE"),
        (["--rest-http-port", f"0.0.0.0:{port}", "--rest-trusted"], "loopback address only"),
        (["--rest-http-port", port, "--rest-trusted", "--rest-certificate", "certs/rest.pem",
          "--rest-private-key", "certs/rest.key"], "contradict"),
    ]:
        result = run_router(armtwin_bin, tmp_path, *args)
        assert result.returncode != 0 and reason in result.stderr, (args, result.stderr)


def listening_addresses(port: int) -> set[str]:
    """The local addresses of the sockets listening on TCP ``port`` (/proc/net/tcp and tcp6)."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            address, port_hex = fields[1].rsplit(":", 1)
            if int(port_hex, 16) == port and fields[3] == "0A":  # 0A: LISTEN
                found.add(address)
    return found


def test_a_bare_rest_port_binds_loopback_only(tmp_path, armtwin_bin):
    router = Router(router_path(armtwin_bin), tmp_path)
    router.rest_port = free_port()
    router.argv += ["--rest-http-port", str(router.rest_port)]
    try:
        router.start()
        assert router.wait_log("REST inside the router"), router.logs()
        # 127.0.0.1 as /proc/net/tcp writes it (little-endian hex).
        assert listening_addresses(router.rest_port) == {"0100007F"}, router.logs()
        with urllib.request.urlopen(f"http://127.0.0.1:{router.rest_port}/twin/state/**", timeout=10) as response:
            assert response.status == 200 and json.loads(response.read()) == []
    finally:
        router.stop()
