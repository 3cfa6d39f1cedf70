"""`KinematicArm`: a UR5 without physics for the emulated controller (an `ArmModel`).

The RTDE base frame is the UR5's DH base frame, so the flange pose is `sim.robot.dh_forward(q)` and inverse
kinematics is `sim.robot.ur_analytic_ik`, each solution shifted by 2 pi per joint to lie nearest the reference
configuration and inside the joint limits. moveJ follows a trapezoidal profile of the leading joint (speed in rad/s,
acceleration in rad/s^2) with all joints synchronised; moveL a trapezoidal profile along the straight tool path
(m/s, m/s^2; a pure rotation uses its angle in rad), its joints interpolated between IK waypoints computed as the
tool reaches them. A stop decelerates along the current path at the given rate (in that motion's units). A
waypoint without an IK solution, or whose nearest solution is another branch (a joint turning more than
`MAX_WAYPOINT_TURN` between waypoints: the path reached a singularity), halts the arm in a protective stop, as a
real arm does at a singularity, instead of swinging it round to the other branch. Safety
planes (`n . p >= offset` for the TCP position) and the joint limits make the controller's safety limits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.lab.controller import HOME_Q_WIRE
from sim.robot import dh_forward, ur_analytic_ik

#: The controller's default joint limits (rad): every UR5 joint turns +-360 degrees.
JOINT_LIMIT = 2 * np.pi
#: Tool path length between moveL waypoints whose joints are solved exactly (m).
WAYPOINT_SPACING = 0.01
#: Most a joint may turn (rad) between two moveL waypoints; more is a jump to another IK branch at a singularity
#: (an elbow stretching straight, a wrist aligning), which a real arm cannot follow either.
MAX_WAYPOINT_TURN = 0.5
#: How close the analytic IK's flange pose (4x4 entries: m and rotation-matrix units) must land on the requested
#: one to count as a solution.
IK_TOLERANCE = 1e-6


def rotation_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """Rotation vector -> 3x3 (Rodrigues)."""
    x, y, z = (float(v) for v in rotvec)
    angle = math.sqrt(x * x + y * y + z * z)
    if angle < 1e-12:
        return np.eye(3)
    x, y, z = x / angle, y / angle, z / angle
    c, s, t = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return np.array([[c + t * x * x, t * x * y - s * z, t * x * z + s * y],
                     [t * x * y + s * z, c + t * y * y, t * y * z - s * x],
                     [t * x * z - s * y, t * y * z + s * x, c + t * z * z]])


def rotvec_from_rotation(R: np.ndarray) -> list[float]:
    """3x3 -> rotation vector (angle in [0, pi]); exact near pi too, where a gripper pointing down lives."""
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R.tolist()
    w = (0.5 * (r21 - r12), 0.5 * (r02 - r20), 0.5 * (r10 - r01))  # sin(angle) * axis
    angle = math.atan2(math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]), 0.5 * (r00 + r11 + r22 - 1.0))
    if angle < 1e-12:
        return [0.0, 0.0, 0.0]
    if angle < math.pi / 2:
        scale = angle / math.sin(angle)
        return [scale * w[0], scale * w[1], scale * w[2]]
    # (R + R^T) / 2 = cos I + (1 - cos) a a^T: the axis from the column with the largest diagonal, signed by w
    cos = math.cos(angle)
    symmetric = [[r00, 0.5 * (r01 + r10), 0.5 * (r02 + r20)], [0.5 * (r01 + r10), r11, 0.5 * (r12 + r21)],
                 [0.5 * (r02 + r20), 0.5 * (r12 + r21), r22]]
    k = max(range(3), key=lambda i: symmetric[i][i])
    column = [symmetric[i][k] - (cos if i == k else 0.0) for i in range(3)]
    norm = math.sqrt(sum(v * v for v in column))
    axis = [v / norm for v in column]
    if sum(a * b for a, b in zip(axis, w)) < 0:
        axis = [-v for v in axis]
    return [angle * v for v in axis]


def pose_matrix(pose: list[float] | np.ndarray) -> np.ndarray:
    """UR pose vector [x, y, z, rx, ry, rz] -> 4x4."""
    pose = np.asarray(pose, dtype=np.float64)
    T = np.eye(4)
    T[:3, :3] = rotation_from_rotvec(pose[3:])
    T[:3, 3] = pose[:3]
    return T


def pose_vector(T: np.ndarray) -> list[float]:
    """4x4 -> UR pose vector."""
    return [*map(float, T[:3, 3]), *rotvec_from_rotation(T[:3, :3])]


@dataclass
class Trapezoid:
    """A rest-to-rest trapezoidal (or triangular) profile over `distance` with peak `speed` and `acceleration`."""

    distance: float
    speed: float
    acceleration: float

    def __post_init__(self) -> None:
        self.ramp = self.speed / self.acceleration
        if self.distance < self.speed * self.ramp:  # never reaches full speed
            self.ramp = math.sqrt(self.distance / self.acceleration)
            self.speed = self.acceleration * self.ramp
        self.duration = 2 * self.ramp + (self.distance - self.speed * self.ramp) / self.speed if self.speed else 0.0

    def at(self, t: float) -> tuple[float, float]:
        """(position, velocity) along the profile at time `t`."""
        a, ramp, total = self.acceleration, self.ramp, self.duration
        if t <= 0:
            return 0.0, 0.0
        if t >= total:
            return self.distance, 0.0
        if t < ramp:
            return 0.5 * a * t * t, a * t
        if t < total - ramp:
            return 0.5 * a * ramp * ramp + self.speed * (t - ramp), self.speed
        left = total - t
        return self.distance - 0.5 * a * left * left, a * left


class _Motion:
    """A path parametrised by its length s, run along a profile; a stop replaces the profile by a deceleration."""

    def __init__(self, length: float, speed: float, acceleration: float) -> None:
        self.length = length
        self.profile = Trapezoid(length, speed, acceleration)
        self.t = 0.0
        self.s = 0.0
        self.sdot = 0.0
        self._stop: tuple[float, float, float] | None = None  # (s, sdot, deceleration) when the stop began
        self._stop_t = 0.0

    def advance(self, dt: float) -> None:
        self.t += dt
        if self._stop is None:
            self.s, self.sdot = self.profile.at(self.t)
            return
        s0, v0, deceleration = self._stop
        tau = min(self.t - self._stop_t, v0 / deceleration)
        self.s = min(self.length, s0 + v0 * tau - 0.5 * deceleration * tau * tau)
        self.sdot = max(0.0, v0 - deceleration * tau)

    def stop(self, deceleration: float) -> None:
        if self._stop is not None and self._stop[2] >= deceleration:
            return
        self._stop, self._stop_t = (self.s, self.sdot, deceleration), self.t

    @property
    def done(self) -> bool:
        return self.s >= self.length - 1e-12 or (self._stop is not None and self.sdot <= 0.0)


class KinematicArm:
    """A UR5 that follows moveJ/moveL/stop exactly, in real time, in the RTDE base frame (an `ArmModel`)."""

    def __init__(self, q: list[float] | np.ndarray = HOME_Q_WIRE, joint_lower: float | np.ndarray = -JOINT_LIMIT,
                 joint_upper: float | np.ndarray = JOINT_LIMIT,
                 planes: tuple[tuple[tuple[float, float, float], float], ...] = ()) -> None:
        self.q = np.asarray(q, dtype=np.float64).copy()
        self.qd = np.zeros(6)
        self.joint_lower = np.broadcast_to(np.asarray(joint_lower, dtype=np.float64), (6,))
        self.joint_upper = np.broadcast_to(np.asarray(joint_upper, dtype=np.float64), (6,))
        self.planes = [(np.asarray(n, dtype=np.float64), float(offset)) for n, offset in planes]
        self.safety_status = "normal"
        self._tcp = np.eye(4)
        self._motion: _Motion | None = None
        self._joint_path: tuple[np.ndarray, np.ndarray] | None = None  # (start q, unit direction) of a moveJ
        self._line: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float] | None = None
        self._waypoints: list[tuple[float, np.ndarray]] = []
        self._pose = dh_forward(self.q) @ self._tcp
        self._pose_vector: list[float] | None = None

    # ------------------------------------------------------------------------------------------------- state
    def actual_q(self) -> list[float]:
        return self.q.tolist()

    def actual_qd(self) -> list[float]:
        return self.qd.tolist()

    def actual_tcp_pose(self) -> list[float]:
        if self._pose_vector is None:
            self._pose_vector = pose_vector(self._pose)
        return self._pose_vector

    def is_moving(self) -> bool:
        return self._motion is not None

    def set_tcp(self, pose: list[float]) -> None:
        self._tcp = pose_matrix(pose)
        self._set_pose(dh_forward(self.q) @ self._tcp)

    def _set_pose(self, T: np.ndarray) -> None:
        self._pose, self._pose_vector = T, None
        self._pose_vector: list[float] | None = None

    # ----------------------------------------------------------------------------------------------- motions
    def move_joints(self, q: list[float], speed: float, acceleration: float) -> None:
        if self.safety_status != "normal":
            return
        target = np.asarray(q, dtype=np.float64)
        delta = target - self.q
        distance = float(np.abs(delta).max())
        self._line = None
        if distance < 1e-9:
            self._motion = None
            return
        self._joint_path = (self.q.copy(), delta / distance)
        self._motion = _Motion(distance, speed, acceleration)

    def move_linear(self, pose: list[float], speed: float, acceleration: float) -> None:
        if self.safety_status != "normal":
            return
        start, target = self._pose, pose_matrix(pose)
        offset = target[:3, 3] - start[:3, 3]
        rotation = np.array(rotvec_from_rotation(start[:3, :3].T @ target[:3, :3]))
        length = float(np.linalg.norm(offset)) or float(np.linalg.norm(rotation))
        self._joint_path = None
        if length < 1e-9:
            self._motion = None
            return
        self._line = (start[:3, 3].copy(), offset, start[:3, :3].copy(), rotation, length)
        self._waypoints = [(0.0, self.q.copy())]
        self._motion = _Motion(length, speed, acceleration)

    def stop(self, deceleration: float) -> None:
        if self._motion is not None:
            self._motion.stop(deceleration)

    def step(self, dt: float) -> None:
        motion = self._motion
        if motion is None:
            return
        if self.safety_status != "normal":
            motion.stop(max(motion.profile.acceleration, 10.0))
        motion.advance(dt)
        if self._joint_path is not None:
            start, direction = self._joint_path
            self.q = start + direction * motion.s
            self.qd = direction * motion.sdot
            self._set_pose(dh_forward(self.q) @ self._tcp)
        else:
            previous = self.q
            if not self._follow_line(motion.s):
                self._halt_protective()
                return
            self.qd = (self.q - previous) / dt if dt > 0 else np.zeros(6)
        if motion.done:
            self._motion = None
            self.qd = np.zeros(6)

    def _follow_line(self, s: float) -> bool:
        """Put the TCP on the line at path length `s` and the joints between the waypoints around it."""
        length = self._line[4]  # type: ignore[index]
        while self._waypoints[-1][0] < s:
            s_next = min(length, self._waypoints[-1][0] + WAYPOINT_SPACING)
            q = self.inverse_kinematics(pose_vector(self._line_pose(s_next)), self._waypoints[-1][1].tolist())
            if q is None or np.abs(np.asarray(q) - self._waypoints[-1][1]).max() > MAX_WAYPOINT_TURN:
                return False
            self._waypoints.append((s_next, np.asarray(q)))
        for (s0, q0), (s1, q1) in zip(self._waypoints[:-1], self._waypoints[1:]):
            if s0 <= s <= s1:
                u = (s - s0) / (s1 - s0) if s1 > s0 else 1.0
                self.q = q0 + u * (q1 - q0)
                break
        self._waypoints = [w for w in self._waypoints if w[0] >= s - WAYPOINT_SPACING]
        self._set_pose(self._line_pose(s))
        return True

    def _line_pose(self, s: float) -> np.ndarray:
        origin, offset, rotation, turn, length = self._line  # type: ignore[misc]
        u = s / length
        T = np.eye(4)
        T[:3, :3] = rotation @ rotation_from_rotvec(u * turn)
        T[:3, 3] = origin + u * offset
        return T

    def _halt_protective(self) -> None:
        self.safety_status = "protective_stop"
        self._motion = None
        self.qd = np.zeros(6)

    # ------------------------------------------------------------------------------------------------ limits
    def joints_within_limits(self, q: list[float]) -> bool:
        q = np.asarray(q, dtype=np.float64)
        return bool(q.shape == (6,) and np.all(np.isfinite(q)) and np.all(q >= self.joint_lower)
                    and np.all(q <= self.joint_upper))

    def pose_within_limits(self, pose: list[float]) -> bool:
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (6,) or not np.all(np.isfinite(pose)):
            return False
        if any(float(normal @ pose[:3]) < offset for normal, offset in self.planes):
            return False
        return self.ik_has_solution(pose.tolist(), None)

    def ik_has_solution(self, pose: list[float], qnear: list[float] | None) -> bool:
        return self.inverse_kinematics(pose, qnear) is not None

    def inverse_kinematics(self, pose: list[float], qnear: list[float] | None) -> list[float] | None:
        """The joint solution nearest `qnear` (default: the current joints) inside the joint limits, or None."""
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (6,) or not np.all(np.isfinite(pose)):
            return None
        reference = self.q if qnear is None or len(qnear) != 6 else np.asarray(qnear, dtype=np.float64)
        flange = pose_matrix(pose) @ np.linalg.inv(self._tcp)
        best, best_distance = None, math.inf
        for solution in ur_analytic_ik(flange):
            q = solution + 2 * np.pi * np.round((reference - solution) / (2 * np.pi))
            q = np.where(q > self.joint_upper, q - 2 * np.pi, np.where(q < self.joint_lower, q + 2 * np.pi, q))
            distance = float(np.abs(q - reference).sum())
            if distance < best_distance and self.joints_within_limits(q) and \
                    np.abs(dh_forward(q) - flange).max() < IK_TOLERANCE:
                best, best_distance = q, distance
        return None if best is None else best.tolist()
