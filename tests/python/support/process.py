"""The one harness for the processes a test starts, and one-shot runs of the armtwin CLI.

Written against docs/protocol/ and Zenoh's own configuration keys, not the Rust source.

* :class:`Process` runs any command with its output (stdout and stderr) in a file of its own per
  run, a watchdog that kills it if a test overruns, and a bounded SIGINT stop.
* :class:`ArmtwinProcess` is ``armtwin serve`` as a peer listening on a private loopback port;
  :class:`Router` is ``armtwin-router`` (zenohd's engine with a bounded REST API);
  :class:`Armtwin` is ``armtwin serve`` as a client of such a router.
* :func:`run_armtwin` runs one armtwin command to its end (60 s at most).

Every process runs on 127.0.0.1 ports chosen free a moment before from the test worker's own
block (:func:`free_port`), with multicast scouting off.
Every wait here is bounded.
"""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import NamedTuple

from support.paths import require_armtwin

STARTUP_TIMEOUT_S = 30.0
STOP_TIMEOUT_S = 15.0
WATCHDOG_S = 240.0
RUN_TIMEOUT_S = 60


# Ports handed out below Linux's ephemeral range (32768-60999 by default), where no outgoing
# connection takes one: each pytest-xdist worker its own block, so two tests running at once
# never get the same port, walked in turn from a random start so a port is seldom reused soon.
# The send buffer of the test's Zenoh links, in their TCP and TLS endpoints (the kernel doubles
# it). Left to itself, Linux grows a socket's send buffer to megabytes while its peer is slower,
# and wakes the writer only once about half of it has drained: a test feeding a debug build on a
# loaded machine saw a put wait longer than Zenoh's `wait_before_close` (5 s) for that wake-up,
# and Zenoh then closed the link and lost what it held, with the receiver still reading. With this
# bound a blocked put waits for a few hundred messages to drain, not thousands.
LINK_SNDBUF = 65536


def bounded_endpoint(endpoint: str) -> str:
    """``endpoint`` with :data:`LINK_SNDBUF`, unless it already names link options."""
    if "#" in endpoint or not endpoint.startswith(("tcp/", "tls/")):
        return endpoint
    return f"{endpoint}#so_sndbuf={LINK_SNDBUF}"


PORT_BLOCK_START = 20000
PORT_BLOCK_SIZE = 1500
PORT_BLOCKS = 8


def _port_block() -> range:
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0").removeprefix("gw")
    index = int(worker) % PORT_BLOCKS if worker.isdigit() else 0
    start = PORT_BLOCK_START + index * PORT_BLOCK_SIZE
    return range(start, start + PORT_BLOCK_SIZE)


_block = _port_block()
_next_port = [_block.start + random.randrange(len(_block))]
_next_port_lock = threading.Lock()


def free_port() -> int:
    """A TCP port free on 127.0.0.1 a moment ago, from this test worker's own block: no other
    worker is handed it, and this one hands it out again only after the rest of its block."""
    for _ in range(len(_block)):
        with _next_port_lock:
            port = _next_port[0]
            _next_port[0] = _block.start + (port + 1 - _block.start) % len(_block)
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            try:
                sock.bind(("127.0.0.1", port))
            except OSError:
                continue
            return port
    raise RuntimeError(f"no free port in {_block}")


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


def run_armtwin(*args, input: str | None = None) -> subprocess.CompletedProcess:
    """Run armtwin with ``args`` (converted with str), text mode, 60 s timeout."""
    binary = require_armtwin()
    return subprocess.run(
        [str(binary), *(str(a) for a in args)],
        input=input,
        stdin=subprocess.DEVNULL if input is None else None,
        capture_output=True,
        text=True,
        timeout=RUN_TIMEOUT_S,
    )


class Stopped(NamedTuple):
    """How a stop ended: the exit code (None if it had to be killed) and the seconds from SIGINT
    to its exit (None if it had exited before, or was killed)."""

    code: int | None
    took_s: float | None


