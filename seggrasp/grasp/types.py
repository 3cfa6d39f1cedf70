"""Grasp containers, the parallel-gripper geometry and the `GraspGenerator` protocol.

Gripper frame (DESIGN.md): z = approach direction, x = closing direction (finger to finger), origin between the
pad centres (as sim/gripper.py builds it), i.e. at the midpoint of the two contact points of an antipodal grasp.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import trimesh


@dataclass(frozen=True)
class GripperGeometry:
    """Box model of a parallel gripper for collision checks, in the gripper frame (metres).

    Defaults are the Robotiq 2F-85: 85 mm stroke, pads ~20 mm wide (y) and ~40 mm long (z). The origin is between
    the pad centres, so the fingertips reach `tip_beyond_origin` (half a pad) past the contacts along +z. Each
    finger is a box of `finger_thickness` (x) x `pad_width` (y) x `finger_length` (z) just outside the pre-grasp
    opening; the palm (plus the wrist behind it) is one box below the fingers.
    """

    max_opening: float = 0.085
    pad_width: float = 0.020
    pad_length: float = 0.040
    finger_thickness: float = 0.012
    finger_length: float = 0.055
    tip_beyond_origin: float = 0.020
    palm_width: float = 0.12  # x
    palm_thickness: float = 0.065  # y
    palm_depth: float = 0.10  # z, palm + coupling + wrist stub
    pre_grasp_margin: float = 0.012  # extra opening on each side of the contacts while approaching

    def pre_grasp_opening(self, width: np.ndarray | float) -> np.ndarray:
        """Finger separation while approaching a grasp of contact distance `width` (capped at the stroke)."""
        return np.minimum(np.asarray(width, dtype=np.float64) + 2.0 * self.pre_grasp_margin, self.max_opening)

    def boxes(self, opening: float) -> np.ndarray:
        """Axis-aligned boxes (3, 2, 3) = [finger -x, finger +x, palm] x [min corner, max corner], gripper frame."""
        half = 0.5 * float(opening)
        tip = self.tip_beyond_origin
        base = tip - self.finger_length
        y = 0.5 * self.pad_width
        fingers = [
            [[-half - self.finger_thickness, -y, base], [-half, y, tip]],
            [[half, -y, base], [half + self.finger_thickness, y, tip]],
        ]
        palm = [
            [-0.5 * self.palm_width, -0.5 * self.palm_thickness, base - self.palm_depth],
            [0.5 * self.palm_width, 0.5 * self.palm_thickness, base],
        ]
        return np.array(fingers + [palm], dtype=np.float64)


ROBOTIQ_2F85 = GripperGeometry()


@dataclass
class GraspSet:
    """N grasps of one object: `poses` (N, 4, 4) T_frame_grasp, `widths` (N,) contact distance in metres,
    `scores` (N,) higher is better, `contacts` (N, 2, 3) the two finger contact points (same frame as `poses`)."""

    poses: np.ndarray
    widths: np.ndarray
    scores: np.ndarray
    contacts: np.ndarray

    def __post_init__(self) -> None:
        self.poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 4, 4)
        n = len(self.poses)
        self.widths = np.asarray(self.widths, dtype=np.float64).reshape(-1)
        self.scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        self.contacts = np.asarray(self.contacts, dtype=np.float64).reshape(-1, 2, 3)
        if not (len(self.widths) == len(self.scores) == len(self.contacts) == n):
            raise ValueError(
                f"GraspSet arrays disagree in length: {n} poses, {len(self.widths)} widths, "
                f"{len(self.scores)} scores, {len(self.contacts)} contact pairs"
            )

    @classmethod
    def empty(cls) -> "GraspSet":
        return cls(np.zeros((0, 4, 4)), np.zeros(0), np.zeros(0), np.zeros((0, 2, 3)))

    def __len__(self) -> int:
        return int(len(self.poses))

    def subset(self, index: np.ndarray) -> "GraspSet":
        """The grasps at `index` (integer indices or a boolean mask), in that order."""
        index = np.asarray(index)
        return GraspSet(self.poses[index], self.widths[index], self.scores[index], self.contacts[index])

    def sorted_by_score(self) -> "GraspSet":
        """Best first; ties keep their generation order (stable sort)."""
        return self.subset(np.argsort(-self.scores, kind="stable"))

    def transformed(self, T_new_frame: np.ndarray) -> "GraspSet":
        """The same grasps expressed in another frame: poses become `T_new_frame @ pose`, contacts move along."""
        T = np.asarray(T_new_frame, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"expected a 4x4 transform, got shape {T.shape}")
        contacts = self.contacts @ T[:3, :3].T + T[:3, 3]
        return GraspSet(T @ self.poses, self.widths.copy(), self.scores.copy(), contacts)


@runtime_checkable
class GraspGenerator(Protocol):
    """Anything that proposes grasps for an object mesh, in the object (mesh) frame.

    `table_plane` (optional) is (a, b, c, d) in the object frame with (a, b, c) the unit normal pointing up, away
    from the table: points with a*x + b*y + c*z + d < 0 are below the table top and must stay free of the gripper.
    """

    name: str

    def generate(self, mesh: trimesh.Trimesh, seed: int = 0, table_plane: np.ndarray | None = None) -> GraspSet:
        """Grasps sorted best first."""
