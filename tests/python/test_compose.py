"""docker/compose.yaml and the image without a Docker engine: the compose file's structure
(services, images, commands, mounts, volumes; shards whose robot key expressions are disjoint and
cover the gateway's robot; Prometheus scraping each shard's dashboard port, with the alert rules
mounted where its configuration names them), the image's command (the dashboard on the port it
exposes, with a configuration the service accepts there), then the same topology run natively
from the file's own commands: the router with REST, both shards with their dashboards, the replay
gateway, and the fleet's state read over REST and /metrics."""

from __future__ import annotations

import json
import re
import subprocess
import tomllib
import urllib.request
from pathlib import Path

import zenoh
from ruamel.yaml import YAML

from support.paths import router_path
from support.process import Process, bounded_endpoint, free_port, port_accepts, wait_until

REPO = Path(__file__).resolve().parents[2]
DOCKER = REPO / "docker"
COMPOSE = DOCKER / "compose.yaml"
ROUTER_ENDPOINT = "tcp/router:7447"


def compose() -> dict:
    return YAML(typ="safe").load(COMPOSE.read_text())


def bind_mounts(service: dict) -> list[tuple[Path, str]]:
    mounts = []
    for volume in service.get("volumes", []):
        source, target = volume.split(":")[:2]
        if source.startswith("."):
            mounts.append(((DOCKER / source).resolve(), target))
    return mounts


def shard_config(service: dict) -> tuple[Path, dict]:
    command = service["command"]
    target = command[command.index("-c") + 1]
    [source] = [source for source, mounted in bind_mounts(service) if mounted == target]
    return source, tomllib.loads(source.read_text())


LOOPBACK_HOSTS = ("127.0.0.1", "[::1]", "localhost")
# Every file that ships a way to publish the image's ports.
SHIPPED_RUNS = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md")), *sorted(p for p in DOCKER.iterdir() if p.is_file())]


def secured(command: list[str]) -> bool:
    """Whether a router's or service's command takes Zenoh over TLS with the shipped access
    control (config/router-tls-acl.json5) or as a TLS client of such a router."""
    text = " ".join(command)
    return "tls/" in text and not re.search(r"\btcp/", text) and (
        "router-tls-acl.json5" in text or "zenoh-client-tls.json5" in text)


def published_on_another_host_address(mapping: str) -> bool:
    """Whether a port mapping (`[HOST:]HOSTPORT:PORT`, compose's or `docker run -p`'s) reaches
    the host's other interfaces: no host address, or a non-loopback one."""
    parts = mapping.split("/")[0].rsplit(":", 2)
    return len(parts) < 3 or parts[0] not in LOOPBACK_HOSTS


def test_no_shipped_file_publishes_an_open_door_beyond_the_hosts_loopback():
    """Plain Zenoh takes any input from whoever reaches it, and this fleet's REST and dashboards
    have no identity: a shipped file publishes them on the host's loopback, or gives them TLS
    and access control first."""
    offenders = []
    for name, service in compose()["services"].items():
        if name == "prometheus":
            continue
        for mapping in service.get("ports", []):
            if published_on_another_host_address(str(mapping)) and not secured(service["command"]):
                offenders.append(f"compose {name}: {mapping}")
    for path in SHIPPED_RUNS:
        for line in path.read_text().splitlines():
            if "docker run" not in line:
                continue
            for mapping in re.findall(r"(?:-p|--publish)[ =](\S+)", line):
                if published_on_another_host_address(mapping):
                    offenders.append(f"{path.relative_to(REPO)}: {line.strip()}")
    # The image's own command listens on plain TCP: only loopback publishing keeps it local.
    dockerfile = (DOCKER / "Dockerfile").read_text()
    [cmd] = re.findall(r"^CMD (\[.*\])$", dockerfile, re.M)
    assert not secured(json.loads(cmd)) and "127.0.0.1:7447:7447" in dockerfile
    assert offenders == [], offenders
    # The checks themselves see an open door.
    assert published_on_another_host_address("7447:7447")
    assert published_on_another_host_address("0.0.0.0:7447:7447")
    assert not published_on_another_host_address("127.0.0.1:7447:7447")
    assert secured(["-c", "/etc/armtwin/router-tls-acl.json5", "-l", "tls/0.0.0.0:7447"])
    assert not secured(["-l", "tcp/0.0.0.0:7447", "--rest-http-port", "0.0.0.0:8000"])


