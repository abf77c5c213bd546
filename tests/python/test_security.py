"""TLS, mutual TLS and access control on a fleet's router, with the shipped example configurations
(config/router-tls-acl.json5, its access control generated from config/fleet.toml,
config/zenoh-client-tls.json5) and certificates made by `armtwin certs config/fleet.toml`: only
gateways put joints (gateway g1 for robot r1), only armtwin publishes outputs, dashboards only
subscribe and read, operators may also change a twin (reset, apply or discard a calibration), and
a client without a certificate of the fleet's CA cannot connect."""

from __future__ import annotations

import json
import time

import pytest
import zenoh

from support.gateway import Gateway
from support.pki import tls_of
from support.paths import router_path
from support.process import Armtwin, Router, wait_until
from support.secured_fleet import denied, open_as, stream_until_paired, tls_client_config, tls_router_and_twin
from support.zenoh_clients import client_config, get_json, wait_queryable


def test_access_control_lets_each_role_do_only_its_part(
    tmp_path, certs, armtwin_bin
):
    router, twin = tls_router_and_twin(tmp_path, certs, armtwin_bin)
    sessions = []
    try:
        router.start()
        twin.start()
        gateway_session = open_as(router, certs, "g1")
        dashboard = open_as(router, certs, "dashboard")
        watcher = open_as(router, certs, "dashboard")
        sessions += [gateway_session, dashboard, watcher]
        poses = []
        watcher.declare_subscriber("twin/pose/**", lambda s: poses.append(json.loads(s.payload.to_bytes())))
        assert wait_queryable(dashboard, "twin/state/**"), router.logs()
        assert wait_queryable(watcher, "twin/state/**"), router.logs()

        gateway = Gateway(gateway_session, "r1")
        paired = stream_until_paired(gateway, router, dashboard, "r1")
        assert wait_until(lambda: poses, 15), router.logs()
        [(_, state)] = get_json(dashboard, "twin/state/r1")
        assert state["metrics"]["paired"] == paired

        # A dashboard's joints are dropped at the router: the twin does not change.
        forged = Gateway(dashboard, "r1", start_seq=1000, start_t=100.0)
        for _ in range(20):
            forged.send_one()
        # A forged pose, from a dashboard and from a gateway, reaches no subscriber.
        dashboard.put("twin/pose/r1", json.dumps({"robot": "r1", "seq": -1}))
        gateway_session.put("twin/pose/r1", json.dumps({"robot": "r1", "seq": -2}))
        time.sleep(1.5)
        [(_, after)] = get_json(dashboard, "twin/state/r1")
        assert after["metrics"]["paired"] == paired and after["joints"]["t"] == state["joints"]["t"]
        seqs = [p["seq"] for p in poses]
        assert seqs == sorted(set(seqs)) and all(0 <= seq < gateway.sent for seq in seqs), (
            "only armtwin's poses of the gateway's samples arrive", seqs[:5], seqs[-5:], gateway.sent)
        # The router's log names each denial (access control at trace level).
        assert wait_until(lambda: denied(router, "dashboard", "Put (ingress) on", "twin/joints/r1"), 10)
        assert denied(router, "dashboard", "Put (ingress) on", "twin/pose/r1")
        assert denied(router, "g1", "Put (ingress) on", "twin/pose/r1")

        # Without a certificate, or with one of another CA, no session opens.
        for name in (None, "stranger"):
            tls = tls_of(certs, None)
            if name is not None:
                tls["connect_private_key"] = str(certs / f"{name}.key")
                tls["connect_certificate"] = str(certs / f"{name}.pem")
            with pytest.raises(zenoh.ZError):
                zenoh.open(tls_client_config(router.endpoint, tls)).close()
        # Plain TCP to the TLS port does not open a session either.
        with pytest.raises(zenoh.ZError):
            zenoh.open(tls_client_config(f"tcp/127.0.0.1:{router.port}", None)).close()
    finally:
        for session in sessions:
            session.close()
        twin.stop()
        router.stop()


def replies(session: zenoh.Session, selector: str) -> tuple[list[dict], list[dict]]:
    """The ok and error replies to ``selector``, each a JSON object."""
    oks, errs = [], []
    for reply in session.get(selector, timeout=5.0, consolidation=zenoh.ConsolidationMode.NONE):
        if reply.ok is not None:
            oks.append(json.loads(reply.ok.payload.to_bytes()))
        else:
            errs.append(json.loads(reply.err.payload.to_bytes()))
    return oks, errs


