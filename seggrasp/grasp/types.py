"""Grasp containers and the `GraspGenerator` protocol; the parallel-gripper geometry is a hand's description
(`seggrasp.hands`: `Hand` and `ROBOTIQ_2F85`, re-exported here).

Gripper frame (docs/design.md section 3): z = approach direction, x = closing direction (finger to finger), origin between the
pad centres (as sim/gripper.py builds it), i.e. at the midpoint of the two contact points of an antipodal grasp.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import trimesh

from seggrasp.hands import FRANKA_HAND, ROBOTIQ_2F85, Hand  # noqa: F401 (re-exported)


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

    @classmethod
    def concatenate(cls, sets: Sequence["GraspSet"]) -> "GraspSet":
        """The grasps of `sets`, in that order."""
        if not sets:
            return cls.empty()
        return cls(*(np.concatenate([getattr(s, name) for s in sets])
                     for name in ("poses", "widths", "scores", "contacts")))

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
