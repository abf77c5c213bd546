"""``armtwin serve`` with ``[opcua]``, read by an independent OPC UA client (Python's ``asyncua``)
while a gateway streams the real UR10e recording: Basic256Sha256 with a user name and password
(refused with a wrong password, anonymously, and before the client's certificate is trusted),
DI's ``DeviceSet`` browsed to the robot's OPC 40010 motion device, each axis's ``ActualPosition``
the last joints streamed in its ``EngineeringUnits``, the arm's nameplate with the serial number its
gateway reported of the controller, changes at the sampling interval, an event
when the twin's position alarm is raised and one when it clears, no write accepted, and the
robot's node gone once it is retired. The position alarm as an Alarms & Conditions alarm, through
asyncua's own alarms-and-conditions subscription: raised, sent again by a ConditionRefresh,
acknowledged and confirmed by an operator and refused to a reader, cleared and let go.

Written against OPC 40010-1, OPC 10000-100, OPC 10000-9 and docs/opcua.md, not the Rust source.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_opcua.py -q``
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import json
import math
import os
import shutil
import threading
import time
import tomllib
from pathlib import Path

import pytest
from asyncua import Client, ua
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography.x509.oid import ExtendedKeyUsageOID

from support.gateway import MEASURED_KEYS, lasttest_rows
from support.process import ArmtwinProcess, free_port, port_accepts, run_armtwin, wait_until
from support.zenoh_clients import TwinClient

DI = "http://opcfoundation.org/UA/DI/"
ROBOTICS = "http://opcfoundation.org/UA/Robotics/"
ARMTWIN = "urn:armtwin:opcua"
ROBOT = "cell-1/ur10e-a"
USER, PASSWORD = "mes", "plant-floor-42"
SAMPLING_MS = 100
# The recording's rows, 2 ms of source time apart: calm, 2 cm off (the position alarm is 5 mm
# held 0.5 s), calm again; sent at 1 000 rows a second.
PHASES = ((0, 1500, 0.0), (1500, 3000, 0.02), (3000, 4500, 0.0))
RATE_HZ = 1000.0
TIMEOUT_S = 20.0
APP_URI = "urn:armtwin:test-client"
SERIAL = "20235500001"


def password_hash(password: str) -> str:
    salt = os.urandom(16)
    digest = hashlib.pbkdf2_hmac("sha256", password.encode(), salt, 1000)
    return f"pbkdf2-sha256:1000:{salt.hex()}:{digest.hex()}"


def config(port: int) -> str:
    return f"""\
[service]
# Long enough for a loaded machine's client to read the last joints before the robot retires,
# short enough for the retirement to be seen within TIMEOUT_S.
forget_after_s = 5.0

[robots.default]
model = "ur10e"
alarm_position_m = 0.005
alarm_angle_rad = 0.05
alarm_hold_s = 0.5

[opcua]
endpoint = "opc.tcp://127.0.0.1:{port}"
sampling_interval_ms = {SAMPLING_MS}
pki_dir = "pki"

[[opcua.users]]
name = "{USER}"
password_hash = "{password_hash(PASSWORD)}"
"""


class Recorder:
    """asyncua's subscription handler: data changes and events, with their arrival times."""

    def __init__(self):
        self.changes: list[tuple[float, object, object]] = []
        self.events: list[object] = []

    def datachange_notification(self, node, value, data):
        self.changes.append((time.monotonic(), node, value))

    def event_notification(self, event):
        self.events.append(event)


