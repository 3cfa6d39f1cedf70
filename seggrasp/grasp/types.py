"""Grasp containers, the parallel-gripper geometry and the `GraspGenerator` protocol.

Gripper frame (docs/design.md section 3): z = approach direction, x = closing direction (finger to finger), origin between the
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

    Defaults are the Robotiq 2F-85 as the simulated one is shaped (ray-probed profile of its collision geometry,
    gripper frame at the origin, sim/gripper.py): 85 mm stroke, origin between the pad centres, fingertips
    `tip_beyond_origin` past it along +z.

    - `finger_boxes` move with the fingers; each is (inner x, outer x, half y, z min, z max) with x measured
      outwards from the finger's inner face at half the opening (mirrored for the other finger): the pad and the
      tip of the finger, then its wedge-shaped base that leans inwards toward the knuckles;
    - `centre_boxes` are fixed and centred on the z axis; each is (half x, half y, z min, z max): the knuckles,
      the gripper body and the wrist behind it.
    """

    max_opening: float = 0.085
    tip_beyond_origin: float = 0.020
    finger_boxes: tuple[tuple[float, float, float, float, float], ...] = (
        (0.0, 0.024, 0.012, -0.020, 0.020),
        (-0.008, 0.036, 0.018, -0.045, -0.020),
    )
    centre_boxes: tuple[tuple[float, float, float, float], ...] = (
        (0.078, 0.022, -0.095, -0.045),
        (0.047, 0.043, -0.150, -0.045),
        (0.045, 0.045, -0.270, -0.150),
    )
    pre_grasp_margin: float = 0.012  # extra opening on each side of the contacts while approaching

    def pre_grasp_opening(self, width: np.ndarray | float) -> np.ndarray:
        """Finger separation while approaching a grasp of contact distance `width` (capped at the stroke)."""
        return np.minimum(np.asarray(width, dtype=np.float64) + 2.0 * self.pre_grasp_margin, self.max_opening)

    def boxes(self, opening: float) -> np.ndarray:
        """Axis-aligned boxes (B, 2, 3) [min corner, max corner] of the gripper opened to `opening`: both fingers'
        boxes (-x finger first), then the centre boxes."""
        half = 0.5 * float(opening)
        boxes = []
        for sign in (-1.0, 1.0):
            for inner, outer, half_y, z_min, z_max in self.finger_boxes:
                x0, x1 = sign * (half + inner), sign * (half + outer)
                boxes.append([[min(x0, x1), -half_y, z_min], [max(x0, x1), half_y, z_max]])
        for half_x, half_y, z_min, z_max in self.centre_boxes:
            boxes.append([[-half_x, -half_y, z_min], [half_x, half_y, z_max]])
        return np.array(boxes, dtype=np.float64)


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

    def generate(
        self,
        mesh: trimesh.Trimesh,
        seed: int = 0,
        table_plane: np.ndarray | None = None,
        center_of_mass: np.ndarray | None = None,
        mass: float | None = None,
    ) -> GraspSet:
        """Grasps sorted best first. `center_of_mass` (mesh frame) and `mass` (kg), when the caller knows them, let a
        generator prefer grasps whose gravity torque the fingers can hold; None means unknown."""
