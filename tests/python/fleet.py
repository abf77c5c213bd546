"""The processes and clients of the deployment tests: a real Zenoh router (``armtwin-router``, zenohd's engine with
the REST plugin linked in), armtwin instances in client mode behind it, and Python Zenoh clients
(gateways, dashboards) that reach armtwin only through the router.

Written against docs/protocol.md and Zenoh's own configuration keys, not the Rust source. Every
process runs on 127.0.0.1 ports chosen free a moment before, with multicast scouting off, has a
watchdog that kills it if a test overruns, and stops within a bounded time. Every wait is bounded.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import zenoh

from armtwin_service import free_port, port_accepts, wait_until

STARTUP_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 15.0
WATCHDOG_S = 240.0


def router_path(armtwin_bin: Path) -> Path:
    """``$ARMTWIN_ROUTER_BIN``, else ``armtwin-router`` beside the armtwin binary."""
    env = os.environ.get("ARMTWIN_ROUTER_BIN")
    return Path(env) if env else Path(armtwin_bin).with_name("armtwin-router")


class Process:
    """A subprocess with its output in files, a watchdog, and a bounded SIGINT stop."""

    def __init__(self, name: str, argv: list[str], workdir: Path, env: dict | None = None):
        self.name = name
        self.argv = [str(a) for a in argv]
        self.workdir = Path(workdir)
        self.env = env
        self.log_path = self.workdir / f"{name}.log"
        self.proc: subprocess.Popen | None = None
        self._log = None
        self._watchdog: threading.Timer | None = None

    def start(self) -> "Process":
        # A restarted process logs to a file of its own: waits on the log see this run alone.
        run = 1
        while (self.workdir / f"{self.name}-{run}.log").exists():
            run += 1
        self.log_path = self.workdir / f"{self.name}-{run}.log"
        self._log = open(self.log_path, "wb")
        environment = dict(os.environ)
        environment.update(self.env or {})
        self.proc = subprocess.Popen(
            self.argv,
            stdin=subprocess.DEVNULL,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            cwd=self.workdir,
            env=environment,
            start_new_session=True,
        )
        self._watchdog = threading.Timer(WATCHDOG_S, self.kill)
        self._watchdog.daemon = True
        self._watchdog.start()
        return self

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def kill(self) -> None:
        """SIGKILL: no teardown at all (a crash, a power cut)."""
        if self.running():
            self.proc.kill()
            self.proc.wait(timeout=10)
        self._close()

    def stop(self, timeout: float = STOP_TIMEOUT_S) -> int | None:
        """SIGINT and wait; killed if it overruns (then None)."""
        if self.proc is None:
            return None
        if self.running():
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=10)
                self._close()
                return None
        self._close()
        return self.proc.returncode

    def _close(self) -> None:
        if self._watchdog is not None:
            self._watchdog.cancel()
        if self._log is not None:
            self._log.close()
            self._log = None

    def log(self, limit: int = 6000) -> str:
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return text if len(text) <= limit else "…" + text[-limit:]

    def wait_log(self, needle: str, timeout: float = STARTUP_TIMEOUT_S) -> bool:
        return wait_until(lambda: needle in self.log(limit=10**9) or not self.running(), timeout) and (
            needle in self.log(limit=10**9)
        )


class Router(Process):
    """``armtwin-router`` listening on one loopback port, REST on another if asked."""

    def __init__(self, binary: Path, workdir: Path, rest: bool = False, config: Path | None = None,
                 port: int | None = None, scheme: str = "tcp", env: dict | None = None,
                 connect: list[str] | None = None):
        self.port = port or free_port()
        self.rest_port = free_port() if rest else None
        self.endpoint = f"{scheme}/127.0.0.1:{self.port}" if scheme == "tcp" else f"{scheme}/localhost:{self.port}"
        argv = [binary, "-l", self.endpoint, "--no-multicast-scouting"]
        if config is not None:
            argv += ["-c", config]
        for endpoint in connect or []:
            argv += ["-e", endpoint]
        if rest:
            argv += ["--rest-http-port", f"127.0.0.1:{self.rest_port}"]
        super().__init__(f"router-{self.port}", argv, workdir, env)

    def start(self) -> "Router":
        super().start()
        if not wait_until(lambda: port_accepts(self.port) or not self.running(), STARTUP_TIMEOUT_S) or not self.running():
            raise RuntimeError(f"armtwin-router did not listen on {self.endpoint}\n{self.log()}")
        if self.rest_port is not None and not wait_until(lambda: port_accepts(self.rest_port), STARTUP_TIMEOUT_S):
            raise RuntimeError(f"armtwin-router's REST did not listen on {self.rest_port}\n{self.log()}")
        return self


class Armtwin(Process):
    """``armtwin serve -m client -e <router>`` with a configuration of its own."""

    def __init__(self, binary: Path, workdir: Path, name: str, config_text: str, router_endpoint: str,
                 extra: list[str] | None = None, wrapper: list[str] | None = None):
        workdir = Path(workdir) / name
        workdir.mkdir(parents=True, exist_ok=True)
        self.config_path = workdir / "armtwin.toml"
        self.config_path.write_text(config_text)
        argv = [binary, "serve", "-c", self.config_path, "-m", "client", "-e", router_endpoint]
        # `wrapper` runs armtwin through another command (e.g. `unshare`), which must exec it.
        argv = list(wrapper or []) + argv + list(extra or [])
        super().__init__(name, argv, workdir, {"RUST_LOG": "armtwin=info"})

    def start(self, ready: bool = True) -> "Armtwin":
        super().start()
        if ready and not self.wait_log("robots claimed"):
            raise RuntimeError(f"{self.name} did not start\n{self.log()}")
        return self


def client_config(endpoint: str, tls: dict | None = None) -> zenoh.Config:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    for key, value in (tls or {}).items():
        conf.insert_json5(f"transport/link/tls/{key}", json.dumps(value))
    return conf


def open_client(endpoint: str, tls: dict | None = None) -> zenoh.Session:
    """A Zenoh client session of the router at ``endpoint``."""
    return zenoh.open(client_config(endpoint, tls))


def wait_queryable(session: zenoh.Session, key: str, timeout: float = 20.0) -> bool:
    """Whether a queryable (armtwin's, through the router) answers ``key`` within ``timeout``;
    then one query round trip, so that armtwin has also seen every subscriber ``session``
    declared before (declarations and queries keep their order on each link)."""
    querier = session.declare_querier(key, timeout=5.0)
    try:
        if not wait_until(lambda: querier.matching_status.matching, timeout):
            return False
    finally:
        querier.undeclare()
    list(session.get(key, timeout=10.0))
    return True


def paired_of(session: zenoh.Session, robot: str) -> int | None:
    """The robot's paired count from its state answer; ``None`` while it is not tracked (no reply),
    so that a wait polls on instead of failing on an empty answer."""
    answers = get_json(session, f"twin/state/{robot}")
    return answers[0][1]["metrics"]["paired"] if answers else None


def get_json(session: zenoh.Session, selector: str, timeout: float = 10.0) -> list[tuple[str, dict]]:
    replies = session.get(selector, timeout=timeout, consolidation=zenoh.ConsolidationMode.NONE)
    out = []
    for reply in replies:
        if reply.ok is not None:
            out.append((str(reply.ok.key_expr), json.loads(reply.ok.payload.to_bytes())))
    return out


class Gateway:
    """A gateway streaming one robot's joints (with a measured pose 1 cm off, so metrics and the
    position alarm have something to show) at a fixed rate on its own thread, counting its seq."""

    Q = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]
    MEASURED = {"x": -0.807, "y": 0.436, "z": 0.42, "qx": -0.408, "qy": -0.9, "qz": -0.014, "qw": 0.152}

    def __init__(self, session: zenoh.Session, robot: str, rate_hz: float = 200.0, start_seq: int = 0,
                 start_t: float = 0.0):
        self.session = session
        self.robot = robot
        self.period_s = 1.0 / rate_hz
        self.seq = start_seq
        self.t = start_t
        self.pub = session.declare_publisher(
            f"twin/joints/{robot}", congestion_control=zenoh.CongestionControl.BLOCK
        )
        self.sent_at: list[tuple[float, int]] = []  # (monotonic, seq)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def send_one(self) -> None:
        body = {"t": round(self.t, 6), "q": self.Q, "seq": self.seq, "measured": self.MEASURED}
        self.pub.put(json.dumps(body), encoding=zenoh.Encoding.APPLICATION_JSON)
        self.sent_at.append((time.monotonic(), self.seq))
        self.seq += 1
        self.t += self.period_s

    def start(self) -> "Gateway":
        def run():
            next_at = time.monotonic()
            while not self._stop.is_set():
                try:
                    self.send_one()
                except Exception:  # a put while the router is away may fail: the seq still moves on
                    self.seq += 1
                    self.t += self.period_s
                next_at += self.period_s
                delay = next_at - time.monotonic()
                if delay > 0:
                    time.sleep(delay)

        self._thread = threading.Thread(target=run, daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)


class Poses:
    """A dashboard's subscriber of one robot's poses (seq, arrival time)."""

    def __init__(self, session, robot: str):
        self.items: list[tuple[float, int]] = []
        self.sub = session.declare_subscriber(f"twin/pose/{robot}", self)

    def __call__(self, sample):
        self.items.append((time.monotonic(), json.loads(sample.payload.to_bytes())["seq"]))

    def seqs(self) -> list[int]:
        return [seq for _, seq in list(self.items)]


def wait_matched(publisher, timeout: float = 20.0) -> None:
    assert wait_until(lambda: publisher.matching_status.matching, timeout), (
        f"no subscriber of {publisher.key_expr} reached through the router"
    )
