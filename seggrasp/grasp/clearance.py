"""Whether a hand's box model (`seggrasp.hands.Hand.boxes`) stays clear of points: the grasp sampler's collision
test against the object, and the episode's test against the other objects on the table, seen by the cameras.

Among several objects, a perceived grasp must keep clear of every other instance's points: the open hand at the
grasp and all along its approach from `APPROACH_CHECKED` back, and the closing fingers behind the pads. A real
cell's planner knows only the table and the arm, so this is what keeps the robot off the neighbours there; the
twin's own check (sim.grasp_primitive) knows the true bodies and refuses what this misses."""

from __future__ import annotations

import numpy as np

from seggrasp.hands import Hand

#: Grasp candidates whose collision test is evaluated in one vectorised block.
COLLISION_CHUNK = 256
#: Every this many collision points form the sparse first pass of the collision test.
COARSE_STRIDE = 8
#: How far back along the approach (m) the open hand must keep clear: the pre-grasp distance of both cells
#: (sim.grasp_primitive.GraspSettings.pregrasp_distance, hardware/cell.example.yaml motion.pregrasp_distance).
APPROACH_CHECKED = 0.10
#: Steps (m) at which the open hand is tested along the approach; the finger boxes are at least 21 mm deep.
APPROACH_STEP = 0.01


def points_outside(hand: Hand, poses: np.ndarray, openings: np.ndarray, points: np.ndarray,
                   closed: bool = False) -> np.ndarray:
    """True per pose where no point lies inside a finger, the palm or the wrist of `hand` opened to `openings`
    (vectorised over chunks of poses); `closed` tests only the finger boxes behind the pads (the pads themselves
    close on the object)."""
    free = np.ones(len(poses), dtype=bool)
    points32 = np.asarray(points, dtype=np.float32)
    for start in range(0, len(poses), COLLISION_CHUNK):
        chunk = np.asarray(poses[start : start + COLLISION_CHUNK], dtype=np.float32)
        half = (0.5 * np.asarray(openings[start : start + COLLISION_CHUNK])).astype(np.float32)[:, None]
        rotations = chunk[:, :3, :3]
        # points in each gripper frame: R^T (x - t)  ->  (G, M, 3)
        local = np.matmul(points32[None], rotations) - np.matmul(chunk[:, None, :3, 3], rotations)
        ax, ay, z = np.abs(local[..., 0]), np.abs(local[..., 1]), local[..., 2]
        hit = np.zeros(ax.shape, dtype=bool)
        for inner, outer, half_y, z_min, z_max in hand.finger_boxes[1 if closed else 0 :]:  # mirrored: test |x|
            hit |= (ax >= half + inner) & (ax <= half + outer) & (ay <= half_y) & (z >= z_min) & (z <= z_max)
        for half_x, half_y, z_min, z_max in () if closed else hand.centre_boxes:
            hit |= (ax <= half_x) & (ay <= half_y) & (z >= z_min) & (z <= z_max)
        free[start : start + COLLISION_CHUNK] = ~hit.any(axis=1)
    return free


def collision_free(hand: Hand, poses: np.ndarray, openings: np.ndarray, points: np.ndarray,
                   closed: bool = False) -> np.ndarray:
    """`points_outside`, with a sparse subset of the points rejecting most colliding poses cheaply first."""
    free = points_outside(hand, poses, openings, points[::COARSE_STRIDE], closed)
    free[free] = points_outside(hand, poses[free], openings[free], points, closed)
    return free


def clear_of(hand: Hand, T_grasp: np.ndarray, width: float, points: np.ndarray) -> bool:
    """Whether a grasp (pose, contact distance) keeps `hand` clear of `points` (same frame): open at the pre-grasp
    opening from `APPROACH_CHECKED` back along its approach to the grasp, and its fingers closed on `width`."""
    if len(points) == 0:
        return True
    T_grasp = np.asarray(T_grasp, dtype=np.float64)
    back = np.arange(0.0, APPROACH_CHECKED + 1e-9, APPROACH_STEP)
    poses = np.repeat(T_grasp[None], len(back), axis=0)
    poses[:, :3, 3] -= back[:, None] * T_grasp[:3, 2]
    opening = np.full(len(back), float(hand.pre_grasp_opening(width)))
    if not collision_free(hand, poses, opening, points).all():
        return False
    return bool(collision_free(hand, T_grasp[None], np.array([float(width)]), points, closed=True)[0])
