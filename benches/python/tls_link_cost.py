"""What the TLS links cost the router: ``armtwin-router`` with the shipped TLS + access-control
configuration forwards ``--messages`` joint messages from a gateway session (certificate ``g1``)
to a dashboard session subscribed to them; prints the seconds from the first put to the last
arrival and the router's CPU seconds over the same span (README.md beside it, "TLS links").

    .venv/bin/python benches/python/tls_link_cost.py target/release/armtwin-router \\
        [--messages 200000] [--bytes 200]

Run it against two builds of the router (with and without vendor/zenoh-link-tls) to compare
them. The two sessions are Python's (the wheel's own TLS link); only the router differs. Not a
test: it prints figures, and exits 1 if a message did not arrive.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests" / "python"))
import zenoh  # noqa: E402

from support.pki import make_ca, make_cert  # noqa: E402
from support.process import Router, cpu_s, wait_until  # noqa: E402
from support.secured_fleet import ROUTER_CONFIG, open_as  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("router", type=Path)
    parser.add_argument("--messages", type=int, default=200_000)
    parser.add_argument("--bytes", type=int, default=200)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as scratch:
        workdir = Path(scratch)
        certs = workdir / "certs"
        certs.mkdir()
        make_ca(certs, "ca")
        for name in ("router", "g1", "dashboard"):
            make_cert(certs, name)
        router = Router(args.router.resolve(), workdir, config=ROUTER_CONFIG, scheme="tls",
                        env={"RUST_LOG": "warn"})
        router.start()
        try:
            return forward(router, certs, args.messages, b"x" * args.bytes)
        finally:
            router.stop()


def forward(router: Router, certs: Path, messages: int, payload: bytes) -> int:
    gateway, dashboard = open_as(router, certs, "g1"), open_as(router, certs, "dashboard")
    try:
        arrived = [0]
        done = threading.Event()

        def count(_sample) -> None:
            arrived[0] += 1
            if arrived[0] == messages:
                done.set()

        subscriber = dashboard.declare_subscriber("twin/joints/r1", count)
        publisher = gateway.declare_publisher("twin/joints/r1", congestion_control=zenoh.CongestionControl.BLOCK)
        if not wait_until(lambda: publisher.matching_status.matching, 20):
            print("the gateway's publisher never matched the dashboard's subscriber", file=sys.stderr)
            return 1
        cpu_before_s = cpu_s(router.proc.pid)
        started = time.monotonic()
        for _ in range(messages):
            publisher.put(payload)
        done.wait(timeout=300)
        seconds = time.monotonic() - started
        router_cpu_s = cpu_s(router.proc.pid) - cpu_before_s
        print(f"messages {arrived[0]}/{messages} seconds {seconds:.3f} "
              f"rate_per_s {arrived[0] / seconds:.0f} router_cpu_s {router_cpu_s:.3f} "
              f"router_cpu_us_per_message {1e6 * router_cpu_s / max(arrived[0], 1):.3f}")
        subscriber.undeclare()
        return 0 if arrived[0] == messages else 1
    finally:
        gateway.close()
        dashboard.close()


if __name__ == "__main__":
    sys.exit(main())