def stream(client: TwinClient, done: threading.Event, go: threading.Event) -> list[float]:
    """Sends PHASES of the recording to ROBOT, the later ones once ``go`` is set (the client has
    browsed the robot and subscribed, however long a loaded machine makes that); returns the
    last joints sent (rad)."""
    rows = lasttest_rows()
    publisher = client.joints(ROBOT)
    period_s = 1.0 / RATE_HZ
    next_at = time.monotonic()
    last = []
    for phase, (start, end, offset_m) in enumerate(PHASES):
        if phase == 1:
            go.wait(TIMEOUT_S)
            next_at = time.monotonic()
        for index in range(start, end):
            q, measured = rows[index]
            pose = list(measured)
            pose[0] += offset_m
            publisher.put(json.dumps({"t": 1000.0 + index * 0.002, "q": q,
                                      "measured": dict(zip(MEASURED_KEYS, pose))}))
            last = q
            next_at += period_s
            delay = next_at - time.monotonic()
            if delay > 0:
                time.sleep(delay)
    done.set()
    return last


def client_for(url: str, keys: Path, user: str | None, password: str | None, timeout: float = 5) -> Client:
    client = Client(url, timeout=timeout)
    client.application_uri = APP_URI
    if user is not None:
        client.set_user(user)
        client.set_password(password)
    return client


async def secured(url: str, keys: Path, user: str | None = USER, password: str | None = PASSWORD,
                  timeout: float = 5) -> Client:
    client = client_for(url, keys, user, password, timeout)
    await client.set_security(SecurityPolicyBasic256Sha256, str(keys / "cert.der"), str(keys / "key.pem"),
                              mode=ua.MessageSecurityMode.SignAndEncrypt)
    return client


async def refused(client: Client) -> str:
    """Connects, expecting a refusal; its reason."""
    try:
        await client.connect()
    except Exception as error:  # asyncua raises the server's status as an exception
        return f"{type(error).__name__}: {error}"
    await client.disconnect()
    pytest.fail("the server let the client in")


async def children_by_name(node) -> dict[str, object]:
    """``node``'s children by browse name; one removed between the browse and the read is left out
    (the fleet changes while a client browses)."""
    found = {}
    for child in await node.get_children():
        try:
            found[(await child.read_browse_name()).Name] = child
        except ua.uaerrors.BadNodeIdUnknown:
            continue
    return found


