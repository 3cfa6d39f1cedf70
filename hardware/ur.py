"""The UR arm over ur_rtde: guarded joint and Cartesian moves, state, stop detection, reconnect and shutdown.

This module is the ONE place where the project's 4x4 poses meet UR's pose vectors `[x, y, z, rx, ry, rz]`
(position in metres, orientation as an axis-angle rotation vector): `ur_pose_from_matrix` and
`matrix_from_ur_pose`. The world frame is the robot's base frame as RTDE reports it (docs/design.md section 3: robot base at the
origin, z up). The controller's TCP is set to the project's gripper frame (`robot.tcp_offset` = `T_flange_gripper`:
z = approach, x = closing direction, origin between the fingertips), so every pose the arm takes or reports is
`T_world_gripper`.

`URArm` talks to an `RTDEControlInterface` / `RTDEReceiveInterface` pair made by the factories it is given (the
real ur_rtde classes by default; tests inject fakes). Each motion is checked by `SafetyGuard` first, then sent
asynchronously and watched: a protective or emergency stop raises `RobotStoppedError`, a lost connection stops the
robot (as far as it can still be reached) and raises `ConnectionLostError`. In dry-run mode nothing connects to the
controller: motions are checked, logged and recorded in `planned_motions`, and the arm's state follows the plan.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from scipy.spatial.transform import Rotation

from hardware.config import RobotConfig
from hardware.errors import ConnectionLostError, MotionError, RobotStoppedError, SafetyError
from hardware.kinematics import ARM_MODELS, forward_kinematics
from hardware.safety import SafetyGuard

log = logging.getLogger(__name__)

#: How close (m, rad) the arm must end to its target for a motion to count as done.
POSITION_TOLERANCE = 0.005
ORIENTATION_TOLERANCE = 0.01
JOINT_TOLERANCE = 0.01
_POLL_PERIOD = 0.01


def ur_pose_from_matrix(T: np.ndarray) -> list[float]:
    """4x4 homogeneous pose -> UR pose vector [x, y, z, rx, ry, rz] (rotation vector, radians)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f"expected a 4x4 pose, got shape {T.shape}")
    return [*map(float, T[:3, 3]), *map(float, Rotation.from_matrix(T[:3, :3]).as_rotvec())]


