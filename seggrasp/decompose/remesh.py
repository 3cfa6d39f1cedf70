"""A closed working mesh for CoACD from a mesh that is not a closed manifold (an open or non-manifold scan).

CoACD's own preprocessing remeshes such input on a voxel grid and then decomposes that remesh; on thin open surfaces
the remesh is large and the decomposition slow (minutes for a 1.5k-face open mesh). Here the mesh is replaced by
the surface at a small distance `offset` around it: the iso-surface of its unsigned distance field, sampled on a
grid and extracted with marching cubes. The result encloses every original face (each lies within `offset` of it,
inside), so the face -> hull mapping stays valid, and it is a closed manifold that manifold3d can simplify to the
face budget; CoACD then runs without its preprocessing.
"""

from __future__ import annotations

import logging
import time

import numpy as np
import trimesh
from scipy.spatial import cKDTree

logger = logging.getLogger(__name__)

#: Grid cells along the longest side of the bounding box. On an open 4.6k-face tube (r 4 cm, 10 cm) 48 cells gave
#: 21 parts at threshold 0.04 in 3.6 CPU s (CoACD's own preprocessing: 19 parts in 23.7 s); 96 cells (a shell half
#: as thick) over 120k faces before simplification.
SHELL_RESOLUTION = 48
#: Offset of the shell from the surface, in grid cells.
SHELL_OFFSET_CELLS = 1.0


def closed_shell(vertices: np.ndarray, faces: np.ndarray, resolution: int = SHELL_RESOLUTION,
                 offset_cells: float = SHELL_OFFSET_CELLS) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and faces of the closed surface at `offset_cells` grid cells around the mesh (grid of `resolution`
    cells along the longest bounding-box side), outward-facing triangles."""
    from skimage.measure import marching_cubes

    started = time.perf_counter()
    mesh = trimesh.Trimesh(vertices, faces, process=False, validate=False)
    low, high = mesh.bounds
    pitch = float((high - low).max()) / resolution
    offset = offset_cells * pitch
    # About ten surface samples per cell face area: the sampled distance is a fraction of a cell above the true one.
    count = int(np.clip(10 * mesh.area / pitch**2, 10_000, 2_000_000))
    samples = np.vstack([trimesh.sample.sample_surface(mesh, count, seed=0)[0], mesh.vertices])
    origin = low - 3 * pitch
    shape = np.ceil((high - low) / pitch).astype(int) + 7
    axes = [origin[k] + pitch * np.arange(shape[k]) for k in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    distance, _ = cKDTree(samples).query(grid, distance_upper_bound=3 * offset, workers=1)
    field = np.minimum(distance, 3 * offset).reshape(shape)  # far cells: capped (outside the shell anyway)
    points, triangles, _, _ = marching_cubes(field, level=offset, spacing=(pitch, pitch, pitch))
    points = points + origin
    shell = trimesh.Trimesh(points, triangles, process=True)
    if shell.volume < 0:
        shell.invert()
    logger.info("decomposition: closed %d-face shell %.2g m around a mesh that is not a closed manifold "
                "(%d-cell grid) in %.1f s", len(shell.faces), offset, int(np.prod(shape)),
                time.perf_counter() - started)
    return np.asarray(shell.vertices, np.float64), np.asarray(shell.faces, np.int64)
