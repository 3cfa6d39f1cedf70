"""Safety checks run BEFORE any command leaves the computer: workspace box, table clearance, speed and force caps.

`SafetyGuard` raises `SafetyError` with a message that says which limit a request breaks. The arm and the gripper
call it for every command; in dry-run mode the same checks run and the command is only logged.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from hardware.config import Limits
from hardware.errors import SafetyError

__all__ = ["SafetyError", "SafetyGuard"]

log = logging.getLogger(__name__)


class SafetyGuard:
    """Checks poses, paths, speeds and forces against the cell's `Limits`.

    A pose is checked at four points: the gripper origin (pad centres), both fingertips (`tip_beyond_origin` past
    the pads along +z, half the finger opening out along x), and the flange (`flange_in_gripper`). Each must lie
    inside the workspace box and `min_table_clearance` above the table. The fingertips are placed at the given
    finger opening, or at the full stroke (`2 * finger_reach`, the worst case: a plan for a whole sequence) when
    none is given. The arm checks each motion at `finger_opening`, which the gripper keeps current (the commanded
    opening; the wider of the old and new one while the fingers move; the full stroke until known), and
    `tool_pose` is the last pose the arm was sent to, so opening the fingers there can be checked.
    """

    def __init__(self, limits: Limits, *, finger_reach: float, tip_beyond_origin: float,
                 flange_in_gripper: np.ndarray) -> None:
        self.limits = limits
        self.stroke = 2.0 * float(finger_reach)
        self.finger_opening = self.stroke
        self.tip_beyond_origin = float(tip_beyond_origin)
        self.flange_in_gripper = np.asarray(flange_in_gripper, dtype=np.float64).reshape(3)
        self.tool_pose: np.ndarray | None = None

    def tool_points(self, T_world_gripper: np.ndarray, opening: float | None = None) -> dict[str, np.ndarray]:
        """World positions of the gripper origin, both fingertips (at `opening`, default the full stroke) and the
        flange, for a gripper pose."""
        T = np.asarray(T_world_gripper, dtype=np.float64)
        R, origin = T[:3, :3], T[:3, 3]
        half = 0.5 * float(np.clip(self.stroke if opening is None else opening, 0.0, self.stroke))
        tip = origin + self.tip_beyond_origin * R[:, 2]
        return {"gripper origin": origin, "fingertip +x": tip + half * R[:, 0], "fingertip -x": tip - half * R[:, 0],
                "flange": origin + R @ self.flange_in_gripper}

    def check_pose(self, T_world_gripper: np.ndarray, what: str = "target", opening: float | None = None) -> None:
        """Refuse a gripper pose whose origin, fingertips (at `opening`, default the full stroke) or flange leave
        the workspace or come near the table."""
        T = np.asarray(T_world_gripper, dtype=np.float64)
        if T.shape != (4, 4) or not np.all(np.isfinite(T)):
            raise SafetyError(f"{what}: pose must be a finite 4x4 matrix, got shape {T.shape}")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0.999:
            raise SafetyError(f"{what}: rotation part is not a proper rotation matrix")
        points = self.tool_points(T, opening)
        floor = self.limits.table_height + self.limits.min_table_clearance
        for name, point in points.items():
            if point[2] < floor:
                raise SafetyError(
                    f"{what}: {name} would be at z = {point[2]:.3f} m, below the table clearance limit "
                    f"{floor:.3f} m (table {self.limits.table_height:.3f} m + "
                    f"{self.limits.min_table_clearance:.3f} m)"
                )
        low, high = self.limits.workspace_min, self.limits.workspace_max
        for name, point in points.items():
            for axis, axis_name in enumerate("xyz"):
                if not low[axis] - 1e-9 <= point[axis] <= high[axis] + 1e-9:
                    raise SafetyError(
                        f"{what}: {name} {axis_name} = {point[axis]:.3f} m is outside the workspace "
                        f"[{low[axis]:.3f}, {high[axis]:.3f}] (position {np.round(point, 3).tolist()})"
                    )

    def check_opening(self, width: float, what: str = "opening the gripper") -> None:
        """Refuse opening the fingers to `width` where the tips would leave the limits at the current tool pose."""
        if self.tool_pose is not None and width > self.finger_opening:
            self.check_pose(self.tool_pose, what, opening=width)

    def check_linear_path(self, T_start: np.ndarray, T_goal: np.ndarray, what: str = "linear move",
                          samples: int = 11, opening: float | None = None) -> None:
        """Check poses along a straight tool path (position lerp, orientation slerp) like the UR's moveL."""
        T_start, T_goal = np.asarray(T_start, float), np.asarray(T_goal, float)
        self.check_pose(T_goal, f"{what} (goal)", opening)
        rotations = Rotation.from_matrix(np.stack([T_start[:3, :3], T_goal[:3, :3]]))
        slerp = Slerp([0.0, 1.0], rotations)
        for s in np.linspace(0.0, 1.0, samples)[1:-1]:
            T = np.eye(4)
            T[:3, :3] = slerp([s]).as_matrix()[0]
            T[:3, 3] = (1 - s) * T_start[:3, 3] + s * T_goal[:3, 3]
            self.check_pose(T, f"{what} (at {s:.0%} of the path)", opening)

    def check_tool_motion(self, speed: float, acceleration: float) -> None:
        """Refuse a Cartesian speed or acceleration above the caps (or not positive)."""
        self._check_cap("tool speed", speed, self.limits.max_tool_speed, "m/s")
        self._check_cap("tool acceleration", acceleration, self.limits.max_tool_acceleration, "m/s^2")

    def check_joint_motion(self, speed: float, acceleration: float) -> None:
        """Refuse a joint speed or acceleration above the caps (or not positive)."""
        self._check_cap("joint speed", speed, self.limits.max_joint_speed, "rad/s")
        self._check_cap("joint acceleration", acceleration, self.limits.max_joint_acceleration, "rad/s^2")

    def check_grip_force(self, force: float) -> None:
        """Refuse a grip force above the cap (or not positive)."""
        self._check_cap("grip force", force, self.limits.max_grip_force, "N")

    @staticmethod
    def _check_cap(name: str, value: float, cap: float, unit: str) -> None:
        if not np.isfinite(value) or value <= 0:
            raise SafetyError(f"{name} must be a positive finite number, got {value!r}")
        if value > cap:
            raise SafetyError(f"{name} {value:g} {unit} exceeds the limit {cap:g} {unit}")
