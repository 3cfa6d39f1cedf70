"""The twin behind the emulated lab cell: `SimCell`'s PyBullet scene, its UR5 as the controller's `ArmModel`
(`TwinArm`) and its 2F-85 as the URCap's `FingerModel` (`TwinFingers`), stepped in real time by a clock thread,
with the control-channel commands `place` and `truth`.

Frames. ur_rtde speaks the controller's base frame (the UR's DH base); the URDF's `base_link` is that frame turned
by pi about z (`sim.robot.T_BASELINK_DHBASE`). After every placement the twin's UR5 body is turned so that its
`base_link` sits at `T_WORLD_BASELINK` = T_DHBASE_BASELINK in the PyBullet world, which makes the world the RTDE
base frame: the wire's joints are PyBullet's, home has q0 = pi (`HOME_Q_WIRE`, the moving links exactly where
SimCell's `HOME_Q` puts them), and the table, the object and the cameras keep SimCell's numbers. A placement is
`SimCell.reset(seed, object_id)` itself, so the wire and the twin backend see the same scene for a seed.

Motion. moveJ is linear in joint space and moveL a straight line of the TCP (joint waypoints every
`sim.world.PATH_RESOLUTION`, as the twin's grasp primitive), both timed by a trapezoidal profile of the path
parameter (leading joint in rad, or TCP path in m; a pure rotation in rad) and tracked by the UR5's joint servos
(`UR5Arm._command`). A stop decelerates along the same path. The arm halts in a protective stop when a link of
the arm (upper arm to wrist) touches the table, or when the net force of table and object on the robot stays above
`PROTECTIVE_FORCE` for `PROTECTIVE_STEPS` physics steps (the fingers' own squeeze cancels in that sum).

Fingers. A request closing the fingers uses the twin's closing drive (`Robotiq2F85.command_close` at the
requested speed and force, then its squeeze once both slides stall, as `close_until_stall`); an opening request
drives the slides open at the requested speed. OBJ follows from the stall (2 closing, 1 opening) or the request
being reached (3); POS is the pad gap on the registers' linear scale.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Protocol, Sequence

import numpy as np
import pybullet
from scipy.spatial.transform import Rotation

from seggrasp.cell import FINGER_SPEED_RANGE, GRIP_FORCE_RANGE
from sim.cell import SimCell
from sim.gripper import Robotiq2F85
from sim.robot import HOME_Q, T_BASELINK_DHBASE, UR5Arm, dh_forward, pose_error, ur_analytic_ik
from sim.world import PATH_RESOLUTION, TABLE_TOP_Z, pose_to_pb

log = logging.getLogger(__name__)

#: Where the twin's URDF `base_link` sits in its world, the RTDE base frame (module docstring).
T_WORLD_BASELINK = np.linalg.inv(T_BASELINK_DHBASE)
#: The twin's home on the wire: SimCell's home with the base joint turned by pi.
HOME_Q_WIRE = HOME_Q + np.array([np.pi, 0.0, 0.0, 0.0, 0.0, 0.0])
#: Net force (N) of table and object on the robot above which the emulated controller stops the arm: the tool
#: force limit of the emulated safety configuration.
PROTECTIVE_FORCE = 150.0
#: Physics steps in a row the force must stay above the limit (one step's solver spike does not stop the arm).
PROTECTIVE_STEPS = 3
#: A motion has ended once every joint is this close (rad) to its target and slower than `SETTLED_SPEED` (rad/s),
#: or `SETTLE_TIME` (s) after its profile ended.
SETTLED_ERROR = 1e-3
SETTLED_SPEED = 0.01
SETTLE_TIME = 1.0
#: Accuracy (m, rad) an inverse-kinematics solution must reach, as the controller's own solver does.
IK_POSITION_ERROR = 1e-5
IK_ANGLE_ERROR = 1e-4
#: Largest joint step (rad) between neighbouring moveL waypoints (a larger one: the line crosses a singularity).
MAX_WAYPOINT_JUMP = 0.25
#: Largest turn (rad) between neighbouring moveL waypoints.
ROTATION_RESOLUTION = np.deg2rad(2.0)
#: A moveL of less translation than this (m) is a pure rotation: its speed and acceleration are rad/s, rad/s^2.
ROTATION_ONLY = 1e-4
#: The URCap's position registers of an activated 2F-85 fully open and closed on nothing, spanning the pad gap
#: linearly (the real gripper reads about these after activation).
OPEN_REGISTER, CLOSED_REGISTER = 3, 228
#: OBJ codes of the URCap: moving, stopped on an object while opening / closing, at the request.
OBJ_MOVING, OBJ_STOPPED_OPENING, OBJ_STOPPED_CLOSING, OBJ_AT_REQUEST = 0, 1, 2, 3
#: A slide this close (m) to its stroke's end is shut (as `Robotiq2F85.close_until_stall`).
SHUT_MARGIN = 0.0005
#: Steps a finger motion runs before its stall is judged (as `Robotiq2F85.close_until_stall`).
STALL_WARMUP = 10
#: The clock drops its backlog (and counts it as lag) when it falls this far (s) behind the wall clock.
MAX_BACKLOG = 0.25


def pose_vector(T: np.ndarray) -> list[float]:
    """4x4 pose -> UR pose vector [x, y, z, rx, ry, rz] (rotation vector)."""
    return [*map(float, T[:3, 3]), *map(float, Rotation.from_matrix(T[:3, :3]).as_rotvec())]


def pose_matrix(pose: Sequence[float]) -> np.ndarray:
    """UR pose vector -> 4x4 pose; ValueError unless it is six finite numbers."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (6,) or not np.all(np.isfinite(pose)):
        raise ValueError(f"a pose is six finite numbers [x, y, z, rx, ry, rz], got {np.asarray(pose).tolist()}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(pose[3:]).as_matrix()
    T[:3, 3] = pose[:3]
    return T


# --- motion profiles --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Profile:
    """The path parameter over time: from (`start`, `speed0`) through segments of constant acceleration
    (duration s, acceleration), clipped to [0, `end`]."""

    start: float
    speed0: float
    segments: tuple[tuple[float, float], ...]
    end: float

    @property
    def duration(self) -> float:
        return float(sum(duration for duration, _ in self.segments))

    def at(self, t: float) -> tuple[float, float]:
        """(parameter, its rate) at time `t` after the start."""
        s, v = self.start, self.speed0
        for duration, acceleration in self.segments:
            step = min(max(t, 0.0), duration)
            s += v * step + 0.5 * acceleration * step * step
            v += acceleration * step
            t -= duration
            if t <= 0:
                break
        if s >= self.end:
            return self.end, 0.0
        return max(s, 0.0), max(v, 0.0)


def trapezoid(length: float, speed: float, acceleration: float) -> Profile:
    """From rest over `length` at most `speed` fast, accelerating and braking at `acceleration`, to rest."""
    if speed <= 0 or acceleration <= 0:
        raise ValueError(f"speed and acceleration must be positive, got {speed} and {acceleration}")
    ramp = speed / acceleration
    if acceleration * ramp * ramp >= length:  # never reaches `speed`
        ramp = float(np.sqrt(length / acceleration))
        return Profile(0.0, 0.0, ((ramp, acceleration), (ramp, -acceleration)), length)
    cruise = (length - acceleration * ramp * ramp) / speed
    return Profile(0.0, 0.0, ((ramp, acceleration), (cruise, 0.0), (ramp, -acceleration)), length)


def braking(start: float, speed: float, deceleration: float, end: float) -> Profile:
    """From (`start`, `speed`) to rest at `deceleration`, never beyond `end`."""
    return Profile(start, speed, ((speed / deceleration if speed > 0 else 0.0, -deceleration),), end)


class JointPath(Protocol):
    """Joint angles along a path parameter in [0, length]."""

    length: float

    def joints(self, s: float) -> np.ndarray: ...


@dataclass(frozen=True)
class Waypoints:
    """Joint waypoints at increasing path parameters, interpolated linearly (a moveJ has two)."""

    params: np.ndarray  # (n,)
    q: np.ndarray  # (n, 6)

    @property
    def length(self) -> float:
        return float(self.params[-1])

    def joints(self, s: float) -> np.ndarray:
        return np.array([np.interp(s, self.params, self.q[:, j]) for j in range(6)])


@dataclass
class Motion:
    """A running motion: its path, its profile and when (simulated time) the profile started."""

    path: JointPath
    profile: Profile
    started: float
    stopping: bool = False


# --- the arm ----------------------------------------------------------------------------------------------------

class TwinArm:
    """The twin's UR5 behind the emulated controller (PLAN.md's ArmModel): poses in the RTDE base frame with the
    active TCP, joints in rad. Getters return the state after the last physics step without touching PyBullet."""

    def __init__(self, scene: "TwinScene") -> None:
        self.scene = scene
        self.safety_status = "normal"
        self.stop_reason = ""
        self.T_flange_tcp = np.eye(4)
        self._q = HOME_Q_WIRE.copy()
        self._qd = np.zeros(6)
        self._motion: Motion | None = None
        self._moving = False
        self._over_force = 0
        self._lower = self._upper = None

    # --- state (cached) ---
    def step(self, dt: float) -> None:
        """Advance the physics by `dt` when no clock thread runs (tests); the clock steps it otherwise."""
        if not self.scene.clock_running:
            self.scene.advance(dt)

    def actual_q(self) -> list[float]:
        return [float(v) for v in self._q]

    def actual_qd(self) -> list[float]:
        return [float(v) for v in self._qd]

    def actual_tcp_pose(self) -> list[float]:
        return pose_vector(dh_forward(self._q) @ self.T_flange_tcp)

    def is_moving(self) -> bool:
        return self._moving

    def set_tcp(self, pose: Sequence[float]) -> None:
        self.T_flange_tcp = pose_matrix(pose)

    # --- queries ---
    def joints_within_limits(self, q: Sequence[float]) -> bool:
        q = np.asarray(q, dtype=np.float64)
        lower, upper = self.scene.joint_limits
        return bool(q.shape == (6,) and np.all(np.isfinite(q)) and np.all(q >= lower) and np.all(q <= upper))

    def inverse_kinematics(self, pose: Sequence[float], qnear: Sequence[float] | None = None) -> list[float] | None:
        """The joint solution nearest `qnear` (default: the current joints) that reaches `pose` with the active TCP
        within the joint limits, or None."""
        near = self._q if qnear is None or len(qnear) == 0 else np.asarray(qnear, dtype=np.float64)
        q = self._solve(pose_matrix(pose), near)
        return None if q is None else [float(v) for v in q]

    def ik_has_solution(self, pose: Sequence[float], qnear: Sequence[float] | None = None) -> bool:
        return self.inverse_kinematics(pose, qnear) is not None

    def pose_within_limits(self, pose: Sequence[float]) -> bool:
        """Reachable (inverse kinematics within the joint limits), with the TCP and the flange above the table
        plane: the emulated controller's one safety plane."""
        T = pose_matrix(pose)
        flange = T @ np.linalg.inv(self.T_flange_tcp)
        return bool(T[2, 3] >= TABLE_TOP_Z and flange[2, 3] >= TABLE_TOP_Z and self._solve(T, self._q) is not None)

    def _solve(self, T_world_tcp: np.ndarray, near: np.ndarray) -> np.ndarray | None:
        T_flange = T_world_tcp @ np.linalg.inv(self.T_flange_tcp)
        lower, upper = self.scene.joint_limits
        best, best_distance = None, np.inf
        for q in ur_analytic_ik(T_flange):
            q = near + (q - near + np.pi) % (2 * np.pi) - np.pi  # the 2 pi turn of each joint nearest `near`
            if np.any(q < lower) or np.any(q > upper):
                continue
            position, angle = pose_error(dh_forward(q), T_flange)
            distance = float(np.linalg.norm(q - near))
            if position <= IK_POSITION_ERROR and angle <= IK_ANGLE_ERROR and distance < best_distance:
                best, best_distance = q, distance
        return best

    # --- commands ---
    def move_joints(self, q: Sequence[float], speed: float, acceleration: float) -> None:
        """Start a moveJ (leading joint at `speed` rad/s, `acceleration` rad/s^2); ValueError for joints outside
        the limits (nothing moves)."""
        target = np.asarray(q, dtype=np.float64)
        if not self.joints_within_limits(target):
            raise ValueError(f"moveJ target {np.round(target, 4).tolist()} is outside the joint limits")
        start = self._q.copy()
        length = float(np.abs(target - start).max())
        self._start(Waypoints(np.array([0.0, max(length, 1e-9)]), np.stack([start, target])), length, speed,
                    acceleration)

    def move_linear(self, pose: Sequence[float], speed: float, acceleration: float) -> None:
        """Start a moveL of the TCP to `pose` (`speed` m/s, `acceleration` m/s^2; rad/s, rad/s^2 for a pure
        rotation); ValueError when a waypoint of the line has no inverse kinematics or the arm would flip between
        neighbouring waypoints (nothing moves)."""
        target = pose_matrix(pose)
        start_q = self._q.copy()
        start = dh_forward(start_q) @ self.T_flange_tcp
        translation = float(np.linalg.norm(target[:3, 3] - start[:3, 3]))
        rotation = pose_error(start, target)[1]
        length = rotation if translation < ROTATION_ONLY else translation
        poses = line_poses(start, target)
        qs, q = [start_q], start_q
        for index, T in enumerate(poses[1:], start=1):
            q_next = self._solve(T, q)
            if q_next is None:
                raise ValueError(f"moveL: no inverse kinematics at {index / (len(poses) - 1):.0%} of the line")
            if np.abs(q_next - q).max() > MAX_WAYPOINT_JUMP:
                raise ValueError(f"moveL: the arm would flip at {index / (len(poses) - 1):.0%} of the line "
                                 "(a singularity on the way)")
            qs.append(q_next)
            q = q_next
        params = np.linspace(0.0, max(length, 1e-9), len(qs))
        self._start(Waypoints(params, np.stack(qs)), length, speed, acceleration)

    def _start(self, path: Waypoints, length: float, speed: float, acceleration: float) -> None:
        if self.safety_status != "normal":
            raise ValueError(f"the arm is in {self.safety_status.replace('_', ' ')}: no motion is started")
        profile = trapezoid(max(length, 1e-9), speed, acceleration)
        with self.scene.lock:
            self._motion = Motion(path, profile, self.scene.sim_time)
            self._moving = True

    def stop(self, deceleration: float) -> None:
        """Decelerate the running motion to rest along its path (stopL / stopJ)."""
        if deceleration <= 0:
            raise ValueError(f"deceleration must be positive, got {deceleration}")
        with self.scene.lock:
            motion = self._motion
            if motion is None:
                return
            s, v = motion.profile.at(self.scene.sim_time - motion.started)
            self._motion = Motion(motion.path, braking(s, v, deceleration, motion.path.length), self.scene.sim_time,
                                  stopping=True)

    # --- per physics step (the scene's lock is held) ---
    def reload(self, robot: UR5Arm) -> None:
        """After a placement rebuilt the robot: turn its base into the RTDE frame and put the arm back where it
        was, at rest."""
        c = robot.world.client
        position, orientation = pose_to_pb(T_WORLD_BASELINK)
        c.resetBasePositionAndOrientation(robot.body, position, orientation)
        robot.place(self._q)
        self._motion, self._moving, self._qd = None, False, np.zeros(6)

    def before_step(self, robot: UR5Arm, now: float) -> None:
        """Command the joint servos for the physics step ending at `now`."""
        motion = self._motion
        if motion is None:
            return
        if self.safety_status != "normal":
            self._halt(robot)
            return
        s, v = motion.profile.at(now - motion.started)
        q = motion.path.joints(s)
        ahead = motion.path.joints(min(s + 1e-4, motion.path.length))
        rate = (ahead - q) / 1e-4 * v if s < motion.path.length else np.zeros(6)
        robot._command(q, rate)  # the UR5's joint servos, as the twin's own motions use them

    def after_step(self, robot: UR5Arm, now: float, table: int, obj: int) -> None:
        """Read the joints, end a motion that has settled, and watch for a protective stop."""
        c = robot.world.client
        states = c.getJointStates(robot.body, robot.arm_joints)
        self._q = np.array([s[0] for s in states])
        self._qd = np.array([s[1] for s in states])
        motion = self._motion
        if motion is not None:
            elapsed = now - motion.started
            if elapsed >= motion.profile.duration:
                target = motion.path.joints(motion.profile.at(elapsed)[0])
                settled = np.abs(self._q - target).max() < SETTLED_ERROR and np.abs(self._qd).max() < SETTLED_SPEED
                if settled or elapsed > motion.profile.duration + SETTLE_TIME:
                    self._motion, self._moving = None, False
        if self.safety_status == "normal":
            reason = self._collision(robot, table, obj)
            if reason:
                self.safety_status, self.stop_reason = "protective_stop", reason
                log.warning("protective stop: %s", reason)
                self._halt(robot)

    def _collision(self, robot: UR5Arm, table: int, obj: int) -> str:
        c = robot.world.client
        arm_links = set(range(robot.arm_joints[1], robot.gripper.base_link))  # upper arm to wrist 3
        force = np.zeros(3)
        for other in (table, obj):
            for point in c.getContactPoints(bodyA=robot.body, bodyB=other):
                if other == table and point[3] in arm_links:
                    name = c.getJointInfo(robot.body, point[3])[12].decode()
                    return f"arm-table collision ({name} touches the table)"
                # force on the robot: normal (on B, towards A) and both friction directions
                force += point[9] * np.asarray(point[7]) + point[10] * np.asarray(point[11]) \
                    + point[12] * np.asarray(point[13])
        magnitude = float(np.linalg.norm(force))
        self._over_force = self._over_force + 1 if magnitude > PROTECTIVE_FORCE else 0
        if self._over_force >= PROTECTIVE_STEPS:
            self._over_force = 0
            return f"force {magnitude:.0f} N on the tool above the {PROTECTIVE_FORCE:.0f} N limit"
        return ""

    def _halt(self, robot: UR5Arm) -> None:
        """Stop dead where the arm is (a stop category 1 brakes in a few ms) and end its motion."""
        robot._command(self._q, np.zeros(6))
        self._motion, self._moving = None, False


def line_poses(start: np.ndarray, target: np.ndarray) -> list[np.ndarray]:
    """Poses on the TCP's straight line from `start` to `target`, both included, at most `PATH_RESOLUTION` m and
    `ROTATION_RESOLUTION` rad apart (orientation by slerp)."""
    translation = float(np.linalg.norm(target[:3, 3] - start[:3, 3]))
    n = max(1, int(np.ceil(translation / PATH_RESOLUTION)),
            int(np.ceil(pose_error(start, target)[1] / ROTATION_RESOLUTION)))
    relative = Rotation.from_matrix(start[:3, :3].T @ target[:3, :3]).as_rotvec()
    poses = []
    for t in np.linspace(0.0, 1.0, n + 1):
        T = np.eye(4)
        T[:3, :3] = start[:3, :3] @ Rotation.from_rotvec(t * relative).as_matrix()
        T[:3, 3] = (1 - t) * start[:3, 3] + t * target[:3, 3]
        poses.append(T)
    return poses


# --- the fingers ------------------------------------------------------------------------------------------------

def speed_of_register(register: int) -> float:
    """SPE register 0-255 -> finger speed (m/s), spanning `FINGER_SPEED_RANGE` linearly."""
    low, high = FINGER_SPEED_RANGE
    return low + (high - low) * float(np.clip(register, 0, 255)) / 255.0


def force_of_register(register: int) -> float:
    """FOR register 0-255 -> grip force (N), spanning `GRIP_FORCE_RANGE` linearly."""
    low, high = GRIP_FORCE_RANGE
    return low + (high - low) * float(np.clip(register, 0, 255)) / 255.0


class TwinFingers:
    """The twin's 2F-85 behind the URCap socket (the FingerModel of sim/lab/robotiq.py): registers in, POS and OBJ
    out (module docstring). `fault` is the FLT code the server reports."""

    #: The slides must have moved on this far (m) past where they stalled for a held object to count as lost.
    LOST_TRAVEL = 0.002

    def __init__(self, scene: "TwinScene") -> None:
        self.scene = scene
        self.fault = 0
        self._request: tuple[int, int, int] | None = None
        self._position = OPEN_REGISTER
        self._object = OBJ_AT_REQUEST
        self._mode = "idle"  # "closing" | "opening" | "holding" | "idle"
        self._goal = 0.0  # slide travel of the request
        self._speed = 0.0
        self._force = 0.0
        self._history: list[tuple[float, float]] = []
        self._travel = 0.0

    def step(self, dt: float) -> None:
        """Advance the physics by `dt` when no clock thread runs (tests); the clock steps it otherwise."""
        if not self.scene.clock_running:
            self.scene.advance(dt)

    def position_register(self) -> int:
        return self._position

    def object_status(self) -> int:
        return self._object

    def request(self, position: int, speed: int, force: int) -> None:
        """Go to POS `position` at SPE `speed` with FOR `force` (registers 0-255)."""
        with self.scene.lock:
            self._request = (int(position), int(speed), int(force))
            self._begin(self.scene.gripper)

    def _begin(self, gripper: Robotiq2F85) -> None:
        position, speed, force = self._request
        span = CLOSED_REGISTER - OPEN_REGISTER
        gap = float(np.clip((CLOSED_REGISTER - position) / span, 0.0, 1.0)) * gripper.max_width
        self._goal = gripper.travel_for_width(gap)
        self._speed, self._force = speed_of_register(speed), force_of_register(force)
        gripper.settings = replace(gripper.settings, closing_speed=self._speed, grip_force=self._force)
        travel = float(np.mean(gripper.travel()))
        self._history = []
        if self._goal > travel + gripper.settings.stall_travel:
            gripper.command_close()
            self._mode, self._object = "closing", OBJ_MOVING
        elif self._goal < travel - gripper.settings.stall_travel:
            gripper.set_travel(travel)  # held by the slides' servo until the opening drive takes them
            self._mode, self._object = "opening", OBJ_MOVING
        else:
            self._mode, self._object = "idle", OBJ_AT_REQUEST

    def reload(self, gripper: Robotiq2F85) -> None:
        """After a placement rebuilt the gripper: the fingers where they were, still heading for the request
        (a held object is gone)."""
        gripper.set_travel(self._travel)
        self._mode = "idle"
        if self._request is not None:
            self._begin(gripper)
        self._read(gripper)

    def before_step(self, gripper: Robotiq2F85) -> None:
        if self._mode == "opening":
            c = gripper.world.client
            c.setJointMotorControlArray(gripper.body, list(gripper.slides), pybullet.VELOCITY_CONTROL,
                                        targetVelocities=[-self._speed] * 2, forces=[self._force] * 2)

    def after_step(self, gripper: Robotiq2F85) -> None:
        travel = gripper.travel()
        settings = gripper.settings
        if self._mode in ("closing", "opening"):
            self._history.append(travel)
            stalled = len(self._history) > max(STALL_WARMUP, settings.stall_steps) and all(
                abs(now - then) < settings.stall_travel
                for now, then in zip(self._history[-1], self._history[-1 - settings.stall_steps]))
            if self._mode == "closing":
                if min(travel) >= min(self._goal, gripper.max_travel - SHUT_MARGIN):
                    gripper.set_travel(self._goal)
                    self._mode, self._object = "idle", OBJ_AT_REQUEST
                elif stalled:
                    gripper.squeeze()
                    self._mode, self._object, self._stall = "holding", OBJ_STOPPED_CLOSING, min(travel)
            elif max(travel) <= self._goal:
                gripper.set_travel(self._goal)
                self._mode, self._object = "idle", OBJ_AT_REQUEST
            elif stalled:
                gripper.set_travel(float(np.mean(travel)))
                self._mode, self._object = "idle", OBJ_STOPPED_OPENING
        elif self._mode == "holding" and min(travel) > self._stall + self.LOST_TRAVEL:
            gripper.command_close()  # the object slipped out: the fingers carry on to the request
            self._mode, self._object, self._history = "closing", OBJ_MOVING, []
        self._read(gripper)

    def _read(self, gripper: Robotiq2F85) -> None:
        self._travel = float(np.mean(gripper.travel()))
        fraction = gripper.width() / gripper.max_width
        self._position = int(np.clip(round(CLOSED_REGISTER - fraction * (CLOSED_REGISTER - OPEN_REGISTER)), 0, 255))


# --- the scene --------------------------------------------------------------------------------------------------

class TwinScene:
    """The twin's world behind the emulated cell: one `SimCell` placed by `place(object_id, seed)`, the arm and
    fingers driven through `arm` / `fingers`, physics advanced by `advance` or by the clock thread (`start`).
    Every PyBullet call holds `lock`."""

    def __init__(self, object_id: str, seed: int, recordings: str | Path | None) -> None:
        self.lock = threading.RLock()
        self.recordings = None if recordings is None else Path(recordings)
        self.sim_time = 0.0
        self.arm = TwinArm(self)
        self.fingers = TwinFingers(self)
        self.cell: SimCell | None = None
        self.joint_limits: tuple[np.ndarray, np.ndarray] = (np.full(6, -2 * np.pi), np.full(6, 2 * np.pi))
        self._models: dict = {}
        self._placed: dict = {}
        self._clock: Clock | None = None
        self.place(object_id, seed)

    @property
    def gripper(self) -> Robotiq2F85:
        return self.cell.robot.gripper

    @property
    def clock_running(self) -> bool:
        return self._clock is not None and self._clock.is_alive()

    @property
    def time_step(self) -> float:
        return self.cell.world.physics.time_step

    def place(self, object_id: str, seed: int) -> dict:
        """Reset the scene as `SimCell.reset(seed, object_id)` does, with the arm and fingers where they are; render
        the cameras into recordings (none without a recordings folder). Returns `truth()` plus the recordings' paths by camera serial."""
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise ValueError(f"place: seed must be a non-negative integer, got {seed!r}")
        model = self._model(object_id)
        started = time.monotonic()
        with self.lock:
            cell = self._cell_with(model)
            cell.reset(seed, object_id)
            robot = cell.robot
            self.arm.reload(robot)
            self.fingers.reload(robot.gripper)
            self.joint_limits = _joint_limits(robot)
            self._placed = {"object": object_id, "seed": seed,
                            "T_world_obj": np.round(cell.object_mesh()[1], 9).tolist()}
            paths = {} if self.recordings is None else write_camera_recordings(cell.capture(), self.recordings)
            if self._clock is not None:
                self._clock.resync(time.monotonic() - started)
        return dict(self._placed, recordings=paths)

    def truth(self) -> dict:
        """The object placed last and its pose now (`T_world_obj`, RTDE base frame), with where it was placed."""
        with self.lock:
            return {"object": self._placed["object"], "seed": self._placed["seed"],
                    "T_world_obj": np.round(self.cell.object_mesh()[1], 9).tolist(),
                    "T_world_obj_placed": self._placed["T_world_obj"]}

    def lose_object(self) -> None:
        """Take the object out of the hand: it lands on the table beside the workspace."""
        with self.lock:
            c, body = self.cell.world.client, self.cell.object_body
            position, orientation = c.getBasePositionAndOrientation(body)
            c.resetBasePositionAndOrientation(body, [0.5, 0.45, position[2] - min(position[2], 0.0) + 0.1],
                                              orientation)
            c.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])

    def _model(self, object_id: str):
        if object_id not in self._models:
            from seggrasp.objects import load_asset

            if not isinstance(object_id, str):
                raise ValueError(f"place: object must be a twin object id, got {object_id!r}")
            self._models[object_id] = load_asset(object_id)
        return self._models[object_id]

    def _cell_with(self, model) -> SimCell:
        if self.cell is None or model.object_id not in {o.object_id for o in self.cell.objects}:
            if self.cell is not None:
                self.cell.close()
            self.cell = SimCell(objects=list(self._models.values()), embodiment="arm")
        return self.cell

    # --- time ---
    def advance(self, seconds: float) -> None:
        """Run the physics for `seconds` of simulated time (whole time steps)."""
        for _ in range(max(1, int(round(seconds / self.time_step)))):
            self.step_once()

    def step_once(self) -> None:
        """One physics step: the arm's and fingers' drives, the step, their state."""
        with self.lock:
            cell = self.cell
            robot, now = cell.robot, self.sim_time + self.time_step
            self.arm.before_step(robot, now)
            self.fingers.before_step(robot.gripper)
            cell.world.step()
            self.sim_time = now
            self.arm.after_step(robot, now, cell.world.table_id, cell.object_body)
            self.fingers.after_step(robot.gripper)

    def start(self) -> None:
        """Start the clock thread that keeps the physics in step with the wall clock."""
        if not self.clock_running:
            self._clock = Clock(self)
            self._clock.start()

    def stats(self) -> dict:
        """The clock's account (`Clock.stats`), or {} without a clock."""
        return self._clock.stats() if self._clock is not None else {}

    def close(self) -> None:
        if self._clock is not None:
            self._clock.stop()
        with self.lock:
            if self.cell is not None:
                self.cell.close()
                self.cell = None


