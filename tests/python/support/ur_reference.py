"""Independent numpy/scipy reference for Universal Robots forward kinematics.

Written from Universal Robots' published DH parameters and the usual
standard-DH / URDF conventions, *not* from the armtwin Rust source.

Conventions
-----------
* Standard DH: T = prod_i Rz(theta_i) Tz(d_i) Tx(a_i) Rx(alpha_i), with
  theta_i = q_i + theta_offset_i + delta_theta_i, d_i = d_nom_i + delta_d_i,
  a_i = a_nom_i + delta_a_i, alpha_i = alpha_nom_i + delta_alpha_i.
* Tool: base_from_tcp = base_from_flange @ flange_from_tcp, with
  flange_from_tcp = Trans(x, y, z) @ Rot(rotvec(rx, ry, rz)).
* Frames: ``base`` is the DH frame 0; ``base_link`` = Rz(pi) @ base pose.
* Quaternion: (x, y, z, w), canonicalised to w >= 0.
* Roll/pitch/yaw: R = Rz(yaw) Ry(pitch) Rx(roll).
* URDF / ur_calibration YAML form: pose = O1 Rz(q1) O2 Rz(q2) ... O6 Rz(q6),
  O_i = Trans(x, y, z) @ Rz(yaw) Ry(pitch) Rx(roll).

All functions are vectorised over a leading batch dimension where it makes
sense: joint arrays have shape (N, 6) and poses (N, 4, 4).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

PI = math.pi

# alpha is the same for every model.
ALPHA = (PI / 2, 0.0, 0.0, PI / 2, -PI / 2, 0.0)

# (d1, a2, a3, d4, d5, d6), from Universal Robots' DH parameter page.
_UR_PARAMS = {
    "ur3": (0.1519, -0.24365, -0.21325, 0.11235, 0.08535, 0.0819),
    "ur5": (0.089159, -0.425, -0.39225, 0.10915, 0.09465, 0.0823),
    "ur10": (0.1273, -0.612, -0.5723, 0.163941, 0.1157, 0.0922),
    "ur3e": (0.15185, -0.24355, -0.2132, 0.13105, 0.08535, 0.0921),
    "ur5e": (0.1625, -0.425, -0.3922, 0.1333, 0.0997, 0.0996),
    "ur10e": (0.1807, -0.6127, -0.57155, 0.17415, 0.11985, 0.11655),
    "ur16e": (0.1807, -0.4784, -0.36, 0.17415, 0.11985, 0.11655),
    "ur20": (0.2363, -0.862, -0.7287, 0.201, 0.1593, 0.1543),
    "ur30": (0.2363, -0.637, -0.5037, 0.201, 0.1593, 0.1543),
}

MODEL_NAMES = tuple(_UR_PARAMS)


@dataclass(frozen=True)
class DH:
    a: tuple
    d: tuple
    alpha: tuple
    theta_offset: tuple = (0.0,) * 6


def dh_table(model: str) -> DH:
    d1, a2, a3, d4, d5, d6 = _UR_PARAMS[model]
    return DH(
        a=(0.0, a2, a3, 0.0, 0.0, 0.0),
        d=(d1, 0.0, 0.0, d4, d5, d6),
        alpha=ALPHA,
    )


@dataclass
class Calibration:
    """Deltas in the UR controller's calibration.conf ``[mounting]`` section."""

    delta_theta: list = field(default_factory=lambda: [0.0] * 6)
    delta_a: list = field(default_factory=lambda: [0.0] * 6)
    delta_d: list = field(default_factory=lambda: [0.0] * 6)
    delta_alpha: list = field(default_factory=lambda: [0.0] * 6)


# --------------------------------------------------------------------------
# elementary transforms (batched)
# --------------------------------------------------------------------------

def _as_batch(x):
    return np.atleast_1d(np.asarray(x, dtype=float))


def rot_z(theta):
    t = _as_batch(theta)
    c, s = np.cos(t), np.sin(t)
    T = np.zeros(t.shape + (4, 4))
    T[..., 0, 0] = c
    T[..., 0, 1] = -s
    T[..., 1, 0] = s
    T[..., 1, 1] = c
    T[..., 2, 2] = 1.0
    T[..., 3, 3] = 1.0
    return T


