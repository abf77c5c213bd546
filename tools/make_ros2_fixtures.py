"""Writes the ROS 2 fixtures of tests/data/ros2/ (tests/python/support/ros2_fixtures.py says what
they are; test_ros2_fixtures.py checks the committed ones are what it writes).

    .venv/bin/python tools/make_ros2_fixtures.py [OUTPUT_DIR]   (default: tests/data/ros2)
"""

from __future__ import annotations

import sys
from pathlib import Path

# The shared test support (tests/python/support) is imported from beside the tests.
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "python"))
from support import ros2_fixtures  # noqa: E402

if __name__ == "__main__":
    ros2_fixtures.main(Path(sys.argv[1]) if len(sys.argv) > 1 else ros2_fixtures.DEFAULT_OUTPUT)
