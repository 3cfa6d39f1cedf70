"""Physical models of objects: mass properties, CoACD convex decomposition, OBJ and URDF writing.

Shared by the twin generator (`assets.generate`) and by `seggrasp.objects.load_external_object`; every name is
also importable from `seggrasp.objects`.
"""

from __future__ import annotations

import logging
import multiprocessing
import multiprocessing.connection
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from seggrasp.io import atomic_write_text

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class MassProperties:
    """Mass (kg), centre of mass (3,) and inertia tensor (3, 3) about the centre of mass, object-frame axes."""

    mass: float
    center_of_mass: np.ndarray
    inertia: np.ndarray


@dataclass(frozen=True)
class CollisionConfig:
    """CoACD settings: concavity threshold (fraction of the bounding-box diagonal), hull cap, sampling resolution,
    MCTS iterations, manifold pre-processing ("on" for scans, "off" for clean manifold meshes) and, for large scans,
    a face budget the mesh is decimated to first (collision shapes need no fine detail; CoACD time grows with it)."""

    threshold: float = 0.06
    max_hulls: int = 24
    resolution: int = 2000
    mcts_iterations: int = 100
    preprocess: str = "on"
    max_faces: int | None = None
    seed: int = 0

    def key(self) -> str:
        return (f"t{self.threshold:g}-h{self.max_hulls}-r{self.resolution}-i{self.mcts_iterations}"
                f"-p{self.preprocess}-f{self.max_faces}-s{self.seed}")


def mass_properties(solid: trimesh.Trimesh, density: float) -> MassProperties:
    """Mass properties of a closed solid of uniform `density` (kg/m^3)."""
    if density <= 0:
        raise ValueError(f"density must be positive, got {density}")
    volume = float(solid.volume)
    if not np.isfinite(volume) or volume <= 0:
        raise ValueError(f"solid has no positive volume ({volume}); is it closed and outward-oriented?")
    props = solid.mass_properties  # density 1
    return MassProperties(
        mass=volume * density,
        center_of_mass=np.asarray(props["center_mass"], dtype=np.float64),
        inertia=np.asarray(props["inertia"], dtype=np.float64) * density,
    )


def combine_mass_properties(parts: Sequence[MassProperties]) -> MassProperties:
    """Mass properties of a rigid union of disjoint bodies (parallel-axis theorem)."""
    mass = sum(p.mass for p in parts)
    if mass <= 0:
        raise ValueError("total mass must be positive")
    com = sum(p.mass * p.center_of_mass for p in parts) / mass
    inertia = np.zeros((3, 3))
    for p in parts:
        d = p.center_of_mass - com
        inertia += p.inertia + p.mass * (float(d @ d) * np.eye(3) - np.outer(d, d))
    return MassProperties(mass=float(mass), center_of_mass=com, inertia=0.5 * (inertia + inertia.T))


def _coacd_child(connection: multiprocessing.connection.Connection, vertices: np.ndarray, faces: np.ndarray,
                 options: dict) -> None:
    import coacd

    coacd.set_log_level("error")
    result = coacd.run_coacd(coacd.Mesh(vertices, faces), **options)
    connection.send([(np.asarray(v), np.asarray(f)) for v, f in result])
    connection.close()


def _run_coacd_isolated(vertices: np.ndarray, faces: np.ndarray, options: dict) -> list | None:
    """Run CoACD in a child process: it aborts the whole process on some meshes. None if the child died."""
    context = multiprocessing.get_context("fork" if sys.platform.startswith("linux") else "spawn")
    receive, send = context.Pipe(duplex=False)
    process = context.Process(target=_coacd_child, args=(send, vertices, faces, options), daemon=True)
    process.start()
    send.close()
    try:
        result = receive.recv()
    except EOFError:
        result = None
    process.join()
    return result


def convex_decomposition(mesh: trimesh.Trimesh, config: CollisionConfig = CollisionConfig()) -> list[trimesh.Trimesh]:
    """Approximate convex decomposition with CoACD; each piece is returned as its convex hull.

    CoACD runs in a child process; if it aborts, it is retried once with the other pre-processing mode, then a
    ValueError says so.
    """
    if config.preprocess not in ("on", "off"):
        raise ValueError(f"CollisionConfig.preprocess must be 'on' or 'off', got {config.preprocess!r}")
    if config.max_faces is not None and len(mesh.faces) > config.max_faces:
        mesh = mesh.simplify_quadric_decimation(face_count=config.max_faces)
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int32)
    options = dict(threshold=config.threshold, max_convex_hull=config.max_hulls, resolution=config.resolution,
                   mcts_iterations=config.mcts_iterations, seed=config.seed)
    result = None
    for preprocess in (config.preprocess, "off" if config.preprocess == "on" else "on"):
        result = _run_coacd_isolated(vertices, faces, {**options, "preprocess_mode": preprocess})
        if result is not None:
            break
        log.warning("CoACD aborted on a mesh of %d faces with preprocess=%s", len(faces), preprocess)
    if result is None:
        raise ValueError(f"CoACD aborted on this mesh ({len(faces)} faces) with pre-processing on and off")
    hulls = [trimesh.Trimesh(v, f, process=False).convex_hull for v, f in result]
    hulls = [h for h in hulls if h.volume > 0]
    if not hulls:
        raise ValueError("CoACD returned no convex pieces")
    return hulls