def test_the_compose_file_describes_a_router_two_disjoint_shards_and_a_gateway():
    spec = compose()
    services = spec["services"]
    assert set(services) == {"router", "shard-a", "shard-b", "gateway", "prometheus"}
    assert services["router"]["build"]["dockerfile"] == "docker/Dockerfile"
    assert (DOCKER / services["router"]["build"]["context"] / "docker" / "Dockerfile").is_file()
    assert all(
        service["image"] == "armtwin" for name, service in services.items() if name != "prometheus"
    )
    assert "ROUTER_FEATURES" in services["router"]["build"]["args"]

    router = services["router"]
    assert router["entrypoint"] == ["armtwin-router"]
    assert "--rest-http-port" in router["command"] and "tcp/0.0.0.0:7447" in router["command"]
    rest_port = router["command"][router["command"].index("--rest-http-port") + 1].rsplit(":", 1)[-1]
    # Published on the host's loopback only: this fleet's REST has no access control.
    assert f"127.0.0.1:{rest_port}:{rest_port}" in router["ports"]

    shards = {name: service for name, service in services.items() if name.startswith("shard-")}
    robots = {}
    for name, service in shards.items():
        command = service["command"]
        assert command[:1] == ["serve"] and command[command.index("-m") + 1] == "client"
        assert command[command.index("-e") + 1] == ROUTER_ENDPOINT
        assert "router" in service["depends_on"]
        path, config = shard_config(service)
        robots[name] = zenoh.KeyExpr(config["service"]["robots"])
        state_dir = config["service"]["state_dir"]
        named = [v.split(":")[0] for v in service["volumes"] if v.split(":")[1] == state_dir]
        assert named and named[0] in spec["volumes"], f"{name}: state_dir {state_dir} is not a volume"
        # The dashboard on the container's interfaces, published on the host's loopback only,
        # which the shard's configuration allows without tokens.
        http = command[command.index("--http") + 1]
        assert http == "0.0.0.0:8080"
        assert any(port.startswith("127.0.0.1:") and port.endswith(":8080") for port in service["ports"])
        assert config["http"]["anonymous"] is True
    a, b = robots.values()
    assert not a.intersects(b), f"the shards overlap: {a} and {b}"

    gateway = services["gateway"]["command"]
    assert gateway[0] == "replay" and gateway[gateway.index("-e") + 1] == ROUTER_ENDPOINT
    robot = zenoh.KeyExpr(gateway[gateway.index("--robot") + 1])
    assert [name for name, key in robots.items() if key.includes(robot)] == ["shard-a"]
    for service in services.values():
        for source, _ in bind_mounts(service):
            assert source.exists(), f"{source} is mounted but missing"
    recording = gateway[1]
    [(data, mounted)] = bind_mounts(services["gateway"])
    assert (data / Path(recording).relative_to(mounted)).is_file()

    # Prometheus scrapes every shard's dashboard and loads config/prometheus/alerts.yml (the rules
    # shipped beside config/prometheus.yml) through its mounts.
    prometheus = services["prometheus"]
    assert set(prometheus["depends_on"]) == set(shards)
    mounts = dict((target, source) for source, target in bind_mounts(prometheus))
    config_file = prometheus_config_path(prometheus)
    scrape = YAML(typ="safe").load(mounts[config_file].read_text())
    [job] = scrape["scrape_configs"]
    assert job["metrics_path"] == "/metrics"
    [targets] = [group["targets"] for group in job["static_configs"]]
    assert sorted(targets) == [f"{name}:8080" for name in sorted(shards)]
    [rules] = scrape["rule_files"]
    assert mounted_source(mounts, rules) == REPO / "config" / "prometheus" / "alerts.yml"


def prometheus_config_path(service: dict) -> str:
    [flag] = [arg for arg in service["command"] if arg.startswith("--config.file=")]
    return flag.split("=", 1)[1]


def mounted_source(mounts: dict[str, Path], path: str) -> Path:
    """The host path behind `path` inside a container with these bind mounts."""
    for target, source in mounts.items():
        if path == target or path.startswith(target.rstrip("/") + "/"):
            return (source / Path(path).relative_to(target)).resolve()
    raise AssertionError(f"{path} is on no mount: {mounts}")


def dockerfile_instructions() -> dict[str, list[str]]:
    """Each instruction of the runtime stage (the last FROM), continuation lines joined."""
    text = re.sub(r"\\\n", " ", (DOCKER / "Dockerfile").read_text())
    stage = text.rsplit("\nFROM ", 1)[1]
    instructions: dict[str, list[str]] = {}
    for line in stage.splitlines()[1:]:
        if line.strip() and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            instructions.setdefault(word, []).append(rest.strip())
    return instructions


