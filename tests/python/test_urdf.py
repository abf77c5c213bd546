"""`armtwin fk --model FILE.urdf`: the pose of a chain of any arm's URDF, against Pinocchio's.

Five descriptions from example-robot-data (tests/data/urdf/, BSD-3-Clause), read unchanged: Franka
Panda (fixed joints to its TCP, mimic fingers off the chain), UR5, Kinova Jaco (continuous
joints), Unitree Z1 (its one leaf taken as the tip) and PAL TIAGo (a prismatic torso lift under the
arm, and the head's chain beside it). Pinocchio builds the whole model from the same file; every
joint off the chain stays at its neutral position. Random joint values within each joint's limits
(continuous joints over a full turn); the tip link's pose in the base link's frame must agree to
1e-12 m and 1e-12 in every rotation matrix entry.

Written against the URDF specification (wiki.ros.org/urdf/XML) and Pinocchio, not the Rust source.

Run: ``ARMTWIN_BIN=$PWD/target/debug/armtwin .venv/bin/python -m pytest tests/python/test_urdf.py -q``
"""

from __future__ import annotations

import contextlib
import json
import math
import time
import urllib.request
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest

from support.paths import REPO_ROOT
from support.process import ArmtwinProcess, free_port, run_armtwin, wait_until
from support.twin_reference import joint_message
from support.zenoh_clients import TwinClient, description_publisher, get_json
from support.dashboard import metric

URDF_DIR = REPO_ROOT / "tests" / "data" / "urdf"
CONFIGURATIONS = 12
TOLERANCE = 1e-12
# (file, base link or None for the root, tip link or None for the one leaf)
CHAINS = [
    ("panda.urdf", "panda_link0", "panda_hand_tcp"),
    ("ur5_robot.urdf", None, "tool0"),
    ("ur5_robot.urdf", "base_link", "ee_link"),
    ("kinova.urdf", None, "j2s6s200_end_effector"),
    ("z1.urdf", None, None),
    ("tiago_no_hand.urdf", None, "wrist_ft_tool_link"),
    ("tiago_no_hand.urdf", "torso_lift_link", "xtion_optical_frame"),
]


def chain_joints(model: pin.Model, base: str, tip: str) -> list[int]:
    """Pinocchio's moving joints between the base and tip links' bodies, base first."""
    def joints_to(frame_name: str) -> list[int]:
        joint = model.frames[model.getFrameId(frame_name)].parentJoint
        path = []
        while joint != 0:
            path.append(joint)
            joint = model.parents[joint]
        return path[::-1]

    to_base, to_tip = joints_to(base), joints_to(tip)
    assert to_tip[:len(to_base)] == to_base, (base, tip)
    return to_tip[len(to_base):]


def random_value(model: pin.Model, joint: int, rng: np.random.Generator) -> float:
    index, nq = model.joints[joint].idx_q, model.joints[joint].nq
    if nq == 2:  # continuous: cos and sin in the configuration
        return float(rng.uniform(-math.pi, math.pi))
    low, high = model.lowerPositionLimit[index], model.upperPositionLimit[index]
    return float(rng.uniform(low, high))


def set_value(model: pin.Model, q: np.ndarray, joint: int, value: float) -> None:
    index, nq = model.joints[joint].idx_q, model.joints[joint].nq
    if nq == 2:
        q[index], q[index + 1] = math.cos(value), math.sin(value)
    else:
        q[index] = value


def random_configuration(model: pin.Model, joints: list[int], rng: np.random.Generator) -> tuple[list[float], np.ndarray]:
    """Random values of the chain's ``joints`` (within limits; continuous over a full turn), and
    Pinocchio's configuration of the whole model with every other joint at its neutral value."""
    values = [random_value(model, joint, rng) for joint in joints]
    q = pin.neutral(model)
    for joint, value in zip(joints, values):
        set_value(model, q, joint, value)
    return values, q


@contextlib.contextmanager
def twin_and_client(armtwin_bin, tmp_path, config: str, robots: list[str]):
    """`armtwin serve` on `config` and a client ready for `robots`' inputs; both stopped after."""
    service = ArmtwinProcess(armtwin_bin, tmp_path, config, 120.0)
    service.start()
    client = None
    try:
        client = TwinClient(service.endpoint)
        client.ready(robots)
        yield service, client
    finally:
        if client is not None:
            client.close()
        service.stop()


