"""Perception shared by the twin and the robot: calibrated RGB-D frames -> object point cloud -> closed object mesh.

Pipeline (`perceive_object`; point-cloud building blocks in seggrasp/cloud.py, the surface in seggrasp/surface.py;
among several objects, `split_instances` keeps every cluster on the table as its own instance after step 4, and
`mesh_of` reconstructs one of them, step 6; `seggrasp.target` picks the requested one):

1. **Back-projection** of every frame's depth with its `K` and `T_world_cam`, cropped to the `Workspace` box.
2. **View registration** (on by default): point-to-plane ICP, damped and linearised about the target's centroid;
   the camera with most points stays fixed and the others, largest first, are aligned to the ones already
   aligned, with a shrinking correspondence radius. It repairs extrinsic drift of a degree or two and a few
   millimetres; the table in the workspace constrains height and tilt, the object the rest.
3. **Table removal**: a RANSAC plane among points just around the known table height (near-horizontal planes only),
   refined by least squares; everything below it or within a margin above it is dropped: `table_margin`, or three
   times the depth noise measured on the table if that is more. With too few table points the known height is
   used. (Parts thinner than the margin that lie flat on the table, like a knife blade, are lost with it: depth
   alone cannot tell them from the table.)
4. **Clean-up**: voxel down-sampling (centroid per voxel), statistical outlier removal (mean distance to the
   k nearest neighbours), noise specks dropped, and only the clusters resting on the table kept (a gripper above
   the object is not it; see `supported_clusters`).
5. **Normals** by PCA over the k nearest neighbours, oriented towards the camera that saw each point.
6. **Surface**: on a voxel grid, a signed distance that is negative inside. Within `imls_bandwidth` of the points
   it is an implicit moving-least-squares (IMLS) estimate, sum_i w_i (x - p_i).n_i / sum_i w_i with Gaussian
   weights, which averages depth noise away. Farther out only inside/outside matters, and it comes from the
   cameras (space carving): space some camera saw in front of a measured surface is outside, space no camera saw
   is inside. So the part the table hides is closed (flat, on the measured table plane, which bounds the solid),
   the inside of a solid stays solid, and a side no camera saw is filled up to the visual hull, the conservative
   choice for grasping. Marching cubes (scikit-image) contours the grid; the largest piece is kept. Large objects
   get a coarser grid (`target_faces`), which keeps the mesh closed where decimation would not.
   `reconstruct_mesh` alone, with points but no frames, decides inside/outside by a flood fill from the grid's
   border that cannot slip through gaps in the data narrower than a few voxels.

Why not Poisson through Open3D: `open3d-cpu` is a 105 MB wheel that pulls in dash, plotly, ipywidgets and
nbformat; Poisson also needs consistently oriented normals and balloons where data is missing (under the object),
while the carving above uses what the cameras saw to be empty. This needs only scipy and scikit-image and is
deterministic.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Callable, Sequence

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from seggrasp.cell import Frame
from seggrasp.cloud import (
    backproject,
    checked_pose,
    estimate_normals,
    icp_point_to_plane,
    orient_normals_by_propagation,
    radius_components,
    statistical_inliers,
    transform_points,
    voxel_downsample,
)
from seggrasp.surface import implicit_surface, seen_free_space

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class Workspace:
    """An axis-aligned box in the world frame that holds the object, and the height of the table top in it.

    The box should reach a little below the table (so the table plane can be measured) and include some table
    around the object.
    """

    lower: tuple[float, float, float]
    upper: tuple[float, float, float]
    table_height: float

    def __post_init__(self) -> None:
        lower, upper = np.asarray(self.lower, dtype=float), np.asarray(self.upper, dtype=float)
        if lower.shape != (3,) or upper.shape != (3,):
            raise ValueError(f"workspace corners must be 3-vectors, got {self.lower} and {self.upper}")
        if not (np.all(np.isfinite(lower)) and np.all(np.isfinite(upper)) and np.isfinite(self.table_height)):
            raise ValueError("workspace corners and table height must be finite")
        if np.any(lower >= upper):
            raise ValueError(f"workspace lower corner {lower.tolist()} must be below upper corner {upper.tolist()}")
        if not lower[2] <= self.table_height < upper[2]:
            raise ValueError(
                f"table height {self.table_height} must lie within the workspace's z range [{lower[2]}, {upper[2]})"
            )
        object.__setattr__(self, "lower", tuple(float(v) for v in lower))
        object.__setattr__(self, "upper", tuple(float(v) for v in upper))
        object.__setattr__(self, "table_height", float(self.table_height))

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Mask of the (N, 3) points inside the box."""
        points = np.asarray(points, dtype=float).reshape(-1, 3)
        return np.all((points >= np.asarray(self.lower)) & (points <= np.asarray(self.upper)), axis=1)