def _joint_limits(robot: UR5Arm) -> tuple[np.ndarray, np.ndarray]:
    """The arm joints' limits from its description (rad)."""
    c = robot.world.client
    info = [c.getJointInfo(robot.body, j) for j in robot.arm_joints]
    return np.array([i[8] for i in info]), np.array([i[9] for i in info])


class Clock(threading.Thread):
    """Steps a scene's physics so that simulated time keeps up with the wall clock: when it falls behind it runs
    steps back to back, and a backlog beyond `MAX_BACKLOG` is dropped and counted as lag."""

    def __init__(self, scene: TwinScene) -> None:
        super().__init__(name="twin-clock", daemon=True)
        self.scene = scene
        self._stopped = threading.Event()
        self._resync = threading.Event()
        self._guard = threading.Lock()
        self.started_at = time.monotonic()
        self.sim_started = scene.sim_time
        self.busy = 0.0
        self.paused = 0.0
        self.dropped = 0.0
        self.longest_step = 0.0

    def run(self) -> None:
        dt = self.scene.time_step
        origin, steps = time.monotonic(), 0
        while not self._stopped.is_set():
            if self._resync.is_set():
                self._resync.clear()
                origin = time.monotonic() - steps * dt
            due = int((time.monotonic() - origin) / dt) - steps
            if due <= 0:
                self._stopped.wait(max(0.0, origin + (steps + 1) * dt - time.monotonic()))
                continue
            if due * dt > MAX_BACKLOG:
                with self._guard:
                    self.dropped += (due - 1) * dt
                origin += (due - 1) * dt
            began = time.monotonic()
            try:
                self.scene.step_once()
            except Exception:  # a broken step must not kill the clock silently
                log.exception("twin physics step failed; the clock stops")
                return
            spent = time.monotonic() - began
            with self._guard:
                self.busy += spent
                self.longest_step = max(self.longest_step, spent)
            steps += 1

    def resync(self, paused: float) -> None:
        """Forget the time the physics stood still (a placement) instead of catching up with it."""
        with self._guard:
            self.paused += paused
        self._resync.set()

    def stop(self) -> None:
        self._stopped.set()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout=5.0)

    def stats(self) -> dict:
        """Simulated vs wall time since the clock started: `real_time_factor` = simulated / (wall - paused),
        `headroom` = simulated / time spent stepping, the lag dropped and the longest step."""
        with self._guard:
            wall = time.monotonic() - self.started_at
            simulated = self.scene.sim_time - self.sim_started
            running = max(wall - self.paused, 1e-9)
            return {"simulated_s": simulated, "wall_s": wall, "paused_s": self.paused, "dropped_s": self.dropped,
                    "real_time_factor": simulated / running, "headroom": simulated / max(self.busy, 1e-9),
                    "longest_step_ms": 1000.0 * self.longest_step}


def write_camera_recordings(frames: list, folder: Path) -> dict[str, str]:
    """The frames of one placement as recordings the client's pyrealsense2 plays, by camera serial."""
    raise NotImplementedError("waiting for lab-cameras' write_recordings")
