"""The UR5 with a Robotiq 2F-85 on its flange: kinematics, inverse kinematics with a reachability check, and
joint-space motion with speed limits.

Kinematics are the UR5's DH parameters (d1 0.089159, a2 -0.425, a3 -0.39225, d4 0.10915, d5 0.09465, d6 0.0823).
The URDF's `base_link` is the DH base frame turned by pi about z (the ROS-Industrial convention); `tests/test_sim_robot.py`
checks that PyBullet's forward kinematics of the URDF equals the DH chain. Inverse kinematics is PyBullet's damped
least squares with null-space limits, refined from its own solution, and accepted only when the DH forward
kinematics of the answer lands within `IK_POSITION_TOLERANCE` / `IK_ANGLE_TOLERANCE` of the target with every joint
inside its limits.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pybullet
from scipy.spatial.transform import Rotation

from sim.gripper import GripperSettings, Robotiq2F85
from sim.world import PATH_RESOLUTION, World, linear_poses, pose_to_pb

log = logging.getLogger(__name__)

ARM_JOINTS = (
    "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
)
GRIPPER_BASE_LINK = "robotiq_base_link"
#: UR5 DH parameters (Universal Robots' published values).
DH_D = np.array([0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823])
DH_A = np.array([0.0, -0.425, -0.39225, 0.0, 0.0, 0.0])
DH_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])
#: URDF base_link = DH base turned by pi about z.
T_BASELINK_DHBASE = np.diag([-1.0, -1.0, 1.0, 1.0])
#: Flange (tool0) -> gripper base: the 13.9 mm Robotiq coupling.
T_FLANGE_GRIPPER = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.0139], [0, 0, 0, 1.0]])
#: Joint limits used for planning: the shoulder stays above the horizontal, the rest as the robot allows.
JOINT_LOWER = np.array([-np.pi, -np.pi, -np.pi, -2 * np.pi, -2 * np.pi, -2 * np.pi])
JOINT_UPPER = np.array([np.pi, 0.0, np.pi, 2 * np.pi, 2 * np.pi, 2 * np.pi])
#: Elbow up, wrist pointing down, above the workspace.
HOME_Q = np.array([0.0, -1.9, 1.9, -1.571, -1.571, 0.0])
#: Torque limits (N m): UR5 base/shoulder/elbow 150, wrists 28.
JOINT_FORCES = np.array([150.0, 150.0, 150.0, 28.0, 28.0, 28.0])
IK_POSITION_TOLERANCE = 0.005
IK_ANGLE_TOLERANCE = np.deg2rad(3.0)
#: The largest joint step allowed between neighbouring straight-line waypoints (rad).
MAX_JOINT_JUMP = 0.25


@dataclass(frozen=True)
class ArmSettings:
    """Joint speed limit (rad/s) for all motions; straight-line speeds are capped so no joint exceeds it."""

    max_joint_speed: float = 1.5


def dh_forward(q: np.ndarray) -> np.ndarray:
    """UR5 forward kinematics: DH base -> flange (tool0) for joint angles `q` (6,)."""
    T = np.eye(4)
    for theta, d, a, alpha in zip(q, DH_D, DH_A, DH_ALPHA):
        ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(alpha), np.sin(alpha)
        T = T @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0, sa, ca, d], [0, 0, 0, 1]])
    return T


def pose_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(position error in m, rotation error in rad) between two poses."""
    position = float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]))
    angle = float(Rotation.from_matrix(T_a[:3, :3].T @ T_b[:3, :3]).magnitude())
    return position, angle