def rot_x(alpha):
    t = _as_batch(alpha)
    c, s = np.cos(t), np.sin(t)
    T = np.zeros(t.shape + (4, 4))
    T[..., 0, 0] = 1.0
    T[..., 1, 1] = c
    T[..., 1, 2] = -s
    T[..., 2, 1] = s
    T[..., 2, 2] = c
    T[..., 3, 3] = 1.0
    return T


def rot_y(beta):
    t = _as_batch(beta)
    c, s = np.cos(t), np.sin(t)
    T = np.zeros(t.shape + (4, 4))
    T[..., 0, 0] = c
    T[..., 0, 2] = s
    T[..., 1, 1] = 1.0
    T[..., 2, 0] = -s
    T[..., 2, 2] = c
    T[..., 3, 3] = 1.0
    return T


def trans(x, y, z):
    T = np.eye(4)
    T[0, 3], T[1, 3], T[2, 3] = x, y, z
    return T


def rpy_matrix(roll, pitch, yaw):
    """3x3 (batched) R = Rz(yaw) Ry(pitch) Rx(roll)."""
    return (rot_z(yaw) @ rot_y(pitch) @ rot_x(roll))[..., :3, :3]


# --------------------------------------------------------------------------
# forward kinematics
# --------------------------------------------------------------------------

def dh_link(theta, d, a, alpha):
    """Standard DH link transform Rz(theta) Tz(d) Tx(a) Rx(alpha), batched over theta."""
    theta = _as_batch(theta)
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = math.cos(alpha), math.sin(alpha)
    T = np.zeros(theta.shape + (4, 4))
    T[..., 0, 0] = ct
    T[..., 0, 1] = -st * ca
    T[..., 0, 2] = st * sa
    T[..., 0, 3] = a * ct
    T[..., 1, 0] = st
    T[..., 1, 1] = ct * ca
    T[..., 1, 2] = -ct * sa
    T[..., 1, 3] = a * st
    T[..., 2, 1] = sa
    T[..., 2, 2] = ca
    T[..., 2, 3] = d
    T[..., 3, 3] = 1.0
    return T


