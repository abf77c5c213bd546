"""Helpers for the end-to-end tests of ``armtwin serve`` over Zenoh.

Written against docs/protocol.md (the wire contract), not the Rust source.

* :class:`ArmtwinProcess` runs the real binary on a private loopback port, with stdout/stderr in
  files, a watchdog that kills it if a test overruns, and a bounded SIGINT shutdown.
* :class:`Collector` records every output sample (``twin/**`` minus the input subtrees) in a
  thread-safe list from the Zenoh callback; JSON is decoded later, off the receive thread.
* :class:`TwinClient` is one Python Zenoh peer: it declares the output subscriber, per-robot input
  publishers (congestion control BLOCK, remote destinations only) and waits until armtwin's
  subscribers and queryables are matched and armtwin has seen the subscriber (a query round trip).

Every wait here is bounded.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import zenoh

PREFIX = "twin"
INPUT_STREAMS = ("joints", "measured")
OUTPUT_STREAMS = ("pose", "deviation", "metrics", "events")

STARTUP_TIMEOUT_S = 30.0
SHUTDOWN_TIMEOUT_S = 15.0
MATCH_TIMEOUT_S = 15.0
QUERY_TIMEOUT_S = 10.0


def free_port() -> int:
    """A TCP port that was free on 127.0.0.1 a moment ago (bind to port 0, read, close)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def port_accepts(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=0.5):
            return True
    except OSError:
        return False


