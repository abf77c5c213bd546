"""The shipped TLS router's links hold while both ends read and write at once: through
config/router-tls-acl.json5, a gateway starts ``ROBOTS`` with a burst of ``BURST`` joint samples
each while armtwin declares their publishers and sends their poses and deviations to a dashboard,
and spinning processes keep the cores busy; armtwin's one link to the router is never reopened,
and every sample is paired unless a Python session's own link was reopened (the wheel's TLS link
is not armtwin's).

Zenoh's TLS link let a link's reading and writing tasks use one rustls connection at the same
time: a write that met a read failed with "handshake not complete", and the link was closed and
reopened, losing what was in flight. armtwin builds a patched copy; vendor/zenoh-link-tls/PATCHED.md
has what this test measured of both.
"""

from __future__ import annotations

import subprocess
import sys

from support.gateway import Gateway
from support.process import wait_until
from support.secured_fleet import secured_fleet, send
from support.zenoh_clients import get_json, wait_queryable

ROBOTS = [f"site-a/r{i}" for i in range(80)]
BURST = 10
# armtwin and the router log each transport they open (Zenoh's own line, at debug).
OPENED = "New transport opened between"
# Zenoh's routing and transport at debug on both ends: the time each message then takes widens
# the window in which the reading and the writing task meet, so that the unpatched link fails
# in most runs rather than in a few.
TRANSPORT_LOG = "zenoh_transport=debug,zenoh::net=debug"


def spinning(count: int) -> list[subprocess.Popen]:
    """``count`` processes that only spin, to keep the cores busy; each stops by itself in 60 s."""
    spin = "import time\nend = time.monotonic() + 60\nwhile time.monotonic() < end: pass\n"
    return [subprocess.Popen([sys.executable, "-c", spin]) for _ in range(count)]


def test_the_tls_links_hold_under_reads_and_writes_at_once(tmp_path, certs, armtwin_bin):
    with secured_fleet(tmp_path, certs, armtwin_bin, ["cell-a", "dashboard"], log=TRANSPORT_LOG) as (
        router, sessions, twin
    ):
        gateway, dashboard = sessions["cell-a"], sessions["dashboard"]
        assert twin.logs(10**9).count(OPENED) == 1, twin.logs()
        # Every pose and deviation back out: armtwin writes on its link as much as it reads.
        outputs = [dashboard.declare_subscriber(f"twin/{stream}/**", lambda sample: None)
                   for stream in ("pose", "deviation")]
        assert wait_queryable(dashboard, "twin/state/**")
        spinners = []
        try:
            spinners += spinning(3)
            for robot in ROBOTS:
                send(Gateway(gateway, robot), count=BURST)
        finally:
            for spinner in spinners:
                spinner.kill()
                spinner.wait()

        def paired() -> dict[str, int]:
            return {key.removeprefix("twin/state/"): state["metrics"]["paired"]
                    for key, state in get_json(dashboard, "twin/state/site-a/**")}

        wait_until(lambda: all(paired().get(robot) == BURST for robot in ROBOTS), 15)
        reopened = twin.logs(10**9).count(OPENED) - 1
        short = {robot: count for robot in ROBOTS if (count := paired().get(robot)) != BURST}
        assert reopened == 0, f"armtwin's link to the router was reopened {reopened} times; short: {short}"
        # The Python sessions' links use the wheel's unpatched TLS: one that was reopened (the
        # router opened more than armtwin's and the sessions') explains a shortfall.
        others_reopened = router.logs(10**9).count(OPENED) - (1 + len(sessions))
        assert not short or others_reopened > 0, f"robots short of {BURST} pairs: {short}"
        del outputs
