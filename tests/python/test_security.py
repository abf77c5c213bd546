"""TLS, mutual TLS and access control on a fleet's router, with the shipped example configurations
(config/router-tls-acl.json5, its access control generated from config/fleet.toml,
config/zenoh-client-tls.json5) and certificates this test makes with the openssl CLI: only
gateways put joints (gateway g1 for robot r1), only armtwin publishes outputs, dashboards only
subscribe and read, operators may also change a twin (reset, apply or discard a calibration), and
a client without a certificate of the fleet's CA cannot connect."""

from __future__ import annotations

import json
import subprocess
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
import zenoh

from armtwin_service import free_port, wait_until
from fleet import Armtwin, Gateway, Router, get_json, paired_of, router_path, wait_queryable

REPO = Path(__file__).resolve().parents[2]
ROUTER_CONFIG = REPO / "config" / "router-tls-acl.json5"
CLIENT_CONFIG = REPO / "config" / "zenoh-client-tls.json5"
ACL_LOG = "z=info,zenoh::net::routing::interceptor::access_control=trace"


def openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True, timeout=60)


def make_ca(folder: Path, name: str) -> None:
    openssl(
        "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-keyout", f"{name}.key", "-out", f"{name}.pem", "-days", "2", "-subj", f"/CN={name}",
        "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=keyCertSign,cRLSign",
        cwd=folder,
    )


def make_cert(folder: Path, name: str, ca: str = "ca") -> None:
    extensions = folder / f"{name}.ext"
    extensions.write_text(
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
        "keyUsage=digitalSignature\nextendedKeyUsage=serverAuth,clientAuth\n"
    )
    openssl(
        "req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:P-256", "-nodes",
        "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={name}", cwd=folder,
    )
    openssl(
        "x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.pem", "-CAkey", f"{ca}.key",
        "-CAcreateserial", "-out", f"{name}.pem", "-days", "2", "-extfile", extensions.name,
        cwd=folder,
    )


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("pki") / "certs"
    folder.mkdir()
    make_ca(folder, "ca")
    # The names config/fleet.toml gives roles: gateways g1 (robot r1) and g2 (r2), REST's `rest`.
    for name in ("router", "armtwin", "g1", "g2", "rest", "dashboard", "operator"):
        make_cert(folder, name)
    # A certificate named like a gateway, signed by a CA the router does not trust.
    make_ca(folder, "stranger-ca")
    make_cert(folder, "stranger", ca="stranger-ca")
    return folder


def tls_of(certs: Path, name: str | None) -> dict:
    tls = {"root_ca_certificate": str(certs / "ca.pem"), "enable_mtls": True,
           "verify_name_on_connect": True}
    if name is not None:
        tls["connect_private_key"] = str(certs / f"{name}.key")
        tls["connect_certificate"] = str(certs / f"{name}.pem")
    return tls


def tls_router_and_twin(tmp_path, certs, armtwin_bin) -> tuple[Router, Armtwin]:
    """The shipped TLS + ACL router and armtwin behind it with its certificate, not started."""
    (tmp_path / "certs").symlink_to(certs)
    router = Router(router_path(armtwin_bin), tmp_path, config=ROUTER_CONFIG, scheme="tls", env={"RUST_LOG": ACL_LOG})
    twin = Armtwin(
        armtwin_bin, tmp_path, "twin",
        f'[zenoh]\nfile = "{CLIENT_CONFIG}"\n[service]\npose_congestion = "block"\n',
        router.endpoint,
    )
    (tmp_path / "twin" / "certs").symlink_to(certs)
    return router, twin


def open_as(router: Router, certs: Path, name: str) -> zenoh.Session:
    """A client session of ``router`` with the certificate ``name``."""
    return zenoh.open(_client(router.endpoint, tls_of(certs, name)))


def send(gateway: Gateway, router: Router, count: int = 20) -> None:
    """Waits until ``gateway``'s publisher knows armtwin's subscriber, then sends ``count`` samples."""
    assert wait_until(lambda: gateway.pub.matching_status.matching, 20), router.log()
    for _ in range(count):
        gateway.send_one()
        time.sleep(0.005)


@contextmanager
def secured_fleet(tmp_path, certs, armtwin_bin, names: list[str], rest: list[str] | None = None):
    """The shipped secured router (with ``rest``, REST flags, if given) and armtwin behind it,
    started, with a session per certificate name in ``names`` and a dashboard's view of armtwin's
    queryables; yields the router and the sessions by name; stops everything after."""
    router, twin = tls_router_and_twin(tmp_path, certs, armtwin_bin)
    if rest is not None:
        router.rest_port = free_port()
        router.argv += ["--rest-http-port", f"127.0.0.1:{router.rest_port}", *rest]
    sessions = {}
    try:
        router.start()
        twin.start()
        sessions = {name: open_as(router, certs, name) for name in names}
        assert wait_queryable(sessions["dashboard"], "twin/state/**"), router.log()
        yield router, sessions
    finally:
        for session in sessions.values():
            session.close()
        twin.stop()
        router.stop()


def denied(router: Router, name: str, action: str, key: str) -> bool:
    """Whether the router's log (access control at trace level) names a denial of ``action``
    (``Put (ingress)``, ``Query``) on ``key`` to the certificate ``name``."""
    return any(
        f"CertCommonName({name})" in line and f"is unauthorized to {action}" in line and key in line
        for line in router.log(10**9).splitlines()
    )


