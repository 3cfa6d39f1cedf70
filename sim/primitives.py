"""Simple labelled objects (box, cylinder) written as one-link URDFs, for tests and quick experiments.

The twin's real objects come from `seggrasp.objects.load_asset_set()`; these exist so the cell can be exercised
with shapes whose contacts are easy to predict. Faces are labelled by their outward normal: "top" (normal up),
"bottom" (down) and "side" (everything else).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from seggrasp.labels import PartLabels
from seggrasp.objects import ObjectModel

PRIMITIVE_PARTS = ["top", "side", "bottom"]


def _labels_by_normal(mesh: trimesh.Trimesh) -> PartLabels:
    nz = mesh.face_normals[:, 2]
    labels = np.where(nz > 0.9, 0, np.where(nz < -0.9, 2, 1))
    return PartLabels(PRIMITIVE_PARTS, labels)


def primitive_object(
    kind: str, size: tuple[float, ...], directory: str | Path, mass: float = 0.2, friction: float = 0.8,
    object_id: str | None = None,
) -> ObjectModel:
    """A box (`size` = x, y, z extents) or cylinder (`size` = radius, height) resting on z = 0 in its own frame,
    with OBJ + URDF written to `directory`."""
    if kind == "box":
        if len(size) != 3:
            raise ValueError(f"a box needs 3 extents, got {size}")
        mesh = trimesh.creation.box(extents=size)
    elif kind == "cylinder":
        if len(size) != 2:
            raise ValueError(f"a cylinder needs (radius, height), got {size}")
        mesh = trimesh.creation.cylinder(radius=size[0], height=size[1], sections=32)
    else:
        raise ValueError(f"unknown primitive kind {kind!r}; use 'box' or 'cylinder'")
    if min(size) <= 0 or mass <= 0:
        raise ValueError(f"sizes and mass must be positive, got size={size}, mass={mass}")
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    object_id = object_id or f"{kind}_" + "x".join(f"{s * 1000:.0f}" for s in size)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    mesh_path = directory / f"{object_id}.obj"
    mesh.export(mesh_path)
    mesh.density = mass / mesh.volume
    com = np.asarray(mesh.center_mass)
    inertia = np.asarray(mesh.moment_inertia)
    urdf_path = directory / f"{object_id}.urdf"
    urdf_path.write_text(
        f'<?xml version="1.0"?>\n<robot name="{object_id}">\n  <link name="object">\n'
        f'    <inertial><origin xyz="{com[0]} {com[1]} {com[2]}" rpy="0 0 0"/><mass value="{mass}"/>'
        f'<inertia ixx="{inertia[0, 0]}" ixy="{inertia[0, 1]}" ixz="{inertia[0, 2]}" iyy="{inertia[1, 1]}" '
        f'iyz="{inertia[1, 2]}" izz="{inertia[2, 2]}"/></inertial>\n'
        f'    <visual><geometry><mesh filename="{mesh_path.name}"/></geometry>'
        f'<material name="object"><color rgba="0.85 0.3 0.2 1"/></material></visual>\n'
        f'    <collision><geometry><mesh filename="{mesh_path.name}"/></geometry></collision>\n'
        "  </link>\n</robot>\n"
    )
    return ObjectModel(
        object_id=object_id, category=kind, mesh=mesh, prompts=list(PRIMITIVE_PARTS), mass=mass, friction=friction,
        center_of_mass=com, inertia=inertia, collision_hulls=[mesh.convex_hull], labels=_labels_by_normal(mesh),
        mesh_path=mesh_path, collision_path=mesh_path, urdf_path=urdf_path,
    )


def top_down_grasp(T_world_obj: np.ndarray, height: float) -> np.ndarray:
    """Gripper pose above the object's origin: approach straight down, closing along the object's x axis."""
    x = T_world_obj[:3, 0] * [1.0, 1.0, 0.0]
    x /= np.linalg.norm(x)
    z = np.array([0.0, 0.0, -1.0])
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(z, x), z
    T[:3, 3] = T_world_obj[:3, 3] + [0.0, 0.0, height]
    return T
