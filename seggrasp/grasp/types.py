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

    Defaults are the Robotiq 2F-85 as the simulated one measures (link bounding boxes with the gripper frame at
    the origin, sim/gripper.py): 85 mm stroke; the origin is between the pad centres and the fingertips reach
    `tip_beyond_origin` past it along +z. Boxes, all conservative:

    - two fingers (pad + inner finger + outer finger tip): x from the pre-grasp opening outwards by
      `finger_thickness`, |y| <= `finger_width` / 2, z from `palm_top` to `tip_beyond_origin`;
    - the palm (knuckles and gripper body): |x| <= `palm_width` / 2, |y| <= `palm_thickness` / 2,
      z from `palm_top - palm_depth` to `palm_top`; nothing may sit deeper than `palm_top` between the fingers;
    - the wrist behind it: |x|, |y| <= `wrist_width` / 2 over `wrist_depth`.
    """

    max_opening: float = 0.085
    finger_thickness: float = 0.030
    finger_width: float = 0.036
    tip_beyond_origin: float = 0.020
    palm_top: float = -0.040
    palm_width: float = 0.160
    palm_thickness: float = 0.085
    palm_depth: float = 0.110
    wrist_width: float = 0.090
    wrist_depth: float = 0.120
    pre_grasp_margin: float = 0.012  # extra opening on each side of the contacts while approaching

    def pre_grasp_opening(self, width: np.ndarray | float) -> np.ndarray:
        """Finger separation while approaching a grasp of contact distance `width` (capped at the stroke)."""
        return np.minimum(np.asarray(width, dtype=np.float64) + 2.0 * self.pre_grasp_margin, self.max_opening)

    def boxes(self, opening: float) -> np.ndarray:
        """Axis-aligned boxes (4, 2, 3) = [finger -x, finger +x, palm, wrist] x [min corner, max corner]."""
        half = 0.5 * float(opening)
        fy, tip, top = 0.5 * self.finger_width, self.tip_beyond_origin, self.palm_top
        bottom = top - self.palm_depth
        px, py, w = 0.5 * self.palm_width, 0.5 * self.palm_thickness, 0.5 * self.wrist_width
        return np.array([
            [[-half - self.finger_thickness, -fy, top], [-half, fy, tip]],
            [[half, -fy, top], [half + self.finger_thickness, fy, tip]],
            [[-px, -py, bottom], [px, py, top]],
            [[-w, -w, bottom - self.wrist_depth], [w, w, bottom]],
        ])


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