def cpu_s(pid: int) -> float:
    """User plus system CPU seconds process ``pid`` has used (from /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def wait_until(predicate, timeout: float, interval: float = 0.01) -> bool:
    """Poll ``predicate`` until true or ``timeout`` seconds pass; returns its last value."""
    deadline = time.monotonic() + timeout
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return bool(predicate())
        time.sleep(interval)


# --------------------------------------------------------------------------------------------
# the process
# --------------------------------------------------------------------------------------------


class ArmtwinProcess:
    """``armtwin serve -c CONFIG -l tcp/127.0.0.1:PORT`` as a subprocess."""

    def __init__(self, binary: Path, workdir: Path, config_text: str, watchdog_s: float):
        self.binary = Path(binary)
        self.workdir = Path(workdir)
        self.config_path = self.workdir / "armtwin.toml"
        self.config_path.write_text(config_text)
        self.stdout_path = self.workdir / "armtwin.stdout"
        self.stderr_path = self.workdir / "armtwin.stderr"
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.proc: subprocess.Popen | None = None
        self.returncode: int | None = None
        self.sigint_at: float | None = None
        self.watchdog_fired = False
        self._watchdog_s = watchdog_s
        self._watchdog: threading.Timer | None = None
        self._files = []

    # -- lifecycle -------------------------------------------------------------------------

    def start(self) -> None:
        out = open(self.stdout_path, "wb")
        err = open(self.stderr_path, "wb")
        self._files = [out, err]
        self.proc = subprocess.Popen(
            [str(self.binary), "serve", "-c", str(self.config_path), "-l", self.endpoint],
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=err,
            cwd=self.workdir,
            start_new_session=True,  # a terminal's Ctrl-C does not reach it; we signal it ourselves
        )
        self._watchdog = threading.Timer(self._watchdog_s, self._on_watchdog)
        self._watchdog.daemon = True
        self._watchdog.start()
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while not port_accepts(self.port):
            if self.proc.poll() is not None:
                raise RuntimeError(
                    f"armtwin exited with {self.proc.returncode} before listening on {self.endpoint}"
                    f"\n{self.logs()}"
                )
            if time.monotonic() > deadline:
                raise RuntimeError(
                    f"armtwin did not listen on {self.endpoint} within {STARTUP_TIMEOUT_S} s\n{self.logs()}"
                )
            time.sleep(0.02)

    def _on_watchdog(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.watchdog_fired = True
            self.proc.kill()

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def interrupt(self) -> None:
        """Send SIGINT once (no wait)."""
        if self.running() and self.sigint_at is None:
            self.sigint_at = time.monotonic()
            self.proc.send_signal(signal.SIGINT)

    def stop(self, timeout: float = SHUTDOWN_TIMEOUT_S) -> tuple[int | None, float | None]:
        """SIGINT, wait up to ``timeout`` s; kill if still alive. Returns (exit code, seconds taken),
        seconds None if it had to be killed (or had already exited before)."""
        if self.proc is None:
            return None, None
        if self.returncode is not None:
            return self.returncode, None
        took = None
        if self.proc.poll() is None:
            self.interrupt()
            try:
                self.proc.wait(timeout=max(0.0, timeout - (time.monotonic() - self.sigint_at)))
                took = time.monotonic() - self.sigint_at
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
                self.returncode = self.proc.returncode
                self._cleanup()
                return None, None
        self.returncode = self.proc.returncode
        self._cleanup()
        return self.returncode, took

    def _cleanup(self) -> None:
        if self._watchdog is not None:
            self._watchdog.cancel()
        for f in self._files:
            f.close()
        self._files = []

    def logs(self, limit: int = 4000) -> str:
        parts = []
        for name, path in (("stdout", self.stdout_path), ("stderr", self.stderr_path)):
            try:
                text = path.read_text(errors="replace")
            except OSError:
                text = ""
            if len(text) > limit:
                text = "…" + text[-limit:]
            parts.append(f"--- armtwin {name} ({path}) ---\n{text}")
        return "\n".join(parts)


# --------------------------------------------------------------------------------------------
# the client
# --------------------------------------------------------------------------------------------


def open_session(endpoint: str) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


@dataclass
class Received:
    at: float  # time.monotonic() at reception
    key: str
    payload: bytes
    _json: object = field(default=None, repr=False)

    @property
    def stream(self) -> str:
        return self.key.split("/", 2)[1]

    @property
    def robot(self) -> str:
        return self.key.split("/", 2)[2]

    def json(self):
        if self._json is None:
            self._json = json.loads(self.payload)
        return self._json


class Collector:
    """Thread-safe record of output samples, in arrival order."""

    def __init__(self):
        self._lock = threading.Lock()
        self._items: list[Received] = []
        self._counts: dict[tuple[str, str], int] = {}
        self.ignored_inputs = 0

    def __call__(self, sample: zenoh.Sample) -> None:
        key = str(sample.key_expr)
        parts = key.split("/", 2)
        if len(parts) < 3 or parts[1] in INPUT_STREAMS:
            with self._lock:
                self.ignored_inputs += 1
            return
        item = Received(time.monotonic(), key, sample.payload.to_bytes())
        with self._lock:
            self._items.append(item)
            k = (parts[1], parts[2])
            self._counts[k] = self._counts.get(k, 0) + 1

    def count(self, stream: str, robot: str) -> int:
        with self._lock:
            return self._counts.get((stream, robot), 0)

    def items(self, stream: str | None = None, robot: str | None = None) -> list[Received]:
        with self._lock:
            items = list(self._items)
        return [
            i
            for i in items
            if (stream is None or i.stream == stream) and (robot is None or i.robot == robot)
        ]

    def messages(self, stream: str, robot: str) -> list[dict]:
        return [i.json() for i in self.items(stream, robot)]

    def last(self, stream: str, robot: str) -> dict | None:
        items = self.items(stream, robot)
        return items[-1].json() if items else None

    def wait_count(self, stream: str, robot: str, n: int, timeout: float) -> bool:
        return wait_until(lambda: self.count(stream, robot) >= n, timeout)

    def wait_message(self, stream: str, robot: str, predicate, timeout: float) -> dict | None:
        """The first message on ``stream``/``robot`` satisfying ``predicate``, polled until
        ``timeout``; None if none."""
        seen = 0
        deadline = time.monotonic() + timeout
        while True:
            items = self.items(stream, robot)
            for item in items[seen:]:
                msg = item.json()
                if predicate(msg):
                    return msg
            seen = len(items)
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.02)


def reply_payloads(replies) -> tuple[list[tuple[str, dict]], list[dict]]:
    """Split replies into ([(key, ok json)], [error json])."""
    oks, errs = [], []
    for reply in replies:
        if reply.ok is not None:
            oks.append((str(reply.ok.key_expr), json.loads(reply.ok.payload.to_bytes())))
        else:
            raw = reply.err.payload.to_bytes()
            try:
                errs.append(json.loads(raw))
            except ValueError:
                errs.append({"<raw>": raw.decode(errors="replace")})
    return oks, errs


class TwinClient:
    """One Python Zenoh peer connected to armtwin's listener."""

    def __init__(self, endpoint: str):
        self.session = open_session(endpoint)
        self.collector = Collector()
        self.subscriber = self.session.declare_subscriber(f"{PREFIX}/**", self.collector)
        self._publishers: dict[str, zenoh.Publisher] = {}
        self._closed = False

    def publisher(self, key: str) -> zenoh.Publisher:
        pub = self._publishers.get(key)
        if pub is None:
            pub = self.session.declare_publisher(
                key,
                congestion_control=zenoh.CongestionControl.BLOCK,
                reliability=zenoh.Reliability.RELIABLE,
                allowed_destination=zenoh.Locality.REMOTE,  # our own twin/** does not count
            )
            self._publishers[key] = pub
        return pub

    def joints(self, robot: str) -> zenoh.Publisher:
        return self.publisher(f"{PREFIX}/joints/{robot}")

    def measured(self, robot: str) -> zenoh.Publisher:
        return self.publisher(f"{PREFIX}/measured/{robot}")

    def ready(self, robots, measured: bool = False, timeout: float = MATCH_TIMEOUT_S) -> None:
        """Declare the input publishers of ``robots``, wait until armtwin's subscribers match
        them and its state queryable matches, then do one ``get twin/state/**`` round trip so
        armtwin has processed our subscriber declaration (declarations and queries share the
        ordered link)."""
        pubs = [self.joints(r) for r in robots]
        if measured:
            pubs += [self.measured(r) for r in robots]
        if not wait_until(lambda: all(p.matching_status.matching for p in pubs), timeout):
            missing = [str(p.key_expr) for p in pubs if not p.matching_status.matching]
            raise AssertionError(f"armtwin's subscribers never matched {missing} within {timeout} s")
        querier = self.session.declare_querier(
            f"{PREFIX}/state/**", allowed_destination=zenoh.Locality.REMOTE, timeout=QUERY_TIMEOUT_S
        )
        try:
            if not wait_until(lambda: querier.matching_status.matching, timeout):
                raise AssertionError(f"armtwin's state queryable never matched within {timeout} s")
        finally:
            querier.undeclare()
        self.get(f"{PREFIX}/state/**")

    def put_json(self, pub: zenoh.Publisher, obj) -> None:
        pub.put(json.dumps(obj, allow_nan=False))

    def get(self, selector: str, payload: bytes | str | None = None, timeout: float = QUERY_TIMEOUT_S):
        """A bounded query; returns the list of replies once all queryables finished."""
        kwargs = {}
        if payload is not None:
            kwargs["payload"] = payload
        handler = self.session.get(
            selector,
            timeout=timeout,
            consolidation=zenoh.ConsolidationMode.NONE,
            allowed_destination=zenoh.Locality.REMOTE,
            **kwargs,
        )
        # The channel ends when every queryable sent its final reply or the timeout fires.
        return list(handler)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self.session.close()
        except Exception:  # pragma: no cover - teardown must not mask the test's failure
            pass

