"""ROS 2 for real: a real rclpy node (ROS 2 Jazzy, Fast DDS, in .venv-ros2) through the real
zenoh-plugin-ros2dds bridge (linked into ``armtwin-router``, feature ``ros2dds``; CycloneDDS) to
``armtwin serve`` in client mode, and the twin's ``PoseStamped`` back the same way.

The node (ros2_driver.py) stands in for the Universal Robots driver: ``JointState`` with shuffled
names, a ``tf_prefix``, a gripper joint, velocities and efforts (currents), and ``PoseStamped`` in
``<tf_prefix>base``, from rows of tests/data/ur10e_lasttest.csv. Checked:

* the twin's poses and metrics equal the numpy reference, the JSON path of the same rows (bit for
  bit) and ``armtwin validate`` of the same rows;
* every twin pose reaches rclpy through the bridge, decoded by rclpy, in ``<tf_prefix>base``,
  stamped as its joint message, equal to the pose armtwin published;
* velocity and effort reach the twin's joint state as what the source says (``current_a``);
* the type hashes rclpy reports are the ones committed beside the rclpy fixtures (which the Rust
  tests hold armtwin's constants to);
* the bridge's ``namespace`` setting in front of every key, both ways;
* a robot joining and leaving: the bridge undeclares the node's routes when it stops, and armtwin
  retires the robot after ``forget_after_s``.
* the bridge and access control: the router's rules do not judge what the bridge puts (a ROS 2
  publisher's joints pass rules that drop a Zenoh client's), so armtwin-router refuses the bridge
  beside access control unless ``--ros2-trusted``.

DDS discovers by multicast: these tests run only inside a private network namespace, where
tests/run_all.sh starts them (``unshare -n``, loopback up with multicast); outside one they skip.
Every process binds to 127.0.0.1, Zenoh multicast scouting is off, the DDS domain is random.
"""

from __future__ import annotations

import csv
import json
import os
import random
import socket
import subprocess
from pathlib import Path

import numpy as np
import pytest
import zenoh
from scipy.spatial.transform import Rotation

from support.checks import Checks
from support.paths import DATA_DIR, REPO_ROOT, SUPPORT_DIR
from support.process import Armtwin, Process, Router, run_armtwin, wait_until
from support.twin_reference import check_metrics, check_poses, reference_deviations, reference_stats
from support.zenoh_clients import Collector, open_client, wait_queryable

RATE_HZ = 500  # the stamps' rate (the UR driver's on e-Series)
PUBLISH_HZ = 250.0  # the node's pace: what this shared 2-core machine keeps without backlog
EPOCH_SEC = 1_748_954_669
NODE_TIMEOUT_S = 120.0
PREFIX = "twin"


def private_network_namespace() -> bool:
    """Whether loopback is this network namespace's only interface (as in a fresh ``unshare -n``)."""
    return [name for _, name in socket.if_nameindex()] == ["lo"]


pytestmark = pytest.mark.skipif(
    not private_network_namespace(),
    reason="DDS discovers by multicast: run inside a private network namespace, as tests/run_all.sh does "
    "(unshare -n sh -c 'ip link set lo up; ip link set lo multicast on; exec …/pytest tests/python/test_ros2_real.py')",
)


def ros2_python() -> Path:
    env = os.environ.get("ARMTWIN_ROS2_PYTHON")
    path = Path(env) if env else REPO_ROOT / ".venv-ros2" / "bin" / "python"
    if not path.is_file():
        pytest.fail(f"no ROS 2 Python at {path}: tests/run_all.sh makes .venv-ros2 from "
                    "tests/python/requirements-ros2.txt", pytrace=False)
    return path


