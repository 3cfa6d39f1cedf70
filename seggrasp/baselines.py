"""The ShapeGrasp baseline as the SegGrasp paper describes it: convex decomposition only, part chosen by the
detector, one grasp at the chosen part's centroid, top-down, with a fixed rotation.

ShapeGrasp reasons over the convex parts of one decomposition. Here the parts are those of the coarsest partition of
the decomposition sweep that has at least one part per prompt (`seggrasp.fusion.coarsest_with_parts`), and the part
for each prompt is chosen from the area-weighted mean of the detector's votes (the same coarse vote matrix S the
other methods start from), one distinct part per prompt (`seggrasp.fusion.assign_parts_to_prompts`, the step
SegGrasp's prompt anchoring shares), so the comparison isolates the geometry: whole convex parts and a fixed
top-down grasp instead of GeoFusion and the antipodal sampler. Its face labels (for mIoU) give the chosen parts
their prompts and every other part its best-voted prompt.
"""

from __future__ import annotations

import logging

import numpy as np
import trimesh

from seggrasp.fusion import assign_parts_to_prompts
from seggrasp.grasp.pads import pad_contacts
from seggrasp.grasp.types import GraspSet
from seggrasp.hands import ROBOTIQ_2F85, Hand
from seggrasp.labels import UNKNOWN

LOG = logging.getLogger(__name__)

#: Fixed closing direction of the top-down grasp, world frame (the approach is always world -z).
SHAPEGRASP_CLOSING_AXIS = np.array([1.0, 0.0, 0.0])
#: Height of the fingertips above the table top when a part's centroid is too low to grasp at.
TABLE_CLEARANCE = 0.005
#: Spacing (m), point-count bounds and seed of the surface sample the pads sweep (`pad_sweep_cloud`).
CLOUD_SPACING = 0.002
CLOUD_POINTS = (2000, 40000)
CLOUD_SEED = 0


def shapegrasp_labels(votes: np.ndarray, part_of_face: np.ndarray) -> np.ndarray:
    """Per-face labels: the parts chosen for prompts take that prompt, every other part its best-voted prompt
    (-1 for parts without any vote)."""
    best = np.argmax(votes, axis=1).astype(np.int64)
    best[~(votes > 0).any(axis=1)] = UNKNOWN
    for prompt, part in enumerate(assign_parts_to_prompts(votes)):
        if part >= 0:
            best[part] = prompt
    return best[np.asarray(part_of_face, dtype=np.int64)]


def shapegrasp_grasps(
    mesh: trimesh.Trimesh,
    votes: np.ndarray,
    part_of_face: np.ndarray,
    T_world_obj: np.ndarray,
    gripper: Hand = ROBOTIQ_2F85,
) -> list[GraspSet]:
    """One grasp per prompt (object frame), empty where no part received a vote for that prompt.

    The grasp sits at the chosen part's centroid (raised so the fingertips clear the table, whose top is taken as
    the object's lowest point in the world), approaches straight down in the world and closes along the fixed
    world axis `SHAPEGRASP_CLOSING_AXIS`. Its contacts are where the pads, closing from fully open, first meet
    the surface (`pad_contacts`, the sampler's pad sweep) and its width their distance; where the pads sweep no
    surface (a part lower than the pads, or off their width) the contacts are NaN (the grasp touches nothing) and the
    width the full opening.
    """
    part_of_face = np.asarray(part_of_face, dtype=np.int64)
    T_world_obj = np.asarray(T_world_obj, dtype=np.float64)
    T_obj_world = np.linalg.inv(T_world_obj)
    world_vertices = mesh.vertices @ T_world_obj[:3, :3].T + T_world_obj[:3, 3]
    table_z = float(world_vertices[:, 2].min())
    lowest_origin = table_z + gripper.tip_beyond_origin + TABLE_CLEARANCE
    closing = SHAPEGRASP_CLOSING_AXIS / np.linalg.norm(SHAPEGRASP_CLOSING_AXIS)
    approach = np.array([0.0, 0.0, -1.0])
    rotation = np.column_stack([closing, np.cross(approach, closing), approach])

    cloud = pad_sweep_cloud(mesh)
    grasps = []
    for k, part in enumerate(assign_parts_to_prompts(votes)):
        if part < 0:
            grasps.append(GraspSet.empty())
            continue
        faces = np.flatnonzero(part_of_face == part)
        areas = mesh.area_faces[faces]
        centroid = mesh.triangles_center[faces].T @ areas / max(float(areas.sum()), 1e-18)
        T_world_grasp = np.eye(4)
        T_world_grasp[:3, :3] = rotation
        T_world_grasp[:3, 3] = T_world_obj[:3, :3] @ centroid + T_world_obj[:3, 3]
        T_world_grasp[2, 3] = max(T_world_grasp[2, 3], lowest_origin)
        T_obj_grasp = T_obj_world @ T_world_grasp
        contacts, widths = pad_contacts(T_obj_grasp[None], gripper.stroke, cloud, gripper.pad_half_width,
                                       gripper.pad_half_length)
        # a grasp whose pads sweep nothing closes on air from the full opening (its contacts stay NaN)
        width = float(widths[0]) if np.isfinite(widths[0]) else gripper.stroke
        grasps.append(GraspSet(T_obj_grasp[None], [width], [float(votes[part, k])], contacts))
        LOG.debug("shapegrasp: prompt %d -> part %d of %d, width %.3f", k, part, votes.shape[0], width)
    return grasps


def pad_sweep_cloud(mesh: trimesh.Trimesh) -> np.ndarray:
    """Surface points of `mesh` for the pads' sweep: its vertices and an area-weighted sample about
    `CLOUD_SPACING` apart (seeded, so a plan is repeatable)."""
    count = int(np.clip(mesh.area / CLOUD_SPACING**2, *CLOUD_POINTS))
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=CLOUD_SEED)
    return np.concatenate([np.asarray(mesh.vertices, dtype=np.float64), points])
