"""A configuration file is layered over the built-in one: a file holding only a robot's section
serves where the built-in configuration says (tcp/127.0.0.1:7447) and a client there gets the
robot's poses; a `[zenoh] file` keeps its own mode and endpoints, and a client listens nowhere it
is not told to; `armtwin config show` prints the effective configuration, every default filled in,
and where the mode and endpoints came from; `serve` warns when nothing can reach it; a built-in
relative path is taken from the folder of the file given, or the working directory without one."""

from __future__ import annotations

import json
import os
import tomllib
from pathlib import Path

import pytest

from support.paths import REPO_ROOT
from support.process import Process, Router, free_port, port_accepts, run_armtwin, wait_until
from support.zenoh_clients import TwinClient

DEFAULT_PORT = 7447
ROBOTS_ONLY = '[robots."r1"]\nmodel = "ur5e"\n'
Q = [-0.693, -0.833, 0.951, 1.149, 1.515, 1.739]


def show(config: Path | None = None) -> dict:
    args = ["config", "show"] + (["-c", str(config)] if config else [])
    result = run_armtwin(*args)
    assert result.returncode == 0, result.stderr
    return tomllib.loads(result.stdout)


def test_config_show_fills_every_default_and_completes_each_robot(tmp_path):
    builtin = tomllib.loads((REPO_ROOT / "config" / "armtwin.toml").read_text())
    assert show() == builtin
    config = tmp_path / "armtwin.toml"
    config.write_text(ROBOTS_ONLY + "[align]\nmax_gap_s = 0.1\n")
    effective = show(config)
    assert effective["zenoh"] == builtin["zenoh"]
    assert effective["align"] == {**builtin["align"], "max_gap_s": 0.1}
    assert effective["robots"]["default"] == builtin["robots"]["default"]
    # r1 keeps its own model and takes every other key from [robots.default].
    assert effective["robots"]["r1"] == {**builtin["robots"]["default"], "model": "ur5e"}
    # What it prints is itself a configuration with the same effect.
    again = tmp_path / "again.toml"
    again.write_text(run_armtwin("config", "show", "-c", config).stdout)
    assert show(again) == effective


def test_config_show_refuses_a_bad_file_naming_the_field(tmp_path):
    config = tmp_path / "armtwin.toml"
    config.write_text('[service]\nwindow_s = -1.0\n')
    result = run_armtwin("config", "show", "-c", config)
    assert result.returncode != 0
    assert "service.window_s" in result.stderr and str(config) in result.stderr


def test_a_file_with_only_a_robot_serves_on_the_default_endpoint(tmp_path, armtwin_bin, processes):
    if port_accepts(DEFAULT_PORT):
        pytest.skip(f"127.0.0.1:{DEFAULT_PORT}, the built-in endpoint under test, is taken by another process")
    config = tmp_path / "armtwin.toml"
    config.write_text(ROBOTS_ONLY)
    serve = Process("armtwin", [armtwin_bin, "serve", "-c", config], tmp_path,
                    {"RUST_LOG": "armtwin=info"})
    processes.append(serve.start())
    serve.wait_port(DEFAULT_PORT, f"listen on the built-in endpoint 127.0.0.1:{DEFAULT_PORT}")
    assert "listening nowhere" not in serve.logs()
    client = TwinClient(f"tcp/127.0.0.1:{DEFAULT_PORT}")
    try:
        client.ready(["r1"])
        joints = client.joints("r1")
        for seq in range(20):
            client.put_json(joints, {"t": 1.0 + seq * 0.01, "q": Q, "seq": seq})
        assert client.collector.wait_count("pose", "r1", 20, timeout=10), serve.logs()
        pose = client.collector.last("pose", "r1")
        # The robot's own section applies: a UR5e, not the default UR10e.
        ur5e = run_armtwin("fk", "--model", "ur5e", "--", *map(str, Q))
        assert ur5e.returncode == 0, ur5e.stderr
        expected = json.loads(ur5e.stdout)
        assert [pose[axis] for axis in "xyz"] == pytest.approx(
            [expected[axis] for axis in "xyz"], abs=1e-9)
    finally:
        client.close()


def test_serve_warns_when_nothing_can_reach_it(tmp_path, armtwin_bin, processes):
    config = tmp_path / "armtwin.toml"
    config.write_text('[zenoh]\nmode = "client"\n')
    serve = Process("armtwin", [armtwin_bin, "serve", "-c", config], tmp_path,
                    {"RUST_LOG": "armtwin=info"})
    processes.append(serve.start())
    assert serve.wait_log("listening nowhere and connecting nowhere"), serve.logs()


