"""The Franka Panda with the Franka Hand: the twin's second robot system (`SimCell(robot="panda")`).

The description is pybullet_data's `franka_panda/panda.urdf` (Franka Emika's, Apache-2.0), as the twin simulates it
(`panda_urdf`): absolute mesh paths, the fingers' collision hulls set back by PyBullet's contact margin
(`sim.world.COLLISION_SKIN`), the fingers' mimic joint removed (`sim.panda_hand` couples them as one motor
does), each finger carrying the drive's effective mass with a small inertia, the finger joints' effort at the hand's
maximum grip force (`seggrasp.hands.FRANKA_HAND`), and the arm's and hand's masses, centres of mass and inertias
those identified on a real Panda (`LINK_INERTIALS`) instead of the description's placeholders (every link 0.1 kg m^2
about each axis, some 50 times a wrist link's real inertia: with the real joint torques the arm then strayed up to
30 mm from a straight 10 cm approach and pushed what it came to grasp).

Kinematics: PyBullet's forward kinematics of the description and its damped-least-squares IK, run on a kinematic
copy of the arm in a physics client of its own (`PandaKinematics`), so that solving never disturbs the simulated
scene, refined by damped least squares on the description's Jacobian until it converges. A solution is accepted,
as the UR5's, only when its forward kinematics lands within `sim.robot.IK_POSITION_TOLERANCE` /
`IK_ANGLE_TOLERANCE` of the target with every joint inside the planning limits (the description's soft limits,
Franka's published joint limits). The Panda is redundant (7 joints): the IK is seeded from the configuration it should stay near, then from home and from home
with the base turned either way, which gives the planner other branches to try.
"""

from __future__ import annotations

import atexit
import xml.etree.ElementTree as ET
from functools import lru_cache
from pathlib import Path

import numpy as np
import pybullet
import pybullet_data
import trimesh
from scipy.spatial.transform import Rotation

from seggrasp.hands import FRANKA_HAND
from sim.gripper import GripperSettings
from sim.gripper_urdf import CARRIAGE_MASS, inertial_element, write_urdf
from sim.panda_hand import FINGER_JOINTS, FINGER_LINKS, HAND_LINK, FrankaHandDrive
from sim.robot import IK_ANGLE_TOLERANCE, IK_POSITION_TOLERANCE, ArmSettings, SerialArm, _joint_line
from sim.world import COLLISION_SKIN, World

PANDA_DIR = Path(pybullet_data.getDataPath()) / "franka_panda"
ARM_JOINTS = tuple(f"panda_joint{i}" for i in range(1, 8))
#: Ready pose: elbow up, the hand pointing straight down above the workspace (Franka's "ready" configuration).
HOME_Q = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
#: Weights of the joints when choosing the IK solution nearest a configuration (big joints move more mass).
JOINT_WEIGHTS = np.array([2.0, 2.0, 1.5, 1.5, 1.0, 1.0, 0.5])
#: IK: damped least-squares steps after PyBullet's solver until the pose error is below this (m, and rad), at most
#: `IK_ROUNDS` of them, each damped by `IK_DAMPING` and no joint moving more than `IK_MAX_STEP` (rad) in one.
IK_CONVERGED = 1e-5
IK_ROUNDS = 40
IK_DAMPING = 0.01
IK_MAX_STEP = 0.2
#: The base joint's turns (rad) added to home as further IK seeds.
IK_SEED_TURNS = (0.8, -0.8)
#: Mass (kg), centre of mass (m, link frame) and inertia about it (kg m^2: ixx, iyy, izz, ixy, ixz, iyz) of the arm's
#: links as identified on a real Panda by Gaz et al., "Dynamic Identification of the Franka Emika Panda Robot With
#: Retrieval of Feasible Parameters Using Penalty-Based Optimization", IEEE RA-L 4(4), 2019 (its link frames are the
#: description's), and of the hand as Franka's description gives it (0.73 kg, the datasheet's).
LINK_INERTIALS = {
    "panda_link1": (4.970684, (0.003875, 0.002081, -0.04762),
                    (0.70337, 0.70661, 0.009117, -0.000139, 0.006772, 0.019169)),
    "panda_link2": (0.646926, (-0.003141, -0.02872, 0.003495),
                    (0.007962, 0.02811, 0.025995, -0.003925, 0.010254, 0.000704)),
    "panda_link3": (3.228604, (0.027518, 0.039252, -0.066502),
                    (0.037242, 0.036155, 0.01083, -0.004761, -0.011396, -0.012805)),
    "panda_link4": (3.587895, (-0.05317, 0.104419, 0.027454),
                    (0.025853, 0.019552, 0.028323, 0.007796, -0.001332, 0.008641)),
    "panda_link5": (1.225946, (-0.011953, 0.041065, -0.038437),
                    (0.035549, 0.029474, 0.008627, -0.002117, -0.004037, 0.000229)),
    "panda_link6": (1.666555, (0.060149, -0.014117, -0.010517),
                    (0.001964, 0.004354, 0.005433, 0.000109, -0.001158, 0.000341)),
    "panda_link7": (0.735522, (0.010517, -0.004252, 0.061597),
                    (0.012516, 0.010027, 0.004815, -0.000428, -0.001196, -0.000741)),
    HAND_LINK: (0.73, (-0.01, 0.0, 0.03), (0.001, 0.0025, 0.0017, 0.0, 0.0, 0.0)),
}