@dataclass(frozen=True)
class PerceptionConfig:
    """Parameters of fusion and reconstruction (metres). Defaults suit tabletop objects seen by D435-class cameras
    from about 0.4-1 m."""

    max_depth: float = 3.0  # readings beyond this are ignored
    register_views: bool = True  # ICP between the cameras' clouds
    icp_radii: tuple[float, ...] = (0.02, 0.01, 0.005)  # correspondence radius per ICP stage
    icp_iterations: int = 10  # per stage
    table_search_below: float = 0.02  # table RANSAC looks at points this far below the known height...
    table_search_above: float = 0.008  # ...up to this far above it
    table_inlier: float = 0.002  # RANSAC inlier distance
    table_max_tilt_deg: float = 10.0
    table_margin: float = 0.004  # points closer than this above the table are table, not object...
    table_noise_sigmas: float = 3.0  # ...nor closer than this many times the depth noise measured on the table
    voxel_size: float = 0.002  # fused-cloud down-sampling
    outlier_neighbours: int = 16
    outlier_std_ratio: float = 2.0
    cluster_radius: float = 0.01  # points closer than this belong to one cluster...
    min_cluster_points: int = 20  # ...and smaller clusters are noise
    cluster_link: float = 0.03  # clusters closer than this are one object (bridges a thin stem seen badly)
    cluster_keep_fraction: float = 0.2  # clusters at least this fraction of the largest are kept
    support_gap: float = 0.02  # a cluster whose lowest point is higher above the table is not the object
    instance_radius: float = 0.006  # objects in a scene stand millimetres apart: instances grow at this spacing
    normal_neighbours: int = 16
    mesh_voxel: float = 0.002  # marching-cubes grid spacing
    imls_bandwidth: float = 0.005  # Gaussian width of the IMLS weights (smooths depth noise)
    imls_neighbours: int = 12
    gap_voxels: int = 3  # gaps in the data up to 2 * gap_voxels * mesh_voxel wide do not leak (see implicit_surface)
    target_faces: int = 40000  # coarsen the grid so the mesh has at most about this many faces (0 = never)
    min_points: int = 100
    carve_margin: float = 0.003  # space this far in front of a measured surface counts as seen empty

    def __post_init__(self) -> None:
        positive = [
            "max_depth", "carve_margin", "table_inlier", "voxel_size", "cluster_radius", "cluster_link", "mesh_voxel",
            "imls_bandwidth", "instance_radius",
        ]
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"PerceptionConfig.{name} must be positive, got {getattr(self, name)}")
        if any(r <= 0 for r in self.icp_radii):
            raise ValueError(f"PerceptionConfig.icp_radii must be positive, got {self.icp_radii}")
        if self.target_faces < 0 or self.min_points < 4 or self.gap_voxels < 0:
            raise ValueError("PerceptionConfig: target_faces and gap_voxels must be >= 0, min_points >= 4")


@dataclass
class OrientedCloud:
    """Fused object points with outward unit normals, the fitted table plane n.x = d (n pointing up), the margin
    above it that counted as table, and the input frames with their camera poses corrected by view registration."""

    points: np.ndarray  # (N, 3)
    normals: np.ndarray  # (N, 3)
    table_normal: np.ndarray  # (3,)
    table_offset: float
    table_margin: float
    frames: list[Frame]


def fuse_point_cloud(
    frames: Sequence[Frame], workspace: Workspace, config: PerceptionConfig | None = None, seed: int = 0
) -> np.ndarray:
    """The object's points (N, 3) in the world frame, fused from calibrated depth frames (module docstring 1-4)."""
    return fuse_oriented_cloud(frames, workspace, config, seed).points