def fk_flange(model, q, calibration: Calibration | None = None):
    """base_from_flange for joints q (shape (6,) or (N, 6)); returns (N, 4, 4)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    assert q.shape[1] == 6
    dh = dh_table(model) if isinstance(model, str) else model
    cal = calibration or Calibration()
    T = np.broadcast_to(np.eye(4), (q.shape[0], 4, 4)).copy()
    for i in range(6):
        theta = q[:, i] + dh.theta_offset[i] + cal.delta_theta[i]
        link = dh_link(
            theta,
            dh.d[i] + cal.delta_d[i],
            dh.a[i] + cal.delta_a[i],
            dh.alpha[i] + cal.delta_alpha[i],
        )
        T = T @ link
    return T


def tcp_transform(tcp):
    """flange_from_tcp from (x, y, z, rx, ry, rz) with a rotation vector."""
    x, y, z, rx, ry, rz = (float(v) for v in tcp)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([rx, ry, rz]).as_matrix()
    T[:3, 3] = (x, y, z)
    return T


BASE_LINK_FROM_BASE = np.diag([-1.0, -1.0, 1.0, 1.0])  # Rz(pi), exact


def apply_tool_and_frame(T_flange, tcp=None, frame="base"):
    T = np.asarray(T_flange)
    if tcp is not None:
        T = T @ tcp_transform(tcp)
    if frame == "base_link":
        T = BASE_LINK_FROM_BASE @ T
    elif frame != "base":
        raise ValueError(frame)
    return T


def fk(model, q, tcp=None, frame="base", calibration=None):
    return apply_tool_and_frame(fk_flange(model, q, calibration), tcp, frame)


# --------------------------------------------------------------------------
# URDF / ur_calibration YAML form
# --------------------------------------------------------------------------

YAML_LINKS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
YAML_KEYS = ("x", "y", "z", "roll", "pitch", "yaw")


def origin_transform(x, y, z, roll, pitch, yaw):
    T = np.eye(4)
    T[:3, :3] = rpy_matrix(roll, pitch, yaw)[0]
    T[:3, 3] = (x, y, z)
    return T


def fk_urdf(origins, q):
    """pose = O1 Rz(q1) O2 Rz(q2) ... O6 Rz(q6).

    ``origins`` is a sequence of 6 (x, y, z, roll, pitch, yaw) tuples, or a dict
    keyed by YAML_LINKS.
    """
    if isinstance(origins, dict):
        origins = [origins[name] for name in YAML_LINKS]
    q = np.atleast_2d(np.asarray(q, dtype=float))
    T = np.broadcast_to(np.eye(4), (q.shape[0], 4, 4)).copy()
    for i in range(6):
        o = origins[i]
        if isinstance(o, dict):
            o = [o[k] for k in YAML_KEYS]
        T = T @ origin_transform(*o) @ rot_z(q[:, i])
    return T


def matrix_to_xyzrpy(T):
    T = np.asarray(T)
    yaw, pitch, roll = Rotation.from_matrix(T[:3, :3]).as_euler("ZYX")
    return (T[0, 3], T[1, 3], T[2, 3], roll, pitch, yaw)


def calibration_to_urdf_origins(model, cal: Calibration):
    """Exact URDF origins of a DH chain with calibration deltas.

    O1 = Rz(dtheta1) Tz(d1);  O_i = Tx(a_{i-1}) Rx(alpha_{i-1}) Rz(dtheta_i) Tz(d_i).
    Exact only when a6 = alpha6 = 0 after calibration (as on real robots).
    """
    dh = dh_table(model)
    a = [dh.a[i] + cal.delta_a[i] for i in range(6)]
    d = [dh.d[i] + cal.delta_d[i] for i in range(6)]
    al = [dh.alpha[i] + cal.delta_alpha[i] for i in range(6)]
    th = [dh.theta_offset[i] + cal.delta_theta[i] for i in range(6)]
    if a[5] != 0.0 or al[5] != 0.0:
        raise ValueError("URDF form is exact only with a6 = alpha6 = 0")
    origins = []
    for i in range(6):
        if i == 0:
            O = rot_z(th[0])[0] @ trans(0, 0, d[0])
        else:
            O = trans(a[i - 1], 0, 0) @ rot_x(al[i - 1])[0] @ rot_z(th[i])[0] @ trans(0, 0, d[i])
        origins.append(matrix_to_xyzrpy(O))
    return origins


def format_calibration_yaml(origins, hash_="calib_1234567890123456789"):
    lines = ["kinematics:"]
    for name, o in zip(YAML_LINKS, origins):
        lines.append(f"  {name}:")
        for k, v in zip(YAML_KEYS, o):
            lines.append(f"    {k}: {float(v)!r}")
    lines.append(f"  hash: {hash_}")
    return "\n".join(lines) + "\n"


def format_calibration_conf(cal: Calibration, checksum=(11, 22, 33, 44, 55, 66)):
    def lst(v):
        return "[ " + ", ".join(repr(float(x)) for x in v) + " ]"

    return (
        "[mounting]\n"
        f"delta_theta = {lst(cal.delta_theta)}\n"
        f"delta_a = {lst(cal.delta_a)}\n"
        f"delta_d = {lst(cal.delta_d)}\n"
        f"delta_alpha = {lst(cal.delta_alpha)}\n"
        "joint_checksum = [ " + ", ".join(str(c) for c in checksum) + " ]\n"
    )


def parse_calibration_conf(text):
    """Tiny parser for the [mounting] lists (used only to double-check our writer)."""
    cal = Calibration()
    for key in ("delta_theta", "delta_a", "delta_d", "delta_alpha"):
        m = re.search(rf"^\s*{key}\s*=\s*\[(.*?)\]", text, re.M)
        setattr(cal, key, [float(v) for v in m.group(1).split(",")])
    return cal


# --------------------------------------------------------------------------
# pose representations
# --------------------------------------------------------------------------

def canonical_quat(R):
    """(N, 4) quaternions x, y, z, w with w >= 0, from (N, 3, 3) rotations."""
    quat = Rotation.from_matrix(np.asarray(R).reshape(-1, 3, 3)).as_quat()
    quat = np.where(quat[:, 3:4] < 0, -quat, quat)
    return quat


def rpy(R):
    """(N, 3) roll, pitch, yaw with R = Rz(yaw) Ry(pitch) Rx(roll).

    Only meaningful away from gimbal lock.
    """
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # gimbal-lock warning
        ypr = Rotation.from_matrix(np.asarray(R).reshape(-1, 3, 3)).as_euler("ZYX")
    return ypr[:, ::-1]


def cos_pitch(R):
    R = np.asarray(R).reshape(-1, 3, 3)
    return np.hypot(R[:, 0, 0], R[:, 1, 0])


def wrap(angle):
    return (np.asarray(angle) + PI) % (2 * PI) - PI
