"""Where the repository, its test data and the binaries under test are.

The binary is ``$ARMTWIN_BIN`` if set, else ``<repo>/target/debug/armtwin``; the tests never
build it (``cargo build`` first) and fail, never skip, when it is missing.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[3]
DATA_DIR = REPO_ROOT / "tests" / "data"
# The stand-ins (rtde_server.py, rtde_readback.py, ros2_driver.py) run by path from here.
SUPPORT_DIR = Path(__file__).resolve().parent


def armtwin_path() -> Path:
    env = os.environ.get("ARMTWIN_BIN")
    return Path(env) if env else REPO_ROOT / "target" / "debug" / "armtwin"


def router_path(armtwin_bin: Path) -> Path:
    """``$ARMTWIN_ROUTER_BIN``, else ``armtwin-router`` beside the armtwin binary."""
    env = os.environ.get("ARMTWIN_ROUTER_BIN")
    return Path(env) if env else Path(armtwin_bin).with_name("armtwin-router")


def require_armtwin() -> Path:
    """The armtwin binary's path; fails the test if it is missing or not executable."""
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
