"""Shared fixtures for the armtwin Python reference tests; what the tests share besides fixtures
is in ``support/`` (its ``__init__`` lists the modules).

The binary is ``$ARMTWIN_BIN`` if set, else ``<repo>/target/debug/armtwin``.
These tests never build it: run ``cargo build`` first.
"""

from __future__ import annotations

import shutil
import signal
import sys
from pathlib import Path

import pytest
import zenoh

# Zenoh's errors in the test's own sessions (a link it closed, and why) land in the captured
# output of the test that failed; without this, only the service's side of a link was logged.
zenoh.init_log_from_env_or("error")

# `support` is imported from this directory whichever way pytest imports the test modules.
HERE = str(Path(__file__).resolve().parent)
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from support.paths import REPO_ROOT, require_armtwin, router_path  # noqa: E402
from support.pki import make_fleet_certs  # noqa: E402

# A test command started in the background (`cmd &` in a script, nohup) runs with SIGINT ignored,
# which every process it starts inherits: the stand-ins and services the tests stop with SIGINT
# then run until they are killed, 15 s each. A handler here gives every child the default again.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="session")
def armtwin_bin() -> Path:
    """Path of the armtwin binary; fails (never skips) if it is missing."""
    return require_armtwin()


@pytest.fixture(scope="module")
def router_bin(armtwin_bin) -> Path:
    """``armtwin-router`` beside the armtwin binary (or ``$ARMTWIN_ROUTER_BIN``); fails if missing."""
    path = router_path(armtwin_bin)
    if not path.is_file():
        pytest.fail(f"armtwin-router not found at {path}: cargo build --workspace first", pytrace=False)
    return path


@pytest.fixture
def processes():
    """Processes a test started, stopped (SIGINT, bounded) in reverse order after it."""
    started = []
    yield started
    for process in reversed(started):
        process.stop()


@pytest.fixture
def sessions():
    """Zenoh sessions a test opened, closed after it."""
    opened = []
    yield opened
    for session in opened:
        try:
            session.close()
        except Exception:
            pass


@pytest.fixture(scope="module")
def certs(tmp_path_factory, armtwin_bin) -> Path:
    """``armtwin certs config/fleet.toml``: the fleet's CA, the router's certificate (localhost,
    127.0.0.1) and a client certificate for each name the description gives a role (gateways g1,
    g2 and cell-a, armtwin, dashboard, REST's rest, operator); and ``stranger``, a gateway's
    certificate from a CA the router does not trust (``stranger-ca.pem``)."""
    folder = tmp_path_factory.mktemp("pki") / "certs"
    make_fleet_certs(armtwin_bin, REPO_ROOT / "config" / "fleet.toml", folder)
    other = tmp_path_factory.mktemp("stranger-pki")
    (other / "fleet.toml").write_text('[gateways]\nstranger = ["r1"]\n')
    make_fleet_certs(armtwin_bin, other / "fleet.toml", other / "certs")
    shutil.copy(other / "certs" / "ca.pem", folder / "stranger-ca.pem")
    for suffix in (".pem", ".key"):
        shutil.copy(other / "certs" / f"stranger{suffix}", folder / f"stranger{suffix}")
    return folder
