"""Shared fixtures for the armtwin Python reference tests; what the tests share besides fixtures
is in ``support/`` (its ``__init__`` lists the modules).

The binary is ``$ARMTWIN_BIN`` if set, else ``<repo>/target/debug/armtwin``.
These tests never build it: run ``cargo build`` first.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

# `support` is imported from this directory whichever way pytest imports the test modules.
HERE = str(Path(__file__).resolve().parent)
if HERE not in sys.path:
    sys.path.insert(0, HERE)

from support.paths import require_armtwin, router_path  # noqa: E402
from support.pki import make_ca, make_cert  # noqa: E402


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
def certs(tmp_path_factory) -> Path:
    """A fleet's certificate authority and a certificate for each name config/fleet.toml gives a
    role, and one of another authority."""
    folder = tmp_path_factory.mktemp("pki") / "certs"
    folder.mkdir()
    make_ca(folder, "ca")
    # The names config/fleet.toml gives roles: gateways g1 (robot r1), g2 (r2) and cell-a
    # (site-a/**), REST's `rest`.
    for name in ("router", "armtwin", "g1", "g2", "cell-a", "rest", "dashboard", "operator"):
        make_cert(folder, name)
    # A certificate named like a gateway, signed by a CA the router does not trust.
    make_ca(folder, "stranger-ca")
    make_cert(folder, "stranger", ca="stranger-ca")
    return folder
