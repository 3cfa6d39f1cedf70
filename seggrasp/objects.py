"""Graspable objects: a mesh with part labels, prompts and the physical properties a simulator needs."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from seggrasp.labels import PartLabels


@dataclass
class ObjectModel:
    """One object of the twin (or an external mesh loaded the same way). All quantities in SI units.

    `mesh` is in the object frame with its faces in the order of `mesh_path`; `labels` (if known) has one label per
    face of `mesh`. `collision_hulls` are convex pieces in the object frame that keep the concavities that matter
    for grasping (a mug handle's hole stays open).
    """

    object_id: str
    category: str
    mesh: trimesh.Trimesh
    prompts: list[str]
    mass: float
    friction: float
    center_of_mass: np.ndarray  # (3,) object frame
    inertia: np.ndarray  # (3, 3) about the centre of mass, object-frame axes
    collision_hulls: list[trimesh.Trimesh] = field(default_factory=list)
    labels: PartLabels | None = None
    mesh_path: Path | None = None
    collision_path: Path | None = None  # one OBJ with one `o` group per convex hull
    urdf_path: Path | None = None
