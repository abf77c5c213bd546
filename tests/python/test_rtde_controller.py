"""What `armtwin gateway rtde` reads of a controller beyond its samples (its `tcp_offset`, and its model
and serial number from the dashboard server) reaching the twin; the stand-in's dashboard server
checked by an independent client (ur-rtde's `DashboardClient`).

No real controller runs here: the stand-in (rtde_server.py) serves rows of the project's UR10e
recording with a `tcp_offset` of the test's choosing. Every process binds loopback only, ports are
picked free, scouting is off, every wait is bounded.
"""

from __future__ import annotations

import numpy as np
import pytest

from support import rtde_recording, ur_reference
from support.paths import DATA_DIR
from support.process import ArmtwinProcess, free_port, wait_until
from support.rtde_processes import WATCHDOG_S, Gateway, StandIn, serving
from support.zenoh_clients import get_json, open_session

ROBOT = "cell-7/ur10e"
CONFIG = """\
[service]
metrics_period_ms = 50

[robots.default]
model = "ur10e"
"""
# A tool 15 cm out along the flange's z, turned: what the pendant's installation would set.
TCP_OFFSET = [0.01, -0.02, 0.15, 0.1, -0.2, 0.3]
SERIAL = "20195500042"
TIMEOUT_S = 30.0


@pytest.fixture(scope="module")
def rows():
    return rtde_recording.rtde_rows(DATA_DIR / "ur10e_lasttest.csv", limit=3000)


def recording_with_tcp(tmp_path, rows, tcp_offset=TCP_OFFSET):
    header = list(rtde_recording.HEADER) + [f"tcp_offset_{j}" for j in range(6)]
    return rtde_recording.write([[*row, *tcp_offset] for row in rows], tmp_path / "rows.csv", header)


@pytest.fixture
def service_config() -> str:
    return CONFIG


@pytest.fixture
def service(armtwin_bin, tmp_path, service_config):
    with serving(armtwin_bin, tmp_path, service_config) as proc:
        yield proc


@pytest.fixture
def started(armtwin_bin, tmp_path, service):
    """Starts a stand-in and a gateway reading it (its dashboard server too, if it has one); both
    stopped after the test, the gateway first."""
    running = []

    def start(recording, server_args=(), gateway_args=()):
        stand_in = StandIn(recording, *server_args, workdir=tmp_path)
        dashboard = ["--dashboard-port", stand_in.dashboard_ports[0]] if stand_in.dashboard_ports else []
        gateway = Gateway(armtwin_bin, tmp_path, service.endpoint, "--host", "127.0.0.1", "--port",
                          stand_in.ports[0], "--robot", ROBOT, *dashboard, *gateway_args)
        running.append((stand_in, gateway))
        return stand_in, gateway

    yield start
    codes = [gateway.stop().code for _, gateway in running]
    for stand_in, _ in running:
        stand_in.stop()
    assert codes == [0] * len(codes), f"a gateway did not stop cleanly: {codes}\n{running[0][1].logs()}"


def state(service) -> dict:
    answers = get_json(service.session, f"twin/state/{ROBOT}", timeout=5.0)
    return answers[0][1] if answers else {}


def controller_events(service, fact: str) -> list[dict]:
    return [e for e in service.events if e.get("kind") == "controller" and e["detail"].get("fact") == fact]


def test_the_stand_ins_dashboard_server_answers_ur_rtdes_dashboard_client(tmp_path, rows):
    import dashboard_client

    stand_in = StandIn(recording_with_tcp(tmp_path, rows[:10]), "--dashboard-port", 0, "--model", "UR5",
                       "--serial", SERIAL, workdir=tmp_path)
    try:
        client = dashboard_client.DashboardClient("127.0.0.1", stand_in.dashboard_ports[0])
        client.connect(2000)
        assert client.isConnected()
        assert client.getRobotModel() == "UR5"
        # getSerialNumber asks PolyscopeVersion first and takes a serial only from 5.6 on, and only
        # digits.
        assert client.getSerialNumber() == SERIAL
        assert client.polyscopeVersion() == "5.21.0.9"
        client.send("power on please\n")
        assert client.receive() == "Could not understand: 'power on please'"
        client.disconnect()
    finally:
        stand_in.stop()


