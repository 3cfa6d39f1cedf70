"""Graspable objects: a mesh with part labels, prompts and the physical properties a simulator needs."""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh

from seggrasp.io import atomic_write_json, atomic_write_text, cache_root
from seggrasp.labels import PartLabels, read_labels
from seggrasp.mesh import load_mesh, mesh_hash
from seggrasp.object_physics import (
    CollisionConfig,
    MassProperties,
    convex_decomposition,
    mass_properties,
    obj_text,
    read_collision_hulls,
    read_obj_arrays,
    urdf_text,
    write_collision_obj,
)

log = logging.getLogger(__name__)

#: Where the twin lives (the repository's `assets/` folder); override with SEGGRASP_ASSETS_DIR.
ASSETS_DIR = Path(os.environ.get("SEGGRASP_ASSETS_DIR", Path(__file__).resolve().parents[1] / "assets"))
#: A graspable object for the twin's hands on a table: its largest side must lie in this range (metres).
GRASPABLE_EXTENT_M = (0.02, 1.0)


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
    notes: list[str] = field(default_factory=list)  # how the physics was obtained (e.g. estimated volume)


# --------------------------------------------------------------------------------------------------------------
# Loaders: the bundled twin (assets/manifest.json) and external meshes.
# --------------------------------------------------------------------------------------------------------------
#: PyBullet-facing defaults for external objects (hard plastic).
DEFAULT_DENSITY = 1000.0
DEFAULT_FRICTION = 0.5
#: Thinner objects (a sheet, a single plane) cannot be given a volume or a collision shape.
MIN_THICKNESS_M = 0.001
#: Payload of a Robotiq 2F-85; heavier objects still load but are reported.
GRIPPER_PAYLOAD_KG = 5.0
#: Voxels along the largest side when a mesh is not watertight and its volume must be estimated.
VOXELS_PER_EXTENT = 96
_GENERIC_STEMS = {"textured", "model", "mesh", "scene", "nontextured", "google_16k", "poisson"}


def _read_manifest(assets_dir: Path = ASSETS_DIR) -> dict:
    path = Path(assets_dir) / "manifest.json"
    if not path.is_file():
        raise FileNotFoundError(f"twin manifest not found: {path} (generate it with `python -m assets generate`)")
    return json.loads(path.read_text())


def _normalise_categories(categories: str | Sequence[str] | None, known: Sequence[str]) -> set[str] | None:
    if categories is None:
        return None
    wanted = {categories} if isinstance(categories, str) else set(categories)
    unknown = wanted - set(known)
    if unknown:
        raise ValueError(f"unknown categories {sorted(unknown)}; the twin has {sorted(set(known))}")
    return wanted


def asset_ids(categories: str | Sequence[str] | None = None, assets_dir: Path = ASSETS_DIR) -> list[str]:
    """Ids of the twin's objects (manifest order), optionally only those of the given categories."""
    records = _read_manifest(assets_dir)["objects"]
    wanted = _normalise_categories(categories, [r["category"] for r in records])
    return [r["id"] for r in records if wanted is None or r["category"] in wanted]


def load_asset(object_id: str, assets_dir: Path = ASSETS_DIR) -> ObjectModel:
    """Load one object of the twin: mesh, exact part labels, physics (mass, inertia, friction), hulls, URDF path."""
    assets_dir = Path(assets_dir)
    records = {r["id"]: r for r in _read_manifest(assets_dir)["objects"]}
    if object_id not in records:
        raise ValueError(f"unknown object id {object_id!r}; the twin has {sorted(records)}")
    record = records[object_id]
    files = {key: assets_dir / rel for key, rel in record["files"].items()}
    vertices, faces = read_obj_arrays(files["mesh"])[0]
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if mesh_hash(mesh) != record["mesh_hash"]:
        raise ValueError(f"{files['mesh']} does not match the manifest (mesh hash differs); regenerate the twin")
    labels = read_labels(files["labels"])
    labels.check_faces(len(mesh.faces), what=str(files["mesh"]))
    return ObjectModel(
        object_id=object_id,
        category=record["category"],
        mesh=mesh,
        prompts=list(record["prompts"]),
        mass=float(record["mass"]),
        friction=float(record["friction"]),
        center_of_mass=np.asarray(record["center_of_mass"], dtype=np.float64),
        inertia=np.asarray(record["inertia"], dtype=np.float64),
        collision_hulls=read_collision_hulls(files["collision"]),
        labels=labels,
        mesh_path=files["mesh"],
        collision_path=files["collision"],
        urdf_path=files["urdf"],
    )