async def scenario(workdir: Path, service: ArmtwinProcess, url: str) -> None:
    keys = workdir / "client"
    keys.mkdir()
    await setup_self_signed_certificate(keys / "key.pem", keys / "cert.der", APP_URI, "localhost",
                                        [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "armtwin-test"})

    # An unknown client certificate is refused and kept under pki/rejected for the administrator.
    reason = await refused(await secured(url, keys))
    rejected = list((workdir / "pki" / "rejected").glob("*.der"))
    assert len(rejected) == 1, (reason, rejected)
    trusted = workdir / "pki" / "trusted"
    trusted.mkdir(exist_ok=True)
    shutil.move(rejected[0], trusted / rejected[0].name)

    # Trusted now: refused still with a wrong password, anonymously, and without security.
    assert "Bad" in await refused(await secured(url, keys, USER, "wrong"))
    assert "Bad" in await refused(await secured(url, keys, None, None))
    endpoints = await Client(url, timeout=5).connect_and_get_server_endpoints()
    assert {e.SecurityPolicyUri.rsplit("#", 1)[1] for e in endpoints} >= {"Basic256Sha256"}
    assert all(e.SecurityMode == ua.MessageSecurityMode.SignAndEncrypt for e in endpoints), endpoints
    assert all(t.TokenType != ua.UserTokenType.Anonymous for e in endpoints for t in e.UserIdentityTokens)

    client = await secured(url, keys)
    async with client:
        di = await client.get_namespace_index(DI)
        r = await client.get_namespace_index(ROBOTICS)
        a = await client.get_namespace_index(ARMTWIN)
        device_set = client.get_node(ua.NodeId(5001, di))
        recorder = Recorder()
        subscription = await client.create_subscription(SAMPLING_MS, recorder)
        # An event queue as a SCADA client asks for: async-opcua revises 0 to 1, which can lose one.
        await subscription.subscribe_events(queuesize=100)

        twin = TwinClient(service.endpoint)
        try:
            twin.ready([ROBOT])
            done, go = threading.Event(), threading.Event()
            sent: list[list[float]] = []
            sender = threading.Thread(target=lambda: sent.append(stream(twin, done, go)), daemon=True)
            sender.start()

            # The robot appears under DeviceSet once first twinned, as a MotionDeviceSystem.
            deadline = time.monotonic() + TIMEOUT_S
            while ROBOT not in await children_by_name(device_set):
                assert time.monotonic() < deadline, "the robot never appeared under DeviceSet"
                await asyncio.sleep(0.05)
            system = (await children_by_name(device_set))[ROBOT]
            assert (await system.read_type_definition()) == ua.NodeId(1002, r)
            device = (await children_by_name(await system.get_child(f"{r}:MotionDevices")))["ur10e"]
            assert (await device.read_type_definition()) == ua.NodeId(1004, r)
            axes = await device.get_child(f"{r}:Axes")
            axis_nodes = sorted((await children_by_name(axes)).items())
            assert [name for name, _ in axis_nodes] == [f"Axis{i}" for i in range(1, 7)]
            positions = [await axis.get_child([f"{di}:ParameterSet", f"{r}:ActualPosition"]) for _, axis in axis_nodes]
            source_time = await system.get_child([f"{a}:Twin", f"{a}:SourceTime"])

            # The nameplate: the serial number once the gateway reports the controller's.
            serial = await device.get_child(f"{di}:SerialNumber")
            assert await serial.read_value() == ""
            assert (await (await device.get_child(f"{di}:Manufacturer")).read_value()).Text == "Universal Robots"
            twin.session.put(f"twin/controller/{ROBOT}", json.dumps({"model": "UR10", "serial": SERIAL}))

            # Changes while the robot streams, sampled: never more than one per sampling interval,
            # though the robot sends 1 000 rows a second. How many fewer a loaded machine delivers
            # is the machine's, so the count is waited for, not a fixed window.
            await subscription.subscribe_data_change([source_time, positions[0]])
            go.set()

            def source_times() -> list[float]:
                return [at for at, node, _ in recorder.changes if node == source_time]

            assert await until(lambda: len(source_times()) >= 8 or done.is_set(), TIMEOUT_S)
            times = source_times()
            assert len(times) >= 3, f"{len(times)} source-time changes while the robot streamed"
            span_s = times[-1] - times[0]
            rate_hz = (len(times) - 1) / span_s
            assert rate_hz <= 1.5 * 1000 / SAMPLING_MS, (len(times), span_s)
            assert any(node == positions[0] for _, node, _ in recorder.changes)

            # Reading is all a client may do.
            written = await client.uaclient.write_attributes(
                [positions[0].nodeid], [ua.DataValue(ua.Variant(0.0, ua.VariantType.Double))], ua.AttributeIds.Value)
            assert written[0].is_bad(), written
            assert await serial.read_value() == SERIAL

            # Off the event loop: a blocking join would hold asyncua's keep-alive, and its
            # supervisor would take the client for disconnected.
            await asyncio.to_thread(sender.join, TIMEOUT_S)
            assert done.is_set() and sent, "the recording was not streamed"
            last_q = sent[0]
            # The last joints streamed, in each axis's stated units, once the twin has taken them:
            # the stream ends when its last put is queued, and a loaded machine's service may be
            # seconds behind it then.
            # The values are checked as read: the robot retires forget_after_s after its last input,
            # and a loaded machine's reads can take that long.
            for position in positions:
                units = await (await position.get_child("0:EngineeringUnits")).read_value()
                assert units.DisplayName.Text == "°" and units.UnitId == 17476, units

            def last_joints(shown: list[float]) -> bool:
                return all(math.isclose(v, math.degrees(q), abs_tol=1e-9) for v, q in zip(shown, last_q))

            deadline = time.monotonic() + TIMEOUT_S
            shown = [await position.read_value() for position in positions]
            while not last_joints(shown) and time.monotonic() < deadline:
                await asyncio.sleep(SAMPLING_MS / 1000)
                shown = [await position.read_value() for position in positions]
            assert last_joints(shown), (shown, [math.degrees(q) for q in last_q])

            # The position alarm raised during the offset phase and cleared after it, as events.
            def alarm_events():
                return [(e.Severity, e.Message.Text) for e in recorder.events if ROBOT in e.Message.Text]
            assert await until(lambda: len(alarm_events()) >= 2, 5.0), recorder.events
            assert alarm_events() == [
                (700, f"{ROBOT}: position deviation alarm raised"),
                (100, f"{ROBOT}: position deviation alarm cleared"),
            ], recorder.events

            # Retired after forget_after_s without input: its node leaves DeviceSet.
            deadline = time.monotonic() + TIMEOUT_S
            while ROBOT in await children_by_name(device_set):
                assert time.monotonic() < deadline, "the robot's node stayed after its retirement"
                await asyncio.sleep(0.1)
        finally:
            twin.close()


