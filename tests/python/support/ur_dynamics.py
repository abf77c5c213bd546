"""Universal Robots arms in Pinocchio (PyPI ``pin``), independently of armtwin: the inertial and
drive parameters typed in again from the sources armtwin's tables cite, and the model built from
an arm's DH table (ur_reference.py) in either DH convention.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

# How closely armtwin's torques must agree with Pinocchio's (N·m).
TOLERANCE_NM = 1e-9
UR_GRAVITY_M_S2 = 9.82


# Inertial parameters, typed in again from the sources named in crates/armtwin-core/src/dynamics/ur.rs: masses (kg), centres
# of mass (m) and diagonal inertias about them (kg·m²) in the standard-DH link frames, and the
# e-Series joint sizes.
_COM_UR3 = [[0, -0.02, 0], [0.13, 0, 0.1157], [0.05, 0, 0.0238],
            [0, 0, 0.01], [0, 0, 0.01], [0, 0, -0.02]]
_COM_UR5 = [[0, -0.02561, 0.00193], [0.2125, 0, 0.11336], [0.15, 0, 0.0265],
            [0, -0.0018, 0.01634], [0, 0.0018, 0.01634], [0, 0, -0.001159]]
_COM_UR10 = [[0.021, 0, 0.027], [0.38, 0, 0.158], [0.24, 0, 0.068],
             [0, 0.007, 0.018], [0, 0.007, 0.018], [0, 0, -0.026]]
_I_UR16E = [[0.03351, 0.03374, 0.02100], [0.02796, 0.47558, 0.47635], [0.01091, 0.12060, 0.11714],
            [0.00609, 0.00245, 0.00579], [0.00389, 0.00219, 0.00363], [0.00117, 0.00118, 0.00084]]
_ZERO = [[0, 0, 0]] * 6

PARAMETERS = {
    "ur3": ([2.0, 3.42, 1.26, 0.8, 0.8, 0.35], _COM_UR3, _ZERO, None),
    "ur5": ([3.7, 8.393, 2.33, 1.219, 1.219, 0.1879], _COM_UR5, _ZERO, None),
    "ur10": ([7.1, 12.7, 4.27, 2.0, 2.0, 0.365], _COM_UR10, _ZERO, None),
    "ur3e": ([1.98, 3.4445, 1.437, 0.871, 0.805, 0.261], _COM_UR3,
             _ZERO[:5] + [[0, 0, 0.000144]], (2, 2, 1, 0, 0, 0)),
    "ur5e": ([3.761, 8.058, 2.846, 1.37, 1.30, 0.365], _COM_UR5,
             _ZERO[:5] + [[0, 0, 0.0002]], (3, 3, 3, 1, 1, 1)),
    "ur10e": ([7.369, 13.051, 3.989, 2.10, 1.98, 0.615], _COM_UR10,
              [[0.03408, 0.03529, 0.02156], [0.02814, 0.77068, 0.76943], [0.01014, 0.30928, 0.30646],
               [0.00296, 0.00222, 0.00258], [0.00296, 0.00222, 0.00258], [0.00040, 0.00041, 0.00034]],
              (4, 4, 3, 2, 2, 2)),
    "ur16e": ([7.369, 10.45, 4.321, 2.18, 2.033, 0.907],
              [[0, -0.016, 0.030], [0.302, 0, 0.160], [0.194, 0, 0.065],
               [0, -0.009, 0.011], [0, 0.018, 0.012], [0, 0, -0.044]],
              _I_UR16E, (4, 4, 3, 2, 2, 2)),
    "ur20": ([16.343, 29.632, 7.879, 3.054, 3.126, 0.846],
             [[0, -0.061, 0.0062], [0.5226, 0, 0.2098], [0.3234, 0, 0.0604],
              [0, -0.0026, 0.0393], [0, 0.0024, 0.0379], [0, -0.0003, -0.0318]],
             [[0.0887, 0.0763, 0.0842], [0.1467, 4.6659, 4.6348], [0.0261, 0.7576, 0.7533],
              [0.0056, 0.0054, 0.0040], [0.0059, 0.0058, 0.0043], [0.0009, 0.0009, 0.0012]],
             None),
    "ur30": ([16.343, 28.542, 7.156, 3.054, 3.126, 0.926],
             [[-0.0001, -0.060, 0.0069], [0.3894, 0, 0.2103], [0.2257, 0, 0.0629],
              [0, -0.0048, 0.0353], [0, 0.0046, 0.0341], [0, 0, -0.0293]],
             _I_UR16E, None),
}
# Rotor inertia (kg·m²) of e-Series joint sizes 0-4 and the gear ratio (controller configuration).
ROTOR_INERTIA_KG_M2 = (7.0e-6, 2.0767e-5, 6.0e-5, 1.8774e-4, 5.90109e-4)
GEAR_RATIO = 101.0
# Nominal torque constants (N·m/A) of e-Series joint sizes 0-4 (controller configuration).
TORQUE_CONSTANT_NM_PER_A = (0.035685, 0.07695, 0.10756, 0.098322, 0.11968)


def tensor(entries):
    """[Ixx, Iyy, Izz, Ixy, Ixz, Iyz] as a symmetric 3x3 matrix."""
    ixx, iyy, izz, ixy, ixz, iyz = entries
    return np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]], dtype=float)


def rot_x(alpha):
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_z(theta):
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def se3(rotation, translation):
    return pin.SE3(np.asarray(rotation, dtype=float), np.asarray(translation, dtype=float))


def tz(d):
    return se3(np.eye(3), [0, 0, d])


def tx_rx(a, alpha):
    return se3(rot_x(alpha), [a, 0, 0])


def pinocchio_arm(convention, a, alpha, d, theta, links, rotor):
    """A Pinocchio model of a DH arm: joint k a revolute about z placed at the frame before its
    rotation; link k's inertia moved from its DH link frame into joint k's frame by Pinocchio.
    Returns the model and the flange's placement in the last joint's frame."""
    model = pin.Model()
    parent = 0
    n = len(a)
    for k in range(n):
        if convention == "standard":
            # frame k = frame k-1 · Rz(q + θ) · Tz(d) · Tx(a) · Rx(α): the joint sits at frame k-1,
            # i.e. at the previous link's frame; the link's frame is Tz·Tx·Rx after the joint.
            before = tz(d[k - 1]) * tx_rx(a[k - 1], alpha[k - 1]) if k > 0 else pin.SE3.Identity()
            link_in_joint = tz(d[k]) * tx_rx(a[k], alpha[k])
        else:
            # Craig: frame k = frame k-1 · Rx(α) · Tx(a) · Rz(q + θ) · Tz(d).
            previous_d = tz(d[k - 1]) if k > 0 else pin.SE3.Identity()
            before = previous_d * se3(rot_x(alpha[k]), [0, 0, 0]) * se3(np.eye(3), [a[k], 0, 0])
            link_in_joint = tz(d[k])
        placement = before * se3(rot_z(theta[k]), [0, 0, 0])
        parent = model.addJoint(parent, pin.JointModelRZ(), placement, f"joint{k + 1}")
        mass, com, inertia = links[k]
        link_inertia = pin.Inertia(mass, np.asarray(com, dtype=float), tensor(inertia))
        model.appendBodyToJoint(parent, link_in_joint.act(link_inertia), pin.SE3.Identity())
    model.armature = np.asarray(rotor, dtype=float)
    return model, link_in_joint


def with_payload(model, flange_in_joint, payload):
    mass, cog, inertia = payload
    loaded = pin.Model(model)
    loaded.appendBodyToJoint(loaded.njoints - 1, pin.Inertia(mass, np.zeros(3), tensor(inertia)),
                             flange_in_joint * se3(np.eye(3), cog))
    return loaded
