"""Partitions of a mesh's faces and the face -> convex hull mapping (see the package docstring for the rule)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from seggrasp.decompose.config import CONTAINMENT_TOLERANCE


@dataclass
class Partition:
    """One decomposition: `part_of_face[i]` is the convex part (0..n_parts-1) of face i."""

    threshold: float
    part_of_face: np.ndarray

    @property
    def n_parts(self) -> int:
        return int(self.part_of_face.max()) + 1 if self.part_of_face.size else 0

    def same_as(self, other: "Partition") -> bool:
        return self.part_of_face.shape == other.part_of_face.shape and bool(
            np.array_equal(self.part_of_face, other.part_of_face)
        )


def canonical_parts(part_of_face: np.ndarray) -> np.ndarray:
    """Renumber part ids in order of first appearance (so equal partitions have equal arrays)."""
    part_of_face = np.asarray(part_of_face, dtype=np.int64)
    _, first, inverse = np.unique(part_of_face, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse.reshape(-1)]


def dedupe_partitions(partitions: Sequence[Partition]) -> list[Partition]:
    """Drop every partition equal to its predecessor in threshold order (the earlier threshold is kept)."""
    ordered = sorted(partitions, key=lambda p: p.threshold)
    kept: list[Partition] = []
    for partition in ordered:
        if not kept or not partition.same_as(kept[-1]):
            kept.append(partition)
    return kept




def hull_planes(vertices: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Outward facet planes (K, 4) [n, -d] of the convex hull of `vertices` and its volume; None if degenerate."""
    try:
        hull = ConvexHull(np.asarray(vertices, dtype=np.float64))
    except (QhullError, ValueError):
        return None
    return hull.equations, float(hull.volume)


def map_faces_to_hulls(
    centroids: np.ndarray, hulls: Sequence[np.ndarray], scale: float, tolerance: float = CONTAINMENT_TOLERANCE
) -> np.ndarray:
    """Hull index for every face centroid (see the package docstring for the rule). `hulls` = vertex arrays.

    Memory stays O(faces + MAP_CHUNK x facets): hulls are visited one by one, faces in chunks of MAP_CHUNK.
    """
    centroids = np.asarray(centroids, dtype=np.float64)
    if len(hulls) == 0:
        raise ValueError("no hulls to map faces to")
    n = len(centroids)
    best_volume = np.full(n, np.inf)  # smallest containing hull so far
    best_inside = np.full(n, -1, dtype=np.int64)
    nearest_value = np.full(n, np.inf)  # smallest outside value so far
    nearest = np.zeros(n, dtype=np.int64)
    for h, vertices in enumerate(hulls):
        outside, volume = _outside_values(centroids, np.asarray(vertices, dtype=np.float64))
        contains = (outside <= tolerance * scale) & (volume < best_volume)
        best_volume[contains], best_inside[contains] = volume, h
        closer = outside < nearest_value
        nearest_value[closer], nearest[closer] = outside[closer], h
    return np.where(best_inside >= 0, best_inside, nearest)


#: Faces per block of the half-space test (bounds its (faces x facets) temporary to a few tens of MB).
MAP_CHUNK = 16384


def _outside_values(centroids: np.ndarray, vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """`max_j (n_j . c - d_j)` over the hull's facet planes for every centroid, and the hull's volume. A flat hull
    gives the distance to its bounding box and volume 0."""
    planes = hull_planes(vertices)
    if planes is None:
        low, high = np.min(vertices, axis=0), np.max(vertices, axis=0)
        return np.linalg.norm(np.maximum(low - centroids, 0) + np.maximum(centroids - high, 0), axis=1), 0.0
    equations, volume = planes
    outside = np.empty(len(centroids))
    for start in range(0, len(centroids), MAP_CHUNK):
        block = centroids[start:start + MAP_CHUNK]
        outside[start:start + MAP_CHUNK] = (block @ equations[:, :3].T + equations[:, 3]).max(axis=1)
    return outside, volume
