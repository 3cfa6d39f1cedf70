"""What a parallel gripper's pads sweep and touch as they close: the surface points between them, where each pad
first touches, how far along the pads the touched surface reaches. Shared by the antipodal sampler, the pad
footprint and the ShapeGrasp baseline's planned contacts."""

from __future__ import annotations

import numpy as np


def box_corners(boxes: np.ndarray) -> np.ndarray:
    """The 8 corners of each box (B, 2, 3) [min, max] -> (B * 8, 3)."""
    pick = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    return np.stack([boxes[:, pick[:, 0], 0], boxes[:, pick[:, 1], 1], boxes[:, pick[:, 2], 2]], axis=-1).reshape(-1, 3)


def swept_points(
    poses: np.ndarray, openings: np.ndarray, cloud: np.ndarray, half_width: float, z_low: float, z_high: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cloud in each gripper frame, x and z (G, M), and which points the closing pads sweep (|y| <= half_width,
    z_low <= z <= z_high, |x| within half the opening)."""
    rotations = poses[:, :3, :3]
    local = np.matmul(cloud[None], rotations) - np.matmul(poses[:, None, :3, 3], rotations)  # (G, M, 3)
    inside = (
        (np.abs(local[..., 1]) <= half_width) & (local[..., 2] >= z_low) & (local[..., 2] <= z_high)
        & (np.abs(local[..., 0]) <= 0.5 * openings[:, None])
    )
    return local[..., 0], local[..., 2], inside


def sweep(
    poses: np.ndarray, openings: np.ndarray, cloud: np.ndarray, half_width: float, z_low: float, z_high: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The cloud points the closing pads sweep per pose (`swept_points`): (span along x, NaN if none; lowest and
    highest x; their cloud indices)."""
    x, _, inside = swept_points(poses, openings, cloud, half_width, z_low, z_high)
    low = np.where(inside, x, np.inf).argmin(axis=1)
    high = np.where(inside, x, -np.inf).argmax(axis=1)
    rows = np.arange(len(x))
    x_low, x_high = x[rows, low], x[rows, high]
    span = np.where(inside.any(axis=1), x_high - x_low, np.nan)
    return span, x_low, x_high, low, high


def pad_touches(
    poses: np.ndarray, openings: np.ndarray, cloud: np.ndarray, half_width: float, half_length: float, tolerance: float,
    tip: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which points of `cloud` each pad closes on, per pose: the points its sweep (`swept_points`, a pad of
    2 half_width x 2 half_length closing from `openings`, reaching `tip` past the origin along z when given, the
    finger's end below the pad) holds within `tolerance` of its first touch. Returns the -x pad's and the +x pad's
    masks (G, M) and the points' z in each gripper frame (G, M)."""
    x, z, inside = swept_points(poses, openings, cloud, half_width, -half_length, half_length if tip is None else tip)
    masks = []
    for sign in (-1.0, 1.0):  # the -x pad touches the lowest x, the +x pad the highest
        first = np.where(inside, sign * x, -np.inf).max(axis=1, keepdims=True)
        masks.append(inside & (sign * x >= first - tolerance))
    return masks[0], masks[1], z


def pad_bands(
    poses: np.ndarray, openings: np.ndarray, cloud: np.ndarray, half_width: float, half_length: float, tolerance: float
) -> np.ndarray:
    """Per pose, how far along the pads (m) the surface they close on reaches: for each pad the extent along z of
    the swept points within `tolerance` of its first touch, the smaller of the two (0 where nothing is swept)."""
    low_pad, high_pad, z = pad_touches(poses, openings, cloud, half_width, half_length, tolerance)
    bands = []
    for touching in (low_pad, high_pad):
        extent = np.where(touching, z, -np.inf).max(axis=1) - np.where(touching, z, np.inf).min(axis=1)
        bands.append(np.where(touching.any(axis=1), extent, 0.0))
    return np.minimum(*bands)


def pressed_centres(poses: np.ndarray, openings: np.ndarray, cloud: np.ndarray, half_width: float, half_length: float,
                    tolerance: float) -> np.ndarray:
    """Per pose, the centre of the surface points each pad presses on (`pad_touches` within `tolerance` of its first
    touch): (G, 2, 3), -x pad first; NaN where a pad touches nothing."""
    low_pad, high_pad, _ = pad_touches(poses, openings, cloud, half_width, half_length, tolerance)
    centres = []
    for touching in (low_pad, high_pad):
        with np.errstate(invalid="ignore"):
            centres.append((touching @ cloud) / touching.sum(axis=1, keepdims=True))
    return np.stack(centres, axis=1)


def pad_contacts(
    poses: np.ndarray, openings: np.ndarray, cloud: np.ndarray, half_width: float, half_length: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Where the two pads (2 half_width x 2 half_length, the hand's, centred on the gripper's x axis), closing from
    `openings` at `poses`, first touch the surface points `cloud` (the sampler's pad sweep, `sweep`): contacts
    (G, 2, 3), -x pad first, and widths (G,); both NaN for a pose whose pads sweep no point (the grasp touches
    nothing)."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    openings = np.broadcast_to(np.asarray(openings, dtype=np.float64), (len(poses),))
    span, _, _, low, high = sweep(poses, openings, cloud, half_width, -half_length, half_length)
    contacts = np.stack([cloud[low], cloud[high]], axis=1)
    contacts[np.isnan(span)] = np.nan
    return contacts, span