def fuse_oriented_cloud(
    frames: Sequence[Frame], workspace: Workspace, config: PerceptionConfig | None = None, seed: int = 0
) -> OrientedCloud:
    """Like `fuse_point_cloud`, also returning camera-oriented normals and the fitted table plane."""
    config = config or PerceptionConfig()
    cleaned = _cleaned_cloud(frames, workspace, config, seed)
    keep = supported_clusters(cleaned.points, cleaned.height, config)
    if keep.sum() < config.min_points:
        raise ValueError(
            f"only {int(keep.sum())} object points remain on the table (need {config.min_points}); is there an "
            "object resting on the table inside the workspace?"
        )
    cloud = cleaned.oriented(keep, config)
    logger.info("fused %d object points from %d frames", len(cloud.points), len(cloud.frames))
    return cloud


def split_instances(
    frames: Sequence[Frame], workspace: Workspace, config: PerceptionConfig | None = None, seed: int = 0
) -> list[OrientedCloud]:
    """The objects on the table, one `OrientedCloud` each (largest first), from calibrated depth frames.

    Fusion, table removal and clean-up are `fuse_oriented_cloud`'s (module docstring 1-5); then the points are
    split into the groups that rest on the table, finer than one object's clean-up links them (`instance_labels`),
    each with its normals estimated from its own points. Each shares the table plane and the registered frames, so
    `mesh_of` reconstructs it alone, carved by what the cameras saw. Touching objects are one instance
    (`seggrasp.target.find_target` cuts the target's by its detector boxes).
    """
    config = config or PerceptionConfig()
    cleaned = _cleaned_cloud(frames, workspace, config, seed)
    labels = instance_labels(cleaned.points, cleaned.height, config)
    if labels.max(initial=-1) < 0:
        raise ValueError(
            f"no cluster of at least {config.min_points} points rests on the table; is there an object on the "
            "table inside the workspace?"
        )
    instances = [cleaned.oriented(labels == index, config) for index in range(labels.max() + 1)]
    logger.info("split %d object instances (%s points) from %d frames", len(instances),
                ", ".join(str(len(i.points)) for i in instances), len(frames))
    return instances


@dataclass
class _CleanedCloud:
    """The fused points above the table after clean-up (module docstring 1-4, before clustering): their height
    above the fitted table, the direction to the camera that saw each, the table and the registered frames."""

    points: np.ndarray
    view_dir: np.ndarray
    height: np.ndarray
    table_normal: np.ndarray
    table_offset: float
    table_margin: float
    frames: list[Frame]

    def oriented(self, mask: np.ndarray, config: PerceptionConfig) -> OrientedCloud:
        """The masked points with PCA normals oriented towards their cameras."""
        points, view_dir = self.points[mask], self.view_dir[mask]
        normals = estimate_normals(points, config.normal_neighbours)
        normals *= np.where(np.einsum("ij,ij->i", normals, view_dir) < 0, -1.0, 1.0)[:, None]
        return OrientedCloud(points, normals, self.table_normal, self.table_offset, self.table_margin, self.frames)


def _cleaned_cloud(
    frames: Sequence[Frame], workspace: Workspace, config: PerceptionConfig, seed: int
) -> _CleanedCloud:
    if not frames:
        raise ValueError("no frames given")
    clouds, centres = [], []
    for index, frame in enumerate(frames):
        points = backproject(frame, config.max_depth)
        clouds.append(voxel_downsample(points[workspace.contains(points)], config.voxel_size))
        centres.append(checked_pose(frame.T_world_cam, f"frame {index} ({frame.name})")[:3, 3])
    if sum(len(c) for c in clouds) < config.min_points:
        raise ValueError(
            f"only {sum(len(c) for c in clouds)} depth points fall inside the workspace {workspace}; check the "
            "workspace box, the camera extrinsics and that the object is in view"
        )
    frames = list(frames)
    if config.register_views and sum(len(c) > 0 for c in clouds) > 1:
        corrections = register_views(clouds, config)
        clouds = [transform_points(c, T) for c, T in zip(clouds, corrections)]
        centres = [transform_points(c[None], T)[0] for c, T in zip(centres, corrections)]
        frames = [
            replace(frame, T_world_cam=T @ np.asarray(frame.T_world_cam, dtype=float))
            for frame, T in zip(frames, corrections)
        ]

    all_points = np.concatenate(clouds)
    table_normal, table_offset, table_noise = fit_table_plane(
        all_points, workspace, config, np.random.default_rng(seed)
    )
    table_margin = max(config.table_margin, config.table_noise_sigmas * table_noise)
    view_dirs = []
    for cloud, centre in zip(clouds, centres):
        to_camera = centre - cloud
        view_dirs.append(to_camera / np.linalg.norm(to_camera, axis=1, keepdims=True))
    view_dir = np.concatenate(view_dirs)
    above = all_points @ table_normal - table_offset > table_margin
    points, view_dir = voxel_downsample(all_points[above], config.voxel_size, view_dir[above])
    keep = statistical_inliers(points, config.outlier_neighbours, config.outlier_std_ratio)
    points, view_dir = points[keep], view_dir[keep]
    height = points @ table_normal - table_offset
    return _CleanedCloud(points, view_dir, height, table_normal, table_offset, table_margin, frames)


