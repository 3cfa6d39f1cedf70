"""Mesh loading, validation, repair and normalisation.

Every per-face result in SegGrasp refers to the faces of the *input file* in file order. Internally a mesh may be
repaired (duplicate vertices merged, zero-area faces dropped); `PreparedMesh` keeps the map between the two orders.
"""

from __future__ import annotations

import hashlib
import io
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

logger = logging.getLogger(__name__)

SUPPORTED_SUFFIXES = (".obj", ".ply", ".off", ".stl", ".glb", ".gltf")
#: Bounding-box extents outside this range (metres) are rejected as absurd: most likely wrong units.
MIN_EXTENT_M = 1e-3
MAX_EXTENT_M = 10.0
#: Faces whose area is below this fraction of the mean face area are treated as degenerate.
DEGENERATE_AREA_FRACTION = 1e-10


@dataclass
class PreparedMesh:
    """A validated working mesh plus the map back to the input face order.

    `mesh.faces[k]` came from input face `source_face[k]`. Input faces that were dropped as degenerate map to the
    nearest kept face in `source_to_work`, so every input face has a working face to take its value from.
    """

    mesh: trimesh.Trimesh
    source_face: np.ndarray
    source_to_work: np.ndarray
    source_path: Path | None = None
    dropped_faces: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    @property
    def n_faces(self) -> int:
        return int(len(self.mesh.faces))

    @property
    def n_source_faces(self) -> int:
        return int(len(self.source_to_work))

    def to_source(self, per_face: np.ndarray) -> np.ndarray:
        """Lift a per-working-face array (first axis = faces) to the input file's face order."""
        per_face = np.asarray(per_face)
        if per_face.shape[0] != self.n_faces:
            raise ValueError(f"expected {self.n_faces} rows (one per working face), got {per_face.shape[0]}")
        return per_face[self.source_to_work]

    def from_source(self, per_source_face: np.ndarray) -> np.ndarray:
        """Restrict a per-input-face array (first axis = input faces) to the working faces."""
        per_source_face = np.asarray(per_source_face)
        if per_source_face.shape[0] != self.n_source_faces:
            raise ValueError(
                f"expected {self.n_source_faces} rows (one per face of the input mesh), got {per_source_face.shape[0]}"
            )
        return per_source_face[self.source_face]


