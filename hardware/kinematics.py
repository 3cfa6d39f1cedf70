"""The UR arm models the bridge knows: published DH parameters, nominal forward kinematics and the arm's envelope.

Used by the config (is the workspace box reachable, and clear of the robot's own base?) and by `hardware/ur.py`
(the joint-path safety check, and the IK check where the controller cannot answer it: PolyScope < 5.10 / 3.15).
Numbers are Universal Robots' published values.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ArmModel:
    """One UR model: standard DH parameters and the envelope from its datasheet."""

    d: np.ndarray  # (6,) m, DH link offsets
    a: np.ndarray  # (6,) m, DH link lengths
    reach: float  # m, largest distance of the flange centre from the shoulder (datasheet "reach")
    base_radius: float  # m, radius of the base column (the Ø 149 mm base and shoulder housing)

    @property
    def shoulder(self) -> np.ndarray:
        """The shoulder joint's centre in the base frame: on the base axis, `d1` above the mounting face."""
        return np.array([0.0, 0.0, float(self.d[0])])


ARM_MODELS = {
    "ur5": ArmModel(d=np.array([0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823]),
                    a=np.array([0.0, -0.425, -0.39225, 0.0, 0.0, 0.0]), reach=0.85, base_radius=0.075),
    "ur5e": ArmModel(d=np.array([0.1625, 0.0, 0.0, 0.1333, 0.0997, 0.0996]),
                     a=np.array([0.0, -0.425, -0.3922, 0.0, 0.0, 0.0]), reach=0.85, base_radius=0.075),
}
_UR_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])


def forward_kinematics(model: str, q: np.ndarray) -> np.ndarray:
    """T_base_flange from the nominal DH parameters (the controller's calibrated kinematics differ by ~1 mm)."""
    T = np.eye(4)
    for i, theta in enumerate(np.asarray(q, dtype=np.float64)):
        T = T @ _dh_link(model, i, theta)
    return T


def _dh_link(model: str, i: int, theta: float) -> np.ndarray:
    """The DH transform of joint `i` (0-based) of `model` at angle `theta`."""
    arm = ARM_MODELS[model]
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(_UR_ALPHA[i]), np.sin(_UR_ALPHA[i])
    return np.array([[ct, -st * ca, st * sa, arm.a[i] * ct],
                     [st, ct * ca, -ct * sa, arm.a[i] * st],
                     [0.0, sa, ca, arm.d[i]],
                     [0.0, 0.0, 0.0, 1.0]])


#: A closed-form solution counts when forward kinematics reproduces the pose this closely (m, and rad-ish for the
#: rotation matrix entries); it rejects the spurious branches clipped cosines produce at the reach boundary.
IK_TOLERANCE = 1e-6


def inverse_kinematics(model: str, T_base_flange: np.ndarray) -> list[np.ndarray]:
    """Every joint solution (angles in [-pi, pi)) whose nominal flange pose is `T_base_flange`; [] when none.

    The UR's wrist is not spherical, but its three wrist axes make a closed form possible: the shoulder pan
    follows from the wrist centre (d6 back along the flange axis), which lies d4 off the pan plane; wrist 2 from
    the flange's height over that plane; wrist 3 from the flange axes; shoulder lift and elbow as a planar
    two-link problem; wrist 1 as the remainder. Every UR5/UR5e joint turns +-360 deg, so each solution is valid
    as far as joint range goes. A singular wrist (wrist 2 at 0 or pi) takes wrist 3 = 0."""
    arm = ARM_MODELS[model]
    T = np.asarray(T_base_flange, dtype=np.float64)
    d4, d6, a2, a3 = arm.d[3], arm.d[5], arm.a[1], arm.a[2]
    centre = T @ np.array([0.0, 0.0, -d6, 1.0])
    radius = float(np.hypot(centre[0], centre[1]))
    if radius < abs(d4):  # the wrist centre inside the cylinder the shoulder offset sweeps: no pan angle fits
        return []
    T_inv = np.linalg.inv(T)
    solutions = []
    for pan in np.arctan2(centre[1], centre[0]) + np.pi / 2 + np.array([1.0, -1.0]) * np.arccos(d4 / radius):
        s1, c1 = np.sin(pan), np.cos(pan)
        cos5 = (T[0, 3] * s1 - T[1, 3] * c1 - d4) / d6
        if abs(cos5) > 1.0 + 1e-9:
            continue
        for wrist2 in np.array([1.0, -1.0]) * np.arccos(np.clip(cos5, -1.0, 1.0)):
            s5 = np.sin(wrist2)
            wrist3 = 0.0 if abs(s5) < 1e-9 else np.arctan2((-T_inv[1, 0] * s1 + T_inv[1, 1] * c1) / s5,
                                                          (T_inv[0, 0] * s1 - T_inv[0, 1] * c1) / s5)
            T_1_4 = (np.linalg.inv(_dh_link(model, 0, pan)) @ T
                     @ np.linalg.inv(_dh_link(model, 4, wrist2) @ _dh_link(model, 5, wrist3)))
            elbow_to_wrist = (T_1_4 @ np.array([0.0, -d4, 0.0, 1.0]))[:3]
            length = float(np.linalg.norm(elbow_to_wrist))
            cos3 = (length ** 2 - a2 ** 2 - a3 ** 2) / (2.0 * a2 * a3)
            if abs(cos3) > 1.0 + 1e-9 or length < 1e-12:
                continue
            for elbow in np.array([1.0, -1.0]) * np.arccos(np.clip(cos3, -1.0, 1.0)):
                lift = (-np.arctan2(elbow_to_wrist[1], -elbow_to_wrist[0])
                        + np.arcsin(np.clip(a3 * np.sin(elbow) / length, -1.0, 1.0)))
                T_3_4 = np.linalg.inv(_dh_link(model, 1, lift) @ _dh_link(model, 2, elbow)) @ T_1_4
                q = np.array([pan, lift, elbow, np.arctan2(T_3_4[1, 0], T_3_4[0, 0]), wrist2, wrist3])
                q = (q + np.pi) % (2.0 * np.pi) - np.pi
                if np.abs(forward_kinematics(model, q) - T).max() <= IK_TOLERANCE:
                    solutions.append(q)
    return solutions