def reconstruct_mesh(
    points: np.ndarray,
    normals: np.ndarray | None = None,
    table_plane: tuple[np.ndarray, float] | None = None,
    config: PerceptionConfig | None = None,
    free_space: Callable[[np.ndarray], np.ndarray] | None = None,
) -> trimesh.Trimesh:
    """A closed surface mesh through object points (IMLS + marching cubes, module docstring 6).

    `normals` should point out of the object; without them they are estimated by PCA and oriented consistently by
    propagation along a minimum spanning tree from the highest point (assumed to face up). `table_plane` = (n, d)
    with n.x = d on the table and n pointing up closes the surface flat on the table. `free_space` (see
    `seen_free_space`) decides inside and outside away from the points; without it, connectivity does.
    """
    config = config or PerceptionConfig()
    points = np.asarray(points, dtype=float)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) < config.min_points:
        raise ValueError(f"need an (N, 3) point array with N >= {config.min_points}, got shape {points.shape}")
    if not np.all(np.isfinite(points)):
        raise ValueError("points contain NaN or infinite coordinates")
    if normals is None:
        normals = orient_normals_by_propagation(points, estimate_normals(points, config.normal_neighbours))
    normals = np.asarray(normals, dtype=float)
    if normals.shape != points.shape:
        raise ValueError(f"normals shape {normals.shape} differs from points shape {points.shape}")
    normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)

    step = config.mesh_voxel
    mesh = _contour(points, normals, step, table_plane, config, free_space)
    if config.target_faces and len(mesh.faces) > config.target_faces:
        # Coarsen the grid rather than decimate the mesh: marching cubes output stays closed and manifold.
        step *= float(np.sqrt(len(mesh.faces) / config.target_faces))
        logger.info("%d faces > target %d: contouring again on a %.4f m grid", len(mesh.faces),
                    config.target_faces, step)
        mesh = _contour(points, normals, step, table_plane, config, free_space)
    logger.info("reconstructed mesh: %d faces, watertight=%s", len(mesh.faces), mesh.is_watertight)
    return mesh


def _contour(
    points: np.ndarray,
    normals: np.ndarray,
    step: float,
    table_plane: tuple[np.ndarray, float] | None,
    config: PerceptionConfig,
    free_space: Callable[[np.ndarray], np.ndarray] | None,
) -> trimesh.Trimesh:
    """Marching cubes of `implicit_surface` on a grid of spacing `step`; the largest piece, outward-facing.

    The IMLS bandwidth is kept at least 1.5 cells so the data band is never thinner than the grid.
    """
    from skimage.measure import marching_cubes

    bandwidth = max(config.imls_bandwidth, 1.5 * step)
    pad = bandwidth + (config.gap_voxels + 3) * step
    origin = points.min(axis=0) - pad
    shape = tuple(int(n) for n in np.ceil((points.max(axis=0) + pad - origin) / step).astype(int) + 1)
    if np.prod(shape) > 30_000_000:
        raise ValueError(f"reconstruction grid {list(shape)} is too large; increase mesh_voxel or crop the cloud")
    volume = implicit_surface(
        shape, origin, step, points, normals, bandwidth, config.imls_neighbours, table_plane,
        config.gap_voxels, free_space,
    )
    for axis in range(3):  # the grid's border is outside, so every contour closes
        border = [slice(None)] * 3
        for end in (0, -1):
            border[axis] = end
            volume[tuple(border)] = np.maximum(volume[tuple(border)], step)
    if volume.min() >= 0:
        raise ValueError("the implicit surface encloses no volume: the points do not outline a solid")
    vertices, faces, _, _ = marching_cubes(volume, level=0.0, spacing=(step, step, step))
    mesh = trimesh.Trimesh(vertices=vertices + origin, faces=faces, process=True)
    mesh = max(mesh.split(only_watertight=False), key=lambda piece: piece.area)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def perceive_object(
    frames: Sequence[Frame], workspace: Workspace, config: PerceptionConfig | None = None, seed: int = 0
) -> trimesh.Trimesh:
    """The object on the table as a closed mesh in the world frame, from calibrated RGB-D frames."""
    config = config or PerceptionConfig()
    return mesh_of(fuse_oriented_cloud(frames, workspace, config, seed), config)


