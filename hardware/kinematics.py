"""The UR arm models the bridge knows: published DH parameters, nominal forward kinematics and the arm's envelope.

Used by the config (is the workspace box reachable, and clear of the robot's own base?) and by `hardware/ur.py`
(the joint-path safety check). Numbers are Universal Robots' published values.
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
    arm = ARM_MODELS[model]
    T = np.eye(4)
    for theta, di, ai, alpha in zip(np.asarray(q, dtype=np.float64), arm.d, arm.a, _UR_ALPHA):
        ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
        T = T @ np.array([[ct, -st * ca, st * sa, ai * ct],
                          [st, ct * ca, -ct * sa, ai * st],
                          [0.0, sa, ca, di],
                          [0.0, 0.0, 0.0, 1.0]])
    return T