def test_the_controllers_tcp_serial_and_model_reach_the_twin(tmp_path, rows, service, started):
    # The dashboard says UR5 and the controller is an e-Series (5.21): a UR5e, not the configured
    # UR10e.
    _, gateway = started(recording_with_tcp(tmp_path, rows),
                         ["--fast", "--dashboard-port", 0, "--model", "UR5", "--serial", SERIAL])

    # The gateway puts what the dashboard server said when it connects, and the TCP with the first
    # RTDE packet (before that packet's joints): the state answer may show the one without the other.
    def facts_shown():
        controller = state(service).get("controller") or {}
        return controller.get("serial") == SERIAL and controller.get("tcp_offset") is not None

    assert wait_until(facts_shown, TIMEOUT_S, interval=0.1), (state(service), gateway.logs())
    answer = state(service)
    assert answer["controller"]["model"] == "UR5"
    assert answer["controller"]["tcp_offset"] == TCP_OFFSET
    assert answer["tool"] == pytest.approx(TCP_OFFSET, abs=1e-15)
    # The twin pose is FK with the controller's TCP, by an independent implementation.
    assert answer["joints"]["t"] == answer["twin"]["t"]
    transform = ur_reference.fk("ur10e", np.array(answer["joints"]["q"]), tcp=TCP_OFFSET)[0]
    twin = answer["twin"]
    assert [twin["x"], twin["y"], twin["z"]] == pytest.approx(transform[:3, 3], abs=1e-9)
    quaternion = ur_reference.canonical_quat(transform[:3, :3])[0]
    assert [twin["qx"], twin["qy"], twin["qz"], twin["qw"]] == pytest.approx(quaternion, abs=1e-9)
    # One event for the TCP the twin took (and the epoch it opened), one for the model.
    tcp_events = controller_events(service, "tcp_offset")
    assert [e["detail"] for e in tcp_events] == [{"fact": "tcp_offset", "tcp_offset": TCP_OFFSET, "in_use": True}]
    assert [e for e in service.events if e.get("kind") == "epoch"], service.events
    model_events = controller_events(service, "model")
    assert [e["detail"] for e in model_events] == [
        {"fact": "model", "configured": "ur10e", "controller": "ur5e", "serial": SERIAL, "in_use": False}
    ], service.events
    assert "ur5e" in model_events[0]["reason"] and "ur10e" in model_events[0]["reason"]
    assert not controller_events(service, "dashboard"), service.events


CONFIGURED_TCP = [0.0, 0.0, 0.1, 0.0, 0.0, 0.0]


@pytest.mark.parametrize("service_config", [CONFIG + f"tcp = {CONFIGURED_TCP}\n"])
def test_a_configured_tcp_stays_in_use_and_the_controllers_is_told(tmp_path, rows, service, started):
    _, gateway = started(recording_with_tcp(tmp_path, rows[:500]), ["--fast", "--dashboard-port", 0])
    assert wait_until(lambda: controller_events(service, "tcp_offset"), TIMEOUT_S), gateway.logs()
    assert controller_events(service, "tcp_offset")[0]["detail"]["in_use"] is False
    answer = state(service)
    assert answer["tool"] == CONFIGURED_TCP and answer["controller"]["tcp_offset"] == TCP_OFFSET
    assert not [e for e in service.events if e.get("kind") == "epoch"], service.events


def test_a_service_started_after_the_gateway_asks_it_for_the_controller(
    armtwin_bin, tmp_path, rows, service, started
):
    gateway_endpoint = f"tcp/127.0.0.1:{free_port()}"
    _, gateway = started(recording_with_tcp(tmp_path, rows[:500]),
                         ["--fast", "--dashboard-port", 0, "--serial", SERIAL], ["-l", gateway_endpoint])
    assert wait_until(lambda: (state(service).get("controller") or {}).get("serial") == SERIAL, TIMEOUT_S,
                      interval=0.1), (state(service), gateway.logs())
    # The stream is over: a service that starts now hears no put, only the gateway's answer. The
    # first one stops first: two instances may not both claim every robot.
    assert service.stop().code == 0, service.logs()
    workdir = tmp_path / "late"
    workdir.mkdir()
    late = ArmtwinProcess(armtwin_bin, workdir, CONFIG + f'\n[zenoh]\nconnect = ["{gateway_endpoint}"]\n',
                          WATCHDOG_S)
    late.start()
    session = open_session(late.endpoint)
    try:
        def late_state():
            answers = get_json(session, f"twin/state/{ROBOT}", timeout=5.0)
            return answers[0][1] if answers else {}

        assert wait_until(lambda: (late_state().get("controller") or {}).get("serial") == SERIAL, TIMEOUT_S,
                          interval=0.2), (late_state(), late.logs())
        assert late_state()["tool"] == pytest.approx(TCP_OFFSET, abs=1e-15)
    finally:
        session.close()
        late.stop()


def test_an_unreachable_dashboard_server_is_an_event_and_the_stream_goes_on(tmp_path, rows, service, started):
    _, gateway = started(recording_with_tcp(tmp_path, rows), ["--fast"], ["--dashboard-port", free_port()])

    def paired_all():
        return (state(service).get("metrics") or {}).get("paired", 0) >= len(rows)

    assert wait_until(paired_all, TIMEOUT_S, interval=0.1), (state(service), gateway.logs())
    events = controller_events(service, "dashboard")
    assert len(events) == 1 and "cannot connect" in events[0]["detail"]["error"], service.events
    assert "cannot read the controller's dashboard server" in gateway.logs()
    assert gateway.proc.poll() is None
    controller = state(service)["controller"]
    assert controller["serial"] is None and controller["tcp_offset"] == TCP_OFFSET
