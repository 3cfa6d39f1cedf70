"""The surface step of seggrasp/perception.py: a signed distance on a voxel grid (IMLS near the points, space
carving by what the cameras saw farther out, or a flood fill from the border without frames)."""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
from scipy.spatial import cKDTree

from seggrasp.cell import Frame
from seggrasp.cloud import checked_pose, project, transform_points


def implicit_surface(
    grid_shape: tuple[int, int, int],
    origin: np.ndarray,
    step: float,
    points: np.ndarray,
    normals: np.ndarray,
    bandwidth: float,
    neighbours: int,
    table_plane: tuple[np.ndarray, float] | None,
    gap_voxels: int = 3,
    free_space: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Signed distance estimate (negative inside) on a regular grid from oriented points.

    Near the data (within `bandwidth` of the nearest point): the Gaussian-weighted mean of the k nearest points'
    tangent-plane distances (IMLS). Farther away only the sign matters, and it never comes from a normal far
    away: with `free_space` (positions -> mask of space seen empty by a camera) a cell is outside when it was seen
    empty and inside otherwise (unseen space counts as occupied, as in space carving); without it, a cell is
    outside when it can be reached from the grid's border without crossing the data band or the table (see
    `_flood_outside`). Below the table everything is outside. The grid's border must be outside for the zero level
    set to be closed; `reconstruct_mesh` forces that.
    """
    axes = [origin[i] + step * np.arange(grid_shape[i]) for i in range(3)]
    queries = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    tree = cKDTree(points)
    distance, _ = tree.query(queries, k=1)
    band = distance < bandwidth
    if table_plane is None:
        above_table = np.ones(len(queries), dtype=bool)
        table_distance = None
    else:
        table_distance = queries @ np.asarray(table_plane[0], dtype=float) - float(table_plane[1])
        above_table = table_distance > 0
    if free_space is not None:
        outside = free_space(queries) & ~band
    else:
        outside = _flood_outside(~band.reshape(grid_shape), above_table.reshape(grid_shape), gap_voxels).reshape(-1)
    field = np.where(outside | ~above_table, distance, -distance)
    k = min(neighbours, len(points))
    near = np.flatnonzero(band)
    for chunk in np.array_split(near, max(1, len(near) // 200_000)):
        near_d, near_i = tree.query(queries[chunk], k=k)
        near_d, near_i = near_d.reshape(len(chunk), k), near_i.reshape(len(chunk), k)
        weights = np.exp(-((near_d / bandwidth) ** 2))
        plane = np.einsum("nkj,nkj->nk", queries[chunk][:, None, :] - points[near_i], normals[near_i])
        field[chunk] = (weights * plane).sum(axis=1) / np.maximum(weights.sum(axis=1), 1e-300)
    if table_distance is not None:
        field = np.maximum(field, -table_distance)  # intersect with the half-space above the table
    return field.reshape(grid_shape)


def _flood_outside(off_band: np.ndarray, above_table: np.ndarray, gap_voxels: int) -> np.ndarray:
    """Grid cells reachable from the border through cells off the data band and above the table.

    The flood runs through free space narrowed by `gap_voxels` away from the data band (not from the table), so
    holes in the data up to 2 * gap_voxels cells wide (unseen spots, the strip the table margin removed) do not
    let "outside" leak into the object; the flooded region is then widened back by as much.
    """
    from scipy import ndimage

    free = off_band & above_table
    ball = ndimage.generate_binary_structure(3, 1)
    narrowed = free
    if gap_voxels:
        narrowed = ndimage.binary_erosion(off_band, ball, iterations=gap_voxels, border_value=1) & free
    components, _ = ndimage.label(narrowed)
    border = np.unique(
        np.concatenate([components[[0, -1]].ravel(), components[:, [0, -1]].ravel(), components[:, :, [0, -1]].ravel()])
    )
    reachable = np.isin(components, border[border > 0])
    if gap_voxels:
        reachable = ndimage.binary_dilation(reachable, ball, iterations=gap_voxels, mask=free)
    return reachable


def seen_free_space(
    frames: Sequence[Frame],
    margin: float,
    table_plane: tuple[np.ndarray, float] | None = None,
    table_margin: float = 0.0,
    max_depth: float = np.inf,
) -> Callable[[np.ndarray], np.ndarray]:
    """A function mapping world positions (N, 3) to a mask of those some camera saw as empty space: in front of
    the measured surface along the pixel's ray by more than `margin`, or anywhere in front of it when the pixel
    sees the table (its point lies within `table_margin` of `table_plane`), so the thin layer of air just above
    the table counts as seen.

    Each depth image is first max-filtered over 3x3 pixels, so a dropout or a noisy pixel next to a valid one does
    not leave a spike of unseen space; this carves at most a pixel or two into silhouettes, which stays within the
    data band where the IMLS surface, not carving, decides.
    """
    from scipy import ndimage

    cameras = []
    for frame in frames:
        depth = np.asarray(frame.depth, dtype=np.float64)
        depth = np.where(np.isfinite(depth) & (depth <= max_depth), depth, 0.0)
        T_world_cam = checked_pose(frame.T_world_cam, f"frame {frame.name}")
        K = np.asarray(frame.K, dtype=np.float64)
        sees_table = np.zeros(depth.shape, dtype=bool)
        if table_plane is not None:
            v, u = np.nonzero(depth > 0)
            z = depth[v, u]
            rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(z)], axis=1)
            world = transform_points(rays * z[:, None], T_world_cam)
            sees_table[v, u] = world @ np.asarray(table_plane[0]) - float(table_plane[1]) < table_margin
        cameras.append((
            ndimage.maximum_filter(depth, size=3), ndimage.binary_dilation(sees_table), K, np.linalg.inv(T_world_cam)
        ))

    def free(positions: np.ndarray) -> np.ndarray:
        seen = np.zeros(len(positions), dtype=bool)
        for depth, sees_table, K, T_cam_world in cameras:
            u, v, z, inside = project(positions, T_cam_world, K, depth.shape)
            measured = np.zeros(len(z))
            table = np.zeros(len(z), dtype=bool)
            measured[inside] = depth[v[inside], u[inside]]
            table[inside] = sees_table[v[inside], u[inside]]
            seen |= inside & (measured > 0) & ((z < measured - margin) | (table & (z < measured)))
        return seen

    return free