def load_rows(n: int):
    """The first ``n`` rows: joints (n,6), measured pose (n,7), stamps at 500 Hz as (sec, nanosec),
    the seconds they read as, velocities from the angles (central differences, rad/s) and
    efforts: currents (A) made up per row, only to be followed through."""
    with open(DATA_DIR / "ur10e_lasttest.csv", newline="") as f:
        reader = csv.reader(f)
        next(reader)
        data = np.array([[float(v) for v in row[1:14]] for _, row in zip(range(n), reader)], float)
    q, meas = data[:, :6], data[:, 6:13]
    stamps = []
    for i in range(n):
        ns = i * (1_000_000_000 // RATE_HZ)
        stamps.append((EPOCH_SEC + ns // 1_000_000_000, ns % 1_000_000_000))
    t = [float(sec) + float(nanosec) * 1e-9 for sec, nanosec in stamps]
    qd = np.gradient(q, 1.0 / RATE_HZ, axis=0)
    current = np.round(np.sin(q * 3.0) * 2.0, 6)
    return q, meas, stamps, t, qd, current


def write_rows(path: Path, q, meas, stamps, qd, current) -> Path:
    rows = [
        {"sec": sec, "nanosec": nanosec, "q": q[i].tolist(), "qd": qd[i].tolist(),
         "effort": current[i].tolist(), "pose": meas[i].tolist()}
        for i, (sec, nanosec) in enumerate(stamps)
    ]
    path.write_text(json.dumps(rows))
    return path


class Deployment:
    """armtwin-router with the bridge (DDS domain ``domain``, the bridge's ``namespace``), one
    armtwin in client mode behind it, and a Zenoh client collecting ``twin/**``."""

    def __init__(self, router_bin: Path, armtwin_bin: Path, workdir: Path, namespace: str, armtwin_config: str):
        self.workdir = workdir
        self.domain = random.randrange(1, 100)
        self.ros_env = {
            "ROS_DOMAIN_ID": str(self.domain),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
            "ROS_DISTRO": "jazzy",
        }
        config = workdir / "bridge.json5"
        config.write_text(json.dumps({"plugins": {"ros2dds": {
            "domain": self.domain, "namespace": namespace, "ros_automatic_discovery_range": "LOCALHOST",
        }}}))
        self.router = Router(router_bin, workdir, config=config, env=self.ros_env)
        self.armtwin = Armtwin(armtwin_bin, workdir, "armtwin", armtwin_config, self.router.endpoint)
        self.session: zenoh.Session | None = None
        self.collector = Collector()

    def start(self) -> "Deployment":
        self.router.start()
        self.armtwin.start()
        self.session = open_client(self.router.endpoint)
        self.subscriber = self.session.declare_subscriber(f"{PREFIX}/**", self.collector)
        assert wait_queryable(self.session, f"{PREFIX}/state/**"), self.armtwin.logs()
        return self

    def node(self, name: str, rows: Path, namespace: str, tf_prefix: str) -> "Node":
        return Node(self, name, rows, namespace, tf_prefix)

    def state(self, robot: str) -> dict:
        replies = list(self.session.get(f"{PREFIX}/state/{robot}", timeout=10.0))
        answers = [json.loads(r.ok.payload.to_string()) for r in replies if r.ok is not None]
        assert len(answers) == 1, replies
        return answers[0]

    def alive(self) -> list[str]:
        replies = self.session.liveliness().get(f"{PREFIX}/alive/**", timeout=5.0)
        return sorted(str(r.ok.key_expr)[len(f"{PREFIX}/alive/"):] for r in replies if r.ok is not None)

    def bridge_publishers(self) -> list[str]:
        """The bridge's liveliness tokens of the DDS writers it routes to Zenoh."""
        replies = self.session.liveliness().get("@/*/@ros2_lv/MP/**", timeout=5.0)
        return sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)

    def stop(self) -> tuple[int | None, int | None]:
        if self.session is not None:
            self.session.close()
        return self.armtwin.stop().code, self.router.stop().code

    def logs(self) -> str:
        return f"{self.armtwin.logs()}\n--- router ---\n{self.router.logs()}"


class Node:
    """ros2_driver.py in .venv-ros2: a real rclpy node publishing ``rows`` in ``namespace``."""

    def __init__(self, deployment: Deployment, name: str, rows: Path, namespace: str, tf_prefix: str):
        self.out = deployment.workdir / f"{name}.json"
        argv = [ros2_python(), SUPPORT_DIR / "ros2_driver.py", "--rows", rows,
                "--namespace", namespace, "--tf-prefix", tf_prefix, "--rate-hz", PUBLISH_HZ, "--out", self.out]
        self.process = Process(f"node-{name}", argv, deployment.workdir, deployment.ros_env)

    def start(self) -> "Node":
        self.process.start()
        return self

    def wait(self, timeout: float = NODE_TIMEOUT_S) -> dict:
        try:
            code = self.process.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            pytest.fail(f"the rclpy node did not finish within {timeout} s\n{self.process.logs()}")
        self.process.stop()
        assert code == 0, f"rclpy node exited with {code}\n{self.process.logs()}"
        return json.loads(self.out.read_text())


def armtwin_config(source_prefix: str, tf_prefix: str, extra_service: str = "") -> str:
    return f"""\
[service]
metrics_period_ms = 50
# Every pose is counted: a test client that falls behind must slow the twin, not miss poses.
pose_congestion = "block"
{extra_service}

[robots.default]
model = "ur10e"
[robots.default.ros2_pose]
scheme = "bridge"
tf_prefix = "{tf_prefix}"
[robots.json_ref.ros2_pose]
enabled = false

[[sources]]
key = "{source_prefix}*/joint_states"
codec = "ros2"
stream = "joints"
scheme = "bridge"
robot_from_key = "ros2_namespace"
tf_prefix = "{tf_prefix}"
effort = "current_a"
[[sources]]
key = "{source_prefix}*/tcp_pose_broadcaster/pose"
codec = "ros2"
stream = "measured"
scheme = "bridge"
robot_from_key = "ros2_namespace"
tf_prefix = "{tf_prefix}"
"""


@pytest.fixture
def deployments(router_bin, armtwin_bin, tmp_path):
    started: list[Deployment] = []

    def start(namespace: str, config: str) -> Deployment:
        workdir = tmp_path / f"deployment-{len(started)}"
        workdir.mkdir()
        deployment = Deployment(router_bin, armtwin_bin, workdir, namespace, config)
        started.append(deployment)
        return deployment.start()

    yield start
    for deployment in started:
        codes = deployment.stop()
        assert codes == (0, 0), f"exit codes (armtwin, router) {codes}\n{deployment.logs()}"


def received_poses(out: dict) -> list[list[float]]:
    return [r["pose"] for r in out["received"]]


def test_a_real_rclpy_node_through_the_real_bridge_twins_as_the_json_path(deployments, tmp_path):
    n = 1000
    q, meas, stamps, t, qd, current = load_rows(n)
    rows = write_rows(tmp_path / "rows.json", q, meas, stamps, qd, current)
    deployment = deployments("/", armtwin_config("", "ur5_"))
    node = deployment.node("ur5", rows, "/ur5", "ur5_").start()

    # The same rows as armtwin's JSON messages, through the same router.
    publishers = [
        deployment.session.declare_publisher(f"{PREFIX}/{stream}/json_ref", congestion_control=zenoh.CongestionControl.BLOCK,
                                             reliability=zenoh.Reliability.RELIABLE)
        for stream in ("joints", "measured")
    ]
    assert wait_until(lambda: all(p.matching_status.matching for p in publishers), 20.0)
    for i in range(n):
        publishers[0].put(json.dumps({"t": t[i], "q": q[i].tolist()}))
        publishers[1].put(json.dumps({"t": t[i], **dict(zip(("x", "y", "z", "qx", "qy", "qz", "qw"), meas[i].tolist()))}))
    out = node.wait()

    c = deployment.collector
    done = wait_until(
        lambda: all((m := c.last("metrics", r)) is not None and m.get("paired") == n for r in ("ur5", "json_ref")), 30.0
    )
    assert done, ({r: c.last("metrics", r) for r in ("ur5", "json_ref")}, deployment.logs())

    checks = Checks()
    # armtwin's view: poses and metrics as the reference, the JSON path and validate.
    poses = {r: c.messages("pose", r) for r in ("ur5", "json_ref")}
    check_poses(checks, poses["ur5"], "ur5", t, q, "ur5")
    stats = reference_stats(reference_deviations(q, meas))
    check_metrics(checks, c.last("metrics", "ur5"), "ur5", n, 0, stats, "ur5", t=t[-1])
    fields = ("t", "seq", "x", "y", "z", "qx", "qy", "qz", "qw", "roll", "pitch", "yaw")
    checks.equal([[p[k] for k in fields] for p in poses["ur5"]], [[p[k] for k in fields] for p in poses["json_ref"]],
                 "ur5: poses as the JSON path's, bit for bit")
    for part in ("paired", "unpaired", "rejected", "cumulative", "window"):
        checks.equal(c.last("metrics", "ur5")[part], c.last("metrics", "json_ref")[part], f"ur5: metrics {part} as the JSON path's")
    head = tmp_path / "head.csv"
    with open(DATA_DIR / "ur10e_lasttest.csv") as f:
        head.write_text("".join(line for _, line in zip(range(n + 1), f)))
    result = run_armtwin("validate", head, "--out", tmp_path / "validate")
    assert result.returncode == 0, result.stderr
    report = json.loads((tmp_path / "validate" / "report.json").read_text())
    checks.equal(c.last("metrics", "ur5")["cumulative"], report["cumulative"], "ur5: cumulative metrics as validate's")
    checks.equal(c.messages("events", "ur5"), [], "ur5: no events")

    # Velocity and effort, carried as the source says (currents), the latest of each.
    joint_state = deployment.state("ur5")["joint_state"]
    checks.equal(joint_state["qd"], qd[-1].tolist(), "ur5: joint velocities from JointState.velocity")
    checks.equal(joint_state["current_a"], current[-1].tolist(), "ur5: currents from JointState.effort")
    checks.equal(joint_state.get("torque_nm"), None, "ur5: the effort is not taken for a torque")

    # rclpy's view: every twin pose, decoded by rclpy, as armtwin published it.
    received = out["received"]
    checks.equal(len(received), n, "rclpy received every twin pose through the bridge")
    checks.true(all(r["frame_id"] == "ur5_base" for r in received), "rclpy: frame ur5_base")
    checks.equal([(r["sec"], r["nanosec"]) for r in received], stamps, "rclpy: stamps as the JointState's")
    checks.equal(received_poses(out), [[p[k] for k in ("x", "y", "z", "qx", "qy", "qz", "qw")] for p in poses["ur5"]],
                 "rclpy: poses equal armtwin's")

    committed = json.loads((DATA_DIR / "ros2" / "rclpy" / "type_hashes.json").read_text())
    checks.equal(out["type_hashes"], {"joint_states": committed["sensor_msgs/msg/JointState"],
                                      "pose": committed["geometry_msgs/msg/PoseStamped"]},
                 "rclpy's live type hashes are the committed ones")
    checks.done(deployment.logs())


def test_robots_come_and_go_under_the_bridges_namespace(deployments, tmp_path):
    """Bridge ``namespace: "/plant"``: ``/ur5/joint_states`` is key ``plant/ur5/joint_states``, the robot
    ``plant/ur5``, its twin pose key ``plant/ur5/armtwin/tcp_pose`` back to ``/ur5/armtwin/tcp_pose``.
    ``ur5`` streams and stops; then ``ur10`` joins. When a node stops, the bridge undeclares its
    routes, and armtwin retires the robot after ``forget_after_s``."""
    n = 300
    q, meas, stamps, t, qd, current = load_rows(n)
    rows = write_rows(tmp_path / "rows.json", q, meas, stamps, qd, current)
    deployment = deployments("/plant", armtwin_config("plant/", "", "forget_after_s = 2.0"))
    checks = Checks()
    c = deployment.collector
    hashes = json.loads((DATA_DIR / "ros2" / "rclpy" / "type_hashes.json").read_text())
    for name in ("ur5", "ur10"):
        robot = f"plant/{name}"
        node = deployment.node(name, rows, f"/{name}", "").start()
        # Joining: the bridge routes the node's writers (its liveliness tokens say so).
        mine = lambda: [k for k in deployment.bridge_publishers() if f"§{name}§" in k]  # noqa: E731
        checks.true(wait_until(lambda: len(mine()) == 2, 20.0, 0.1),
                    f"{name}: the bridge declared the node's two writers ({deployment.bridge_publishers()})")
        # Its tokens carry the type hash the bridge read from DDS discovery: a third opinion.
        joint_tokens = [k for k in mine() if f"plant§{name}§joint_states/sensor_msgs§msg§JointState/" in k]
        checks.true(len(joint_tokens) == 1 and f"typehash={hashes['sensor_msgs/msg/JointState']};" in joint_tokens[0],
                    f"{name}: the bridge's JointState route and its type hash ({mine()})")
        out = node.wait()
        done = wait_until(lambda: (m := c.last("metrics", robot)) is not None and m.get("paired") == n, 30.0)
        checks.true(done, f"{robot}: every pair ({c.last('metrics', robot)})")
        check_poses(checks, c.messages("pose", robot), robot, t, q, robot)
        checks.equal(len(out["received"]), n, f"{name}: rclpy received every twin pose")
        checks.true(all(r["frame_id"] == "base" for r in out["received"]), f"{name}: frame base")
        checks.equal(received_poses(out), [[p[k] for k in ("x", "y", "z", "qx", "qy", "qz", "qw")]
                                           for p in c.messages("pose", robot)], f"{name}: poses equal armtwin's")
        # The node has stopped: the bridge undeclares its routes; armtwin retires the robot.
        checks.true(wait_until(lambda: not mine(), 20.0, 0.2),
                    f"{name}: the bridge undeclared the node's writers ({deployment.bridge_publishers()})")
        checks.true(wait_until(lambda: robot not in deployment.alive(), 15.0, 0.2),
                    f"{robot}: retired after forget_after_s ({deployment.alive()})")
    checks.equal(c.messages("events", "plant/ur5"), [], "plant/ur5: no events")
    checks.done(deployment.logs())


# A DDS participant of the bridge's domain, not the robot's driver: JointState on TOPIC for
# SECONDS at 20 Hz.
FORGER = """
import sys, time
import rclpy
from sensor_msgs.msg import JointState
rclpy.init()
node = rclpy.create_node("forger")
publisher = node.create_publisher(JointState, sys.argv[1], 10)
deadline = time.monotonic() + float(sys.argv[2])
while time.monotonic() < deadline:
    msg = JointState()
    msg.name = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    msg.position = [0.0] * 6
    publisher.publish(msg)
    time.sleep(0.05)
node.destroy_node()
rclpy.shutdown()
"""


def bridge_router(router_bin: Path, workdir: Path, access_control: dict) -> tuple[Router, dict]:
    """armtwin-router with the bridge (a random DDS domain, namespace `/`) and ``access_control``,
    not started; and the environment of a ROS 2 process on its domain."""
    domain = random.randrange(1, 100)
    ros_env = {"ROS_DOMAIN_ID": str(domain), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
               "ROS_DISTRO": "jazzy"}
    config = workdir / "bridge-acl.json5"
    config.write_text(json.dumps({
        "access_control": access_control,
        "plugins": {"ros2dds": {"domain": domain, "namespace": "/",
                                "ros_automatic_discovery_range": "LOCALHOST"}},
    }))
    router = Router(router_bin, workdir, config=config,
                    env={**ros_env, "RUST_LOG": "z=info,armtwin_router=info,zenoh::net::routing::interceptor::access_control=trace"})
    return router, ros_env


# Zenoh clients over TCP may subscribe to twin/** and hear what is put there; nobody may put.
LISTEN_ONLY = {
    "enabled": True,
    "default_permission": "deny",
    "rules": [
        {"id": "subscribe", "permission": "allow", "flows": ["ingress"],
         "messages": ["declare_subscriber"], "key_exprs": [f"{PREFIX}/**"]},
        {"id": "hear", "permission": "allow", "flows": ["egress"], "messages": ["put"],
         "key_exprs": [f"{PREFIX}/**"]},
    ],
    "subjects": [{"id": "tcp-clients", "link_protocols": ["tcp"]}],
    "policies": [{"rules": ["subscribe", "hear"], "subjects": ["tcp-clients"]}],
}


def test_the_routers_access_control_does_not_judge_its_bridge(router_bin, tmp_path, processes):
    """Why the bridge needs --ros2-trusted beside access control: under rules that let no session
    put, a Zenoh client's put of robot r3's joints is dropped while a ROS 2 publisher's r2 joints,
    through the bridge in the router's own session, reach a subscriber."""
    router, ros_env = bridge_router(router_bin, tmp_path, LISTEN_ONLY)
    router.argv += ["--ros2-trusted"]
    processes.append(router.start())
    assert router.wait_log("past its access control (--ros2-trusted)"), router.logs()
    listener = open_client(router.endpoint)
    putter = open_client(router.endpoint)
    heard: list[str] = []  # the keys heard, appended from Zenoh's callback (atomic in CPython)
    try:
        listener.declare_subscriber(f"{PREFIX}/joints/**", lambda sample: heard.append(str(sample.key_expr)))
        forger = Process("forger", [ros2_python(), "-c", FORGER, f"/{PREFIX}/joints/r2", "60"],
                         tmp_path, ros_env)
        processes.append(forger.start())
        forged = putter.declare_publisher(f"{PREFIX}/joints/r3")

        def bridge_heard() -> bool:
            forged.put(json.dumps({"t": 1.0, "q": [0.0] * 6}))
            return heard.count(f"{PREFIX}/joints/r2") >= 20

        assert wait_until(bridge_heard, 60.0, interval=0.05), (heard[:3], router.logs())
        assert f"{PREFIX}/joints/r3" not in heard, "the Zenoh client's put passed the rules"
        assert "is unauthorized to Put (ingress)" in router.logs(10**9), router.logs()
    finally:
        listener.close()
        putter.close()


def test_the_router_refuses_the_bridge_beside_access_control_unless_trusted(router_bin, tmp_path):
    router, _ = bridge_router(router_bin, tmp_path, LISTEN_ONLY)
    result = subprocess.run([str(a) for a in router.argv], cwd=tmp_path, capture_output=True,
                            text=True, timeout=60, env={**os.environ, **router.env})
    assert result.returncode != 0, result.stderr
    assert "the router has access control, which the ROS 2 bridge bypasses" in result.stderr, result.stderr
    assert "--ros2-trusted" in result.stderr and "panicked" not in result.stderr


PANDA_JOINTS = [f"panda_joint{k}" for k in range(1, 8)]


def test_a_panda_twins_from_its_own_robot_description_through_the_real_bridge(router_bin, armtwin_bin, tmp_path):
    """A non-UR arm with no model in armtwin's configuration: a real rclpy node publishes the
    Panda's URDF (tests/data/urdf/panda.urdf) on ``/panda/robot_description``, transient local as
    ``robot_state_publisher`` does, *before* armtwin starts; armtwin, given only a description
    source and a joint source, reads it from the bridge's cache, takes it (an event, a new epoch:
    seven joints where the default model has six), and twins the node's ``JointState``s: every twin
    pose equals Pinocchio's pose of the same URDF at the same joints (``robot_state_publisher``'s
    TF is not installed here) to 1e-12 m."""
    import pinocchio as pin

    path = DATA_DIR / "urdf" / "panda.urdf"
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    rng = np.random.default_rng(7)
    n = 200
    rows, expected = [], []
    base, tip = model.getFrameId("panda_link0"), model.getFrameId("panda_hand_tcp")
    for i in range(n):
        q = pin.neutral(model)
        values = []
        for name in PANDA_JOINTS:
            joint = model.getJointId(name)
            index = model.joints[joint].idx_q
            q[index] = rng.uniform(model.lowerPositionLimit[index], model.upperPositionLimit[index])
            values.append(float(q[index]))
        pin.framesForwardKinematics(model, data, q)
        pose = data.oMf[base].inverse() * data.oMf[tip]
        expected.append((pose.translation.copy(), pose.rotation.copy()))
        ns = EPOCH_SEC * 10**9 + i * 10**7
        rows.append({"sec": ns // 10**9, "nanosec": ns % 10**9, "names": PANDA_JOINTS, "q": values})
    rows_path = tmp_path / "panda_rows.json"
    rows_path.write_text(json.dumps(rows))
    config = """\
[service]
metrics_period_ms = 50
pose_congestion = "block"

[robots.default]
model = "ur10e"
tip_link = "panda_hand_tcp"        # the chain of the descriptions the robots publish

[[sources]]
key = "*/robot_description"
codec = "ros2"
stream = "description"
scheme = "bridge"
robot_from_key = "ros2_namespace"
[[sources]]
key = "*/joint_states"
codec = "ros2"
stream = "joints"
scheme = "bridge"
robot_from_key = "ros2_namespace"
joint_names = ["panda_joint1", "panda_joint2", "panda_joint3", "panda_joint4", "panda_joint5", "panda_joint6", "panda_joint7"]
"""
    deployment = Deployment(router_bin, armtwin_bin, tmp_path, "/", config)
    go = tmp_path / "go"
    node = Process("node-panda", [ros2_python(), SUPPORT_DIR / "ros2_description_node.py", "--urdf", path,
                                  "--rows", rows_path, "--namespace", "/panda", "--go", go],
                   tmp_path, deployment.ros_env)
    try:
        deployment.router.start()
        node.start()
        assert wait_until(lambda: '"described"' in node.logs(), 60.0), node.logs()
        # armtwin starts after the description was published: it comes from the bridge's cache.
        deployment.armtwin.start()
        deployment.session = open_client(deployment.router.endpoint)
        deployment.subscriber = deployment.session.declare_subscriber(f"{PREFIX}/**", deployment.collector)
        c = deployment.collector

        def taken():
            return [m for m in c.messages("events", "panda") if m["kind"] == "description"]

        assert wait_until(taken, 60.0), (c.messages("events", "panda"), deployment.logs(), node.logs())
        [event] = taken()
        assert event["detail"]["in_use"] is True and event["detail"]["joints"] == 7, event
        assert event["detail"]["origin"] == "panda/robot_description", event
        go.write_text("go")
        assert wait_until(lambda: c.count("pose", "panda") >= n, 90.0), (c.count("pose", "panda"), node.logs(),
                                                                         c.messages("events", "panda")[-3:])
        worst_m = worst_rotation = 0.0
        for message, (position, rotation) in zip(c.messages("pose", "panda"), expected, strict=True):
            got = np.array([message["x"], message["y"], message["z"]])
            worst_m = max(worst_m, float(np.abs(got - position).max()))
            got_rotation = Rotation.from_quat([message[k] for k in ("qx", "qy", "qz", "qw")]).as_matrix()
            worst_rotation = max(worst_rotation, float(np.abs(got_rotation - rotation).max()))
        print(f"\n[panda through the bridge] {n} poses: worst position {worst_m:.1e} m, rotation entry {worst_rotation:.1e}")
        assert worst_m <= 1e-12 and worst_rotation <= 1e-12
        assert deployment.state("panda")["model"] == "panda"
        assert [m for m in c.messages("events", "panda") if m["kind"] == "rejected"] == []
    finally:
        go.unlink(missing_ok=True)
        node.stop()
        codes = deployment.stop()
    assert codes == (0, 0), f"exit codes (armtwin, router) {codes}\n{deployment.logs()}"