def load_asset_set(categories: str | Sequence[str] | None = None, assets_dir: Path = ASSETS_DIR) -> list[ObjectModel]:
    """All objects of the twin (manifest order: category by category), optionally filtered by category."""
    return [load_asset(i, assets_dir) for i in asset_ids(categories, assets_dir)]


def _voxel_mass_properties(mesh: trimesh.Trimesh, density: float) -> tuple[MassProperties, float]:
    """Mass properties of the filled voxelisation of a (possibly open) surface; returns them and the voxel pitch.

    Voxels cut by the surface count half (the surface passes through them on average halfway), which removes most
    of the bias a full surface layer would add to thin-walled objects.
    """
    pitch = float(mesh.extents.max()) / VOXELS_PER_EXTENT
    surface = mesh.voxelized(pitch)
    filled = surface.copy().fill()
    centres = np.asarray(filled.points, dtype=np.float64)
    if len(centres) == 0:
        raise ValueError("cannot estimate a volume: the voxelised mesh is empty")
    filled_index = np.asarray(filled.sparse_indices, dtype=np.int64)
    surface_index = np.asarray(surface.sparse_indices, dtype=np.int64)
    dims = np.maximum(filled_index.max(axis=0), surface_index.max(axis=0)) + 1
    on_surface = np.isin(np.ravel_multi_index(filled_index.T, dims), np.ravel_multi_index(surface_index.T, dims))
    weights = np.where(on_surface, 0.5, 1.0)
    cell_volume = pitch**3
    mass = density * cell_volume * float(weights.sum())
    com = (weights[:, None] * centres).sum(axis=0) / weights.sum()
    d = centres - com
    point_masses = density * cell_volume * weights
    # point masses plus each cube's own inertia (m a^2 / 6 about each axis)
    inertia = np.eye(3) * np.einsum("i,ij,ij->", point_masses, d, d) - (d * point_masses[:, None]).T @ d
    inertia += np.eye(3) * mass * pitch**2 / 6.0
    return MassProperties(mass=float(mass), center_of_mass=com, inertia=inertia), pitch


def _boundary_edge_count(mesh: trimesh.Trimesh) -> int:
    _, counts = np.unique(mesh.edges_sorted, axis=0, return_counts=True)
    return int((counts == 1).sum())


def estimate_mass_properties(mesh: trimesh.Trimesh, density: float) -> tuple[MassProperties, str]:
    """Mass properties of a (possibly scanned) surface and a note saying how they were obtained.

    Watertight meshes use the exact enclosed volume. A closed surface (no boundary edges) that is not a clean
    2-manifold (a few non-manifold edges, typical of scans) still encloses a well-defined volume, so the exact
    divergence-theorem integrals are used. Open scans are closed by filling small holes if that makes them
    watertight; otherwise their filled voxelisation is used (an estimate).
    """
    if mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0:
        return mass_properties(mesh, density), "exact volume of the watertight mesh"
    if _boundary_edge_count(mesh) == 0 and mesh.is_winding_consistent and mesh.volume > 0:
        return mass_properties(mesh, density), "volume of the closed (but not 2-manifold) surface"
    patched = mesh.copy()
    patched.fill_holes()
    if patched.is_watertight and patched.is_winding_consistent and patched.volume > 0:
        return mass_properties(patched, density), "volume after filling holes in the scan"
    props, pitch = _voxel_mass_properties(mesh, density)
    return props, f"mesh is open: volume from its filled voxelisation (pitch {pitch * 1000:.2f} mm)"