def test_only_gateways_put_joints_only_armtwin_publishes_and_strangers_cannot_connect(
    tmp_path, certs, armtwin_bin
):
    router, twin = tls_router_and_twin(tmp_path, certs, armtwin_bin)
    sessions = []
    try:
        router.start()
        twin.start()
        gateway_session = open_as(router, certs, "g1")
        dashboard = open_as(router, certs, "dashboard")
        watcher = open_as(router, certs, "dashboard")
        sessions += [gateway_session, dashboard, watcher]
        poses = []
        watcher.declare_subscriber("twin/pose/**", lambda s: poses.append(json.loads(s.payload.to_bytes())))
        assert wait_queryable(dashboard, "twin/state/**"), router.log()
        assert wait_queryable(watcher, "twin/state/**"), router.log()

        send(Gateway(gateway_session, "r1"), router)
        assert wait_until(lambda: len(poses) == 20, 15), (len(poses), router.log())
        [(_, state)] = get_json(dashboard, "twin/state/r1")
        assert state["metrics"]["paired"] == 20

        # A dashboard's joints are dropped at the router: the twin does not change.
        forged = Gateway(dashboard, "r1", start_seq=1000, start_t=100.0)
        for _ in range(20):
            forged.send_one()
        # A forged pose, from a dashboard and from a gateway, reaches no subscriber.
        dashboard.put("twin/pose/r1", json.dumps({"robot": "r1", "seq": -1}))
        gateway_session.put("twin/pose/r1", json.dumps({"robot": "r1", "seq": -2}))
        time.sleep(1.5)
        [(_, after)] = get_json(dashboard, "twin/state/r1")
        assert after["metrics"]["paired"] == 20 and after["joints"]["t"] == state["joints"]["t"]
        assert [p["seq"] for p in poses] == list(range(20)), "only armtwin's poses arrive"
        # The router's log names each denial (access control at trace level).
        assert wait_until(lambda: denied(router, "dashboard", "Put (ingress) on", "twin/joints/r1"), 10)
        assert denied(router, "dashboard", "Put (ingress) on", "twin/pose/r1")
        assert denied(router, "g1", "Put (ingress) on", "twin/pose/r1")

        # Without a certificate, or with one of another CA, no session opens.
        for name in (None, "stranger"):
            tls = tls_of(certs, None)
            if name is not None:
                tls["connect_private_key"] = str(certs / f"{name}.key")
                tls["connect_certificate"] = str(certs / f"{name}.pem")
            with pytest.raises(zenoh.ZError):
                zenoh.open(_client(router.endpoint, tls)).close()
        # Plain TCP to the TLS port does not open a session either.
        with pytest.raises(zenoh.ZError):
            zenoh.open(_client(f"tcp/127.0.0.1:{router.port}", None)).close()
    finally:
        for session in sessions:
            session.close()
        twin.stop()
        router.stop()


def replies(session: zenoh.Session, selector: str) -> tuple[list[dict], list[dict]]:
    """The ok and error replies to ``selector``, each a JSON object."""
    oks, errs = [], []
    for reply in session.get(selector, timeout=5.0, consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is not None:
            oks.append(json.loads(reply.ok.payload.to_bytes()))
        else:
            errs.append(json.loads(reply.err.payload.to_bytes()))
    return oks, errs


def test_a_dashboard_reads_a_twin_but_cannot_change_it_and_an_operator_can(tmp_path, certs, armtwin_bin):
    router, twin = tls_router_and_twin(tmp_path, certs, armtwin_bin)
    sessions = []
    try:
        router.start()
        twin.start()
        gateway_session = open_as(router, certs, "g1")
        dashboard = open_as(router, certs, "dashboard")
        operator = open_as(router, certs, "operator")
        sessions += [gateway_session, dashboard, operator]
        assert wait_queryable(dashboard, "twin/state/**"), router.log()
        assert wait_queryable(operator, "twin/admin/reset/**"), router.log()
        send(Gateway(gateway_session, "r1"), router)
        assert wait_until(lambda: paired_of(dashboard, "r1") == 20, 15)

        # The dashboard reads, and every change it asks for is dropped at the router or refused.
        for selector in ("twin/admin/reset/r1", "twin/admin/calibrate/r1?action=apply",
                         "twin/admin/calibrate/r1?action=discard", "twin/admin/**"):
            assert replies(dashboard, selector) == ([], []), selector
        oks, [refused] = replies(dashboard, "twin/calibrate/r1?action=apply")
        assert oks == [] and "twin/admin/calibrate/r1" in refused["error"], refused
        # A wide read that reaches the admin queryables changes nothing either.
        list(dashboard.get("twin/**", timeout=5.0))
        [(_, state)] = get_json(dashboard, "twin/state/r1")
        assert state["metrics"]["paired"] == 20, "the dashboard changed nothing"

        assert wait_until(lambda: denied(router, "dashboard", "Query", "twin/admin/reset/r1"), 10), router.log()
        assert denied(router, "dashboard", "Query", "twin/admin/calibrate/r1")

        # The operator reads and changes.
        [(_, by_operator)] = get_json(operator, "twin/state/r1")
        assert by_operator["metrics"]["paired"] == 20
        oks, errs = replies(operator, "twin/admin/reset/r1")
        assert errs == [] and len(oks) == 1 and oks[0]["paired"] == 20, (oks, errs)
        [(_, after)] = get_json(dashboard, "twin/state/r1")
        assert after["metrics"]["paired"] == 0, "reset by the operator"
        oks, [answer] = replies(operator, "twin/admin/calibrate/r1?action=discard")
        assert "does not self-calibrate" in answer["error"], "the service answered the operator"
    finally:
        for session in sessions:
            session.close()
        twin.stop()
        router.stop()


def _client(endpoint: str, tls: dict | None) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/timeout_ms", "3000")
    for key, value in (tls or {}).items():
        conf.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    return conf