def matrix_from_ur_pose(pose: Any) -> np.ndarray:
    """UR pose vector [x, y, z, rx, ry, rz] -> 4x4 homogeneous pose."""
    pose = np.asarray(pose, dtype=np.float64)
    if pose.shape != (6,):
        raise ValueError(f"expected a UR pose [x, y, z, rx, ry, rz], got {pose.tolist()}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(pose[3:]).as_matrix()
    T[:3, 3] = pose[:3]
    return T


def _close_to(T: np.ndarray, target: np.ndarray) -> bool:
    """Whether pose `T` is within the position and orientation tolerances of `target`."""
    angle = Rotation.from_matrix(T[:3, :3].T @ target[:3, :3]).magnitude()
    return bool(np.linalg.norm(T[:3, 3] - target[:3, 3]) <= POSITION_TOLERANCE and angle <= ORIENTATION_TOLERANCE)


@dataclass(frozen=True)
class PlannedMotion:
    """One motion as checked (and, unless dry-run, sent): kind is "moveJ" or "moveL"."""

    kind: str
    target: tuple[float, ...]  # joints (rad) for moveJ, UR pose vector for moveL
    speed: float
    acceleration: float


def _default_control_factory(ip: str) -> Any:
    import rtde_control

    return rtde_control.RTDEControlInterface(ip)


def _default_receive_factory(ip: str) -> Any:
    import rtde_receive

    return rtde_receive.RTDEReceiveInterface(ip)


class URArm:
    """A UR5/UR5e driven over RTDE with every motion checked by a `SafetyGuard` before it is sent."""

    def __init__(self, config: RobotConfig, guard: SafetyGuard, *, dry_run: bool = False,
                 control_factory: Callable[[str], Any] | None = None,
                 receive_factory: Callable[[str], Any] | None = None) -> None:
        self.config = config
        self.guard = guard
        self.dry_run = dry_run
        self.planned_motions: list[PlannedMotion] = []
        self._control_factory = control_factory or _default_control_factory
        self._receive_factory = receive_factory or _default_receive_factory
        self._control: Any = None
        self._receive: Any = None
        self._planned_q = np.asarray(config.home_joints, dtype=np.float64).copy()
        self._planned_T: np.ndarray | None = None

    # ---------------------------------------------------------------------------------------------------- connection
    def connect(self) -> None:
        """Open the RTDE receive and control connections and set the TCP to the gripper frame (not in dry run)."""
        if self.dry_run:
            log.info("[dry run] not connecting to the robot at %s; planning from the home joints", self.config.ip)
            self.guard.tool_pose = self.tcp_pose()
            return
        try:
            self._receive = self._receive_factory(self.config.ip)
            self._control = self._control_factory(self.config.ip)
        except RuntimeError as exc:
            raise ConnectionLostError(f"cannot connect to the UR controller at {self.config.ip}: {exc}") from exc
        self._apply_tcp()
        self.check_state()
        self.guard.tool_pose = self.tcp_pose()
        log.info("connected to the UR at %s", self.config.ip)

    def _apply_tcp(self) -> None:
        tcp = ur_pose_from_matrix(self.config.T_flange_gripper)
        if not self._call(self._control, "setTcp", tcp):
            raise MotionError(f"the controller refused the TCP offset {np.round(tcp, 4).tolist()}")

    def reconnect(self) -> None:
        """Re-open lost RTDE connections and re-apply the TCP offset."""
        if self.dry_run:
            return
        try:
            ok = bool(self._receive.reconnect()) and bool(self._control.reconnect())
        except RuntimeError as exc:
            raise ConnectionLostError(f"reconnecting to the UR at {self.config.ip} failed: {exc}") from exc
        if not ok or not self.is_connected():
            raise ConnectionLostError(f"reconnecting to the UR at {self.config.ip} failed")
        self._apply_tcp()
        log.info("reconnected to the UR at %s", self.config.ip)

    def is_connected(self) -> bool:
        """True when both RTDE connections are up (always True in dry run)."""
        if self.dry_run:
            return True
        try:
            return bool(self._control is not None and self._receive is not None and self._control.isConnected()
                        and self._receive.isConnected())
        except RuntimeError:
            return False

    def close(self) -> None:
        """Stop the RTDE script on the controller and disconnect. Safe to call more than once."""
        if self.dry_run:
            return
        for name, interface, methods in (("control", self._control, ("stopScript", "disconnect")),
                                         ("receive", self._receive, ("disconnect",))):
            if interface is None:
                continue
            for method in methods:
                try:
                    getattr(interface, method)()
                except RuntimeError as exc:  # already gone: nothing left to stop
                    log.warning("UR %s.%s failed during shutdown: %s", name, method, exc)
        self._control = self._receive = None

    # --------------------------------------------------------------------------------------------------------- state
    def tcp_pose(self) -> np.ndarray:
        """Current `T_world_gripper` (the planned one in dry run)."""
        if self.dry_run:
            if self._planned_T is None:
                self._planned_T = self._gripper_pose_at(self._planned_q)
            return self._planned_T.copy()
        return matrix_from_ur_pose(self._call(self._receive, "getActualTCPPose"))

    def joints(self) -> np.ndarray:
        """Current joint angles in radians (the planned ones in dry run)."""
        if self.dry_run:
            return self._planned_q.copy()
        return np.asarray(self._call(self._receive, "getActualQ"), dtype=np.float64)

    def check_state(self) -> None:
        """Raise if the connection is down or the robot is protective/emergency stopped."""
        if self.dry_run:
            return
        if not self.is_connected():
            raise ConnectionLostError(f"lost the RTDE connection to the UR at {self.config.ip}")
        if self._call(self._receive, "isEmergencyStopped"):
            raise RobotStoppedError("the robot is emergency stopped; release the e-stop and restart the program")
        if self._call(self._receive, "isProtectiveStopped"):
            raise RobotStoppedError("the robot is in a protective stop; unlock it on the teach pendant")

    def home_pose(self) -> np.ndarray:
        """`T_world_gripper` at the home joints (nominal kinematics)."""
        return self._gripper_pose_at(self.config.home_joints)

    def _gripper_pose_at(self, q: np.ndarray) -> np.ndarray:
        return forward_kinematics(self.config.model, q) @ self.config.T_flange_gripper

    # ------------------------------------------------------------------------------------------------------- motions
    def move_joints(self, q: Any, speed: float, acceleration: float) -> None:
        """moveJ to joint angles `q` (rad); the tool path (nominal kinematics) is checked against the limits, and
        the controller is asked whether the joints and the tool pose there are within its safety limits."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (6,) or not np.all(np.isfinite(q)):
            raise SafetyError(f"moveJ target must be 6 finite joint angles, got {q.tolist()}")
        self.guard.check_joint_motion(speed, acceleration)
        start = self.joints()
        for s in np.linspace(0.0, 1.0, 21)[1:]:
            self.guard.check_pose(self._gripper_pose_at((1 - s) * start + s * q), f"moveJ (at {s:.0%} of the path)",
                                  self.guard.finger_opening)
        motion = PlannedMotion("moveJ", tuple(map(float, q)), float(speed), float(acceleration))
        goal = self._gripper_pose_at(q)
        if self.dry_run:
            self._record_dry_run(motion)
            self._planned_q = q.copy()
            self._planned_T = self.guard.tool_pose = goal
            return
        if not self._call(self._control, "isJointsWithinSafetyLimits", list(motion.target)):
            raise SafetyError(f"moveJ: the controller reports joints {np.round(q, 4).tolist()} as outside its "
                              "safety limits")
        self._check_controller_pose(goal, "moveJ")
        self.planned_motions.append(motion)
        self._run(motion, lambda: np.max(np.abs(self.joints() - q)) <= JOINT_TOLERANCE)
        self.guard.tool_pose = goal

    def move_linear(self, T_world_gripper: np.ndarray, speed: float, acceleration: float) -> None:
        """moveL the gripper frame to `T_world_gripper` in a straight line; the path is checked first."""
        target = np.asarray(T_world_gripper, dtype=np.float64)
        self.guard.check_tool_motion(speed, acceleration)
        start = self.tcp_pose()
        self.guard.check_linear_path(start, target, "moveL", opening=self.guard.finger_opening)
        pose = ur_pose_from_matrix(target)
        motion = PlannedMotion("moveL", tuple(pose), float(speed), float(acceleration))
        if self.dry_run:
            self._record_dry_run(motion)
            self._planned_T = target.copy()
            self.guard.tool_pose = target.copy()
            return
        self._check_controller_pose(target, "moveL")
        self.planned_motions.append(motion)
        self._run(motion, lambda: _close_to(self.tcp_pose(), target))
        self.guard.tool_pose = target.copy()

    def _check_controller_pose(self, T_world_gripper: np.ndarray, what: str) -> None:
        """Ask the controller's own safety configuration (planes, tool limits) about a gripper pose."""
        pose = ur_pose_from_matrix(T_world_gripper)
        if not self._call(self._control, "isPoseWithinSafetyLimits", pose):
            raise SafetyError(f"{what}: the controller reports {np.round(pose, 4).tolist()} as outside its safety "
                              "limits or unreachable")

    def has_ik_solution(self, T_world_gripper: np.ndarray) -> bool:
        """Whether the controller finds joint angles for this gripper pose. In dry run, with no controller to ask,
        the necessary condition: the flange is within the arm's reach of the shoulder and outside its base column."""
        if self.dry_run:
            arm = ARM_MODELS[self.config.model]
            flange = (np.asarray(T_world_gripper, dtype=np.float64) @ np.linalg.inv(self.config.T_flange_gripper))[:3, 3]
            return bool(np.linalg.norm(flange - arm.shoulder) <= arm.reach
                        and np.linalg.norm(flange[:2]) >= arm.base_radius)
        return bool(self._call(self._control, "getInverseKinematicsHasSolution",
                               ur_pose_from_matrix(T_world_gripper)))

    def stop(self) -> None:
        """Decelerate the arm to rest (best effort: the connection may already be gone)."""
        if self.dry_run or self._control is None:
            return
        try:
            self._control.stopL(self.guard.limits.max_tool_acceleration)
        except RuntimeError as exc:
            log.error("stopping the arm failed: %s", exc)

    def _record_dry_run(self, motion: PlannedMotion) -> None:
        self.planned_motions.append(motion)
        log.info("[dry run] %s target=%s speed=%g acceleration=%g", motion.kind,
                 np.round(motion.target, 4).tolist(), motion.speed, motion.acceleration)

    def _run(self, motion: PlannedMotion, at_target: Callable[[], bool]) -> None:
        """Send `motion` asynchronously and watch it until it ends at its target, stops, or the link drops."""
        self.check_state()
        self.guard.tool_pose = None  # unknown until the motion has ended at its target
        token = self._call(self._control, "getAsyncOperationProgress")
        method = getattr(self._control, motion.kind)
        log.info("%s target=%s speed=%g acceleration=%g", motion.kind, np.round(motion.target, 4).tolist(),
                 motion.speed, motion.acceleration)
        accepted = self._call_motion(method, list(motion.target), motion.speed, motion.acceleration, True)
        if not accepted:
            self.check_state()
            raise MotionError(f"the controller rejected {motion.kind} to {np.round(motion.target, 4).tolist()}")
        deadline = time.monotonic() + self.config.motion_timeout
        while True:
            try:
                self.check_state()
            except ConnectionLostError:
                self.stop()
                raise
            progress = self._call(self._control, "getAsyncOperationProgress")
            if progress < 0 and (progress != token or at_target()):
                break
            if time.monotonic() > deadline:
                self.stop()
                raise MotionError(f"{motion.kind} did not finish within its time limit; the arm was stopped")
            time.sleep(_POLL_PERIOD)
        self.check_state()
        if not at_target():
            raise MotionError(f"{motion.kind} ended away from its target {np.round(motion.target, 4).tolist()}")

    def _call_motion(self, method: Callable, *args: Any) -> Any:
        try:
            return method(*args)
        except RuntimeError as exc:
            self.stop()
            raise ConnectionLostError(f"the UR connection failed while sending a motion: {exc}") from exc

    def _call(self, interface: Any, name: str, *args: Any) -> Any:
        if interface is None:
            raise ConnectionLostError("the arm is not connected (call connect() first)")
        try:
            return getattr(interface, name)(*args)
        except RuntimeError as exc:
            self.stop()
            raise ConnectionLostError(f"the UR connection failed during {name}: {exc}") from exc