def mesh_of(cloud: OrientedCloud, config: PerceptionConfig | None = None) -> trimesh.Trimesh:
    """The closed mesh of a fused cloud (or one instance of `split_instances`), closed on its table and carved by
    what its frames saw empty (`seen_free_space`)."""
    config = config or PerceptionConfig()
    table_plane = (cloud.table_normal, cloud.table_offset)
    free_space = seen_free_space(cloud.frames, config.carve_margin, table_plane, cloud.table_margin, config.max_depth)
    return reconstruct_mesh(cloud.points, cloud.normals, table_plane, config, free_space)


# --- building blocks -------------------------------------------------------------------------------------------


def supported_clusters(points: np.ndarray, height: np.ndarray, config: PerceptionConfig) -> np.ndarray:
    """Mask of the points of the object on the table.

    Points are grouped by single linkage at `cluster_radius`; groups under `min_cluster_points` are specks of
    noise (the tail of the table's depth noise above the margin) and dropped. The rest are linked again at
    `cluster_link`, which bridges a thin part the cameras see badly (a wine glass's stem). Clusters whose lowest
    point is more than `support_gap` above the table are not the object (a gripper above it); of the others the
    largest is kept, with any at least `cluster_keep_fraction` of its size.
    """
    if len(points) == 0:
        return np.zeros(0, dtype=bool)
    fine = radius_components(points, config.cluster_radius)
    keep = np.bincount(fine)[fine] >= config.min_cluster_points
    if not keep.any():
        return keep
    coarse = radius_components(points[keep], config.cluster_link)
    sizes = np.bincount(coarse)
    lowest = np.full(len(sizes), np.inf)
    np.minimum.at(lowest, coarse, height[keep])
    supported = lowest <= config.support_gap
    if not supported.any():
        return np.zeros(len(points), dtype=bool)
    chosen = supported & (sizes >= config.cluster_keep_fraction * sizes[supported].max())
    keep[keep] = chosen[coarse]
    return keep


def instance_labels(points: np.ndarray, height: np.ndarray, config: PerceptionConfig) -> np.ndarray:
    """Instance index per point (0 the largest instance, -1 none).

    Objects in a scene stand closer to each other than `cluster_radius` and `cluster_link` (packed ones 5-30 mm),
    so instances grow by single linkage at the finer `instance_radius`: every group of at least `min_points` points
    whose lowest point rests on the table (within `support_gap`) is an instance. Every other group of at least
    `min_cluster_points` (a part the cameras broke off, an object lying on another) joins the instance nearest to
    it when that is within `cluster_link`; the rest are dropped (specks of noise, a gripper above the table).
    Touching objects stay one instance, and a wine glass's bowl over a stem seen badly may join a neighbour
    nearer than its foot.
    """
    labels = np.full(len(points), -1, dtype=np.int64)
    if len(points) == 0:
        return labels
    groups = radius_components(points, config.instance_radius)
    sizes = np.bincount(groups)
    lowest = np.full(len(sizes), np.inf)
    np.minimum.at(lowest, groups, height)
    by_size = np.argsort(-sizes, kind="stable")
    resting = [g for g in by_size if sizes[g] >= config.min_points and lowest[g] <= config.support_gap]
    if not resting:
        return labels
    index_of = np.full(len(sizes), -1, dtype=np.int64)
    index_of[resting] = np.arange(len(resting))
    labels = index_of[groups]
    seeded = labels >= 0
    tree, owner = cKDTree(points[seeded]), labels[seeded]
    for group in by_size:
        if index_of[group] >= 0 or sizes[group] < config.min_cluster_points:
            continue
        members = groups == group
        distance, nearest = tree.query(points[members])
        if distance.min() <= config.cluster_link:
            labels[members] = owner[nearest[np.argmin(distance)]]
    counts = np.bincount(labels[labels >= 0], minlength=len(resting))
    rank = np.empty(len(resting), dtype=np.int64)
    rank[np.argsort(-counts, kind="stable")] = np.arange(len(resting))
    return np.where(labels >= 0, rank[np.maximum(labels, 0)], -1)


