"""Mesh loading, validation, repair and normalisation.

Every per-face result in SegGrasp refers to the faces of the *input file* in file order. Internally a mesh may be
repaired (duplicate vertices merged, zero-area faces dropped, duplicate faces merged); `PreparedMesh` keeps the map
between the two orders.

Duplicate faces (two or more faces on the same three vertices in the same winding, after vertex merging) are one
working face: a renderer's depth test shows only one of the coincident copies, so the others would collect no votes.
Every copy takes the working face's value (`PreparedMesh.to_source`), so all copies get the same label. A face and
its reverse are kept apart: they are the two sides of a zero-thickness fin (scans have them), and merging them would
open a closed surface.
"""

from __future__ import annotations

import hashlib
import io
import logging
import os
import stat
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
#: Vertices farther than this from the origin (metres) are rejected: float64 resolves only about 1e-16 of a
#: coordinate, so an object placed 1e12 m away has its faces collapse (wrong units or a geo-referenced scan).
MAX_COORDINATE_M = 1.0e3
#: Faces whose area is below this fraction of the mean face area are treated as degenerate.
DEGENERATE_AREA_FRACTION = 1e-10


@dataclass
class PreparedMesh:
    """A validated working mesh plus the map back to the input face order.

    `mesh.faces[k]` came from input face `source_face[k]`. Input faces that were dropped as degenerate map to the
    nearest kept face in `source_to_work`, so every input face has a working face to take its value from.
    `duplicate_faces` are the input faces that repeat an earlier face (`to_source` gives them its value).
    """

    mesh: trimesh.Trimesh
    source_face: np.ndarray
    source_to_work: np.ndarray
    source_path: Path | None = None
    dropped_faces: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    duplicate_faces: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

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
    format, or only points, is a ValueError naming the file and what was found; so is a path that is a folder, a
    named pipe or a device (never opened), and an ASCII PLY whose header's element counts disagree with its body.
    """
    path = Path(path)
    _check_regular_file(path)
    suffix = path.suffix.lower()
    if suffix not in SUPPORTED_SUFFIXES:
        raise ValueError(f"unsupported mesh format {path.suffix!r} for {path}; use one of {SUPPORTED_SUFFIXES}")
    fmt = suffix[1:].upper()
    if path.stat().st_size == 0:
        raise ValueError(f"{path} is empty (0 bytes): not a readable {fmt} mesh")
    raw = path.read_bytes() if suffix == ".ply" else None  # read once: checked here, then re-encoded if need be
    if raw is not None:
        check_ascii_ply_counts(path, raw)
    try:
        source = _utf8_source(path, suffix, raw)
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


def _check_regular_file(path: Path) -> None:
    """FileNotFoundError if nothing is at `path`, ValueError naming what is there if it is no regular file. Uses
    `stat` only, so a named pipe is never opened (opening one for reading blocks until a writer comes)."""
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise FileNotFoundError(f"mesh file not found: {path}") from None
    except OSError as exc:
        raise ValueError(f"mesh file {path} cannot be read: {exc.strerror or exc}") from exc
    kinds = ((stat.S_ISDIR, "a folder"), (stat.S_ISFIFO, "a named pipe (FIFO)"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    for test, kind in kinds:
        if test(mode):
            raise ValueError(f"{path} is {kind}, not a mesh file")


def check_ascii_ply_counts(path: Path, raw: bytes) -> None:
    """ValueError naming the file and line when an ASCII PLY's body holds fewer data lines than its header's element
    counts declare (a truncated file) or more (a header that understates a count: the extra faces would be lost).
    Binary PLY files and files without a header are left to the reader."""
    end = raw.find(b"end_header")
    if end < 0:
        return
    header = raw[:end].decode("latin-1").splitlines()
    if not any(line.split()[:2] == ["format", "ascii"] for line in header):
        return
    elements: list[tuple[str, int, int]] = []  # (name, count, header line number)
    for number, line in enumerate(header, start=1):
        words = line.split()
        if len(words) == 3 and words[0] == "element":
            try:
                elements.append((words[1], int(words[2]), number))
            except ValueError:
                raise ValueError(f"{path} line {number}: element count {words[2]!r} is not an integer") from None
    newline = raw.find(b"\n", end)
    body = raw[newline + 1:] if newline >= 0 else b""
    first_line = len(header) + 1 + (newline >= 0)  # line number of the body's first line
    expected = sum(count for _, count, _ in elements)
    if body.count(b"\n") + (not body.endswith(b"\n") and bool(body)) == expected and b"\n\n" not in body:
        return  # the common case, checked without splitting the body
    lines = [first_line + i for i, text in enumerate(body.splitlines()) if text.strip()]
    start = 0
    for name, count, declared_on in elements:
        if len(lines) < start + count:
            where = f"line {lines[-1]}" if lines else f"line {first_line - 1}"
            raise ValueError(
                f"{path} {where}: the file ends after {len(lines) - start} of the {count} {name} lines that the "
                f"header declares on line {declared_on} (a truncated file?)"
            )
        start += count
    if len(lines) > expected:
        name, count, declared_on = elements[-1] if elements else ("data", 0, len(header))
        raise ValueError(
            f"{path} line {lines[expected]}: {len(lines) - expected} data lines follow the {count} {name} lines that "
            f"the header declares on line {declared_on} (the header understates a count; those lines would be lost)"
        )


def _utf8_source(path: Path, suffix: str, raw: bytes | None = None) -> Path | io.BytesIO:
    """`path`, or its bytes (`raw` when already read) with non-UTF-8 text re-encoded from Latin-1 (trimesh would
    otherwise need an optional charset detector). Text is the whole file for OBJ, OFF and ASCII STL, the header for
    PLY."""
    if suffix not in (".obj", ".off", ".stl", ".ply"):
        return path
    raw = path.read_bytes() if raw is None else raw
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
    out of range, a mesh whose faces are all degenerate, a bounding box outside [min_extent, max_extent] metres, or
    vertices farther than MAX_COORDINATE_M from the origin. Repairs: merges duplicate vertices, drops zero-area faces
    and merges duplicate faces (module docstring), keeping the map to the input face order.
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
    # Copies of a face (its corners in the same winding, from any corner) are one working face, the first copy in
    # file order. A face and its reverse are two sides of a sheet (scans have such fins) and both stay.
    _, first, group = np.unique(_from_lowest_corner(merged_faces[kept]), axis=0, return_index=True,
                                return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    work_of_kept = rank[group.reshape(-1)]
    unique = kept[np.sort(first)]
    duplicates = np.setdiff1d(kept, unique)
    if len(duplicates):
        logger.info("%s: %d duplicate faces merged (each copy takes its original's label)", name, len(duplicates))

    mesh = trimesh.Trimesh(vertices=merged_vertices, faces=merged_faces[unique], process=False, validate=False)
    mesh.remove_unreferenced_vertices()

    source_to_work = np.empty(len(faces), dtype=np.int64)
    source_to_work[kept] = work_of_kept
    if len(dropped):
        centroids = vertices[faces].mean(axis=1)
        _, nearest = cKDTree(centroids[unique]).query(centroids[dropped])
        source_to_work[dropped] = nearest
    return PreparedMesh(mesh=mesh, source_face=unique, source_to_work=source_to_work, dropped_faces=dropped,
                        duplicate_faces=duplicates)


def _from_lowest_corner(faces: np.ndarray) -> np.ndarray:
    """Each face's corners rotated to start at its lowest vertex index (winding kept): equal rows are copies."""
    start = np.argmin(faces, axis=1)
    rows = np.arange(len(faces))[:, None]
    return faces[rows, (start[:, None] + np.arange(3)) % 3]


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
    used = vertices[np.unique(faces)]
    extent = float(np.ptp(used, axis=0).max())
    if not (min_extent <= extent <= max_extent):
        raise ValueError(
            f"{name}: absurd size: largest bounding-box side is {extent:.6g} m, outside [{min_extent}, {max_extent}] m. "
            "Meshes must be in metres (a scan in millimetres needs scaling by 0.001)."
        )
    farthest = float(np.abs(used).max())
    if farthest > MAX_COORDINATE_M:
        raise ValueError(
            f"{name}: absurd position: a vertex lies {farthest:.6g} m from the origin (at most {MAX_COORDINATE_M:g} m), "
            "where float64 cannot resolve a tabletop object's faces (wrong units, or a geo-referenced scan?); move "
            "the mesh near the origin."
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