def test_the_image_serves_the_dashboard_on_the_port_it_exposes(tmp_path, armtwin_bin):
    instructions = dockerfile_instructions()
    [cmd] = instructions["CMD"]
    command = json.loads(cmd)
    http = command[command.index("--http") + 1]
    host, port = http.rsplit(":", 1)
    assert host == "0.0.0.0" and port in instructions["EXPOSE"][0].split()
    config_in_image = command[command.index("-c") + 1]
    [copied] = [
        line.split()[0] for line in instructions["COPY"] if line.split()[-1] == config_in_image
    ]
    # The image's configuration, with the command's --http written in, is one the service
    # accepts: `config show` checks it as `serve` does, binding nothing.
    config = tmp_path / "image.toml"
    config.write_text(f'{(REPO / copied).read_text()}\nlisten = "{http}"\n')
    shown = subprocess.run([str(armtwin_bin), "config", "show", "-c", str(config)],
                           capture_output=True, text=True, timeout=30)
    assert shown.returncode == 0, shown.stderr
    effective = tomllib.loads(shown.stdout)
    assert effective["http"]["listen"] == http
    # The recorder writes where the image's user may: a folder the image makes its own.
    user = instructions["USER"][0]
    [owned] = [line for line in instructions["RUN"] if f"chown -R {user}" in line]
    own_dir = owned.split()[-1]
    assert effective["recorder"]["enabled"] and effective["recorder"]["dir"].startswith(own_dir + "/"), (
        effective["recorder"], owned)
    assert effective["recorder"]["dir"] in owned.split(), owned
    # OPC UA's port is exposed, for a configuration that turns it on.
    assert "4840" in instructions["EXPOSE"][0].split()
    # The guide's word: the image holds config/ under /etc/armtwin/.
    assert "config/ /etc/armtwin/" in instructions["COPY"], instructions["COPY"]
    assert "`config/` under `/etc/armtwin/`" in (REPO / "docs" / "fleet.md").read_text()


def test_the_compose_topology_runs_natively(tmp_path, armtwin_bin):
    services = compose()["services"]
    router_port, rest_port = free_port(), free_port()
    endpoint = f"tcp/127.0.0.1:{router_port}"
    linked = bounded_endpoint(endpoint)  # every link of the topology, as the other tests' links
    http_ports = {}

    def native(argv: list[str], name: str = "") -> list[str]:
        text = [
            arg.replace("tcp/0.0.0.0:7447", linked).replace(ROUTER_ENDPOINT, linked)
            for arg in argv
        ]
        if "--rest-http-port" in text:
            text[text.index("--rest-http-port") + 1] = f"127.0.0.1:{rest_port}"
        if "--http" in text:
            http_ports[name] = free_port()
            text[text.index("--http") + 1] = f"127.0.0.1:{http_ports[name]}"
        return text

    started = []
    try:
        router = Process("router", [router_path(armtwin_bin), *native(services["router"]["command"])], tmp_path)
        started.append(router.start())
        assert wait_until(lambda: port_accepts(router_port) and port_accepts(rest_port), 30), router.logs()
        for name in ("shard-a", "shard-b"):
            source, _ = shard_config(services[name])
            state = tmp_path / f"{name}-state"
            config = tmp_path / f"{name}.toml"
            config.write_text(re.sub(r'state_dir = ".*"', f'state_dir = "{state}"', source.read_text()))
            argv = native(services[name]["command"], name)
            argv[argv.index("-c") + 1] = str(config)
            shard = Process(name, [armtwin_bin, *argv], tmp_path, {"RUST_LOG": "armtwin=info"})
            started.append(shard.start())
            assert shard.wait_log("robots claimed"), shard.logs()
        argv = native(services["gateway"]["command"])
        argv[1] = str(REPO / "tests" / "data" / Path(argv[1]).name)
        replay = subprocess.run(
            [str(armtwin_bin), *argv, "--max-rate"], capture_output=True, text=True, timeout=180
        )
        assert replay.returncode == 0, replay.stderr
        with urllib.request.urlopen(f"http://127.0.0.1:{rest_port}/twin/state/**", timeout=10) as response:
            fleet = json.loads(response.read())
        assert [item["key"] for item in fleet] == ["twin/state/site-a/ur10e"]
        state = fleet[0]["value"]
        assert state["joints"] is not None and state["metrics"]["paired"] > 0
        assert "site-a/ur10e" in started[1].logs(10**9) and "site-a/ur10e" not in started[2].logs(10**9)
        # Each shard's /metrics, what the compose file's Prometheus scrapes, has its own robots.
        metrics = {}
        for name in ("shard-a", "shard-b"):
            url = f"http://127.0.0.1:{http_ports[name]}/metrics"
            with urllib.request.urlopen(url, timeout=10) as response:
                metrics[name] = response.read().decode()
        assert 'robot="site-a/ur10e"' in metrics["shard-a"]
        assert 'robot="site-a/ur10e"' not in metrics["shard-b"]
    finally:
        for process in reversed(started):
            process.stop()