def test_only_an_operator_may_reset_a_twin(tmp_path, certs, armtwin_bin):
    router, twin = tls_router_and_twin(tmp_path, certs, armtwin_bin)
    sessions = []
    try:
        router.start()
        twin.start()
        gateway_session = open_as(router, certs, "g1")
        dashboard = open_as(router, certs, "dashboard")
        operator = open_as(router, certs, "operator")
        sessions += [gateway_session, dashboard, operator]
        assert wait_queryable(dashboard, "twin/state/**"), router.logs()
        assert wait_queryable(operator, "twin/admin/reset/**"), router.logs()
        paired = stream_until_paired(Gateway(gateway_session, "r1"), router, dashboard, "r1")

        # The dashboard reads, and every change it asks for is dropped at the router or refused.
        for selector in ("twin/admin/reset/r1", "twin/admin/calibrate/r1?action=apply",
                         "twin/admin/calibrate/r1?action=discard", "twin/admin/**"):
            assert replies(dashboard, selector) == ([], []), selector
        oks, [refused] = replies(dashboard, "twin/calibrate/r1?action=apply")
        assert oks == [] and "twin/admin/calibrate/r1" in refused["error"], refused
        # A wide read that reaches the admin queryables changes nothing either.
        list(dashboard.get("twin/**", timeout=5.0))
        [(_, state)] = get_json(dashboard, "twin/state/r1")
        assert state["metrics"]["paired"] == paired, "the dashboard changed nothing"
        # The history is a read like the state.
        [(_, history)] = get_json(dashboard, "twin/history/r1?_time=[now(-1h)..]")
        assert history["robot"] == "r1" and isinstance(history["seconds"], list), history

        assert wait_until(lambda: denied(router, "dashboard", "Query", "twin/admin/reset/r1"), 10), router.logs()
        assert denied(router, "dashboard", "Query", "twin/admin/calibrate/r1")

        # The operator reads and changes.
        [(_, by_operator)] = get_json(operator, "twin/state/r1")
        assert by_operator["metrics"]["paired"] == paired
        oks, errs = replies(operator, "twin/admin/reset/r1")
        assert errs == [] and len(oks) == 1 and oks[0]["paired"] == paired, (oks, errs)
        [(_, after)] = get_json(dashboard, "twin/state/r1")
        assert after["metrics"]["paired"] == 0, "reset by the operator"
        oks, [answer] = replies(operator, "twin/admin/calibrate/r1?action=discard")
        assert "does not self-calibrate" in answer["error"], "the service answered the operator"
    finally:
        for session in sessions:
            session.close()
        twin.stop()
        router.stop()


def test_armtwin_behind_the_shipped_acl_hears_a_gateways_controller_facts_at_its_start(tmp_path, certs, armtwin_bin):
    """armtwin asks `twin/controller/**` when it starts; behind the shipped access control the
    gateway already streaming must be asked, and its answer must reach armtwin."""
    router, twin = tls_router_and_twin(tmp_path, certs, armtwin_bin)
    asked = []
    try:
        router.start()
        g1 = open_as(router, certs, "g1")
        facts = json.dumps({"model": "UR10", "serial": "20235500001"})

        def answer(query: zenoh.Query) -> None:
            asked.append(str(query.key_expr))
            query.reply("twin/controller/r1", facts, encoding=zenoh.Encoding.APPLICATION_JSON)

        queryable = g1.declare_queryable("twin/controller/r1", answer)
        time.sleep(0.5)
        twin.start()
        assert wait_until(lambda: asked, 10), f"armtwin's start query never reached g1\n{router.logs()}"
        # armtwin takes the answer (it would warn on facts it refuses).
        time.sleep(1.0)
        assert "controller facts refused" not in twin.logs(10**9), twin.logs()
        queryable.undeclare()
        g1.close()
    finally:
        twin.stop()
        router.stop()


@pytest.mark.parametrize("admin, answered", [(None, False), ('"mesh"', True), ('"off"', False)])
def test_admin_queries_are_closed_unless_the_configuration_opens_them(tmp_path, armtwin_bin, admin, answered):
    """armtwin behind a router without an ACL (here on loopback; on a plant network anyone who
    reaches the router): by default nobody may reset, since the instance connects beyond this
    host without access control of its own; `admin = "mesh"` hands the decision to the mesh;
    `"off"` refuses even then. Reads are answered either way."""
    router = Router(router_path(armtwin_bin), tmp_path).start()
    setting = f"admin = {admin}\n" if admin else ""
    twin = Armtwin(armtwin_bin, tmp_path, "twin",
                   f'[service]\npose_congestion = "block"\n{setting}\n[robots.default]\nmodel = "ur10e"\n',
                   router.endpoint).start()
    client = zenoh.open(client_config(router.endpoint))
    try:
        wait_queryable(client, "twin/admin/reset/r1")
        gateway = Gateway(client, "r1", rate_hz=500.0, rows=50)
        gateway.start()
        gateway.join(timeout=30)
        assert wait_until(lambda: get_json(client, "twin/state/r1") and
                          get_json(client, "twin/state/r1")[0][1]["metrics"]["paired"] == 50, 20.0)
        oks, errs = replies(client, "twin/admin/reset/r1")
        paired = get_json(client, "twin/state/r1")[0][1]["metrics"]["paired"]
        if answered:
            assert errs == [] and len(oks) == 1 and paired == 0, (oks, errs, paired)
        else:
            assert oks == [] and len(errs) == 1 and paired == 50, (oks, errs, paired)
            assert "[service] admin" in errs[0]["error"], errs
            if admin is None:
                assert f"connects to {router.endpoint}" in errs[0]["error"], errs
    finally:
        client.close()
        twin.stop()
        router.stop()
    assert ("admin queries are answered only for this host" in twin.logs()) == (admin is None)
