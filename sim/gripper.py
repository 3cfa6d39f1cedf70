"""The Robotiq 2F-85: its six-bar linkage as one actuated joint plus gear constraints, and a floating gripper.

The description (assets/robots/) has the linkage opened into a tree: `finger_joint` (left outer knuckle) is the
actuated joint; the right outer knuckle and both inner knuckles turn with it (multiplier +1) and both inner
fingers counter-rotate (multiplier -1), which keeps the pads parallel. Before every physics step each follower is
servoed (stiff position control) to its multiple of the current `finger_joint` angle, so the fingers stay symmetric
under load: measured < 1 mm while holding a box, where PyBullet gear constraints (erp 0.2-1, maxForce up to 1e4)
let the loaded finger lag by 9-12 mm. Closing is velocity control with a torque limit on `finger_joint` (the grip
force), stopped when the finger stalls; the followers only copy its angle.

Gripper frame (DESIGN.md): z = approach, x = closing direction, origin between the pad centres. The pad centres'
height above the gripper base depends on the opening (the fingers swing on an arc), so `T_base_tcp(width)` gives
the frame for the width at which the pads will meet the object.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import pybullet

from seggrasp.cell import DEFAULT_GRIP_FORCE, GRIP_FORCE_RANGE
from sim.world import PATH_RESOLUTION, ROBOT_ASSETS, World, linear_poses, pose_to_pb

FINGER_JOINT = "finger_joint"
#: The gripper description's root link (the floating gripper's gantry carries it).
GANTRY_TOOL_LINK = "robotiq_base_link"
#: Followers of `finger_joint` and their multipliers (the 2F-85's mimic joints).
MIMIC_JOINTS = {
    "right_outer_knuckle_joint": 1.0,
    "left_inner_knuckle_joint": 1.0,
    "right_inner_knuckle_joint": 1.0,
    "left_inner_finger_joint": -1.0,
    "right_inner_finger_joint": -1.0,
}
PAD_LINKS = ("left_inner_finger_pad", "right_inner_finger_pad")
#: The rigid fingertip of each side: the inner finger and the pad mounted on it (both touch what is grasped).
FINGERTIP_LINKS = (("left_inner_finger", "left_inner_finger_pad"), ("right_inner_finger", "right_inner_finger_pad"))
PAD_THICKNESS = 0.00635
FINGER_JOINT_MAX = 0.8
#: Datasheet: 85 mm stroke.
MAX_WIDTH = 0.085
#: Fingertip friction (silicone-like pads).
PAD_FRICTION = 1.0
#: Torsional friction of the pad's rubber patch, as PyBullet's `spinningFriction` (a length: the torque limit about
#: the contact normal is this x the object's friction x the normal force). A patch with friction mu and normal
#: force N resists twist with mu N times its mean contact radius; the narrowest patch a 2F-85 pad makes is a line
#: across its 22 mm width (a round handle), whose mean radius is 22 mm / 4 = 5.5 mm (a flat face under the whole
#: pad gives more). PyBullet's point contacts alone hold almost no twist.
PAD_SPINNING_FRICTION = 0.0055
PAD_ROLLING_FRICTION = 0.0001


#: `finger_joint` torque (N m) per newton of grip force: the linkage's lever from the motor to the pad centres
#: (about 8 cm over the stroke; tests/test_sim_gripper.py checks the resulting squeeze).
TORQUE_PER_NEWTON = 0.08


@dataclass(frozen=True)
class GripperSettings:
    """Actuation: `grip_force` (N, the 2F-85's setting within `GRIP_FORCE_RANGE`) becomes the torque limit of the
    velocity-controlled `finger_joint`; closing speed (rad/s), the followers' servo force and stall detection."""

    grip_force: float = DEFAULT_GRIP_FORCE
    closing_speed: float = 1.5
    stall_travel: float = 0.004  # rad over `stall_steps` steps: the finger has stalled
    stall_steps: int = 8
    follower_force: float = 50.0
    follower_gain: float = 1.0

    def __post_init__(self) -> None:
        low, high = GRIP_FORCE_RANGE
        if not low <= self.grip_force <= high:
            raise ValueError(f"grip_force must be within the 2F-85's {low:g}-{high:g} N, got {self.grip_force}")

    @property
    def closing_torque(self) -> float:
        """Torque limit (N m) of `finger_joint` that squeezes with `grip_force`."""
        return self.grip_force * TORQUE_PER_NEWTON


class Robotiq2F85:
    """Drives the 2F-85 joints of a body (the floating gripper or the arm with the gripper on its flange)."""

    def __init__(self, world: World, body: int, base_link: int, settings: GripperSettings | None = None) -> None:
        self.world = world
        self.body = body
        self.base_link = base_link
        self.settings = settings or GripperSettings()
        c = world.client
        names = {c.getJointInfo(body, j)[1].decode(): j for j in range(c.getNumJoints(body))}
        links = {c.getJointInfo(body, j)[12].decode(): j for j in range(c.getNumJoints(body))}
        self.finger_joint = names[FINGER_JOINT]
        self.mimic = {names[n]: m for n, m in MIMIC_JOINTS.items()}
        self.pad_links = tuple(links[n] for n in PAD_LINKS)
        self.fingertip_links = tuple(tuple(links[n] for n in side) for side in FINGERTIP_LINKS)
        world.pre_step_hooks.append(self._servo_followers)
        for link in (link for side in self.fingertip_links for link in side):
            c.changeDynamics(
                body, link, lateralFriction=PAD_FRICTION, spinningFriction=PAD_SPINNING_FRICTION,
                rollingFriction=PAD_ROLLING_FRICTION, frictionAnchor=1,
            )
        self._calibrate()

    def _servo_followers(self) -> None:
        """Mimic joints: before every physics step, drive each follower to its multiple of the finger angle."""
        c = self.world.client
        angle = c.getJointState(self.body, self.finger_joint)[0]
        joints = list(self.mimic)
        c.setJointMotorControlArray(
            self.body, joints, pybullet.POSITION_CONTROL, targetPositions=[self.mimic[j] * angle for j in joints],
            forces=[self.settings.follower_force] * len(joints), positionGains=[self.settings.follower_gain] * len(joints),
        )

    # --- geometry -------------------------------------------------------------------------------------------

    def _calibrate(self) -> None:
        """Tabulate pad gap and pad-centre height over the finger angle by forward kinematics."""
        angles = np.linspace(0.0, FINGER_JOINT_MAX, 33)
        saved = self.joint_positions()
        gaps, heights = [], []
        T_base_world = np.linalg.inv(self.world.link_pose(self.body, self.base_link))
        for angle in angles:
            self.set_angle(angle)
            left, right = (T_base_world @ self.world.link_pose(self.body, link) for link in self.pad_links)
            gaps.append(np.linalg.norm(left[:3, 3] - right[:3, 3]) - PAD_THICKNESS)
            heights.append(0.5 * (left[2, 3] + right[2, 3]))
        self._restore(saved)
        self._angles = angles
        self._gaps = np.asarray(gaps)  # decreasing with the angle
        self._heights = np.asarray(heights)

    def angle_for_width(self, width: float) -> float:
        """Finger angle whose pad gap is `width` (clipped to the stroke)."""
        width = float(np.clip(width, self._gaps[-1], self._gaps[0]))
        return float(np.interp(width, self._gaps[::-1], self._angles[::-1]))

    def width_for_angle(self, angle: float) -> float:
        return float(np.interp(angle, self._angles, self._gaps))

    @property
    def max_width(self) -> float:
        return float(self._gaps[0])

    def T_base_tcp(self, width: float) -> np.ndarray:
        """Gripper base -> TCP (between the pad centres) when the gripper is opened to `width`."""
        T = np.eye(4)
        T[2, 3] = float(np.interp(self.angle_for_width(width), self._angles, self._heights))
        return T

    # --- state ------------------------------------------------------------------------------------------------

    def joint_positions(self) -> dict[int, float]:
        c = self.world.client
        return {j: c.getJointState(self.body, j)[0] for j in (self.finger_joint, *self.mimic)}

    def _restore(self, positions: dict[int, float]) -> None:
        for joint, value in positions.items():
            self.world.client.resetJointState(self.body, joint, value)

    def set_angle(self, angle: float) -> None:
        """Place the linkage at a finger angle instantly (no physics); used at reset and for calibration."""
        c = self.world.client
        c.resetJointState(self.body, self.finger_joint, angle)
        for joint, multiplier in self.mimic.items():
            c.resetJointState(self.body, joint, multiplier * angle)
        c.setJointMotorControl2(
            self.body, self.finger_joint, pybullet.POSITION_CONTROL, targetPosition=angle,
            force=self.settings.closing_torque * 4,
        )

    def set_width(self, width: float) -> None:
        self.set_angle(self.angle_for_width(width))

    def angle(self) -> float:
        return float(self.world.client.getJointState(self.body, self.finger_joint)[0])

    def width(self) -> float:
        """Current pad gap in metres."""
        return self.width_for_angle(self.angle())

    def finger_asymmetry(self) -> float:
        """Distance (m) between the two pad centres' offsets from the gripper's centre plane, i.e. how far the
        fingers are from mirror symmetry about the base's y-z plane."""
        T_base_world = np.linalg.inv(self.world.link_pose(self.body, self.base_link))
        left, right = (T_base_world @ self.world.link_pose(self.body, link) for link in self.pad_links)
        return float(np.linalg.norm(left[:3, 3] * np.array([-1.0, 1.0, 1.0]) - right[:3, 3]))

    # --- actuation --------------------------------------------------------------------------------------------

    def command_close(self) -> None:
        """Velocity control towards closed with the force (torque) limit: squeezes whatever is between the pads."""
        self.world.client.setJointMotorControl2(
            self.body, self.finger_joint, pybullet.VELOCITY_CONTROL, targetVelocity=self.settings.closing_speed,
            force=self.settings.closing_torque,
        )

    def close_until_stall(self, on_step=None, max_steps: int = 240) -> int:
        """Close until the finger stalls (contact) or the gripper is shut; returns the number of physics steps."""
        self.command_close()
        c = self.world.client
        history: list[float] = []
        window = self.settings.stall_steps
        for step in range(1, max_steps + 1):
            if on_step is not None:
                on_step()
            self.world.step()
            position = c.getJointState(self.body, self.finger_joint)[0]
            if position >= FINGER_JOINT_MAX - 0.01:
                return step
            history.append(position)
            if step > 10 and abs(history[-1] - history[-1 - window]) < self.settings.stall_travel:
                return step
        return max_steps


#: The floating gripper's slides: force limit (N) and the mass (kg) of each carriage.
SLIDE_FORCE = 1000.0
SLIDE_MASS = 1.0
#: Position and velocity gains of the slides' servo while following a path.
SLIDE_GAINS = (0.05, 1.0)


@lru_cache(maxsize=1)
def gantry_urdf() -> Path:
    """The 2F-85 description (assets/robots/robotiq_2f85.urdf) mounted on three prismatic slides (x, y, z of a
    fixed anchor), written once per process to a temporary file with absolute mesh paths."""
    text = (ROBOT_ASSETS / "robotiq_2f85.urdf").read_text()
    text = text.replace('filename="robotiq_2f85/', f'filename="{ROBOT_ASSETS}/robotiq_2f85/')
    inertial = '<inertial><mass value="{:g}"/><inertia ixx="1e-3" ixy="0" ixz="0" iyy="1e-3" iyz="0" izz="1e-3"/></inertial>'
    chain, parent = [f'<link name="gantry_anchor">{inertial.format(0.0)}</link>'], "gantry_anchor"
    for name, axis, child in (("x", "1 0 0", "gantry_x_carriage"), ("y", "0 1 0", "gantry_y_carriage"), ("z", "0 0 1", GANTRY_TOOL_LINK)):
        if child != GANTRY_TOOL_LINK:
            chain.append(f'<link name="{child}">{inertial.format(SLIDE_MASS)}</link>')
        chain.append(
            f'<joint name="gantry_{name}" type="prismatic"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="0 0 0"/><axis xyz="{axis}"/>'
            f'<limit lower="-2" upper="2" effort="{SLIDE_FORCE:g}" velocity="1"/></joint>'
        )
        parent = child
    anchor = f'<link name="{GANTRY_TOOL_LINK}">'
    if anchor not in text:
        raise ValueError(f"{ROBOT_ASSETS / 'robotiq_2f85.urdf'} has no link {GANTRY_TOOL_LINK!r}")
    text = text.replace(anchor, "\n  ".join(chain) + "\n  " + anchor, 1)
    directory = tempfile.mkdtemp(prefix="seggrasp-gantry-")
    atexit.register(shutil.rmtree, directory, ignore_errors=True)
    path = Path(directory) / "robotiq_2f85_gantry.urdf"
    path.write_text(text)
    return path


class FloatingGripper:
    """A 2F-85 with no arm, for fast sweeps: placed directly at free-space targets (as in VGN), then moved along
    straight lines by three stiff prismatic slides under a fixed anchor (a Cartesian gantry, `gantry_urdf`).

    The slides make the gripper part of a fixed-base chain, as on the arm, so the solver anchors the squeezing
    linkage as firmly. A free base dragged by a fixed constraint (the model before) let the pads' grip fade during
    the lift: a claw hammer held at 100 N fell from every top-3 oracle grasp at 100 solver iterations and needed 300
    (`tests/test_sim_gripper.py` lifts it). `place` re-anchors the gantry at the pose with the slides at zero;
    `follow` servos the slides along the path in the anchor's frame (orientation fixed, as every straight line of
    the grasp primitive keeps it).

    Exposes the same motion interface as the arm (`reset_home`, `configuration`, `plan`,
    `free_space_paths`, `move_free`, `place`, `follow`, `hold`, `table_check_links`, `gripper`).
    """

    name = "floating"

    def __init__(self, world: World, T_world_home: np.ndarray, settings: GripperSettings | None = None) -> None:
        self.world = world
        self.T_world_home = np.asarray(T_world_home, dtype=float)
        position, orientation = pose_to_pb(self.T_world_home)
        self.body = world.client.loadURDF(
            str(gantry_urdf()), position, orientation, useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE,
        )
        c = world.client
        joints = {c.getJointInfo(self.body, j)[1].decode(): j for j in range(c.getNumJoints(self.body))}
        self.slides = [joints[f"gantry_{axis}"] for axis in "xyz"]
        self.gripper = Robotiq2F85(world, self.body, joints["gantry_z"], settings)  # the slide z carries the gripper
        self._anchor = self.T_world_home.copy()
        self._commanded = self.T_world_home.copy()
        self.max_speed = 0.5  # m/s along straight lines

    def _servo(self, T_world_base: np.ndarray, velocity: np.ndarray | None = None) -> None:
        """Drive the slides towards the base pose `T_world_base` (its position in the anchor frame)."""
        R, origin = self._anchor[:3, :3], self._anchor[:3, 3]
        target = R.T @ (np.asarray(T_world_base)[:3, 3] - origin)
        velocity = np.zeros(3) if velocity is None else R.T @ velocity
        kp, kd = SLIDE_GAINS
        self.world.client.setJointMotorControlArray(
            self.body, self.slides, pybullet.POSITION_CONTROL, targetPositions=target.tolist(),
            targetVelocities=velocity.tolist(), forces=[SLIDE_FORCE] * 3, positionGains=[kp] * 3,
            velocityGains=[kd] * 3,
        )

    def _teleport(self, T_world_base: np.ndarray) -> None:
        """Re-anchor the gantry at `T_world_base` with the slides at zero and at rest."""
        c = self.world.client
        self._anchor = np.asarray(T_world_base, dtype=float).copy()
        self._commanded = self._anchor.copy()
        position, orientation = pose_to_pb(self._anchor)
        c.resetBasePositionAndOrientation(self.body, position, orientation)
        for joint in self.slides:
            c.resetJointState(self.body, joint, 0.0, 0.0)
        self._servo(self._anchor)

    def reset_home(self, width: float = MAX_WIDTH) -> None:
        self._teleport(self.T_world_home)
        self.gripper.set_width(width)

    def plan(self, poses: list[np.ndarray]) -> tuple[list[list[list[np.ndarray]]], str]:
        """One candidate (a floating gripper reaches every pose): the first pose alone, then straight lines with
        waypoints every `PATH_RESOLUTION` m."""
        paths = [[np.asarray(poses[0], dtype=float)]]
        for index in range(1, len(poses)):
            paths.append(linear_poses(poses[index - 1], poses[index], PATH_RESOLUTION)[1:])
        return [paths], ""

    def configuration(self) -> np.ndarray:
        """The commanded base pose."""
        return self._commanded.copy()

    def free_space_paths(self, T_world_start: np.ndarray, T_world_target: np.ndarray) -> list[list[np.ndarray]]:
        """Poses to check on the way to a free-space target: the floating gripper is placed there directly."""
        return [[T_world_target]]

    def move_free(self, path: list[np.ndarray], on_step=None) -> None:
        """Free-space move of a floating gripper: placed at the end of the (checked) path, as in VGN."""
        self._teleport(path[-1])

    def place(self, T_world_base: np.ndarray) -> None:
        """Put the gripper base at a pose instantly (kinematic; used for checks and free-space moves)."""
        self._teleport(T_world_base)

    def follow(self, path: list[np.ndarray], speed: float, on_step=None) -> None:
        """Move the base through waypoints at `speed` (m/s), one slide target per physics step; ends at rest on
        the last waypoint."""
        dt = self.world.physics.time_step
        for T_next in path:
            start = self._commanded[:3, 3]
            delta = np.asarray(T_next)[:3, 3] - start
            steps = max(1, int(round(float(np.linalg.norm(delta)) / (min(speed, self.max_speed) * dt))))
            for k in range(1, steps + 1):
                T = self._commanded.copy()
                T[:3, 3] = start + delta * k / steps
                self._servo(T, delta / (steps * dt))
                if on_step is not None:
                    on_step()
                self.world.step()
            self._commanded[:3, 3] = start + delta
        self._servo(self._commanded)

    def hold(self, steps: int, on_step=None) -> None:
        for _ in range(steps):
            if on_step is not None:
                on_step()
            self.world.step()

    def table_check_links(self) -> tuple[int, list[int]]:
        """(body, links) whose geometry must stay clear of the table (the slides have none)."""
        return self.body, list(range(self.gripper.base_link, self.world.client.getNumJoints(self.body)))
