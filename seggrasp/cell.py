"""The robot-cell interface that both backends implement (`sim.SimCell`, `hardware.RealCell`).

Frames follow DESIGN.md: `world` has the robot base at the origin and z up; cameras use the OpenCV convention
(x right, y down, z forward); `T_a_b` maps coordinates in frame b to frame a. The gripper frame has z along the
approach direction, x along the closing direction (finger to finger) and its origin between the fingertips.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
import trimesh


@dataclass
class Frame:
    """One RGB-D capture of one camera."""

    name: str
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres; 0 where the camera has no reading
    K: np.ndarray  # (3, 3) pinhole intrinsics
    T_world_cam: np.ndarray  # (4, 4) camera (OpenCV) -> world


@dataclass
class GraspOutcome:
    """What happened when a grasp was executed.

    `touched_faces` are faces of the object mesh (in its file order) that the finger pads touched; a backend that
    cannot observe contacts (the real robot) leaves it empty and sets `contacts_observed=False`.
    """

    reachable: bool
    lifted: bool
    lift_height: float  # metres the object rose (0 if not reached or not lifted)
    touched_faces: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    contact_force: float = 0.0  # newtons, total normal force between pads and object while holding
    contacts_observed: bool = True
    message: str = ""

    def to_json(self) -> dict:
        return {
            "reachable": bool(self.reachable),
            "lifted": bool(self.lifted),
            "lift_height": float(self.lift_height),
            "touched_faces": [int(f) for f in self.touched_faces],
            "contact_force": float(self.contact_force),
            "contacts_observed": bool(self.contacts_observed),
            "message": self.message,
        }


@runtime_checkable
class Cell(Protocol):
    """A robot cell: cameras, an arm with a parallel gripper, and one object on a table."""

    def reset(self, seed: int | None = None, object_id: str | None = None) -> None:
        """Put the scene in its start state (the same seed gives the same scene)."""

    def capture(self) -> list[Frame]:
        """One RGB-D frame from every camera."""

    def object_mesh(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        """The object's mesh (object frame, metres) and `T_world_obj`, when the backend knows them.

        The simulator knows the twin's mesh and pose; the real cell raises `NotImplementedError` and the mesh is
        reconstructed from `capture()` instead.
        """

    def execute(self, T_world_grasp: np.ndarray, width: float) -> GraspOutcome:
        """Pre-grasp, approach, close, lift 20 cm and hold; report the outcome. Never raises for a failed grasp."""

    def close(self) -> None:
        """Release the backend's resources (physics client, robot connection, cameras)."""