def listed(values) -> str:
    """Numbers as one comma-separated flag value, each read back to the same bits."""
    return ",".join(repr(float(v)) for v in values)


def chain_ends(path, base: str | None, tip: str | None) -> tuple[str, str]:
    """The chain's base and tip links as the URDF specification makes them: those given, else
    the root (the link no joint has as its child) and the one leaf (no joint's parent)."""
    robot = ET.parse(path).getroot()
    links = [link.get("name") for link in robot.findall("link")]
    parents = {j.find("parent").get("link") for j in robot.findall("joint")}
    children = {j.find("child").get("link") for j in robot.findall("joint")}
    [root] = [link for link in links if link not in children]
    leaves = [link for link in links if link not in parents]
    if tip is None:
        assert len(leaves) == 1, leaves
    return base or root, tip or leaves[0]


@pytest.mark.parametrize("file,base,tip", CHAINS, ids=[f"{f}:{b or 'root'}->{t or 'leaf'}" for f, b, t in CHAINS])
def test_the_chain_pose_equals_pinocchios(armtwin_bin, file, base, tip):
    path = URDF_DIR / file
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    base_name, tip_name = chain_ends(path, base, tip)
    joints = chain_joints(model, base_name, tip_name)
    rng = np.random.default_rng(sum(map(ord, file + base_name + tip_name)))
    flags = ["--model", str(path)]
    if base:
        flags += ["--base-link", base]
    if tip:
        flags += ["--tip-link", tip]
    worst_m, worst_rotation = 0.0, 0.0
    for _ in range(CONFIGURATIONS):
        values, q = random_configuration(model, joints, rng)
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        expected = data.oMf[model.getFrameId(base_name)].inverse() * data.oMf[model.getFrameId(tip_name)]
        run = run_armtwin("fk", *flags, "--matrix", "--", *[repr(v) for v in values])
        assert run.returncode == 0, run.stderr
        matrix = np.array(json.loads(run.stdout)["matrix"])
        worst_m = max(worst_m, float(np.max(np.abs(matrix[:3, 3] - expected.translation))))
        worst_rotation = max(worst_rotation, float(np.max(np.abs(matrix[:3, :3] - expected.rotation))))
    print(f"\n[{file} {base_name} -> {tip_name}] {len(joints)} joints, {CONFIGURATIONS} configurations: "
          f"worst position {worst_m:.1e} m, worst rotation entry {worst_rotation:.1e}")
    assert worst_m <= TOLERANCE and worst_rotation <= TOLERANCE, (worst_m, worst_rotation)


def test_a_chain_that_cannot_be_chosen_or_a_xacro_is_refused_naming_why(armtwin_bin, tmp_path):
    panda = URDF_DIR / "panda.urdf"
    leaves = run_armtwin("fk", "--model", str(panda), "0")
    assert leaves.returncode != 0
    assert "leaf links ('panda_hand_tcp', 'panda_leftfinger', 'panda_rightfinger')" in leaves.stderr, leaves.stderr
    mimic = run_armtwin("fk", "--model", str(panda), "--tip-link", "panda_rightfinger", *["0"] * 8)
    assert mimic.returncode != 0 and "joint 'panda_finger_joint2'" in mimic.stderr, mimic.stderr
    count = run_armtwin("fk", "--model", str(panda), "--tip-link", "panda_hand_tcp", "0", "0")
    assert count.returncode != 0 and "has 7 moving joints (panda_joint1" in count.stderr, count.stderr
    template = tmp_path / "arm.urdf"
    text = panda.read_text()
    assert 'xmlns:xacro="http://www.ros.org/wiki/xacro">' in text  # declared, unused: a URDF still
    template.write_text(text.replace('xmlns:xacro="http://www.ros.org/wiki/xacro">',
                                     'xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:include filename="hand.xacro"/>', 1))
    xacro = run_armtwin("fk", "--model", str(template), "0")
    assert xacro.returncode != 0 and "xacro robot.urdf.xacro > robot.urdf" in xacro.stderr, xacro.stderr
    # The commands that run the twin's model take revolute chains, and say so of a prismatic joint.
    tiago = URDF_DIR / "tiago_no_hand.urdf"
    ik = run_armtwin("ik", "--model", tiago, "--tip-link", "wrist_ft_tool_link", "--pose=0.3,0,0.5,1,0,0,0")
    assert ik.returncode != 0 and "joint 'torso_lift_joint': is prismatic" in ik.stderr, ik.stderr