def listening_ports(pid: int) -> list[int]:
    """The TCP ports process ``pid`` listens on, any address, IPv4 or IPv6: the sockets among its
    open files that the kernel lists in LISTEN state."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            target = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(target[len("socket:["):-1])
    ports = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            fields = line.split()
            local, state, inode = fields[1], fields[3], fields[9]
            if state == "0A" and inode in inodes:
                ports.append(int(local.rsplit(":", 1)[1], 16))
    return ports


def exchanges_data_through(router: Router) -> None:
    """A peer of ``router`` puts r1's joints and receives its poses back from the service."""
    client = TwinClient(router.endpoint)
    try:
        client.ready(["r1"])
        joints = client.joints("r1")
        for seq in range(20):
            client.put_json(joints, {"t": 1.0 + seq * 0.01, "q": Q, "seq": seq})
        assert client.collector.wait_count("pose", "r1", 20, timeout=10)
    finally:
        client.close()


def test_a_zenoh_files_client_mode_stands_and_it_listens_nowhere(tmp_path, armtwin_bin, router_bin,
                                                                  processes):
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    (tmp_path / "zenoh-client.json5").write_text(
        '{ mode: "client", connect: { endpoints: ["%s"] } }\n' % router.endpoint)
    config = tmp_path / "armtwin.toml"
    config.write_text(ROBOTS_ONLY + '[zenoh]\nfile = "zenoh-client.json5"\n')

    shown = run_armtwin("config", "show", "-c", config)
    assert shown.returncode == 0, shown.stderr
    origins = [line for line in shown.stdout.splitlines() if line.startswith("# [zenoh] ")]
    assert origins == [
        '# [zenoh] mode = "client": the [zenoh] file',
        "# [zenoh] listen = []: a client's: it listens only where its configuration, "
        "its [zenoh] file or -l says",
        f'# [zenoh] connect = ["{router.endpoint}"]: the [zenoh] file',
    ], shown.stdout
    effective = tomllib.loads(shown.stdout)["zenoh"]
    assert effective["mode"] == "client" and effective["listen"] == [], effective
    assert "connect" not in effective, "the file's own list is left in the file"

    serve = Process("armtwin", [armtwin_bin, "serve", "-c", config], tmp_path,
                    {"RUST_LOG": "armtwin=info"})
    processes.append(serve.start())
    assert serve.wait_log("armtwin serving"), serve.logs()
    assert "mode=client" in serve.logs(), serve.logs()
    exchanges_data_through(router)
    assert listening_ports(serve.proc.pid) == [], serve.logs()
    assert "listening nowhere" not in serve.logs()


def test_a_client_by_flag_alone_listens_nowhere(tmp_path, armtwin_bin, router_bin, processes):
    router = Router(router_bin, tmp_path).start()
    processes.append(router)
    serve = Process("armtwin", [armtwin_bin, "serve", "-m", "client", "-e", router.endpoint],
                    tmp_path, {"RUST_LOG": "armtwin=info"})
    processes.append(serve.start())
    assert serve.wait_log("armtwin serving"), serve.logs()
    assert listening_ports(serve.proc.pid) == [], serve.logs()
    exchanges_data_through(router)
    # Told to listen, it does (alone: two instances may not both own every robot).
    serve.stop()
    port = free_port()
    told = Process("armtwin-told", [armtwin_bin, "serve", "-m", "client", "-e", router.endpoint,
                                    "-l", f"tcp/127.0.0.1:{port}"], tmp_path,
                   {"RUST_LOG": "armtwin=info"})
    processes.append(told.start())
    told.wait_port(port, f"listen on 127.0.0.1:{port}, as -l says")
    assert listening_ports(told.proc.pid) == [port]


def test_a_built_in_path_is_taken_from_the_folder_of_the_file_given(tmp_path, armtwin_bin, processes):
    # The built-in [recorder] dir, "recordings", is a path like any other of the effective
    # configuration: beside the file given with -c, and in the working directory without one
    # (docs/configuration.md), never beside the built-in file's own place in the checkout.
    site, run = tmp_path / "site", tmp_path / "run"
    site.mkdir()
    run.mkdir()
    (site / "armtwin.toml").write_text(ROBOTS_ONLY)
    for name, file_args, folder in (("with-file", ["-c", site / "armtwin.toml"], site), ("built-in", [], run)):
        port = free_port()
        serve = Process(f"armtwin-{name}", [armtwin_bin, "serve", *file_args, "-l", f"tcp/127.0.0.1:{port}"], run)
        processes.append(serve.start())
        serve.wait_port(port, f"listen on 127.0.0.1:{port}")
        client = TwinClient(f"tcp/127.0.0.1:{port}", subscribe=False)
        try:
            client.ready(["r1"])
            joints = client.joints("r1")
            for seq in range(200):
                client.put_json(joints, {"t": 1.0 + seq * 0.01, "q": Q, "seq": seq})
            [reply] = client.get("twin/admin/record/r1?pre_s=1;post_s=0")
            path = run / json.loads(reply.ok.payload.to_string())["path"]
            assert path.parent == folder / "recordings" / "r1", (path, serve.logs())
            assert wait_until(path.exists, 20.0), (path, serve.logs())
        finally:
            client.close()
        serve.stop()
