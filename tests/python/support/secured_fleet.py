"""The shipped secured fleet: the router with TLS and access control (config/router-tls-acl.json5,
its access control generated from config/fleet.toml), armtwin behind it with its certificate
(config/zenoh-client-tls.json5), and sessions that present the certificates of
``support.pki``."""

from __future__ import annotations

import json
import time
from contextlib import contextmanager
from pathlib import Path

import zenoh

from support.gateway import Gateway
from support.paths import REPO_ROOT, router_path
from support.pki import tls_of
from support.process import Armtwin, Router, free_port, wait_until
from support.zenoh_clients import paired_of, wait_matched, wait_queryable

ROUTER_CONFIG = REPO_ROOT / "config" / "router-tls-acl.json5"
CLIENT_CONFIG = REPO_ROOT / "config" / "zenoh-client-tls.json5"
ACL_LOG = "z=info,zenoh::net::routing::interceptor::access_control=trace"


def tls_router_and_twin(tmp_path, certs, armtwin_bin, log: str = "") -> tuple[Router, Armtwin]:
    """The shipped TLS + ACL router and armtwin behind it with its certificate, not started;
    ``log`` adds tracing directives to both's logs."""
    (tmp_path / "certs").symlink_to(certs)
    more = f",{log}" if log else ""
    router = Router(router_path(armtwin_bin), tmp_path, config=ROUTER_CONFIG, scheme="tls",
                    env={"RUST_LOG": ACL_LOG + more})
    twin = Armtwin(
        armtwin_bin, tmp_path, "twin",
        # The router's ACL decides who may change a twin (operators only): `admin = "mesh"`.
        f'[zenoh]\nfile = "{CLIENT_CONFIG}"\n[service]\npose_congestion = "block"\nadmin = "mesh"\n',
        router.endpoint,
    )
    (tmp_path / "twin" / "certs").symlink_to(certs)
    twin.env["RUST_LOG"] += more
    return router, twin


def open_as(router: Router, certs: Path, name: str) -> zenoh.Session:
    """A client session of ``router`` with the certificate ``name``."""
    return zenoh.open(tls_client_config(router.endpoint, tls_of(certs, name)))


def stream_until_paired(gateway: Gateway, router: Router, reader: zenoh.Session, robot: str,
                        at_least: int = 20, timeout: float = 30.0) -> int:
    """Streams ``gateway`` (at its rate, once armtwin's subscriber matched its publisher) until
    the state answer ``reader`` gets for ``robot`` pairs ``at_least`` samples, then stops it;
    returns the paired count once two answers 0.3 s apart agree.

    These tests are about who may speak for a robot, so they stream until the twin has heard
    enough rather than count what one burst delivered: the Python sessions' TLS link (the
    wheel's, without armtwin's fix: vendor/zenoh-link-tls/PATCHED.md) may be reopened under
    load, losing what was in flight. Delivery itself is test_tls_link.py's."""
    wait_matched(gateway.pub)
    gateway.start()
    try:
        reached = wait_until(lambda: (paired_of(reader, robot) or 0) >= at_least, timeout)
    finally:
        gateway.stop()
    assert reached, f"{robot} paired {paired_of(reader, robot)} < {at_least} in {timeout} s\n{router.logs()}"
    counts = [paired_of(reader, robot)]
    time.sleep(0.3)

    def settled() -> bool:
        counts.append(paired_of(reader, robot))
        return counts[-1] is not None and counts[-1] == counts[-2]

    assert wait_until(settled, 10.0, interval=0.3), f"{robot}'s paired count did not settle: {counts}"
    return counts[-1]


def send(gateway: Gateway, count: int = 20) -> None:
    """Waits until ``gateway``'s publisher knows armtwin's subscriber, then sends ``count`` samples."""
    wait_matched(gateway.pub)
    for _ in range(count):
        gateway.send_one()
        time.sleep(0.005)


@contextmanager
def secured_fleet(tmp_path, certs, armtwin_bin, names: list[str], rest: list[str] | None = None, log: str = ""):
    """The shipped secured router (with ``rest``, REST flags, if given) and armtwin behind it,
    started, with a session per certificate name in ``names`` and a dashboard's view of armtwin's
    queryables; yields the router, the sessions by name and armtwin; stops everything after.
    ``log`` adds tracing directives to the router's and armtwin's logs."""
    router, twin = tls_router_and_twin(tmp_path, certs, armtwin_bin, log)
    if rest is not None:
        router.rest_port = free_port()
        router.argv += ["--rest-http-port", f"127.0.0.1:{router.rest_port}", *rest]
    sessions = {}
    try:
        router.start()
        twin.start()
        sessions = {name: open_as(router, certs, name) for name in names}
        assert wait_queryable(sessions["dashboard"], "twin/state/**"), router.logs()
        yield router, sessions, twin
    except BaseException:
        print(f"armtwin's log:\n{twin.logs()}")  # shown with the failure
        raise
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
        for line in router.logs(10**9).splitlines()
    )


def tls_client_config(endpoint: str, tls: dict | None) -> zenoh.Config:
    """A client configuration of ``endpoint`` presenting ``tls`` (no certificate if None), which
    gives up connecting after 3 s."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/timeout_ms", "3000")
    for key, value in (tls or {}).items():
        conf.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    return conf