TORQUE_TOLERANCE = 1e-9  # relative to the torque vector's largest entry (at least 1 N·m or N)


@pytest.mark.parametrize("file,base,tip", CHAINS, ids=[f"{f}:{b or 'root'}->{t or 'leaf'}" for f, b, t in CHAINS])
def test_the_chain_torques_equal_pinocchios_rnea_on_the_whole_model(armtwin_bin, file, base, tip):
    """Inverse dynamics of the chain with every body of the tree: Pinocchio's RNEA on the whole
    model, every joint off the chain at its neutral position and at rest, gravity 9.81 m/s²."""
    path = URDF_DIR / file
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    base_name, tip_name = chain_ends(path, base, tip)
    joints = chain_joints(model, base_name, tip_name)
    rng = np.random.default_rng(7 + sum(map(ord, file + base_name + tip_name)))
    flags = ["--model", str(path)] + (["--base-link", base] if base else []) + (["--tip-link", tip] if tip else [])
    worst = 0.0
    for _ in range(CONFIGURATIONS):
        values, q = random_configuration(model, joints, rng)
        qd = rng.uniform(-2.0, 2.0, len(joints))
        qdd = rng.uniform(-5.0, 5.0, len(joints))
        v, a = np.zeros(model.nv), np.zeros(model.nv)
        for k, joint in enumerate(joints):
            v[model.joints[joint].idx_v], a[model.joints[joint].idx_v] = qd[k], qdd[k]
        expected = pin.rnea(model, data, q, v, a)[[model.joints[j].idx_v for j in joints]]
        run = run_armtwin("torques", *flags, f"--q={listed(values)}", f"--qd={listed(qd)}", f"--qdd={listed(qdd)}")
        assert run.returncode == 0, run.stderr
        got = np.array(json.loads(run.stdout)["torque"])
        worst = max(worst, float(np.max(np.abs(got - expected)) / max(1.0, float(np.max(np.abs(expected))))))
    print(f"\n[{file} {base_name} -> {tip_name}] torques at {CONFIGURATIONS} states: worst relative {worst:.1e}")
    assert worst <= TORQUE_TOLERANCE, worst


