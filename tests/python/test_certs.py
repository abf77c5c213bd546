"""`armtwin certs`: a fleet's certificates by role, read back with openssl (only the router's
serves, for the names given; every fleet name's is a client's, its name the subject's CN; keys
0600; existing files kept unless --force), and a gateway's certificate presented as the router
refused by armtwin and by the Python Zenoh client."""

from __future__ import annotations

import stat
import subprocess
import tomllib
from pathlib import Path

import pytest
import zenoh

from support.paths import REPO_ROOT
from support.pki import make_fleet_certs, tls_of
from support.process import Armtwin, Router, free_port, run_armtwin
from support.secured_fleet import CLIENT_CONFIG, tls_client_config

FLEET = REPO_ROOT / "config" / "fleet.toml"


def fleet_names() -> list[str]:
    fleet = tomllib.loads(FLEET.read_text())
    return fleet["armtwin"] + fleet["dashboards"] + fleet["operators"] + list(fleet["gateways"])


def openssl(*args) -> subprocess.CompletedProcess:
    return subprocess.run(["openssl", *map(str, args)], capture_output=True, text=True, timeout=60)


def verifies(folder: Path, name: str, purpose: str) -> bool:
    result = openssl("verify", "-CAfile", folder / "ca.pem", "-purpose", purpose, folder / f"{name}.pem")
    return result.returncode == 0 and result.stdout.strip().endswith("OK")


def text_of(folder: Path, name: str) -> str:
    result = openssl("x509", "-in", folder / f"{name}.pem", "-noout", "-text")
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_only_the_routers_certificate_serves_and_every_name_is_a_client(tmp_path, armtwin_bin):
    folder = tmp_path / "certs"
    make_fleet_certs(armtwin_bin, FLEET, folder, "--router-name", "localhost",
                     "--router-name", "router.plant", "--router-name", "10.1.2.3")
    names = fleet_names()
    assert sorted(p.stem for p in folder.glob("*.pem")) == sorted(["ca", "router", *names])

    router = text_of(folder, "router")
    assert verifies(folder, "router", "sslserver") and verifies(folder, "router", "sslclient")
    assert "DNS:localhost, DNS:router.plant, IP Address:10.1.2.3" in router, router
    assert "TLS Web Server Authentication" in router
    for name in names:
        text = text_of(folder, name)
        assert verifies(folder, name, "sslclient"), name
        assert not verifies(folder, name, "sslserver"), f"{name}'s certificate could serve:\n{text}"
        assert f"Subject: CN = {name}\n" in text, text
        assert "TLS Web Client Authentication" in text
        assert "Server Authentication" not in text and "Subject Alternative Name" not in text, text
        assert "CA:FALSE" in text
    assert "CA:TRUE" in text_of(folder, "ca")
    for key in folder.glob("*.key"):
        assert stat.S_IMODE(key.stat().st_mode) == 0o600, key

    # Files already there are kept, all of them, unless --force.
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    again = run_armtwin("certs", FLEET, folder)
    assert again.returncode != 0 and "--force" in again.stderr and "ca.key" in again.stderr, again.stderr
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    make_fleet_certs(armtwin_bin, FLEET, folder, "--force")
    assert (folder / "ca.pem").read_bytes() != before["ca.pem"]
    assert stat.S_IMODE((folder / "g1.key").stat().st_mode) == 0o600


@pytest.mark.parametrize("args, expected", [
    (["--router-name", "*.plant"], "router name '*.plant' is neither an IP address nor a DNS name"),
    (["--router-name", "10.0.0.300"], "router name '10.0.0.300'"),
    (["--days", "0"], "--days 0"),
])
def test_bad_requests_are_refused_with_the_reason(tmp_path, args, expected):
    result = run_armtwin("certs", FLEET, tmp_path / "certs", *args)
    assert result.returncode != 0 and expected in result.stderr, result.stderr
    assert "panicked" not in result.stderr and not (tmp_path / "certs").exists()


def test_a_fleet_name_that_would_leave_the_folder_or_take_the_routers_files_is_refused(tmp_path):
    for name, expected in (("../g1", "path separator"), ("router", "the CA's and the router's")):
        fleet = tmp_path / "fleet.toml"
        fleet.write_text(f'[gateways]\n"{name}" = ["r1"]\n')
        result = run_armtwin("certs", fleet, tmp_path / "certs")
        assert result.returncode != 0 and expected in result.stderr, result.stderr
        assert not (tmp_path / "certs").exists() and not (tmp_path / "g1.pem").exists()


def imposter_config(tmp_path: Path, certs: Path, name: str) -> Path:
    """A router configuration listening with ``name``'s certificate and key, TLS with client
    certificates of the fleet's CA."""
    config = tmp_path / f"router-as-{name}.json5"
    config.write_text(
        '{ mode: "router", scouting: { multicast: { enabled: false } },\n'
        '  transport: { link: { tls: {\n'
        f'    root_ca_certificate: "{certs / "ca.pem"}",\n'
        f'    listen_private_key: "{certs / f"{name}.key"}",\n'
        f'    listen_certificate: "{certs / f"{name}.pem"}",\n'
        '    enable_mtls: true } } } }\n')
    return config


@pytest.mark.parametrize("serving_as", ["g1", "router"])
def test_a_gateways_certificate_cannot_pose_as_the_router(tmp_path, certs, armtwin_bin, router_bin,
                                                          processes, serving_as):
    """With ``router``, the fleet's router certificate, every client connects: the control."""
    router = Router(router_bin, tmp_path, config=imposter_config(tmp_path, certs, serving_as),
                    scheme="tls", env={"RUST_LOG": "warn"})
    processes.append(router.start())

    # The Python client, presenting armtwin's certificate and verifying the router's.
    try:
        session = zenoh.open(tls_client_config(router.endpoint, tls_of(certs, "armtwin")))
    except zenoh.ZError as error:
        session = None
        refusal = str(error)
    if serving_as == "router":
        assert session is not None
        session.close()
    else:
        assert session is None, "the Python client took a gateway's certificate as the router"
        assert "Unable to connect" in refusal, refusal

    # armtwin, as config/zenoh-client-tls.json5 has it.
    twin = Armtwin(armtwin_bin, tmp_path, "twin", f'[zenoh]\nfile = "{CLIENT_CONFIG}"\n',
                   router.endpoint)
    (tmp_path / "twin" / "certs").symlink_to(certs)
    # armtwin's own default filter: the refusal must be plain to an operator who set nothing.
    twin.env["RUST_LOG"] = "armtwin=info,zenoh=warn"
    processes.append(twin.start(ready=False))
    if serving_as == "router":
        assert twin.wait_log("robots claimed"), twin.logs()
        return
    stopped = twin.proc.wait(timeout=30)
    logs = twin.logs(limit=10**6)
    assert stopped != 0 and "armtwin serving" not in logs, logs
    assert "does not allow extended key usage for server authentication" in logs, logs
