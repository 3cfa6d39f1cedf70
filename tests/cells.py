"""A test cell on a fixed mesh, for the episode tests that need a cell but no physics."""

from __future__ import annotations

import numpy as np
import trimesh

from seggrasp.cell import GraspOutcome
from seggrasp.hands import ROBOTIQ_2F85


class FixedMeshCell:
    """A cell (`seggrasp.cell.Cell`) on a fixed mesh, world = object frame, with the 2F-85: it reaches every grasp,
    answers every execution with `outcome` and counts the executions. `models_scene`: whether the episode treats
    it as a cell whose reach checks pose the robot in the scene (`Cell.models_scene`)."""

    hand = ROBOTIQ_2F85

    def __init__(self, mesh: trimesh.Trimesh, outcome: GraspOutcome, models_scene: bool = True) -> None:
        self.mesh, self.outcome, self.models_scene, self.executed = mesh, outcome, models_scene, 0

    def reset(self, seed=None, object_id=None) -> None:
        pass

    def object_mesh(self):
        return self.mesh, np.eye(4)

    def check_reach(self, T_world_grasp, width) -> str:
        return ""

    def execute(self, T_world_grasp, width) -> GraspOutcome:
        self.executed += 1
        return self.outcome