def obj_text(vertices: np.ndarray, faces: np.ndarray, decimals: int = 8) -> str:
    """Wavefront OBJ text (vertices and triangles only) with fixed-decimal coordinates."""
    fmt = f"v %.{decimals}f %.{decimals}f %.{decimals}f"
    lines = [fmt % tuple(v) for v in np.asarray(vertices, dtype=np.float64)]
    lines += ["f %d %d %d" % tuple(f) for f in np.asarray(faces, dtype=np.int64) + 1]
    return "\n".join(lines) + "\n"


def write_collision_obj(
    path: str | os.PathLike, hulls: Sequence[trimesh.Trimesh], decimals: int = 8, names: Sequence[str] | None = None
) -> None:
    """Write convex hulls as ONE OBJ with an `o <name>` group per hull (default names hull_0, hull_1, ...).

    PyBullet loads such a file (as a URDF collision mesh or GEOM_MESH) as a compound of one convex hull per group.
    """
    names = [f"hull_{k}" for k in range(len(hulls))] if names is None else list(names)
    if len(names) != len(hulls) or any(not n or " " in n for n in names):
        raise ValueError(f"need one non-empty group name without spaces per hull, got {names}")
    chunks, offset = [], 0
    fmt = f"v %.{decimals}f %.{decimals}f %.{decimals}f"
    for name, hull in zip(names, hulls):
        chunks.append(f"o {name}")
        chunks += [fmt % tuple(v) for v in np.asarray(hull.vertices, dtype=np.float64)]
        chunks += ["f %d %d %d" % tuple(f) for f in np.asarray(hull.faces, dtype=np.int64) + 1 + offset]
        offset += len(hull.vertices)
    atomic_write_text(path, "\n".join(chunks) + "\n")


def obj_group_names(path: str | os.PathLike) -> list[str]:
    """The `o` group names of an OBJ file, in file order."""
    return [line[2:].strip() for line in Path(path).read_text().splitlines() if line.startswith("o ")]


def read_obj_arrays(path: str | os.PathLike) -> list[tuple[np.ndarray, np.ndarray]]:
    """(vertices, faces) per `o` group of an OBJ written by `write_collision_obj` (or a single group)."""
    groups: list[tuple[list, list]] = []
    all_vertices: list[list[float]] = []
    for line in Path(path).read_text().splitlines():
        if line.startswith("o ") or (line.startswith("v ") and not groups):
            groups.append(([], []))
            if line.startswith("o "):
                continue
        if line.startswith("v "):
            all_vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("f "):
            groups[-1][1].append([int(tok.split("/")[0]) - 1 for tok in line.split()[1:4]])
    vertices = np.asarray(all_vertices, dtype=np.float64)
    out = []
    for _, faces in groups:
        faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        used = np.unique(faces)
        remap = np.full(len(vertices), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        out.append((vertices[used], remap[faces]))
    return out


def read_collision_hulls(path: str | os.PathLike) -> list[trimesh.Trimesh]:
    """The convex hulls stored in a collision OBJ, one Trimesh per `o` group."""
    return [trimesh.Trimesh(v, f, process=False) for v, f in read_obj_arrays(path)]


def urdf_text(
    name: str,
    visual_file: str,
    collision_file: str,
    props: MassProperties,
    friction: float,
    spinning_friction: float = 0.002,
    rolling_friction: float = 0.0002,
) -> str:
    """A one-link URDF: visual mesh, compound convex collision mesh, inertial, contact friction.

    The inertial frame keeps the object's axes (rpy = 0) and only the diagonal of the inertia tensor is written:
    PyBullet reports and sets a base pose as the pose of the inertial frame, so an unrotated inertial frame makes
    `getBasePositionAndOrientation` differ from the object pose by the centre-of-mass offset only. The products of
    inertia this drops are small for handheld objects (at most 11 % of the tensor's norm in the twin: frying pans).
    Load it with `pybullet.URDF_USE_INERTIA_FROM_FILE`, or PyBullet recomputes the inertia from the hulls.
    """
    moments = np.maximum(np.diag(props.inertia), 1e-12)

    def vec(v: Sequence[float]) -> str:
        return " ".join(f"{float(x):.8g}" for x in v)

    return f"""<?xml version="1.0"?>
<robot name="{name}">
  <link name="base_link">
    <contact>
      <lateral_friction value="{friction:.4g}"/>
      <spinning_friction value="{spinning_friction:.4g}"/>
      <rolling_friction value="{rolling_friction:.4g}"/>
    </contact>
    <inertial>
      <origin xyz="{vec(props.center_of_mass)}" rpy="0 0 0"/>
      <mass value="{props.mass:.8g}"/>
      <inertia ixx="{moments[0]:.8g}" ixy="0" ixz="0" iyy="{moments[1]:.8g}" iyz="0" izz="{moments[2]:.8g}"/>
    </inertial>
    <visual>
      <geometry><mesh filename="{visual_file}" scale="1 1 1"/></geometry>
    </visual>
    <collision>
      <geometry><mesh filename="{collision_file}" scale="1 1 1"/></geometry>
    </collision>
  </link>
</robot>
"""