def _mesh_path(filename: str) -> str:
    return str(PANDA_DIR / filename.replace("package://", ""))


@lru_cache(maxsize=1)
def pad_centre_height() -> float:
    """The pads' centre above the hand link (m): the finger joint's origin plus the middle of the finger's flat
    inner face (the collision mesh's vertices within 0.5 mm of its inner plane)."""
    robot = ET.parse(PANDA_DIR / "panda.urdf").getroot()
    joint = next(j for j in robot.iter("joint") if j.get("name") == FINGER_JOINTS[0])
    link = next(k for k in robot.iter("link") if k.get("name") == FINGER_LINKS[0])
    mesh = trimesh.load(_mesh_path(link.find("collision/geometry/mesh").get("filename")), force="mesh")
    inner = mesh.vertices[:, 1] <= mesh.vertices[:, 1].min() + 0.0005
    z = mesh.vertices[inner, 2]
    return float(joint.find("origin").get("xyz").split()[2]) + 0.5 * float(z.min() + z.max())


@lru_cache(maxsize=1)
def panda_urdf() -> Path:
    """pybullet_data's Panda as the twin simulates it (module docstring), written once per process."""
    robot = ET.parse(PANDA_DIR / "panda.urdf").getroot()
    for mesh in robot.iter("mesh"):
        mesh.set("filename", _mesh_path(mesh.get("filename")))
    for link in robot.iter("link"):
        if link.get("name") in LINK_INERTIALS:
            mass, com, inertia = LINK_INERTIALS[link.get("name")]
            link.remove(link.find("inertial"))
            link.append(inertial_element(mass, inertia, com))
        if link.get("name") in FINGER_LINKS:
            link.remove(link.find("inertial"))
            link.append(inertial_element(CARRIAGE_MASS, 1e-4))
            contact = link.find("contact")
            if contact is not None:  # friction and stiffness are set by the drive (sim.panda_hand)
                link.remove(contact)
            # PyBullet keeps contacts on the finger's convex hull `COLLISION_SKIN` outside it: set the hull back
            # by that much, so that the fingers touch where the mesh's inner face is (the pad gap is the joints')
            collision = link.find("collision")
            origin = collision.find("origin")
            if origin is None:
                origin = ET.SubElement(collision, "origin", rpy="0 0 0")
            outwards = 1.0 if link.get("name") == FINGER_LINKS[0] else -1.0  # the left finger opens along +y
            origin.set("xyz", f"0 {outwards * COLLISION_SKIN:g} 0")
    for joint in robot.iter("joint"):
        if joint.get("name") in FINGER_JOINTS:
            mimic = joint.find("mimic")
            if mimic is not None:
                joint.remove(mimic)
            joint.find("limit").set("effort", f"{FRANKA_HAND.grip_force_range[1]:g}")
    return write_urdf(robot, "panda_franka_hand.urdf")


class PandaKinematics:
    """Forward and inverse kinematics of the Panda on a kinematic copy in its own PyBullet client (module
    docstring)."""

    def __init__(self) -> None:
        self.client = pybullet.connect(pybullet.DIRECT)
        atexit.register(self.close)
        self.body = pybullet.loadURDF(str(panda_urdf()), useFixedBase=True, physicsClientId=self.client)
        infos = [pybullet.getJointInfo(self.body, j, physicsClientId=self.client)
                 for j in range(pybullet.getNumJoints(self.body, physicsClientId=self.client))]
        names = {info[1].decode(): info[0] for info in infos}
        self.arm_joints = [names[n] for n in ARM_JOINTS]
        self.hand_link = next(info[0] for info in infos if info[12].decode() == HAND_LINK)
        self.movable = [info[0] for info in infos if info[2] != pybullet.JOINT_FIXED]
        robot = ET.parse(PANDA_DIR / "panda.urdf").getroot()
        soft = {j.get("name"): j.find("safety_controller") for j in robot.iter("joint")}
        self.lower = np.array([float(soft[n].get("soft_lower_limit")) for n in ARM_JOINTS])
        self.upper = np.array([float(soft[n].get("soft_upper_limit")) for n in ARM_JOINTS])
        self.max_speed = np.array([infos[j][11] for j in self.arm_joints])
        self.max_force = np.array([infos[j][10] for j in self.arm_joints])
        # PyBullet's null-space IK takes limits for every movable joint (the fingers: their travel)
        finger = [(infos[j][8], infos[j][9]) for j in self.movable if j not in self.arm_joints]
        self._lower_all = [*self.lower, *(f[0] for f in finger)]
        self._upper_all = [*self.upper, *(f[1] for f in finger)]
        # the Jacobian is of a point given in the link's centre-of-mass frame: the link frame's origin there
        state = pybullet.getLinkState(self.body, self.hand_link, physicsClientId=self.client)
        self._jacobian_point = (-Rotation.from_quat(state[3]).inv().apply(state[2])).tolist()
        self._ranges = [high - low for low, high in zip(self._lower_all, self._upper_all)]

    def close(self) -> None:
        if self.client >= 0 and pybullet.isConnected(self.client):
            pybullet.disconnect(self.client)
        self.client = -1

    def _set(self, q: np.ndarray) -> None:
        for joint, value in zip(self.arm_joints, q):
            pybullet.resetJointState(self.body, joint, float(value), physicsClientId=self.client)

    def fk(self, q: np.ndarray) -> np.ndarray:
        """World (the base) -> hand link for arm joints `q`."""
        self._set(q)
        state = pybullet.getLinkState(self.body, self.hand_link, computeForwardKinematics=True,
                                      physicsClientId=self.client)
        T = np.eye(4)
        T[:3, :3] = np.array(pybullet.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        T[:3, 3] = state[4]
        return T

    def solve(self, T_world_hand: np.ndarray, seed: np.ndarray, local: bool = False) -> np.ndarray:
        """PyBullet's IK from `seed` (null space pulled towards it; skipped when `local`: the target is near the
        seed's pose, a waypoint 1 cm from the last), then damped least squares on the description's Jacobian within
        the joint limits until the pose error is below `IK_CONVERGED` (m, and its rad) or `IK_ROUNDS` steps have
        run. PyBullet's IK alone, from home, left a median 2.4 mm and a 95th percentile of 11 mm over grasp poses
        above the workspace (bench/bench_panda_hand.py's poses)."""
        seed = np.asarray(seed, dtype=float)
        q = seed
        if not local:
            position = T_world_hand[:3, 3].tolist()
            w, x, y, z = _quaternion(T_world_hand[:3, :3])
            rest = [*seed, *([0.0] * (len(self.movable) - len(self.arm_joints)))]
            self._set(seed)
            solution = pybullet.calculateInverseKinematics(
                self.body, self.hand_link, position, [x, y, z, w], lowerLimits=self._lower_all,
                upperLimits=self._upper_all, jointRanges=self._ranges, restPoses=rest, maxNumIterations=100,
                residualThreshold=1e-6, physicsClientId=self.client,
            )
            q = np.clip(np.asarray(solution[: len(self.arm_joints)]), self.lower, self.upper)
        columns = [self.movable.index(j) for j in self.arm_joints]
        fingers = [0.0] * (len(self.movable) - len(self.arm_joints))
        for _ in range(IK_ROUNDS):
            T = self.fk(q)
            error = np.r_[T_world_hand[:3, 3] - T[:3, 3], _rotation_vector(T_world_hand[:3, :3] @ T[:3, :3].T)]
            if np.abs(error[:3]).max() < IK_CONVERGED and np.abs(error[3:]).max() < IK_CONVERGED:
                break
            linear, angular = pybullet.calculateJacobian(
                self.body, self.hand_link, self._jacobian_point, [*q.tolist(), *fingers], [0.0] * len(self.movable),
                [0.0] * len(self.movable), physicsClientId=self.client,
            )
            J = np.vstack([np.asarray(linear)[:, columns], np.asarray(angular)[:, columns]])
            step = J.T @ np.linalg.solve(J @ J.T + IK_DAMPING**2 * np.eye(6), error)
            step *= min(1.0, IK_MAX_STEP / max(float(np.abs(step).max()), 1e-12))
            q = np.clip(q + step, self.lower, self.upper)
        return q


def _rotation_vector(R: np.ndarray) -> np.ndarray:
    """The rotation vector of a rotation matrix (scipy's `as_rotvec`, without its cost on 3 x 3 matrices)."""
    skew = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    angle = float(np.arccos(np.clip(0.5 * (np.trace(R) - 1.0), -1.0, 1.0)))
    if angle < 1e-6:
        return 0.5 * skew
    if angle > np.pi - 1e-3:
        return Rotation.from_matrix(R).as_rotvec()
    return angle / (2.0 * np.sin(angle)) * skew


def _pose_error(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """`sim.robot.pose_error`, faster."""
    return (float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])),
            float(np.linalg.norm(_rotation_vector(T_a[:3, :3].T @ T_b[:3, :3]))))


