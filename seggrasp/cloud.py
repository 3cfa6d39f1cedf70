"""Point-cloud building blocks of seggrasp/perception.py: back-projection, down-sampling, outlier removal,
clustering, normals and point-to-plane ICP (numpy and scipy only)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from seggrasp.cell import Frame


def backproject(frame: Frame, max_depth: float = np.inf) -> np.ndarray:
    """World points (N, 3) of a frame's valid depth pixels (0 < depth <= max_depth), OpenCV pinhole model."""
    depth = np.asarray(frame.depth, dtype=np.float64)
    K = np.asarray(frame.K, dtype=np.float64)
    if depth.ndim != 2:
        raise ValueError(f"frame {frame.name}: depth must be (H, W), got shape {depth.shape}")
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"frame {frame.name}: K must be a 3x3 pinhole matrix with positive focal lengths, got {K}")
    T_world_cam = checked_pose(frame.T_world_cam, f"frame {frame.name}")
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0) & (depth <= max_depth))
    z = depth[v, u]
    camera_points = np.stack([(u - K[0, 2]) * z / K[0, 0], (v - K[1, 2]) * z / K[1, 1], z], axis=1)
    return transform_points(camera_points, T_world_cam)


def project(
    points: np.ndarray, T_cam_world: np.ndarray, K: np.ndarray, shape: tuple[int, ...]
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pixels of world points (N, 3) in a pinhole camera of image `shape` (H, W), `backproject`'s inverse:
    (column, row, depth along the optical axis, inside); the pixel is rounded and valid where `inside` (in front of
    the camera and in the image)."""
    local = transform_points(points, T_cam_world)
    z = local[:, 2]
    in_front = z > 1e-6
    u = np.full(len(z), -1, dtype=np.int64)
    v = np.full(len(z), -1, dtype=np.int64)
    u[in_front] = np.round(K[0, 0] * local[in_front, 0] / z[in_front] + K[0, 2]).astype(np.int64)
    v[in_front] = np.round(K[1, 1] * local[in_front, 1] / z[in_front] + K[1, 2]).astype(np.int64)
    inside = in_front & (u >= 0) & (u < shape[1]) & (v >= 0) & (v < shape[0])
    return u, v, z, inside


def transform_points(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points."""
    return points @ T[:3, :3].T + T[:3, 3]


def voxel_downsample(points: np.ndarray, voxel: float, *attributes: np.ndarray):
    """Centroid of the points (and mean of each per-point attribute) in every occupied voxel.

    Returns the points alone when no attributes are given, else a tuple (points, *attributes).
    """
    if len(points) == 0:
        return (points, *attributes) if attributes else points
    keys = np.floor(points / voxel).astype(np.int64)
    _, inverse, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)

    def mean(values: np.ndarray) -> np.ndarray:
        sums = np.zeros((len(counts), values.shape[1]))
        np.add.at(sums, inverse, values)
        return sums / counts[:, None]

    reduced = mean(points)
    if not attributes:
        return reduced
    return (reduced, *(mean(a) for a in attributes))


def statistical_inliers(points: np.ndarray, neighbours: int, std_ratio: float) -> np.ndarray:
    """Mask of points whose mean distance to their k nearest neighbours is within mean + std_ratio * std."""
    if len(points) <= neighbours:
        return np.ones(len(points), dtype=bool)
    distances, _ = cKDTree(points).query(points, k=neighbours + 1)
    mean_distance = distances[:, 1:].mean(axis=1)
    return mean_distance <= mean_distance.mean() + std_ratio * mean_distance.std()


def radius_components(points: np.ndarray, radius: float) -> np.ndarray:
    """Connected-component index of every point under single linkage at `radius`."""
    pairs = cKDTree(points).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))
    return connected_components(graph, directed=False)[1]


def estimate_normals(points: np.ndarray, neighbours: int) -> np.ndarray:
    """Unit normals (unoriented) from PCA over each point's k nearest neighbours."""
    k = min(neighbours, len(points))
    _, index = cKDTree(points).query(points, k=k)
    local = points[index] - points[index].mean(axis=1, keepdims=True)
    covariance = np.einsum("nki,nkj->nij", local, local)
    _, eigenvectors = np.linalg.eigh(covariance)
    return eigenvectors[:, :, 0]


def orient_normals_by_propagation(points: np.ndarray, normals: np.ndarray, neighbours: int = 10) -> np.ndarray:
    """Consistently oriented normals: flip along a minimum spanning tree of the k-NN graph (weights 1 - |n_i.n_j|)
    starting from the highest point, whose normal is made to point up."""
    k = min(neighbours + 1, len(points))
    _, index = cKDTree(points).query(points, k=k)
    rows = np.repeat(np.arange(len(points)), k - 1)
    cols = index[:, 1:].reshape(-1)
    weights = 1.0 - np.abs(np.einsum("ij,ij->i", normals[rows], normals[cols])) + 1e-6
    tree = minimum_spanning_tree(coo_matrix((weights, (rows, cols)), shape=(len(points), len(points))))
    tree = tree + tree.T
    oriented = normals.copy()
    _, components = connected_components(tree, directed=False)
    for component in np.unique(components):
        members = np.flatnonzero(components == component)
        root = members[np.argmax(points[members, 2])]
        if oriented[root, 2] < 0:
            oriented[root] *= -1
        order, predecessors = breadth_first_order(tree, root, directed=False)
        for node in order[1:]:
            if oriented[node] @ oriented[predecessors[node]] < 0:
                oriented[node] *= -1
    return oriented


def icp_point_to_plane(
    source: np.ndarray,
    target: np.ndarray,
    target_normals: np.ndarray,
    max_distance: float,
    iterations: int,
    damping: float = 1e-3,
) -> np.ndarray:
    """4x4 transform moving `source` onto the surface sampled by `target` (linearised point-to-plane ICP,
    correspondences farther than `max_distance` ignored).

    Each step is linearised about the target's centroid and damped (Levenberg-Marquardt style, `damping` times
    the largest curvature), so motions the geometry hardly constrains - sliding along a table, turning about the
    axis of a nearly round object - stay small instead of drifting.
    """
    tree = cKDTree(target)
    centre = target.mean(axis=0)
    T = np.eye(4)
    current = source
    for _ in range(iterations):
        distance, index = tree.query(current, k=1, distance_upper_bound=max_distance)
        matched = np.isfinite(distance)
        if matched.sum() < 6:
            break
        p, q, n = current[matched] - centre, target[index[matched]] - centre, target_normals[index[matched]]
        A = np.concatenate([np.cross(p, n), n], axis=1)
        b = np.einsum("ij,ij->i", q - p, n)
        H = A.T @ A
        x = np.linalg.solve(H + damping * np.linalg.eigvalsh(H)[-1] * np.eye(6), A.T @ b)
        rotation = _rotation_from_vector(x[:3])
        step = np.eye(4)
        step[:3, :3] = rotation
        step[:3, 3] = centre + x[3:] - rotation @ centre
        T = step @ T
        current = transform_points(source, T)
        if np.linalg.norm(x[:3]) < 1e-6 and np.linalg.norm(x[3:]) < 1e-6:
            break
    return T


def _rotation_from_vector(rotvec: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(rotvec).as_matrix()


def checked_pose(T: np.ndarray, what: str) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{what}: T_world_cam must be a finite 4x4 matrix, got shape {T.shape}")
    if not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-4) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise ValueError(f"{what}: T_world_cam is not a rigid transform")
    return T