@contextlib.contextmanager
def opcua_service(armtwin_bin: Path, workdir: Path):
    """The service with `[opcua]` on a free port, accepting, as (process, url); checked to stop
    cleanly after."""
    port = free_port()
    service = ArmtwinProcess(armtwin_bin, workdir, config(port), watchdog_s=120.0)
    service.start()
    try:
        assert wait_until(lambda: port_accepts(port), 15.0), service.logs()
        yield service, f"opc.tcp://127.0.0.1:{port}"
    finally:
        stopped = service.stop()
    assert stopped.code == 0, service.logs()


def test_an_opcua_client_reads_the_streaming_robot_as_a_40010_motion_device(armtwin_bin, tmp_path):
    with opcua_service(armtwin_bin, tmp_path) as (service, url):
        asyncio.run(asyncio.wait_for(scenario(tmp_path, service, url), 90.0))


async def fresh_certificates(workdir: Path, url: str, count: int) -> None:
    """`count` sign-in attempts, each with a certificate never seen before."""
    for index in range(count):
        keys = workdir / f"stranger-{index}"
        keys.mkdir()
        await setup_self_signed_certificate(keys / "key.pem", keys / "cert.der", APP_URI, "localhost",
                                            [ExtendedKeyUsageOID.CLIENT_AUTH],
                                            {"commonName": f"stranger-{index}"})
        await refused(await secured(url, keys))


def test_certificates_refused_before_sign_in_cannot_fill_the_disk(armtwin_bin, tmp_path):
    """A client that presents a new certificate on every try leaves at most 64 of them (1 MiB)
    under pki/rejected, the newest kept for the administrator to trust."""
    with opcua_service(armtwin_bin, tmp_path) as (service, url):
        asyncio.run(asyncio.wait_for(fresh_certificates(tmp_path, url, 80), 90.0))
        rejected = tmp_path / "pki" / "rejected"
        # Pruned once a second, beside the sampler.
        assert wait_until(lambda: len(list(rejected.iterdir())) <= 64, 5.0), len(list(rejected.iterdir()))
        kept = list(rejected.iterdir())
        assert sum(f.stat().st_size for f in kept) <= 1 << 20
        newest = max(kept, key=lambda f: f.stat().st_mtime)
        assert time.time() - newest.stat().st_mtime < 30, "the newest refused certificate is kept"
        assert len(kept) >= 32, f"only {len(kept)} kept: more removed than the bound asks"
    assert "refused client certificates removed" in service.logs()


# A sign-in checks a 600 000-iteration digest: seconds in a debug build on a loaded machine.
SIGN_IN_S = 30.0