@pytest.mark.parametrize("frame", ["base", "base_link"])
def test_the_exported_urdf_of_a_calibrated_ur_arm_gives_armtwins_poses_in_pinocchio(armtwin_bin, tmp_path, frame):
    """`armtwin models --urdf ur10e` with a calibration (the example file: synthetic, with the
    hundreds of metres of cancelling delta_d a real controller's file has), a tool and a frame:
    Pinocchio's pose of the tip equals `armtwin fk`'s with the same flags to 1e-9, and armtwin
    reads its own file back to the same poses."""
    calibration = REPO_ROOT / "config" / "examples" / "calibration.conf"
    flags = ["--calibration", calibration, "--tcp=0.01,-0.02,0.15,0.1,-0.2,0.3", "--frame", frame]
    exported = run_armtwin("models", "--urdf", "ur10e", *flags)
    assert exported.returncode == 0, exported.stderr
    urdf = tmp_path / "ur10e_calibrated.urdf"
    urdf.write_text(exported.stdout)
    model = pin.buildModelFromXML(exported.stdout)
    data = model.createData()
    assert [model.names[j] for j in range(1, model.njoints)] == [
        "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    rng = np.random.default_rng(5)
    worst_pinocchio, worst_read_back = 0.0, 0.0
    for _ in range(CONFIGURATIONS):
        q = rng.uniform(-math.pi, math.pi, 6)
        values = ["--", *[repr(float(v)) for v in q]]
        twin = run_armtwin("fk", "--model", "ur10e", *flags, "--matrix", *values)
        assert twin.returncode == 0, twin.stderr
        expected = np.array(json.loads(twin.stdout)["matrix"])
        pin.forwardKinematics(model, data, q)
        pin.updateFramePlacements(model, data)
        tip = data.oMf[model.getFrameId("tcp")].homogeneous
        worst_pinocchio = max(worst_pinocchio, float(np.max(np.abs(tip[:3] - expected[:3]))))
        again = run_armtwin("fk", "--model", urdf, "--matrix", *values)
        assert again.returncode == 0, again.stderr
        read_back = np.array(json.loads(again.stdout)["matrix"])
        worst_read_back = max(worst_read_back, float(np.max(np.abs(read_back[:3] - expected[:3]))))
    print(f"\n[ur10e calibrated, {frame}] Pinocchio on the exported URDF against armtwin fk: worst {worst_pinocchio:.1e}; "
          f"armtwin on its own URDF: worst {worst_read_back:.1e}")
    assert worst_pinocchio <= 1e-9 and worst_read_back <= 1e-9, (worst_pinocchio, worst_read_back)


def stream_panda(client: TwinClient, robot: str, count: int, seed: int) -> tuple[float, float, float]:
    """Streams ``count`` random Panda configurations with Pinocchio's pose of each as the measured
    pose; waits for their twin poses and deviations. Returns the worst position (m) and quaternion
    component differences of the twin poses from Pinocchio's, and the worst deviation (m)."""
    path = URDF_DIR / "panda.urdf"
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    joints = chain_joints(model, "panda_link0", "panda_hand_tcp")
    rng = np.random.default_rng(seed)
    collector = client.collector
    poses_before, deviations_before = collector.count("pose", robot), collector.count("deviation", robot)
    expected = []
    publisher = client.joints(robot)
    for k in range(count):
        values, q = random_configuration(model, joints, rng)
        pin.framesForwardKinematics(model, data, q)
        tip = data.oMf[model.getFrameId("panda_link0")].inverse() * data.oMf[model.getFrameId("panda_hand_tcp")]
        quaternion = pin.Quaternion(tip.rotation).coeffs()  # x, y, z, w
        pose = [*tip.translation, *quaternion]
        expected.append(pose)
        publisher.put(json.dumps(joint_message(100.0 * seed + 0.01 * k, values, pose)))
    assert wait_until(lambda: collector.count("deviation", robot) >= deviations_before + count, 30.0), \
        (collector.count("deviation", robot), collector.count("pose", robot), collector.messages("events", robot)[-5:])
    assert collector.count("pose", robot) == poses_before + count
    worst_m, worst_quaternion, worst_deviation_m = 0.0, 0.0, 0.0
    for message, pose in zip(collector.messages("pose", robot)[poses_before:], expected, strict=True):
        got = np.array([message[key] for key in ("x", "y", "z", "qx", "qy", "qz", "qw")])
        want = np.array(pose)
        if want[6] < 0:
            want[3:] = -want[3:]
        worst_m = max(worst_m, float(np.max(np.abs(got[:3] - want[:3]))))
        worst_quaternion = max(worst_quaternion, float(np.max(np.abs(got[3:] - want[3:]))))
    for message in collector.messages("deviation", robot)[deviations_before:]:
        worst_deviation_m = max(worst_deviation_m, float(message["position"]))
    return worst_m, worst_quaternion, worst_deviation_m


def test_a_panda_from_its_urdf_is_twinned_live(armtwin_bin, tmp_path):
    """`armtwin serve` with `model` a URDF (the Panda to its hand's TCP, every axis a URDF axis
    turned onto z inside the twin): its twin poses equal Pinocchio's for the joints streamed, and
    a measured pose equal to Pinocchio's deviates by nothing."""
    path = URDF_DIR / "panda.urdf"
    robot = "lab/panda"
    config = (f'[robots."{robot}"]\nmodel = "{path}"\ntip_link = "panda_hand_tcp"\n'
              f'[robots.default]\nmodel = "ur10e"\n')
    with twin_and_client(armtwin_bin, tmp_path, config, [robot]) as (service, client):
        worst_m, worst_quaternion, worst_deviation_m = stream_panda(client, robot, 50, 11)
        print(f"\n[panda live] 50 poses: worst position {worst_m:.1e} m, quaternion {worst_quaternion:.1e}; "
              f"worst deviation {worst_deviation_m:.1e} m")
        assert worst_m <= TOLERANCE and worst_quaternion <= TOLERANCE and worst_deviation_m <= TOLERANCE


def test_a_robot_takes_its_own_description_and_a_robot_with_a_model_checks_it(armtwin_bin, tmp_path):
    """Descriptions on `twin/description/<robot>`, as a gateway puts them. A robot with no model
    of its own (here a Panda, while the default model is a six-joint UR10e) takes its URDF: an
    event, a new metrics epoch, and twin poses equal to Pinocchio's from then on. A robot whose
    own section sets its model has its description checked: armtwin's own URDF of that model
    agrees and changes nothing; a UR5's disagrees and is refused, as is a text that is no URDF,
    each counted on `/metrics`. The same text again is not read twice."""
    panda, ur10e = "lab/panda", "lab/ur10e"
    http_port = free_port()
    config = (f'[http]\nlisten = "127.0.0.1:{http_port}"\n'
              f'[robots.default]\nmodel = "ur10e"\n'
              f'[robots."{panda}"]\ntip_link = "panda_hand_tcp"\n'
              f'[robots."{ur10e}"]\nmodel = "ur10e"\ntip_link = "tool0"\n')
    with twin_and_client(armtwin_bin, tmp_path, config, [panda, ur10e]) as (service, client):
        collector = client.collector

        def descriptions(robot: str) -> list[dict]:
            return [m for m in collector.messages("events", robot) if m["kind"] == "description"]

        describe = {robot: description_publisher(client.session, robot) for robot in (panda, ur10e)}
        # The Panda's own URDF: taken, with a new epoch.
        panda_text = (URDF_DIR / "panda.urdf").read_text()
        describe[panda].put(panda_text)
        assert wait_until(lambda: descriptions(panda), 20.0), (collector.messages("events", panda), service.logs())
        [taken] = descriptions(panda)
        assert taken["detail"]["in_use"] is True and taken["detail"]["joints"] == 7, taken
        assert taken["detail"]["name"] == "panda", taken
        assert any(m["kind"] == "epoch" for m in collector.messages("events", panda)), collector.messages("events", panda)
        worst_m, worst_quaternion, worst_deviation_m = stream_panda(client, panda, 30, 5)
        print(f"\n[panda from its description] 30 poses: worst position {worst_m:.1e} m, "
              f"quaternion {worst_quaternion:.1e}; worst deviation {worst_deviation_m:.1e} m")
        assert worst_m <= TOLERANCE and worst_quaternion <= TOLERANCE and worst_deviation_m <= TOLERANCE
        # The dashboard draws it from its link frames: each joint's origin, then the TCP, as
        # Pinocchio places them in the base link at the last joints streamed.
        with urllib.request.urlopen(f"http://127.0.0.1:{http_port}/api/robot/frames?id={panda}", timeout=10) as r:
            drawn = json.loads(r.read())
        model = pin.buildModelFromUrdf(str(URDF_DIR / "panda.urdf"))
        data = model.createData()
        q = pin.neutral(model)
        for k, value in enumerate(drawn["q"]):
            q[model.joints[model.getJointId(f"panda_joint{k + 1}")].idx_q] = value
        pin.framesForwardKinematics(model, data, q)
        base = data.oMf[model.getFrameId("panda_link0")].inverse()
        places = [(base * data.oMi[model.getJointId(f"panda_joint{k}")]).translation for k in range(1, 8)]
        places.append((base * data.oMf[model.getFrameId("panda_hand_tcp")]).translation)
        got = np.array([frame["position_m"] for frame in drawn["frames"]])
        assert drawn["model"] == "panda" and got.shape == (8, 3), drawn
        assert float(np.abs(got - np.array(places)).max()) <= TOLERANCE, (got, places)
        # The same text again: not read again, no event.
        describe[panda].put(panda_text)

        # armtwin's own URDF of the configured model agrees: an event, nothing changes.
        own = run_armtwin("models", "--urdf", "ur10e")
        assert own.returncode == 0, own.stderr
        describe[ur10e].put(own.stdout)
        assert wait_until(lambda: descriptions(ur10e), 20.0), service.logs()
        [agrees] = descriptions(ur10e)
        assert agrees["detail"]["in_use"] is False and "agrees" in agrees["reason"], agrees
        assert agrees["detail"]["position_difference_m"] <= 1e-9, agrees

        # A UR5's description disagrees with the configured UR10e: refused, counted.
        describe[ur10e].put((URDF_DIR / "ur5_robot.urdf").read_text())
        assert wait_until(lambda: len(descriptions(ur10e)) >= 2, 20.0), service.logs()
        refused = descriptions(ur10e)[1]
        assert refused["detail"]["in_use"] is False and "keeps the configured model" in refused["reason"], refused
        assert refused["detail"]["position_difference_m"] > 0.01, refused
        # No URDF at all: refused on its own, naming why.
        describe[ur10e].put("<robot name='x'><link name='a'/>")
        assert wait_until(lambda: len(descriptions(ur10e)) >= 3, 20.0), service.logs()
        garbage = descriptions(ur10e)[2]
        assert "is refused" in garbage["reason"] and "at once" not in garbage["reason"], garbage
        assert garbage["detail"]["in_use"] is False and garbage["detail"]["error"], garbage
        print(f"[not a URDF] {garbage['reason']}")
        # A flood: the first refused beyond the burst is said, the rest only counted. Refusals are
        # said once a second at most: a second after the last one said, the flood's first is.
        time.sleep(1.1)
        for k in range(20):
            describe[ur10e].put(f"<robot name='flood-{k}'/>")
        assert wait_until(lambda: (metric(http_port, "armtwin_descriptions_refused_total") or 0) >= 2 + 20, 20.0), \
            metric(http_port, "armtwin_descriptions_refused_total")
        # The counter is read over HTTP as the events travel the mesh: wait for them (bounded).
        wait_until(lambda: len(descriptions(ur10e)) >= 4, 10.0)
        time.sleep(0.3)
        flood = descriptions(ur10e)[3:]
        assert 1 <= len(flood) <= 6, [m["reason"] for m in flood]
        assert len(descriptions(panda)) == 1, descriptions(panda)
        # Each computes with what its state says: the Panda's description, the configured UR10e.
        [(_, panda_state)] = get_json(client.session, f"twin/state/{panda}")
        [(_, ur10e_state)] = get_json(client.session, f"twin/state/{ur10e}")
        assert (panda_state["model"], ur10e_state["model"]) == ("panda", "ur10e"), (panda_state, ur10e_state)


def test_a_robot_back_after_its_retirement_computes_with_its_own_description_again(armtwin_bin, tmp_path):
    """A robot known only by its inputs is retired after `forget_after_s` of silence. One that had
    taken its own description (a transient-local `/robot_description` is not sent again) comes back
    computing with it: its first samples of seven joints are twinned, none rejected."""
    robot = "lab/p2"
    http_port = free_port()
    config = (f'[service]\nforget_after_s = 1.0\n[http]\nlisten = "127.0.0.1:{http_port}"\n'
              f'[robots.default]\nmodel = "ur10e"\ntip_link = "panda_hand_tcp"\n')
    with twin_and_client(armtwin_bin, tmp_path, config, [robot]) as (service, client):
        collector = client.collector
        description_publisher(client.session, robot).put((URDF_DIR / "panda.urdf").read_text())
        assert wait_until(lambda: any(m["kind"] == "description" for m in collector.messages("events", robot)), 20.0)
        stream_panda(client, robot, 10, 3)
        assert wait_until(lambda: (metric(http_port, "armtwin_robots_retired_total") or 0) >= 1, 30.0), service.logs()
        worst_m, worst_quaternion, _ = stream_panda(client, robot, 10, 4)
        assert worst_m <= TOLERANCE and worst_quaternion <= TOLERANCE
        rejected = [m for m in collector.messages("events", robot) if m["kind"] == "rejected"]
        assert rejected == [], rejected
        [(_, state)] = get_json(client.session, f"twin/state/{robot}")
        assert state["model"] == "panda" and state["metrics"]["paired"] == 10, state["metrics"]


# (file, base link, tip link): a six-joint arm whose gripper is a body the last joint carries, a
# seven-joint arm whose fingers hang off its hand on prismatic joints, and that arm's first five
# joints as a five-joint arm carrying the rest held at zero.
LOAD_TWIN_ARMS = [
    ("z1.urdf", "link00", "link06"),
    ("panda.urdf", "panda_link0", "panda_hand_tcp"),
    ("panda.urdf", "panda_link0", "panda_link5"),
]


@pytest.mark.parametrize("file,base,tip", LOAD_TWIN_ARMS, ids=[f"{f}:{t}" for f, _, t in LOAD_TWIN_ARMS])
def test_a_urdf_arm_reporting_joint_torques_is_watched_for_collisions(armtwin_bin, tmp_path, file, base, tip):
    """The load twin on an arm known only by its URDF: `effort = true` with `model` the URDF. A
    torque-sensing gateway sends each sample's joint torques (`state.torque_nm`) beside the target
    state; here they are Pinocchio's RNEA on the whole model (every joint off the chain at zero),
    plus a contact on joint 3 of 2.5 times its threshold for 0.2 s. The twin's model torques
    equal Pinocchio's, its thresholds are 10 % of the URDF's effort limits, and the contact, and
    nothing else, raises a collision on joint 3 within 50 ms (source time)."""
    path = URDF_DIR / file
    robot = "lab/arm"
    config = (
        "[service]\nmetrics_period_ms = 50\npose_congestion = \"block\"\n"
        "[effort]\nthreshold_learning_s = 0.0\n"
        f'[robots."{robot}"]\nmodel = "{path}"\nbase_link = "{base}"\ntip_link = "{tip}"\neffort = true\n'
        '[robots.default]\nmodel = "ur10e"\n'
    )
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    joints = chain_joints(model, base, tip)
    efforts = [model.effortLimit[model.joints[j].idx_v] for j in joints]
    centre = np.array([(model.lowerPositionLimit[model.joints[j].idx_q] + model.upperPositionLimit[model.joints[j].idx_q]) / 2
                       for j in joints])  # within every joint's limits
    dt_s, count, contact = 0.002, 2000, (2.0, 2.2, 2, 2.5 * 0.1 * efforts[2])  # onset, end (s), joint (0-based), N·m
    messages, expected = [], []
    for i in range(count):
        t = i * dt_s
        phase = 0.9 * t + np.arange(len(joints))
        q_chain, qd, qdd = 0.4 * np.sin(phase) + centre, 0.36 * np.cos(phase), -0.324 * np.sin(phase)
        q, v, a = pin.neutral(model), np.zeros(model.nv), np.zeros(model.nv)
        for k, joint in enumerate(joints):
            set_value(model, q, joint, float(q_chain[k]))
            v[model.joints[joint].idx_v], a[model.joints[joint].idx_v] = qd[k], qdd[k]
        tau = pin.rnea(model, data, q, v, a)[[model.joints[j].idx_v for j in joints]].copy()
        expected.append(tau.copy())
        if contact[0] <= t < contact[1]:
            tau[contact[2]] += contact[3]
        messages.append(json.dumps({"t": t, "q": q_chain.tolist(), "state": {
            "qd": qd.tolist(), "target_q": q_chain.tolist(), "target_qd": qd.tolist(),
            "target_qdd": qdd.tolist(), "torque_nm": tau.tolist()}}))
    with twin_and_client(armtwin_bin, tmp_path, config, [robot]) as (service, client):
        publisher = client.joints(robot)
        for message in messages:
            publisher.put(message)
        collector = client.collector
        assert wait_until(lambda: collector.count("effort", robot) >= count, 60.0), \
            (collector.count("effort", robot), collector.messages("events", robot)[-5:])
        readouts = collector.messages("effort", robot)
        worst = max(
            float(np.max(np.abs(np.array(r["model_nm"]) - want)) / max(1.0, float(np.max(np.abs(want)))))
            for r, want in zip(readouts, expected, strict=True)
        )
        time.sleep(0.3)  # the events that follow the last readout
        collisions = [(e["kind"], e["t"], e["detail"]) for e in collector.messages("events", robot)
                      if (e.get("detail") or {}).get("metric") == "collision"]
        raised = [(t, detail) for kind, t, detail in collisions if kind == "alarm"]
        answers = get_json(client.session, f"twin/state/{robot}")
        assert len(answers) == 1, answers
        thresholds = answers[0][1]["effort"]["collision"]
        print(f"\n[{file} to {tip}, load twin] {count} samples: model torques against Pinocchio, worst relative {worst:.1e}; "
              f"thresholds {thresholds['threshold_nm']} N·m ({thresholds['threshold_source']}); collisions {collisions}")
        assert worst <= TORQUE_TOLERANCE, worst
        assert thresholds["threshold_source"] == "rated"
        assert np.allclose(thresholds["threshold_nm"], 0.1 * np.array(efforts), rtol=1e-12), thresholds
        assert [detail["joint"] for _, detail in raised] == [contact[2] + 1], collisions
        assert contact[0] <= raised[0][0] < contact[0] + 0.05, raised  # within 50 ms of its onset
        assert thresholds["count"] == 1

