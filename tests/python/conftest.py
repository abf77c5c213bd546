"""Shared fixtures for the armtwin Python reference tests.

The binary is ``$ARMTWIN_BIN`` if set, else ``<repo>/target/debug/armtwin``.
These tests never build it: run ``cargo build`` first.
"""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[2]
DATA_DIR = REPO_ROOT / "tests" / "data"
TIMEOUT_S = 60


def armtwin_path() -> Path:
    env = os.environ.get("ARMTWIN_BIN")
    return Path(env) if env else REPO_ROOT / "target" / "debug" / "armtwin"


def _require_binary() -> Path:
    path = armtwin_path()
    if not path.is_file():
        source = "ARMTWIN_BIN" if os.environ.get("ARMTWIN_BIN") else "default path"
        pytest.fail(
            f"armtwin binary not found at {path} ({source}). "
            "Build it first (cargo build) or set ARMTWIN_BIN to the binary's path.",
            pytrace=False,
        )
    if not os.access(path, os.X_OK):
        pytest.fail(f"armtwin binary at {path} is not executable.", pytrace=False)
    return path


@pytest.fixture(scope="session")
def armtwin_bin() -> Path:
    """Path of the armtwin binary; fails (never skips) if it is missing."""
    return _require_binary()


@pytest.fixture(scope="module")
def router_bin(armtwin_bin) -> Path:
    """``armtwin-router`` beside the armtwin binary (or ``$ARMTWIN_ROUTER_BIN``); fails if missing."""
    from fleet import router_path

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


def run_armtwin(*args, input: str | None = None) -> subprocess.CompletedProcess:
    """Run armtwin with ``args`` (converted with str), text mode, 60 s timeout."""
    binary = _require_binary()
    return subprocess.run(
        [str(binary), *(str(a) for a in args)],
        input=input,
        stdin=subprocess.DEVNULL if input is None else None,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )
