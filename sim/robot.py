"""The UR5 with a Robotiq 2F-85 on its flange: kinematics, inverse kinematics with a reachability check, and
joint-space motion with speed limits.

Kinematics are the UR5's DH parameters (d1 0.089159, a2 -0.425, a3 -0.39225, d4 0.10915, d5 0.09465, d6 0.0823).
The URDF's `base_link` is the DH base frame turned by pi about z (the ROS-Industrial convention); `tests/test_sim_robot.py`
checks that PyBullet's forward kinematics of the URDF equals the DH chain. Inverse kinematics is the UR's closed
form (up to 8 solutions: shoulder left/right, wrist up/down, elbow up/down), each shifted by 2 pi to lie nearest the
current configuration; a solution is accepted only when its DH forward kinematics lands within
`IK_POSITION_TOLERANCE` / `IK_ANGLE_TOLERANCE` of the target with every joint inside the planning limits. (PyBullet's
damped-least-squares IK, tried first, missed reachable side grasps by 15-300 mm from the home seed and picked wrist
branches that hit the table, with no way to ask for another branch.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet
from scipy.spatial.transform import Rotation

from sim.gripper import GripperSettings, Robotiq2F85
from sim.gripper_urdf import GRIPPER_BASE_LINK, simulated_urdf
from sim.world import PATH_RESOLUTION, World, linear_poses

ARM_JOINTS = (
    "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
)
#: UR5 DH parameters (Universal Robots' published values).
DH_D = np.array([0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823])
DH_A = np.array([0.0, -0.425, -0.39225, 0.0, 0.0, 0.0])
DH_ALPHA = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])
#: URDF base_link = DH base turned by pi about z.
T_BASELINK_DHBASE = np.diag([-1.0, -1.0, 1.0, 1.0])
#: The arm with the gripper on its flange (assets/robots/).
ARM_DESCRIPTION = "ur5_robotiq_2f85.urdf"
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
#: Weights of the joints when choosing the IK branch nearest a configuration (big joints move more mass).
JOINT_WEIGHTS = np.array([2.0, 2.0, 1.5, 1.0, 1.0, 0.5])
IK_ANGLE_TOLERANCE = np.deg2rad(3.0)
#: The largest joint step allowed between neighbouring straight-line waypoints (rad).
MAX_JOINT_JUMP = 0.25
#: A joint move has ended when every joint is this close to its target (rad) and slower than this (rad/s) ...
SETTLED_RAD = 1e-3
#: ... or after this long (s).
SETTLE_TIME = 1.0


@dataclass(frozen=True)
class ArmSettings:
    """Joint speed limit (rad/s) for all motions (the UR5 allows 3.15); straight lines are slowed where a joint
    would exceed it."""

    max_joint_speed: float = 3.0


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


class SerialArm:
    """A fixed-base arm with a gripper on its flange at the world origin: planning through gripper-base poses and
    joint-space motion with speed limits, shared by the UR5 (`UR5Arm`) and the Franka Panda (`sim.panda.PandaArm`).
    A subclass sets `world`, `settings`, `body`, `arm_joints`, `gripper`, `home_q`, `joint_forces` and
    `q_commanded`, and gives the kinematics (`fk`, `ik_solutions`, `ik`), `free_space_paths` and
    `table_check_links`."""

    name = "arm"

    # --- planning ---------------------------------------------------------------------------------------------

    def plan(self, poses: list[np.ndarray]) -> tuple[list[list[list[np.ndarray]]], str]:
        """Candidate joint paths through gripper-base poses, one per IK branch of the first pose (nearest home
        first): the first pose alone (reached through free space), then a straight line to each next pose with
        waypoints every `PATH_RESOLUTION` m, each waypoint the solution nearest the previous one. A branch is
        dropped when a waypoint is unreachable or the arm would have to flip between neighbours. Returns
        ([], reason) when no branch works."""
        candidates, reason = [], ""
        for q_start in self.ik_solutions(poses[0]):
            paths, q = [[q_start]], q_start
            for index in range(1, len(poses)):
                segment = []
                for T in linear_poses(poses[index - 1], poses[index], PATH_RESOLUTION)[1:]:
                    q_next, why = self.ik(T, q)
                    if q_next is None or np.abs(q_next - q).max() > MAX_JOINT_JUMP:
                        reason = f"pose {index}: " + (why or "the arm would flip between waypoints")
                        break
                    segment.append(q_next)
                    q = q_next
                else:
                    paths.append(segment)
                    continue
                break
            if len(paths) == len(poses):
                candidates.append(paths)
        if not candidates and not reason:
            reason = "pose 0: " + self.ik(poses[0])[1]
        return candidates, reason

    def configuration(self) -> np.ndarray:
        """The commanded joint angles."""
        return self.q_commanded.copy()

    # --- motion -----------------------------------------------------------------------------------------------

    def reset_home(self, width: float) -> None:
        self.place(self.home_q)
        self.gripper.set_width(width)

    def place(self, q: np.ndarray) -> None:
        """Set the arm's joints instantly (kinematic) and hold them there."""
        c = self.world.client
        for joint, value in zip(self.arm_joints, q):
            c.resetJointState(self.body, joint, float(value))
        self._command(np.asarray(q, dtype=float), np.zeros(len(self.arm_joints)))

    def _command(self, q: np.ndarray, qd: np.ndarray) -> None:
        self.q_commanded = q.copy()
        self.world.client.setJointMotorControlArray(
            self.body, self.arm_joints, pybullet.POSITION_CONTROL, targetPositions=q.tolist(),
            targetVelocities=qd.tolist(), forces=self.joint_forces.tolist(),
            positionGains=[0.3] * len(self.arm_joints), velocityGains=[1.0] * len(self.arm_joints),
        )

    def follow(self, path: list[np.ndarray], speed: float, acceleration: float, on_step=None) -> None:
        """Track joint waypoints `PATH_RESOLUTION` m apart at Cartesian `speed` (m/s), starting and ending at rest
        with the speed ramping up and down at `acceleration` (m/s^2), as a real arm's linear move does (a
        trapezoidal profile along the path), slowed where a joint would exceed the joint speed limit; joint targets
        are interpolated every physics step."""
        if acceleration <= 0 or speed <= 0:
            raise ValueError(f"speed and acceleration must be positive, got {speed} m/s and {acceleration} m/s^2")
        dt = self.world.physics.time_step
        waypoints = np.array([self.q_commanded, *path])
        steps = np.diff(waypoints, axis=0)
        joint_step = np.maximum(np.abs(steps).max(axis=1), 1e-12)
        capped = np.minimum(speed, self.settings.max_joint_speed * PATH_RESOLUTION / joint_step)
        length = len(steps) * PATH_RESOLUTION
        s = v = 0.0
        while length - s > 1e-9:
            segment = min(int(s / PATH_RESOLUTION), len(steps) - 1)
            v = min(capped[segment], v + acceleration * dt, float(np.sqrt(2.0 * acceleration * (length - s))))
            s = min(s + v * dt, length)
            segment = min(int(s / PATH_RESOLUTION), len(steps) - 1)
            fraction = s / PATH_RESOLUTION - segment
            self._command(waypoints[segment] + steps[segment] * fraction, steps[segment] / PATH_RESOLUTION * v)
            if on_step is not None:
                on_step()
            self.world.step()
        self._command(waypoints[-1], np.zeros(len(self.arm_joints)))

    def move_free(self, path: list[np.ndarray], on_step=None) -> None:
        """Follow a free-space joint path at the joint speed limit (simulated), then hold the arm until it is at
        rest on the path's end (its joints within `SETTLED_RAD` of it and slower than `SETTLED_RAD` per second; at
        most `SETTLE_TIME`), as a real arm's joint move ends before the next move starts: braking from full speed
        in one step leaves an arm swinging, and a Panda still swinging strayed 20-30 mm off its straight approach."""
        dt = self.world.physics.time_step

        def steps_for(dq: np.ndarray) -> int:
            return max(1, int(np.ceil(np.abs(dq).max() / self.settings.max_joint_speed / dt)))

        self._track(path, steps_for, on_step)
        for _ in range(int(round(SETTLE_TIME / dt))):
            states = self.world.client.getJointStates(self.body, self.arm_joints)
            if (max(abs(state[0] - q) for state, q in zip(states, self.q_commanded)) < SETTLED_RAD
                    and max(abs(state[1]) for state in states) < SETTLED_RAD):
                break
            if on_step is not None:
                on_step()
            self.world.step()

    def _track(self, path: list[np.ndarray], steps_for, on_step=None) -> None:
        """Interpolate joint targets every physics step towards each waypoint, in `steps_for(q_next - q)` steps;
        the move ends at rest on its last waypoint (as a UR5 move does), not still commanding its last velocity."""
        dt = self.world.physics.time_step
        q = self.q_commanded.copy()
        for q_next in path:
            steps = steps_for(q_next - q)
            velocity = (q_next - q) / (steps * dt)
            for k in range(1, steps + 1):
                self._command(q + (q_next - q) * k / steps, velocity)
                if on_step is not None:
                    on_step()
                self.world.step()
            q = q_next
        self._command(q, np.zeros(len(self.arm_joints)))

    def hold(self, steps: int, on_step=None) -> None:
        self._command(self.q_commanded, np.zeros(len(self.arm_joints)))
        for _ in range(steps):
            if on_step is not None:
                on_step()
            self.world.step()

    def joint_positions(self) -> np.ndarray:
        return np.array([s[0] for s in self.world.client.getJointStates(self.body, self.arm_joints)])

class UR5Arm(SerialArm):
    """UR5 + 2F-85 as one fixed-base body at the world origin."""

    def __init__(self, world: World, settings: ArmSettings | None = None, gripper: GripperSettings | None = None):
        self.world = world
        self.settings = settings or ArmSettings()
        c = world.client
        self.body = world.load_robot(simulated_urdf(ARM_DESCRIPTION))
        joints = {c.getJointInfo(self.body, j)[1].decode(): j for j in range(c.getNumJoints(self.body))}
        links = {c.getJointInfo(self.body, j)[12].decode(): j for j in range(c.getNumJoints(self.body))}
        self.arm_joints = [joints[n] for n in ARM_JOINTS]
        self.gripper_base_link = links[GRIPPER_BASE_LINK]
        self.gripper = Robotiq2F85(world, self.body, self.gripper_base_link, ARM_DESCRIPTION, gripper)
        self.home_q = HOME_Q
        self.joint_forces = JOINT_FORCES
        self.q_commanded = HOME_Q.copy()

    # --- kinematics -----------------------------------------------------------------------------------------

    def fk(self, q: np.ndarray) -> np.ndarray:
        """World -> gripper base for arm joints `q` (robot base at the world origin)."""
        return T_BASELINK_DHBASE @ dh_forward(np.asarray(q, dtype=float)) @ T_FLANGE_GRIPPER

    def ik_solutions(self, T_world_target: np.ndarray, near: np.ndarray | None = None) -> list[np.ndarray]:
        """Every IK branch that passes the reachability check, nearest to `near` (default: home) first."""
        near = HOME_Q if near is None else np.asarray(near, dtype=float)
        T_dh = np.linalg.inv(T_BASELINK_DHBASE) @ T_world_target @ np.linalg.inv(T_FLANGE_GRIPPER)
        solutions = []
        for q in ur_analytic_ik(T_dh):
            q = near + (q - near + np.pi) % (2 * np.pi) - np.pi  # the 2 pi turn nearest `near`
            if np.any(q < JOINT_LOWER - 1e-9) or np.any(q > JOINT_UPPER + 1e-9):
                continue
            position_error, angle_error = pose_error(self.fk(q), T_world_target)
            if position_error <= IK_POSITION_TOLERANCE and angle_error <= IK_ANGLE_TOLERANCE:
                solutions.append(q)
        return sorted(solutions, key=lambda q: float(np.abs((q - near) * JOINT_WEIGHTS).sum()))

    def ik(self, T_world_target: np.ndarray, near: np.ndarray | None = None) -> tuple[np.ndarray | None, str]:
        """The reachable IK solution nearest to `near`, or (None, reason)."""
        solutions = self.ik_solutions(T_world_target, near)
        if solutions:
            return solutions[0], ""
        if not ur_analytic_ik(np.linalg.inv(T_BASELINK_DHBASE) @ T_world_target @ np.linalg.inv(T_FLANGE_GRIPPER)):
            return None, "pose outside the UR5's workspace (no IK solution)"
        return None, "every IK solution violates the joint limits"

    def free_space_paths(self, q_start: np.ndarray, q_target: np.ndarray) -> list[list[np.ndarray]]:
        """Candidate joint-space paths from `q_start` to `q_target` (waypoints <= 0.05 rad apart): straight, or
        through a raised via point (target base and wrist angles, home shoulder and elbow)."""
        via = q_target.copy()
        via[1:3] = HOME_Q[1:3]
        return [_joint_line(q_start, [q_target]), _joint_line(q_start, [via, q_target])]

    def table_check_links(self) -> tuple[int, list[int]]:
        """Links that must stay clear of the table: everything from the upper arm on (base and shoulder sit on it)."""
        return self.body, [j for j in range(self.world.client.getNumJoints(self.body)) if j >= self.arm_joints[1]]


def _joint_line(q_start: np.ndarray, targets: list[np.ndarray], step: float = 0.05) -> list[np.ndarray]:
    """Joint-space straight lines through `targets`, waypoints at most `step` rad apart (start excluded)."""
    path, q = [], q_start
    for target in targets:
        n = max(1, int(np.ceil(np.abs(target - q).max() / step)))
        path += [q + (target - q) * k / n for k in range(1, n + 1)]
        q = target
    return path


def _dh_link(theta: float, i: int) -> np.ndarray:
    ct, st, ca, sa = np.cos(theta), np.sin(theta), np.cos(DH_ALPHA[i]), np.sin(DH_ALPHA[i])
    return np.array([[ct, -st * ca, st * sa, DH_A[i] * ct], [st, ct * ca, -ct * sa, DH_A[i] * st], [0, sa, ca, DH_D[i]], [0, 0, 0, 1]])


def ur_analytic_ik(T_dh: np.ndarray) -> list[np.ndarray]:
    """Closed-form UR5 IK: all joint solutions (angles in (-pi, pi]) whose DH flange pose is `T_dh` (DH base frame).

    Shoulder pan from the wrist centre's distance to the base axis, wrist 2 from the flange height along the pan
    plane, wrist 3 from the flange axes, then a planar 2-link problem for shoulder lift and elbow, and wrist 1 as the
    remainder. Singular wrist (sin(theta5) ~ 0) takes theta6 = 0.
    """
    d4, d6, a2, a3 = DH_D[3], DH_D[5], DH_A[1], DH_A[2]
    solutions: list[np.ndarray] = []
    wrist_centre = T_dh @ np.array([0.0, 0.0, -d6, 1.0])
    radius = float(np.hypot(wrist_centre[0], wrist_centre[1]))
    if radius < abs(d4):
        return solutions
    psi = np.arctan2(wrist_centre[1], wrist_centre[0])
    phi = np.arccos(d4 / radius)
    T_inv = np.linalg.inv(T_dh)
    for t1 in (psi + phi + np.pi / 2, psi - phi + np.pi / 2):
        c5 = (T_dh[0, 3] * np.sin(t1) - T_dh[1, 3] * np.cos(t1) - d4) / d6
        if abs(c5) > 1 + 1e-9:
            continue
        for t5 in (np.arccos(np.clip(c5, -1, 1)), -np.arccos(np.clip(c5, -1, 1))):
            s5 = np.sin(t5)
            if abs(s5) < 1e-9:
                t6 = 0.0
            else:
                t6 = np.arctan2(
                    (-T_inv[1, 0] * np.sin(t1) + T_inv[1, 1] * np.cos(t1)) / s5,
                    (T_inv[0, 0] * np.sin(t1) - T_inv[0, 1] * np.cos(t1)) / s5,
                )
            T14 = np.linalg.inv(_dh_link(t1, 0)) @ T_dh @ np.linalg.inv(_dh_link(t5, 4) @ _dh_link(t6, 5))
            p13 = (T14 @ np.array([0.0, -d4, 0.0, 1.0]))[:3]
            n13 = float(np.linalg.norm(p13))
            c3 = (n13**2 - a2**2 - a3**2) / (2 * a2 * a3)
            if abs(c3) > 1 + 1e-9:
                continue
            for t3 in (np.arccos(np.clip(c3, -1, 1)), -np.arccos(np.clip(c3, -1, 1))):
                t2 = -np.arctan2(p13[1], -p13[0]) + np.arcsin(np.clip(a3 * np.sin(t3) / n13, -1, 1))
                T34 = np.linalg.inv(_dh_link(t2, 1) @ _dh_link(t3, 2)) @ T14
                t4 = np.arctan2(T34[1, 0], T34[0, 0])
                q = np.array([t1, t2, t3, t4, t5, t6])
                solutions.append((q + np.pi) % (2 * np.pi) - np.pi)
    return solutions
