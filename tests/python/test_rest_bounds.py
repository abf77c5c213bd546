"""The router's REST API bounded, attacked with real HTTP clients (raw sockets, curl) on a real
armtwin-router: a huge body is refused (413) before it is read and the router's memory stays
flat; a body trickled in holds up nobody else; a web page of a foreign origin is refused and no
origin is answered with a wildcard; a GET (or POST) under admin/ never reaches a twin."""

from __future__ import annotations

import http.client
import json
import select
import socket
import subprocess
import threading
import time
from pathlib import Path

from support.gateway import Gateway
from support.process import Armtwin, Router, wait_until
from support.zenoh_clients import open_client, paired_of, wait_matched, wait_queryable

BIG_BODY_BYTES = 256 << 20
# What the router may grow by while refusing a 256 MiB body: its socket buffers and a bounded
# body (4 MiB) at most, far below the body itself.
RSS_GROWTH_BOUND_BYTES = 64 << 20
CHUNK = b"\0" * (64 << 10)


def peak_rss_bytes(pid: int) -> int:
    """The most the process has held resident (VmHWM in /proc/<pid>/status): a body read whole
    and freed after shows here, not in VmRSS once it is gone."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    raise AssertionError(f"no VmHWM for {pid}")


def status_line(data: bytes) -> int:
    return int(data.split(b" ", 2)[1])


def stream_body(port: int, head: bytes, chunked: bool) -> tuple[int | None, int]:
    """Sends ``head`` and then up to 256 MiB of body as fast as the router takes it, reading its
    answer as soon as one comes; returns (the answer's status or None, body bytes sent)."""
    sent = 0
    with socket.create_connection(("127.0.0.1", port), timeout=30) as sock:
        sock.sendall(head)
        answer = b""
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            readable, writable, _ = select.select([sock], [sock] if sent < BIG_BODY_BYTES else [], [], 5)
            if readable:
                try:
                    data = sock.recv(65536)
                except ConnectionResetError:
                    break
                answer += data
                if not data or b"\r\n" in answer:
                    break
            elif writable:
                piece = (b"%x\r\n" % len(CHUNK) + CHUNK + b"\r\n") if chunked else CHUNK
                try:
                    sock.sendall(piece)
                except (BrokenPipeError, ConnectionResetError):
                    # Closed on us: the answer, if any, is already in our receive buffer.
                    try:
                        answer += sock.recv(65536)
                    except OSError:
                        pass
                    break
                sent += len(CHUNK)
            elif sent >= BIG_BODY_BYTES:
                break
        return (status_line(answer) if answer.startswith(b"HTTP/") else None), sent


def rest_get(port: int, path: str, headers: dict | None = None, method: str = "GET",
             timeout: float = 10.0) -> tuple[int, dict, bytes]:
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    try:
        connection.request(method, path, headers=headers or {})
        response = connection.getresponse()
        return response.status, {k.lower(): v for k, v in response.getheaders()}, response.read()
    finally:
        connection.close()


def test_a_huge_body_is_refused_before_it_is_read(tmp_path, router_bin, processes, sessions):
    router = Router(router_bin, tmp_path, rest=True).start()
    processes.append(router)
    watcher = open_client(router.endpoint)
    sessions.append(watcher)
    heard = []
    watcher.declare_subscriber("bulk/**", lambda sample: heard.append(len(sample.payload.to_bytes())))
    time.sleep(0.5)
    before = peak_rss_bytes(router.proc.pid)
    announced = (f"PUT /bulk/x HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/octet-stream\r\n"
                 f"Content-Length: {BIG_BODY_BYTES}\r\n\r\n").encode()
    status, sent = stream_body(router.rest_port, announced, chunked=False)
    assert status == 413, (status, sent)
    # Answered from the header: the router read none of it; what we sent sat in socket buffers.
    assert sent < 32 << 20, sent
    chunked = (b"PUT /bulk/y HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/octet-stream\r\n"
               b"Transfer-Encoding: chunked\r\n\r\n")
    status, sent = stream_body(router.rest_port, chunked, chunked=True)
    assert status == 413, (status, sent)
    assert sent < 64 << 20, sent
    growth = peak_rss_bytes(router.proc.pid) - before
    print(f"router peak RSS {before / 2**20:.1f} MiB, grew {growth / 2**20:.1f} MiB refusing 2 x 256 MiB bodies")
    assert growth < RSS_GROWTH_BOUND_BYTES, growth
    assert heard == [], "a refused body reached the mesh"
    # Still answering, and a body under the bound still goes through.
    assert rest_get(router.rest_port, "/twin/state/**")[0] == 200
    connection = http.client.HTTPConnection("127.0.0.1", router.rest_port, timeout=10)
    connection.request("PUT", "/bulk/z", body=b"\1" * (1 << 20), headers={"Content-Type": "application/octet-stream"})
    assert connection.getresponse().status == 200
    connection.close()
    assert wait_until(lambda: heard == [1 << 20], 5), heard


def test_a_trickled_body_holds_up_nobody_else(tmp_path, router_bin, processes):
    router = Router(router_bin, tmp_path, rest=True).start()
    processes.append(router)
    stop = threading.Event()

    def trickle(sock: socket.socket) -> None:
        sock.sendall(b"PUT /bulk/slow HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 1000000\r\n\r\n")
        while not stop.wait(0.2):
            try:
                sock.sendall(b"x")
            except OSError:
                return

    slow = [socket.create_connection(("127.0.0.1", router.rest_port)) for _ in range(8)]
    threads = [threading.Thread(target=trickle, args=(sock,), daemon=True) for sock in slow]
    for thread in threads:
        thread.start()
    try:
        time.sleep(0.5)
        started = time.monotonic()
        for _ in range(20):
            assert rest_get(router.rest_port, "/twin/state/**")[0] == 200
        assert time.monotonic() - started < 5.0
    finally:
        stop.set()
        for sock in slow:
            sock.close()


def test_a_foreign_origin_is_refused_and_none_is_a_wildcard(tmp_path, router_bin, processes):
    allowed = "http://hmi.plant:8080"
    router = Router(router_bin, tmp_path, rest=True)
    router.argv += ["--rest-allow-origin", allowed]
    router.start()
    processes.append(router)
    evil = {"Origin": "http://evil.example"}
    status, headers, _ = rest_get(router.rest_port, "/twin/state/**", evil)
    assert status == 403 and "access-control-allow-origin" not in headers, (status, headers)
    preflight = {**evil, "Access-Control-Request-Method": "PUT"}
    status, headers, _ = rest_get(router.rest_port, "/twin/joints/r1", preflight, method="OPTIONS")
    assert status == 403 and "access-control-allow-origin" not in headers, (status, headers)
    # A simple cross-site POST (a form) is refused before it becomes a query.
    status, _, _ = rest_get(router.rest_port, "/twin/state/**", {**evil, "Content-Type": "text/plain"}, method="POST")
    assert status == 403
    # The configured origin is named, never `*`.
    status, headers, _ = rest_get(router.rest_port, "/twin/state/**", {"Origin": allowed})
    assert status == 200 and headers.get("access-control-allow-origin") == allowed, headers
    status, headers, _ = rest_get(router.rest_port, "/twin/joints/r1", {"Origin": allowed, "Access-Control-Request-Method": "PUT"}, method="OPTIONS")
    assert status in (200, 204) and headers.get("access-control-allow-origin") == allowed, headers
    # curl, without an Origin, is not a web page: it reads.
    result = subprocess.run(["curl", "-s", "-o", "/dev/null", "-w", "%{http_code}",
                             f"http://127.0.0.1:{router.rest_port}/twin/state/**"],
                            capture_output=True, text=True, timeout=30)
    assert result.stdout == "200", result


def test_a_rest_get_never_resets_a_twin(tmp_path, armtwin_bin, router_bin, processes, sessions):
    router = Router(router_bin, tmp_path, rest=True).start()
    processes.append(router)
    config = '[service]\npose_congestion = "block"\n\n[robots.default]\nmodel = "ur10e"\n'
    processes.append(Armtwin(armtwin_bin, tmp_path, "twin", config, router.endpoint).start())
    gateway_session, dashboard = open_client(router.endpoint), open_client(router.endpoint)
    sessions += [gateway_session, dashboard]
    assert wait_queryable(dashboard, "twin/state/**")
    gateway = Gateway(gateway_session, "r1")
    wait_matched(gateway.pub)
    for _ in range(30):
        gateway.send_one()
        time.sleep(0.005)
    assert wait_until(lambda: paired_of(dashboard, "r1") == 30, 15), paired_of(dashboard, "r1")
    for method in ("GET", "POST"):
        for path in ("/twin/admin/reset/r1", "/twin/admin/reset/**", "/**/admin/**"):
            status, _, body = rest_get(router.rest_port, path, method=method)
            assert status == 403, (method, path, status, body)
    # A link to it from any web page (curl stands for the browser: no Origin on a GET).
    result = subprocess.run(["curl", "-s", "-o", "/dev/null", "-w", "%{http_code}",
                             f"http://127.0.0.1:{router.rest_port}/twin/admin/reset/r1"],
                            capture_output=True, text=True, timeout=30)
    assert result.stdout == "403", result
    time.sleep(0.5)
    assert paired_of(dashboard, "r1") == 30, "the twin was reset through REST"
    # Reading through REST still works.
    status, _, body = rest_get(router.rest_port, "/twin/state/r1")
    [answer] = json.loads(body)
    assert status == 200 and answer["value"]["metrics"]["paired"] == 30