def load_external_object(
    mesh_path: str | os.PathLike,
    labels_path: str | os.PathLike | None = None,
    prompts: Sequence[str] | None = None,
    density: float = DEFAULT_DENSITY,
    friction: float = DEFAULT_FRICTION,
    cache_dir: str | os.PathLike | None = None,
    mass: float | None = None,
    object_id: str | None = None,
    category: str = "external",
    collision: CollisionConfig = CollisionConfig(
        threshold=0.08, max_hulls=16, resolution=1000, mcts_iterations=60, preprocess="on", max_faces=4000
    ),
) -> ObjectModel:
    """Make any mesh file a physical object of the same kind as the twin's.

    The mesh (metres; its size is checked) is moved into the twin's frame convention (footprint centre at the
    origin, lowest point at z = 0, face order kept) and written with its CoACD collision model (cached by mesh
    hash and settings) and a one-link URDF into `cache_dir` (default `$SEGGRASP_CACHE/objects`). Mass comes from `density` times the estimated volume,
    or from `mass` if given (then the density is derived). `labels_path` holds one label per face of the file;
    `prompts` (default: the label file's part names) fixes label order: label k = prompt k.
    Raises ValueError for what cannot be made physical: absurd or ungraspable size, a flat sheet (no volume), no
    convex pieces.
    """
    mesh_path = Path(mesh_path)
    _check_physical_inputs(density, friction, mass)
    mesh, work, shift = _placed_meshes(mesh_path)
    labels = None
    if labels_path is not None:
        file_labels = read_labels(labels_path)
        file_labels.check_faces(len(mesh.faces), what=str(mesh_path))
        prompts = list(file_labels.parts) if prompts is None else list(prompts)
        labels = PartLabels(prompts, file_labels.remap_to(prompts))
    prompts = [] if prompts is None else [str(p) for p in prompts]
    props, notes = _external_mass(work, density, mass, mesh_path)

    digest = mesh_hash(mesh)
    name = object_id or (mesh_path.parent.name if mesh_path.stem.lower() in _GENERIC_STEMS else mesh_path.stem)
    entry = Path(cache_dir if cache_dir is not None else cache_root() / "objects") / f"{name}-{digest[:12]}"
    entry.mkdir(parents=True, exist_ok=True)
    local_mesh = entry / "mesh.obj"
    if not local_mesh.is_file():
        atomic_write_text(local_mesh, obj_text(mesh.vertices, mesh.faces))
    hulls, collision_path = _cached_collision_hulls(entry, work, collision, mesh_path)
    urdf_path = entry / "object.urdf"
    atomic_write_text(urdf_path, urdf_text(name, local_mesh.name, collision_path.name, props, friction))
    atomic_write_json(entry / "info.json", {
        "source": str(mesh_path.resolve()), "shift": shift.tolist(), "mass": props.mass, "notes": notes,
        "collision": collision.key(), "n_hulls": len(hulls),
    })
    for note in notes:
        log.info("%s: %s", name, note)
    return ObjectModel(
        object_id=name,
        category=category,
        mesh=mesh,
        prompts=prompts,
        mass=float(props.mass),
        friction=float(friction),
        center_of_mass=props.center_of_mass,
        inertia=props.inertia,
        collision_hulls=hulls,
        labels=labels,
        mesh_path=local_mesh,
        collision_path=collision_path,
        urdf_path=urdf_path,
        notes=notes,
    )