def _quaternion(R: np.ndarray) -> tuple[float, float, float, float]:
    x, y, z, w = Rotation.from_matrix(R).as_quat()
    return w, x, y, z


@lru_cache(maxsize=1)
def kinematics() -> PandaKinematics:
    """One kinematic copy per process (every Panda cell shares it; its state is set before every use)."""
    return PandaKinematics()


class PandaArm(SerialArm):
    """The Franka Panda + Franka Hand as one fixed-base body at the world origin, with the UR5's motion interface
    (`sim.robot.SerialArm`)."""

    def __init__(self, world: World, settings: ArmSettings | None = None, gripper: GripperSettings | None = None):
        self.world = world
        self.kinematics = kinematics()
        limit = float(self.kinematics.max_speed.min())
        settings = settings or ArmSettings(max_joint_speed=limit)
        self.settings = ArmSettings(max_joint_speed=min(settings.max_joint_speed, limit))
        c = world.client
        self.body = world.load_robot(panda_urdf())
        joints = {c.getJointInfo(self.body, j)[1].decode(): j for j in range(c.getNumJoints(self.body))}
        self.arm_joints = [joints[n] for n in ARM_JOINTS]
        self.home_q = HOME_Q
        self.joint_forces = self.kinematics.max_force
        gripper = (gripper or GripperSettings(hand=FRANKA_HAND)).for_hand(FRANKA_HAND)
        self.gripper = FrankaHandDrive(world, self.body, pad_centre_height(), gripper)
        self.gripper_base_link = self.gripper.base_link
        self.q_commanded = HOME_Q.copy()

    @property
    def joint_lower(self) -> np.ndarray:
        return self.kinematics.lower

    @property
    def joint_upper(self) -> np.ndarray:
        return self.kinematics.upper

    # --- kinematics -----------------------------------------------------------------------------------------

    def fk(self, q: np.ndarray) -> np.ndarray:
        """World -> hand link (the gripper base) for arm joints `q`."""
        return self.kinematics.fk(np.asarray(q, dtype=float))

    def _accepted(self, q: np.ndarray, T_world_target: np.ndarray) -> bool:
        if np.any(q < self.joint_lower - 1e-9) or np.any(q > self.joint_upper + 1e-9):
            return False
        position_error, angle_error = _pose_error(self.fk(q), T_world_target)
        return position_error <= IK_POSITION_TOLERANCE and angle_error <= IK_ANGLE_TOLERANCE

    def ik_solutions(self, T_world_target: np.ndarray, near: np.ndarray | None = None) -> list[np.ndarray]:
        """The IK solutions from each seed (`near`, default home; home; home with the base turned) that pass the
        reachability check, distinct, nearest to `near` first."""
        near = HOME_Q if near is None else np.asarray(near, dtype=float)
        seeds = [near, HOME_Q]
        for turn in IK_SEED_TURNS:
            seed = HOME_Q.copy()
            seed[0] += turn
            seeds.append(seed)
        solutions: list[np.ndarray] = []
        for seed in seeds:
            q = self.kinematics.solve(T_world_target, seed)
            if self._accepted(q, T_world_target) and all(np.abs(q - s).max() > 1e-3 for s in solutions):
                solutions.append(q)
        return sorted(solutions, key=lambda q: float(np.abs((q - near) * JOINT_WEIGHTS).sum()))

    def ik(self, T_world_target: np.ndarray, near: np.ndarray | None = None) -> tuple[np.ndarray | None, str]:
        """The solution found from `near` (default home; by damped least squares alone when `near` is given, as
        for the waypoints of a straight line) if it passes the check, else the nearest of `ik_solutions`, or
        (None, reason)."""
        local = near is not None
        near = HOME_Q if near is None else np.asarray(near, dtype=float)
        q = self.kinematics.solve(T_world_target, near, local=local)
        if self._accepted(q, T_world_target):
            return q, ""
        solutions = self.ik_solutions(T_world_target, near)
        if solutions:
            return solutions[0], ""
        return None, "no IK solution of the Panda within its joint limits reaches the pose"

    def free_space_paths(self, q_start: np.ndarray, q_target: np.ndarray) -> list[list[np.ndarray]]:
        """Candidate joint-space paths from `q_start` to `q_target` (waypoints <= 0.05 rad apart): straight, or
        through a raised via point (target joints, home shoulder and elbow)."""
        via = q_target.copy()
        via[[1, 3]] = HOME_Q[[1, 3]]
        return [_joint_line(q_start, [q_target]), _joint_line(q_start, [via, q_target])]

    def table_check_links(self) -> tuple[int, list[int]]:
        """Links that must stay clear of the table: everything from the upper arm on (the base and the shoulder
        sit on it)."""
        return self.body, [j for j in range(self.world.client.getNumJoints(self.body)) if j >= self.arm_joints[1]]