class UR5Arm:
    """UR5 + 2F-85 as one fixed-base body at the world origin."""

    name = "arm"

    def __init__(self, world: World, settings: ArmSettings | None = None, gripper: GripperSettings | None = None):
        self.world = world
        self.settings = settings or ArmSettings()
        c = world.client
        self.body = world.load_robot("ur5_robotiq_2f85.urdf")
        joints = {c.getJointInfo(self.body, j)[1].decode(): j for j in range(c.getNumJoints(self.body))}
        links = {c.getJointInfo(self.body, j)[12].decode(): j for j in range(c.getNumJoints(self.body))}
        self.arm_joints = [joints[n] for n in ARM_JOINTS]
        self.gripper_base_link = links[GRIPPER_BASE_LINK]
        self.movable = [j for j in range(c.getNumJoints(self.body)) if c.getJointInfo(self.body, j)[2] != pybullet.JOINT_FIXED]
        self.gripper = Robotiq2F85(world, self.body, self.gripper_base_link, gripper)
        # Null-space arrays cover every movable joint (the gripper's too), as PyBullet requires.
        lower, upper = [], []
        for j in self.movable:
            info = c.getJointInfo(self.body, j)
            lower.append(info[8])
            upper.append(info[9])
        for k, j in enumerate(self.arm_joints):
            index = self.movable.index(j)
            lower[index], upper[index] = JOINT_LOWER[k], JOINT_UPPER[k]
        self._ik_lower, self._ik_upper = lower, upper
        self._ik_ranges = [u - lo for lo, u in zip(lower, upper)]
        self._arm_slots = [self.movable.index(j) for j in self.arm_joints]
        self.q_commanded = HOME_Q.copy()

    # --- kinematics -----------------------------------------------------------------------------------------

    def fk(self, q: np.ndarray) -> np.ndarray:
        """World -> gripper base for arm joints `q` (robot base at the world origin)."""
        return T_BASELINK_DHBASE @ dh_forward(np.asarray(q, dtype=float)) @ T_FLANGE_GRIPPER

    def _pybullet_ik(self, T_world_target: np.ndarray, seed: np.ndarray) -> np.ndarray:
        position, orientation = pose_to_pb(T_world_target)
        current = [0.0] * len(self.movable)
        rest = [0.0] * len(self.movable)
        for k, slot in enumerate(self._arm_slots):
            current[slot] = float(seed[k])
            rest[slot] = float(HOME_Q[k])
        solution = self.world.client.calculateInverseKinematics(
            self.body, self.gripper_base_link, position, orientation,
            lowerLimits=self._ik_lower, upperLimits=self._ik_upper, jointRanges=self._ik_ranges, restPoses=rest,
            currentPositions=current, maxNumIterations=100, residualThreshold=1e-6,
        )
        return np.array([solution[slot] for slot in self._arm_slots])

    def ik(self, T_world_target: np.ndarray, seed: np.ndarray | None = None) -> tuple[np.ndarray | None, str]:
        """Joint angles that put the gripper base at `T_world_target`, or (None, reason) if unreachable."""
        q = HOME_Q.copy() if seed is None else np.asarray(seed, dtype=float).copy()
        best: tuple[float, np.ndarray] | None = None
        for _ in range(8):
            q = self._pybullet_ik(T_world_target, q)
            position_error, angle_error = pose_error(self.fk(q), T_world_target)
            score = position_error / IK_POSITION_TOLERANCE + angle_error / IK_ANGLE_TOLERANCE
            if best is None or score < best[0]:
                best = (score, q.copy())
            if position_error < 0.2 * IK_POSITION_TOLERANCE and angle_error < 0.2 * IK_ANGLE_TOLERANCE:
                break
        q = best[1]
        position_error, angle_error = pose_error(self.fk(q), T_world_target)
        if position_error > IK_POSITION_TOLERANCE or angle_error > IK_ANGLE_TOLERANCE:
            return None, f"IK misses the target by {position_error * 1000:.1f} mm / {np.rad2deg(angle_error):.1f} deg"
        if np.any(q < JOINT_LOWER - 1e-6) or np.any(q > JOINT_UPPER + 1e-6):
            return None, f"IK solution outside the joint limits: {np.round(q, 3).tolist()}"
        return q, ""

    # --- planning ---------------------------------------------------------------------------------------------

    def plan(self, poses: list[np.ndarray]) -> tuple[list[list[np.ndarray]] | None, str]:
        """Joint paths through gripper-base poses: the first pose alone (reached through free space), then a
        straight line to each next pose with waypoints every `PATH_RESOLUTION` m. None + reason if any waypoint
        is unreachable or the arm would have to flip between neighbouring waypoints."""
        q, reason = self.ik(poses[0], HOME_Q)
        if q is None:
            return None, f"pose 0: {reason}"
        paths = [[q]]
        for index in range(1, len(poses)):
            segment = []
            for T in linear_poses(poses[index - 1], poses[index], PATH_RESOLUTION)[1:]:
                q_next, reason = self.ik(T, q)
                if q_next is None:
                    return None, f"pose {index}: {reason}"
                if np.abs(q_next - q).max() > MAX_JOINT_JUMP:
                    return None, f"pose {index}: the arm would flip ({np.abs(q_next - q).max():.2f} rad in one step)"
                segment.append(q_next)
                q = q_next
            paths.append(segment)
        return paths, ""

    def free_space_path(self, q_target: np.ndarray) -> list[np.ndarray]:
        """Joint-space straight line from the commanded configuration to `q_target`, 0.05 rad apart."""
        steps = max(1, int(np.ceil(np.abs(q_target - self.q_commanded).max() / 0.05)))
        return [self.q_commanded + (q_target - self.q_commanded) * k / steps for k in range(1, steps + 1)]

    # --- motion -----------------------------------------------------------------------------------------------

    def reset_home(self, width: float) -> None:
        self.place(HOME_Q)
        self.gripper.set_width(width)

    def place(self, q: np.ndarray) -> None:
        """Set the arm's joints instantly (kinematic) and hold them there."""
        c = self.world.client
        for joint, value in zip(self.arm_joints, q):
            c.resetJointState(self.body, joint, float(value))
        self._command(np.asarray(q, dtype=float), np.zeros(6))

    def _command(self, q: np.ndarray, qd: np.ndarray) -> None:
        self.q_commanded = q.copy()
        self.world.client.setJointMotorControlArray(
            self.body, self.arm_joints, pybullet.POSITION_CONTROL, targetPositions=q.tolist(),
            targetVelocities=qd.tolist(), forces=JOINT_FORCES.tolist(), positionGains=[0.3] * 6,
            velocityGains=[1.0] * 6,
        )

    def follow(self, path: list[np.ndarray], speed: float, on_step=None) -> None:
        """Track joint waypoints `PATH_RESOLUTION` m apart at Cartesian `speed` (m/s), slowed where a joint would
        exceed the joint speed limit; joint targets are interpolated every physics step."""
        dt = self.world.physics.time_step
        q = self.q_commanded.copy()
        for q_next in path:
            duration = max(PATH_RESOLUTION / speed, np.abs(q_next - q).max() / self.settings.max_joint_speed)
            steps = max(1, int(round(duration / dt)))
            velocity = (q_next - q) / (steps * dt)
            for k in range(1, steps + 1):
                self._command(q + (q_next - q) * k / steps, velocity)
                if on_step is not None:
                    on_step()
                self.world.step()
            q = q_next

    def hold(self, steps: int, on_step=None) -> None:
        self._command(self.q_commanded, np.zeros(6))
        for _ in range(steps):
            if on_step is not None:
                on_step()
            self.world.step()

    def joint_positions(self) -> np.ndarray:
        return np.array([s[0] for s in self.world.client.getJointStates(self.body, self.arm_joints)])

    def table_check_links(self) -> tuple[int, list[int]]:
        """Links that must stay clear of the table: everything from the upper arm on (base and shoulder sit on it)."""
        return self.body, [j for j in range(self.world.client.getNumJoints(self.body)) if j >= self.arm_joints[1]]