def test_a_user_from_opcua_user_signs_in_where_clients_are_told(armtwin_bin, tmp_path):
    """`armtwin opcua-user` prints an entry whose digest an independent PBKDF2 (Python's hashlib)
    checks; with it pasted under [opcua], that user signs in. `advertise` is the URL every
    endpoint names, while the server listens on `endpoint`."""
    made = run_armtwin("opcua-user", "mes", input="plant floor 7\n")
    assert made.returncode == 0, made.stderr
    entry = tomllib.loads(made.stdout)["opcua"]["users"][0]
    scheme, iterations, salt, digest = entry["password_hash"].split(":")
    assert (entry["name"], scheme, int(iterations)) == ("mes", "pbkdf2-sha256", 600_000), entry
    assert hashlib.pbkdf2_hmac("sha256", b"plant floor 7", bytes.fromhex(salt), int(iterations)).hex() == digest
    assert run_armtwin("opcua-user", "mes", input="\n").returncode == 1

    port = free_port()
    text = config(port).split("[[opcua.users]]")[0].replace(
        "[opcua]\n", f'[opcua]\nadvertise = "opc.tcp://localhost:{port}"\n') + made.stdout
    service = ArmtwinProcess(armtwin_bin, tmp_path, text, watchdog_s=120.0)
    service.start()
    try:
        assert wait_until(lambda: port_accepts(port), 15.0), service.logs()
        url = f"opc.tcp://127.0.0.1:{port}"

        async def sign_in() -> None:
            endpoints = await Client(url, timeout=5).connect_and_get_server_endpoints()
            assert {e.EndpointUrl.rstrip("/") for e in endpoints} == {f"opc.tcp://localhost:{port}"}, endpoints
            keys = tmp_path / "client"
            keys.mkdir()
            await setup_self_signed_certificate(keys / "key.pem", keys / "cert.der", APP_URI, "localhost",
                                                [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": "mes"})
            await refused(await secured(url, keys, "mes", "plant floor 7", SIGN_IN_S))
            trusted = tmp_path / "pki" / "trusted"
            trusted.mkdir(exist_ok=True)
            [rejected] = list((tmp_path / "pki" / "rejected").glob("*.der"))
            shutil.move(rejected, trusted / rejected.name)
            assert "Bad" in await refused(await secured(url, keys, "mes", "plant floor 8", SIGN_IN_S))
            client = await secured(url, keys, "mes", "plant floor 7", SIGN_IN_S)
            await client.connect()
            try:
                assert ROBOTICS in await client.get_namespace_array()
            finally:
                await client.disconnect()

        asyncio.run(asyncio.wait_for(sign_in(), 90.0))
    finally:
        stopped = service.stop()
    assert stopped.code == 0, service.logs()


OPERATOR, READER = ("shift-lead", "acknowledge-7"), ("scada", "read-only-3")
ACKNOWLEDGE, CONFIRM = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge), ua.NodeId(
    ua.ObjectIds.AcknowledgeableConditionType_Confirm)
CONDITION_TYPES = [ua.ObjectIds.AlarmConditionType, ua.ObjectIds.RefreshStartEventType,
                   ua.ObjectIds.RefreshEndEventType]
def conditions_config(port: int) -> str:
    """config(), its one user replaced by an operator and a reader."""
    users = "".join(
        f'\n[[opcua.users]]\nname = "{name}"\npassword_hash = "{password_hash(password)}"\nrole = "{role}"\n'
        for (name, password), role in ((OPERATOR, "operator"), (READER, "reader")))
    return config(port).split("[[opcua.users]]")[0] + users


class Offsetting:
    """Streams the recording to ROBOT at 500 Hz, its measured x moved by ``offset_m``, until
    stopped: 2 cm raises the 5-mm position alarm after its 0.5-s hold, 0 clears it."""

    def __init__(self, twin: TwinClient):
        self.offset_m = 0.0
        self._rows = lasttest_rows()[:PHASES[-1][1]]  # rows with a measured pose each
        self._publisher = twin.joints(ROBOT)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        index, period_s, next_at = 0, 0.002, time.monotonic()
        while not self._stop.is_set():
            q, measured = self._rows[index % len(self._rows)]
            pose = list(measured)
            pose[0] += self.offset_m
            self._publisher.put(json.dumps({"t": 1000.0 + index * period_s, "q": q,
                                            "measured": dict(zip(MEASURED_KEYS, pose))}))
            index += 1
            next_at += period_s
            time.sleep(max(0.0, next_at - time.monotonic()))

    def stop(self):
        self._stop.set()
        self._thread.join(timeout=5)


async def until(predicate, timeout: float) -> bool:
    """wait_until for a coroutine: the client's notifications arrive on this event loop, which a
    blocking wait would hold."""
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            return False
        await asyncio.sleep(0.02)
    return True


def field(event, name: str):
    return getattr(event, name, None)


async def trusted_client(workdir: Path, url: str, name: str, password: str) -> Path:
    """A client certificate for ``name``, refused once and then trusted as an administrator would."""
    keys = workdir / f"client-{name}"
    keys.mkdir()
    await setup_self_signed_certificate(keys / "key.pem", keys / "cert.der", APP_URI, "localhost",
                                        [ExtendedKeyUsageOID.CLIENT_AUTH], {"commonName": name})
    await refused(await secured(url, keys, name, password, SIGN_IN_S))
    trusted = workdir / "pki" / "trusted"
    trusted.mkdir(exist_ok=True)
    for rejected in (workdir / "pki" / "rejected").glob("*.der"):
        shutil.move(rejected, trusted / rejected.name)
    return keys


async def conditions_scenario(workdir: Path, service: ArmtwinProcess, url: str) -> None:
    keys = await trusted_client(workdir, url, *OPERATOR)
    operator = await secured(url, keys, *OPERATOR, SIGN_IN_S)
    reader = await secured(url, keys, *READER, SIGN_IN_S)
    async with operator, reader:
        seen_by_operator, seen_by_reader = Recorder(), Recorder()
        subscriptions = {}
        for client, recorder in ((operator, seen_by_operator), (reader, seen_by_reader)):
            subscription = await client.create_subscription(SAMPLING_MS, recorder)
            # asyncua's own alarms-and-conditions filter for these types: every field they declare
            # or inherit, and the ConditionId (an empty browse path, read as `event.NodeId`).
            await subscription.subscribe_alarms_and_conditions(evtypes=CONDITION_TYPES, queuesize=100)
            subscriptions[client] = subscription

        def conditions(recorder: Recorder) -> list:
            return [e for e in recorder.events if field(e, "ConditionName") == "PositionDeviation"]

        async def latest(recorder: Recorder, **states):
            """Waits for a condition event in ``states`` (field name to value), and returns it."""
            def match():
                found = [e for e in conditions(recorder)
                         if all(field(e, key.replace("_", "/")) == value for key, value in states.items())]
                return found[-1] if found else None
            assert await until(lambda: match() is not None, TIMEOUT_S), (
                states, recorder.events[-3:], service.logs()[-3000:])
            return match()

        twin = TwinClient(service.endpoint)
        twin.ready([ROBOT])
        stream = Offsetting(twin)
        try:
            # Raised: active, unacknowledged, retained, at the deviation alarm's severity.
            stream.offset_m = 0.02
            raised = await latest(seen_by_operator, ActiveState_Id=True, AckedState_Id=False)
            assert (raised.Retain, raised.Severity, field(raised, "ActiveState").Text) == (True, 700, "Active")
            assert raised.SourceName == ROBOT and ROBOT in raised.Message.Text, raised
            condition = reader.get_node(raised.NodeId)
            assert raised.NodeId.NamespaceIndex == await reader.get_namespace_index(ARMTWIN), raised.NodeId

            # A refresh sends the reader's subscription the retained condition between its markers.
            before = len(seen_by_reader.events)
            await reader.get_node(ua.ObjectIds.ConditionType).call_method(
                ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                ua.Variant(subscriptions[reader].subscription_id, ua.VariantType.UInt32))

            def refreshed():
                types = [e.EventType for e in seen_by_reader.events[before:]]
                return ua.NodeId(ua.ObjectIds.RefreshEndEventType) in types
            assert await until(refreshed, TIMEOUT_S), seen_by_reader.events[before:]
            window = seen_by_reader.events[before:]
            start = [e.EventType for e in window].index(ua.NodeId(ua.ObjectIds.RefreshStartEventType))
            end = [e.EventType for e in window].index(ua.NodeId(ua.ObjectIds.RefreshEndEventType))
            inside = [e for e in window[start + 1:end] if field(e, "ConditionName") == "PositionDeviation"]
            assert [(e.EventId, field(e, "ActiveState/Id")) for e in inside] == [(raised.EventId, True)], window

            # A reader may not acknowledge; an operator may, once, on the latest event.
            comment = ua.LocalizedText("checked the fixture")
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await condition.call_method(ACKNOWLEDGE, ua.Variant(raised.EventId, ua.VariantType.ByteString), comment)
            await operator.get_node(raised.NodeId).call_method(
                ACKNOWLEDGE, ua.Variant(raised.EventId, ua.VariantType.ByteString), comment)
            acked = await latest(seen_by_reader, ActiveState_Id=True, AckedState_Id=True)
            assert (acked.Retain, acked.ClientUserId, field(acked, "Comment").Text) == (
                True, OPERATOR[0], "checked the fixture"), acked
            with pytest.raises(ua.uaerrors.BadConditionBranchAlreadyAcked):
                await operator.get_node(raised.NodeId).call_method(
                    ACKNOWLEDGE, ua.Variant(acked.EventId, ua.VariantType.ByteString), comment)
            with pytest.raises(ua.uaerrors.BadEventIdUnknown):
                await operator.get_node(raised.NodeId).call_method(
                    CONFIRM, ua.Variant(raised.EventId, ua.VariantType.ByteString), comment)

            # Cleared: inactive, still retained until confirmed; confirmed, it is let go.
            stream.offset_m = 0.0
            cleared = await latest(seen_by_operator, ActiveState_Id=False, AckedState_Id=True)
            assert (cleared.Retain, cleared.Severity) == (True, 100), cleared
            with pytest.raises(ua.uaerrors.BadUserAccessDenied):
                await condition.call_method(CONFIRM, ua.Variant(cleared.EventId, ua.VariantType.ByteString), comment)
            await operator.get_node(raised.NodeId).call_method(
                CONFIRM, ua.Variant(cleared.EventId, ua.VariantType.ByteString), comment)
            settled = await latest(seen_by_reader, ConfirmedState_Id=True)
            assert (settled.Retain, field(settled, "ActiveState/Id")) == (False, False), settled

            # Nothing is retained any more: a refresh sends its two markers alone.
            before = len(seen_by_reader.events)
            await reader.get_node(ua.ObjectIds.ConditionType).call_method(
                ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
                ua.Variant(subscriptions[reader].subscription_id, ua.VariantType.UInt32))
            assert await until(refreshed, TIMEOUT_S), seen_by_reader.events[before:]
            assert not [e for e in seen_by_reader.events[before:] if field(e, "ConditionName")]
        finally:
            stream.stop()
            twin.close()
    log = service.logs()
    assert "a condition method refused to a reader" in log and "condition changed by a client" in log, log


def test_an_operator_acknowledges_and_confirms_a_twin_alarm_a_reader_only_sees_it(armtwin_bin, tmp_path):
    """The position alarm as an OPC UA AlarmCondition: raised, refreshed, acknowledged and
    confirmed by an operator of [[opcua.users]], both refused to a reader, cleared and let go."""
    port = free_port()
    service = ArmtwinProcess(armtwin_bin, tmp_path, conditions_config(port), watchdog_s=120.0)
    service.start()
    try:
        assert wait_until(lambda: port_accepts(port), 15.0), service.logs()
        url = f"opc.tcp://127.0.0.1:{port}"
        asyncio.run(asyncio.wait_for(conditions_scenario(tmp_path, service, url), 120.0))
    finally:
        stopped = service.stop()
    assert stopped.code == 0, service.logs()
