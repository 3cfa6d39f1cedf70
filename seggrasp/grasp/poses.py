"""Candidate gripper poses of the antipodal sampler: poses around each contact pair's axis, straight-down poses
closing level across a pair lying near the table (`level_poses`), and envelope poses closing around a whole cluster
of surface from outside (`envelope_poses`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from seggrasp.hands import Hand

if TYPE_CHECKING:
    from seggrasp.grasp.antipodal import AntipodalConfig

#: Envelope line centres whose clusters are found in one vectorised block (memory: this x cloud x 3 floats).
ENVELOPE_CHUNK = 64


def poses_around_axes(
    p: np.ndarray, q: np.ndarray, axis: np.ndarray, k: int, rng: np.random.Generator, down: np.ndarray | None
) -> np.ndarray:
    """k poses per pair: x = grasp axis, z = approach rotated about x at evenly spaced angles.

    With a `down` direction (into the table) the first approach of every pair is the one closest to straight
    down, so grasps that must come from above (flat objects) are never missed; otherwise the angles start at a
    random offset.
    """
    helper = np.eye(3)[np.argmin(np.abs(axis), axis=1)]
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(axis, u)
    if down is None:
        offsets = 2.0 * np.pi * rng.random(len(p))
    else:
        offsets = np.arctan2(v @ down, u @ down)  # angle of `down` projected onto the plane normal to the axis
    angles = offsets[:, None] + 2.0 * np.pi * np.arange(k)[None, :] / k  # (P, k)
    cos, sin = np.cos(angles)[..., None], np.sin(angles)[..., None]
    z = cos * u[:, None, :] + sin * v[:, None, :]
    x = np.broadcast_to(axis[:, None, :], z.shape)
    y = np.cross(z, x)
    poses = np.zeros((len(p), k, 4, 4))
    poses[..., :3, 0], poses[..., :3, 1], poses[..., :3, 2] = x, y, z
    poses[..., :3, 3] = (0.5 * (p + q))[:, None, :]
    poses[..., 3, 3] = 1.0
    return poses.reshape(-1, 4, 4)


def level_poses(
    p: np.ndarray, q: np.ndarray, axis: np.ndarray, down: np.ndarray, max_tilt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Straight-down poses closing level with the table across the middle of each pair tilted by 1e-3 to `max_tilt`
    rad from it, and the indices of those pairs. On a round part lying flat (a handle) the pairs through its axis
    tilt every way, and the pads coming straight down close on its widest section, the one line across the pads
    that holds against twist; the footprint (`_apply_footprint`) then finds those contacts."""
    sine = axis @ down
    pairs = np.flatnonzero((np.abs(sine) > 1e-3) & (np.abs(sine) <= np.sin(max_tilt)))
    x = axis[pairs] - sine[pairs, None] * down[None]
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    z = np.broadcast_to(down, x.shape)
    poses = np.zeros((len(pairs), 4, 4))
    poses[:, :3, 0], poses[:, :3, 1], poses[:, :3, 2] = x, np.cross(z, x), z
    poses[:, :3, 3] = 0.5 * (p[pairs] + q[pairs])
    poses[:, 3, 3] = 1.0
    return poses, pairs


def envelope_poses(
    cloud: np.ndarray, plane: np.ndarray, gripper: Hand, cfg: AntipodalConfig
) -> tuple[np.ndarray, np.ndarray]:
    """Straight-down poses closing level with the table around the whole cluster of surface that lies under the
    fingers on a line through each of `envelope_centres` points of `cloud`, in `envelope_directions` directions,
    and the clusters' widths. Along the line, the points within a finger's half width of it (any height) split into
    clusters where a gap leaves room for a finger and its approach margin; the cluster holding the centre point, if it
    fits the stroke, gets a pose at its middle, halfway up it or as low as the deepest pinch reaches. A hole narrower
    than a finger does not split a cluster: the pads then close on its outer walls."""
    up = plane[:3]
    reach = cfg.widest_contact_distance(gripper)
    half_y = max(box[2] for box in gripper.finger_boxes)
    split_gap = max(box[1] for box in gripper.finger_boxes) + gripper.pre_grasp_margin
    # no lower than the deepest pinch reaches with its fingertips clear (without pinches, no lower than halfway up)
    lowest = (cfg.pinch_table_clearance + gripper.tip_beyond_origin - max(cfg.pinch_contact_depths) + 1e-4
              if cfg.pinch_contact_depths else -np.inf)
    helper = np.eye(3)[np.argmin(np.abs(up))]
    u = np.cross(up, helper)
    u /= np.linalg.norm(u)
    angles = np.pi * np.arange(cfg.envelope_directions) / cfg.envelope_directions
    directions = np.cos(angles)[:, None] * u + np.sin(angles)[:, None] * np.cross(up, u)
    centres = cloud[np.unique(np.linspace(0, len(cloud) - 1, min(cfg.envelope_centres, len(cloud))).astype(int))]
    heights = cloud @ up + plane[3]
    poses, widths = [], []
    for direction in directions:
        across = np.cross(up, direction)
        for chunk in np.array_split(centres, -(-len(centres) // ENVELOPE_CHUNK)):
            relative = cloud[None] - chunk[:, None]  # (C, M, 3)
            x, y = relative @ direction, relative @ across
            column = (np.abs(y) <= half_y) & (np.abs(x) <= reach + split_gap)  # a cluster running out is too wide
            xs = np.sort(np.where(column, x, np.inf), axis=1)
            centre_index = (xs < 0.0).sum(axis=1, keepdims=True)  # the centre itself has x = 0
            with np.errstate(invalid="ignore"):
                split = ~(np.diff(xs, axis=1) < split_gap)  # a wide gap, or the end of the column
            index = np.arange(xs.shape[1] - 1)[None]
            last = np.where(split & (index >= centre_index), index, xs.shape[1] - 1).min(axis=1)
            first = np.where(split & (index < centre_index), index, -1).max(axis=1) + 1
            rows = np.arange(len(chunk))
            low, high = xs[rows, first], xs[rows, last]
            member = column & (x >= low[:, None]) & (x <= high[:, None])
            bottom = np.where(member, heights[None], np.inf).min(axis=1)
            top = np.where(member, heights[None], -np.inf).max(axis=1)
            keep = np.isfinite(high) & (high - low >= cfg.min_width) & (high - low <= reach)
            origin = chunk + 0.5 * (low + high)[:, None] * direction
            height = np.maximum(0.5 * (bottom + top), lowest)
            origin += (height - (origin @ up + plane[3]))[:, None] * up
            pose = np.tile(np.eye(4), (int(keep.sum()), 1, 1))
            pose[:, :3, 0], pose[:, :3, 1], pose[:, :3, 2] = direction, np.cross(-up, direction), -up
            pose[:, :3, 3] = origin[keep]
            poses.append(pose)
            widths.append((high - low)[keep])
    poses, widths = np.concatenate(poses), np.concatenate(widths)
    # many centres on one cluster give the same pose: keep one per millimetre of origin and width, per direction
    key = np.c_[np.round(poses[:, :3, 3] / 1e-3), np.round(widths / 1e-3), np.round(poses[:, :3, 0] * 1e3)]
    _, unique = np.unique(key, axis=0, return_index=True)
    unique.sort()
    return poses[unique], widths[unique]