def _check_physical_inputs(density: float, friction: float, mass: float | None) -> None:
    """ValueError for a density, friction coefficient or mass no physical object has."""
    if density <= 0 or not np.isfinite(density):
        raise ValueError(f"density must be a positive number of kg/m^3, got {density}")
    if not 0.0 < friction <= 2.0:
        raise ValueError(f"friction coefficient must be in (0, 2], got {friction}")
    if mass is not None and not mass > 0:
        raise ValueError(f"mass must be positive, got {mass}")


def _placed_meshes(mesh_path: Path) -> tuple[trimesh.Trimesh, trimesh.Trimesh, np.ndarray]:
    """The file's mesh (face order kept) and its repaired working copy, both moved so the footprint centre is at the
    origin and the lowest point at z = 0, and that shift; ValueError for an ungraspable size or a flat sheet."""
    prepared = load_mesh(mesh_path)
    largest = float(prepared.mesh.extents.max())
    if not GRASPABLE_EXTENT_M[0] <= largest <= GRASPABLE_EXTENT_M[1]:
        raise ValueError(
            f"{mesh_path}: {largest:.3f} m across; a tabletop object for a parallel gripper must be "
            f"{GRASPABLE_EXTENT_M[0]}-{GRASPABLE_EXTENT_M[1]} m (check the units of the file)"
        )
    thinnest = float(prepared.mesh.extents.min())
    if thinnest < MIN_THICKNESS_M:
        raise ValueError(
            f"{mesh_path}: flat: its thinnest side is {thinnest * 1000:.3g} mm; a surface without thickness has no "
            f"volume, mass or collision shape (need at least {MIN_THICKNESS_M * 1000:g} mm)"
        )
    raw = trimesh.load(mesh_path, force="mesh", process=False, skip_materials=True)
    lower, upper = prepared.mesh.bounds
    shift = np.array([-(lower[0] + upper[0]) / 2, -(lower[1] + upper[1]) / 2, -lower[2]])
    mesh = trimesh.Trimesh(np.asarray(raw.vertices, dtype=np.float64) + shift, np.asarray(raw.faces), process=False)
    work = prepared.mesh.copy()
    work.apply_translation(shift)
    return mesh, work, shift


def _external_mass(
    work: trimesh.Trimesh, density: float, mass: float | None, mesh_path: Path
) -> tuple[MassProperties, list[str]]:
    """Mass properties at `density` (scaled to `mass` when given) and notes on how they were found."""
    props, how = estimate_mass_properties(work, density)
    notes = [f"mass: {how}"]
    if mass is not None:
        scale = mass / props.mass
        props = MassProperties(mass, props.center_of_mass, props.inertia * scale)
        notes.append(f"mass fixed at {mass} kg (effective density {density * scale:.0f} kg/m^3)")
    if props.mass > GRIPPER_PAYLOAD_KG:
        log.warning("%s: %.2f kg exceeds the 2F-85 payload of %.1f kg", mesh_path, props.mass, GRIPPER_PAYLOAD_KG)
        notes.append(f"heavier than the gripper payload ({GRIPPER_PAYLOAD_KG} kg)")
    return props, notes


def _cached_collision_hulls(
    entry: Path, work: trimesh.Trimesh, collision: CollisionConfig, mesh_path: Path
) -> tuple[list[trimesh.Trimesh], Path]:
    """The CoACD collision hulls of `work`, read from or written to `entry` (keyed by the CoACD settings)."""
    collision_path = entry / f"collision-{hashlib.sha256(collision.key().encode()).hexdigest()[:10]}.obj"
    if collision_path.is_file():
        return read_collision_hulls(collision_path), collision_path
    log.info("running CoACD on %s (%d faces); cached in %s", mesh_path, len(work.faces), collision_path)
    try:
        hulls = convex_decomposition(work, collision)
    except ValueError as exc:
        raise ValueError(f"{mesh_path}: no collision model: {exc}") from exc
    write_collision_obj(collision_path, hulls)
    return hulls, collision_path