class Process:
    """A subprocess with its output in files, a watchdog, and a bounded SIGINT stop."""

    def __init__(self, name: str, argv: list, workdir: Path, env: dict | None = None,
                 watchdog_s: float = WATCHDOG_S):
        self.name = name
        self.argv = [str(a) for a in argv]
        self.workdir = Path(workdir)
        self.env = env
        self.log_path = self.workdir / f"{name}.log"
        self.proc: subprocess.Popen | None = None
        self.sigint_at: float | None = None
        self.watchdog_fired = False
        self._watchdog_s = watchdog_s
        self._log = None
        self._watchdog: threading.Timer | None = None

    def start(self) -> Process:
        # A restarted process logs to a file of its own: waits on the log see this run alone.
        run = 1
        while (self.workdir / f"{self.name}-{run}.log").exists():
            run += 1
        self.log_path = self.workdir / f"{self.name}-{run}.log"
        self._log = open(self.log_path, "wb")
        environment = dict(os.environ)
        environment.update(self.env or {})
        self.sigint_at = None
        self.proc = subprocess.Popen(
            self.argv,
            stdin=subprocess.DEVNULL,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            cwd=self.workdir,
            env=environment,
            start_new_session=True,  # a terminal's Ctrl-C does not reach it; we signal it ourselves
        )
        self._watchdog = threading.Timer(self._watchdog_s, self._on_watchdog)
        self._watchdog.daemon = True
        self._watchdog.start()
        return self

    def _on_watchdog(self) -> None:
        if self.running():
            self.watchdog_fired = True
            self.kill()

    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def interrupt(self) -> None:
        """Send SIGINT once (no wait)."""
        if self.running() and self.sigint_at is None:
            self.sigint_at = time.monotonic()
            self.proc.send_signal(signal.SIGINT)

    def kill(self) -> None:
        """SIGKILL: no teardown at all (a crash, a power cut)."""
        if self.running():
            self.proc.kill()
            self.proc.wait(timeout=10)
        self._close()

    def stop(self, timeout: float = STOP_TIMEOUT_S) -> Stopped:
        """SIGINT, then wait up to ``timeout`` s from it; killed if it overruns."""
        if self.proc is None:
            return Stopped(None, None)
        if not self.running():
            self._close()
            return Stopped(self.proc.returncode, None)
        self.interrupt()
        try:
            self.proc.wait(timeout=max(0.0, timeout - (time.monotonic() - self.sigint_at)))
        except subprocess.TimeoutExpired:
            self.kill()
            return Stopped(None, None)
        took_s = time.monotonic() - self.sigint_at
        self._close()
        return Stopped(self.proc.returncode, took_s)

    def _close(self) -> None:
        if self._watchdog is not None:
            self._watchdog.cancel()
        if self._log is not None:
            self._log.close()
            self._log = None

    def logs(self, limit: int = 6000) -> str:
        """The last ``limit`` characters of this run's output."""
        try:
            text = self.log_path.read_text(errors="replace")
        except OSError:
            return ""
        return text if len(text) <= limit else "…" + text[-limit:]

    def wait_log(self, needle: str, timeout: float = STARTUP_TIMEOUT_S) -> bool:
        return wait_until(lambda: needle in self.logs(limit=10**9) or not self.running(), timeout) and (
            needle in self.logs(limit=10**9)
        )

    def wait_port(self, port: int, what: str) -> None:
        """Returns once ``port`` accepts; raises if the process exits first or it takes too long."""
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while not port_accepts(port):
            if not self.running():
                raise RuntimeError(f"{self.name} exited with {self.proc.returncode} before {what}\n{self.logs()}")
            if time.monotonic() > deadline:
                raise RuntimeError(f"{self.name} did not {what} within {STARTUP_TIMEOUT_S} s\n{self.logs()}")
            time.sleep(0.02)


class ArmtwinProcess(Process):
    """``armtwin serve -c CONFIG -l tcp/127.0.0.1:PORT``: a peer on a private loopback port;
    with ``listen_options`` (Zenoh link options, ``so_sndbuf=65536``) it also listens on a second
    port with them, ``option_endpoint``, so that only the clients that connect there get them."""

    def __init__(self, binary: Path, workdir: Path, config_text: str, watchdog_s: float,
                 listen_options: str = ""):
        workdir = Path(workdir)
        self.config_path = workdir / "armtwin.toml"
        self.config_path.write_text(config_text)
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        argv = [binary, "serve", "-c", self.config_path, "-l", self.endpoint]
        self.option_endpoint = None
        self.option_port = None
        if listen_options:
            self.option_port = free_port()
            self.option_endpoint = f"tcp/127.0.0.1:{self.option_port}"
            argv += ["-l", f"{self.option_endpoint}#{listen_options}"]
        super().__init__("armtwin", argv, workdir, watchdog_s=watchdog_s)

    def start(self) -> ArmtwinProcess:
        super().start()
        self.wait_port(self.port, f"listen on {self.endpoint}")
        if self.option_port is not None:
            self.wait_port(self.option_port, f"listen on {self.option_endpoint}")
        return self


class Router(Process):
    """``armtwin-router`` listening on one loopback port, REST on another if asked."""

    def __init__(self, binary: Path, workdir: Path, rest: bool = False, config: Path | None = None,
                 port: int | None = None, scheme: str = "tcp", env: dict | None = None,
                 connect: list[str] | None = None):
        self.port = port or free_port()
        self.rest_port = free_port() if rest else None
        self.endpoint = f"{scheme}/127.0.0.1:{self.port}" if scheme == "tcp" else f"{scheme}/localhost:{self.port}"
        argv = [binary, "-l", bounded_endpoint(self.endpoint), "--no-multicast-scouting"]
        if config is not None:
            argv += ["-c", config]
        for endpoint in connect or []:
            argv += ["-e", endpoint]
        if rest:
            argv += ["--rest-http-port", f"127.0.0.1:{self.rest_port}"]
        super().__init__(f"router-{self.port}", argv, workdir, env)

    def start(self) -> Router:
        super().start()
        self.wait_port(self.port, f"listen on {self.endpoint}")
        if self.rest_port is not None:
            self.wait_port(self.rest_port, f"serve REST on {self.rest_port}")
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

    def start(self, ready: bool = True) -> Armtwin:
        super().start()
        if ready and not self.wait_log("robots claimed"):
            raise RuntimeError(f"{self.name} did not start\n{self.logs()}")
        return self