def fit_table_plane(
    points: np.ndarray, workspace: Workspace, config: PerceptionConfig, rng: np.random.Generator
) -> tuple[np.ndarray, float, float]:
    """Table plane (n, d) with n.x = d, n pointing up, and the depth noise measured on it (m, RMS).

    RANSAC among points near the known height, refined by least squares. The noise is the RMS distance of the
    points below the plane (nothing but table noise lies there). With too few table points: the known height and
    noise 0."""
    known = (np.array([0.0, 0.0, 1.0]), workspace.table_height, 0.0)
    height = points[:, 2] - workspace.table_height
    candidates = points[(height > -config.table_search_below) & (height < config.table_search_above)]
    if len(candidates) < 50:
        logger.info("only %d points near the table height: using the known table height", len(candidates))
        return known
    min_cos = np.cos(np.radians(config.table_max_tilt_deg))
    best_inliers, best_count = None, 0
    for _ in range(200):
        sample = candidates[rng.choice(len(candidates), 3, replace=False)]
        normal = np.cross(sample[1] - sample[0], sample[2] - sample[0])
        length = np.linalg.norm(normal)
        if length < 1e-12 or abs(normal[2]) / length < min_cos:
            continue
        normal /= length
        inliers = np.abs((candidates - sample[0]) @ normal) < config.table_inlier
        if inliers.sum() > best_count:
            best_inliers, best_count = inliers, int(inliers.sum())
    if best_inliers is None or best_count < 50:
        logger.info("no table plane found near the known height: using it as is")
        return known
    inlier_points = candidates[best_inliers]
    centroid = inlier_points.mean(axis=0)
    normal = np.linalg.svd(inlier_points - centroid, full_matrices=False)[2][2]
    normal = normal if normal[2] > 0 else -normal
    offset = float(normal @ centroid)
    residual = candidates @ normal - offset
    below = residual[residual < 0]
    noise = float(np.sqrt(np.mean(below**2))) if len(below) else 0.0
    logger.info("table plane: %d inliers, height %.4f m, tilt %.2f deg, depth noise %.1f mm", best_count,
                centroid[2], np.degrees(np.arccos(min(1.0, normal[2]))), 1000 * noise)
    return normal, offset, noise


def register_views(clouds: list[np.ndarray], config: PerceptionConfig) -> list[np.ndarray]:
    """Rigid corrections (4x4, world frame) that align each camera's cloud to the others by point-to-plane ICP.

    The cloud with the most points stays fixed. Once per correspondence radius in `config.icp_radii`, the other
    clouds, largest first, are each aligned to the union of the fixed cloud and those already aligned in that
    pass, so a badly calibrated camera cannot pull the well calibrated ones towards itself.
    """
    corrections = [np.eye(4) for _ in clouds]
    usable = [i for i in np.argsort([-len(c) for c in clouds], kind="stable") if len(clouds[i]) >= config.min_points]
    normals = {i: estimate_normals(clouds[i], config.normal_neighbours) for i in usable}
    for radius in config.icp_radii:
        aligned = usable[:1]
        for i in usable[1:]:
            target = np.concatenate([transform_points(clouds[j], corrections[j]) for j in aligned])
            target_normals = np.concatenate([normals[j] @ corrections[j][:3, :3].T for j in aligned])
            step = icp_point_to_plane(
                transform_points(clouds[i], corrections[i]), target, target_normals, radius, config.icp_iterations
            )
            corrections[i] = step @ corrections[i]
            aligned.append(i)
    return corrections