def load_mesh(
    path: str | os.PathLike, min_extent: float = MIN_EXTENT_M, max_extent: float = MAX_EXTENT_M
) -> PreparedMesh:
    """Load a mesh file (OBJ, PLY, OFF, STL, GLB/glTF) and validate and repair it; see `prepare_mesh`.

    Text that is not UTF-8 (a Latin-1 byte in a comment) is read as Latin-1. A file that holds no mesh of its
    format, or only points, is a ValueError naming the file and what was found.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise ValueError(f"unsupported mesh format {path.suffix!r} for {path}; use one of {SUPPORTED_SUFFIXES}")
    fmt = suffix[1:].upper()
    if path.stat().st_size == 0:
        raise ValueError(f"{path} is empty (0 bytes): not a readable {fmt} mesh")
    try:
        source = _utf8_source(path, suffix)
        scene = trimesh.load_scene(source, file_type=suffix[1:], process=False, skip_materials=True)
        geometry = scene.dump()
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise ValueError(f"{path} is not a readable {fmt} mesh ({type(exc).__name__}: {exc})") from exc
    meshes = [g for g in geometry if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    if not meshes:
        n_points = sum(len(getattr(g, "vertices", ())) for g in geometry)
        if n_points:
            raise ValueError(f"{path} has {n_points} vertices and no faces (a point cloud?): SegGrasp needs a "
                             "triangle mesh")
        raise ValueError(f"{path} is not a readable {fmt} mesh: no vertices or faces found in it")
    loaded = scene.to_mesh()
    prepared = prepare_mesh(
        np.asarray(loaded.vertices), np.asarray(loaded.faces), min_extent=min_extent, max_extent=max_extent,
        name=str(path),
    )
    prepared.source_path = path
    return prepared


def _utf8_source(path: Path, suffix: str) -> Path | io.BytesIO:
    """`path`, or its bytes with non-UTF-8 text re-encoded from Latin-1 (trimesh would otherwise need an optional
    charset detector). Text is the whole file for OBJ, OFF and ASCII STL, the header for PLY."""
    if suffix not in (".obj", ".off", ".stl", ".ply"):
        return path
    raw = path.read_bytes()
    if suffix == ".stl" and len(raw) >= 84 and len(raw) == 84 + 50 * int.from_bytes(raw[80:84], "little"):
        return path  # binary STL
    end = raw.find(b"end_header") if suffix == ".ply" else len(raw)
    text = raw[: end if end >= 0 else len(raw)]
    try:
        text.decode("utf-8")
        return path
    except UnicodeDecodeError:
        logger.info("%s is not UTF-8: reading its text as Latin-1", path)
    return io.BytesIO(text.decode("latin-1").encode("utf-8") + raw[len(text):])


def prepare_mesh(
    vertices: np.ndarray,
    faces: np.ndarray,
    min_extent: float = MIN_EXTENT_M,
    max_extent: float = MAX_EXTENT_M,
    name: str = "mesh",
) -> PreparedMesh:
    """Validate raw arrays and build a repaired working mesh.

    Raises ValueError for: no vertices or faces, non-finite vertices, faces that are not triangles, face indices
    out of range, a mesh whose faces are all degenerate, or a bounding box outside [min_extent, max_extent] metres.
    Repairs: merges duplicate vertices and drops zero-area faces (keeping the map to the input face order).
    """
    vertices, faces = _checked_arrays(vertices, faces, min_extent, max_extent, name)

    # Merge duplicate vertices first (keeps face order), then drop faces that are degenerate afterwards: a sliver
    # whose corners merge becomes a face with a repeated vertex.
    merged = trimesh.Trimesh(vertices=vertices, faces=faces, process=False, validate=False)
    merged.merge_vertices(merge_tex=True, merge_norm=True)
    merged_faces = np.asarray(merged.faces, dtype=np.int64)
    merged_vertices = np.asarray(merged.vertices, dtype=np.float64)
    areas = _triangle_areas(merged_vertices, merged_faces)
    threshold = DEGENERATE_AREA_FRACTION * max(float(_triangle_areas(vertices, faces).mean()), np.finfo(float).tiny)
    distinct = (
        (merged_faces[:, 0] != merged_faces[:, 1])
        & (merged_faces[:, 1] != merged_faces[:, 2])
        & (merged_faces[:, 0] != merged_faces[:, 2])
    )
    keep = (areas > threshold) & distinct
    if not keep.any():
        raise ValueError(f"{name}: all {len(faces)} faces have zero area")
    kept = np.flatnonzero(keep)
    dropped = np.flatnonzero(~keep)

    mesh = trimesh.Trimesh(vertices=merged_vertices, faces=merged_faces[kept], process=False, validate=False)
    mesh.remove_unreferenced_vertices()

    source_to_work = np.empty(len(faces), dtype=np.int64)
    source_to_work[kept] = np.arange(len(kept))
    if len(dropped):
        centroids = vertices[faces].mean(axis=1)
        _, nearest = cKDTree(centroids[kept]).query(centroids[dropped])
        source_to_work[dropped] = nearest
    return PreparedMesh(mesh=mesh, source_face=kept, source_to_work=source_to_work, dropped_faces=dropped)


def _checked_arrays(vertices: np.ndarray, faces: np.ndarray, min_extent: float, max_extent: float,
                    name: str) -> tuple[np.ndarray, np.ndarray]:
    """Float64 vertices and int64 faces after the checks of `prepare_mesh` (ValueError naming the first problem)."""
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise ValueError(f"{name}: empty mesh or malformed vertices (shape {vertices.shape}); need (N, 3) with N > 0")
    if faces.ndim != 2 or len(faces) == 0:
        raise ValueError(f"{name}: empty mesh: no faces (faces shape {faces.shape})")
    if faces.shape[1] != 3:
        raise ValueError(f"{name}: faces must be triangles, got {faces.shape[1]} indices per face")
    if not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"{name}: face indices must be integers, got {faces.dtype}")
    bad_vertices = ~np.isfinite(vertices).all(axis=1)
    if bad_vertices.any():
        raise ValueError(
            f"{name}: {int(bad_vertices.sum())} vertices have NaN or infinite coordinates "
            f"(first: vertex {int(np.flatnonzero(bad_vertices)[0])})"
        )
    out_of_range = (faces < 0) | (faces >= len(vertices))
    if out_of_range.any():
        row = int(np.flatnonzero(out_of_range.any(axis=1))[0])
        raise ValueError(
            f"{name}: {int(out_of_range.any(axis=1).sum())} faces index vertices outside 0..{len(vertices) - 1} "
            f"(first: face {row} = {faces[row].tolist()})"
        )
    faces = faces.astype(np.int64)
    extent = float(np.ptp(vertices[np.unique(faces)], axis=0).max())
    if not (min_extent <= extent <= max_extent):
        raise ValueError(
            f"{name}: absurd size: largest bounding-box side is {extent:.6g} m, outside [{min_extent}, {max_extent}] m. "
            "Meshes must be in metres (a scan in millimetres needs scaling by 0.001)."
        )
    return vertices, faces


def _triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    tri = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def unit_normalisation(mesh: trimesh.Trimesh) -> np.ndarray:
    """4x4 transform that centres the mesh's bounding box at the origin and scales it into the unit sphere."""
    centre = mesh.bounds.mean(axis=0)
    radius = float(np.linalg.norm(mesh.vertices - centre, axis=1).max())
    transform = np.eye(4)
    transform[:3, :3] *= 1.0 / radius
    transform[:3, 3] = -centre / radius
    return transform


def mesh_hash(mesh: trimesh.Trimesh) -> str:
    """Stable content hash of a mesh's geometry (vertices rounded to 1e-9, faces) for cache keys."""
    digest = hashlib.sha256()
    digest.update(np.round(np.asarray(mesh.vertices, dtype=np.float64), 9).tobytes())
    digest.update(np.asarray(mesh.faces, dtype=np.int64).tobytes())
    return digest.hexdigest()[:32]
