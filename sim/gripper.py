"""The Robotiq 2F-85 as simulated: the linkage's parallel pads on force-limited slides, and a floating gripper.

The 2F-85 is a parallel-pad gripper: its six-bar linkage moves each inner finger (with its pad) along an arc of
the outer knuckle's pivot without turning it. The description (assets/robots/) has that linkage opened into a tree
of revolute joints, which PyBullet's iterative solver does not converge under a squeeze: at 100 iterations the
pads splayed 3.5-5 deg apart, a thin shaft rolled between them and the grip force never exceeded ~100 N
(docs/results/archive/twin-physics-round4-roll.md). `simulated_urdf` therefore re-hangs each inner finger from the gripper
body on two prismatic joints traced from the linkage's own kinematics: a closing slide (actuated: velocity control
at the closing speed with the grip force as its limit until the fingers stall, then pushed with the grip force
itself, as the 2F-85's motor squeezes; `Robotiq2F85.squeeze`) and a lift (servoed to the arc's height for
the slide's travel). The pads keep the 2F-85's geometry and arc, stay parallel by construction, and the squeeze
passes one joint to the gripper body. The knuckles and outer fingers stay as servoed followers of the arc's angle:
they are seen by the cameras and collide, but carry no squeeze.

Gripper frame (docs/design.md section 3): z = approach, x = closing direction, origin between the pad centres. The pad centres'
height above the gripper base depends on the opening (the arc), so `T_base_tcp(width)` gives the frame for the
width at which the pads will meet the object.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import pybullet
from scipy.spatial.transform import Rotation

from seggrasp.cell import DEFAULT_GRIP_FORCE, GRIP_FORCE_RANGE
from sim.world import PATH_RESOLUTION, ROBOT_ASSETS, World, linear_poses, pose_to_pb

#: The body the fingers hang from, and each side's linkage: (outer knuckle joint, inner knuckle joint, inner
#: finger joint of the description; the simulated closing slide and lift that replace the inner finger joint).
GRIPPER_BODY_LINK = "robotiq_body"
SIDES = (
    ("finger_joint", "left_inner_knuckle_joint", "left_inner_finger_joint", "left_finger_slide", "left_finger_lift"),
    ("right_outer_knuckle_joint", "right_inner_knuckle_joint", "right_inner_finger_joint", "right_finger_slide",
     "right_finger_lift"),
)
#: The gripper alone (the floating gripper's description); the arm's carries the same gripper.
GRIPPER_DESCRIPTION = "robotiq_2f85.urdf"
#: The gripper description's root link (the floating gripper's gantry carries it).
GANTRY_TOOL_LINK = "robotiq_base_link"
PAD_LINKS = ("left_inner_finger_pad", "right_inner_finger_pad")
#: The rigid fingertip of each side: the inner finger and the pad mounted on it (both touch what is grasped).
FINGERTIP_LINKS = (("left_inner_finger", "left_inner_finger_pad"), ("right_inner_finger", "right_inner_finger_pad"))
PAD_THICKNESS = 0.00635
#: The outer knuckle's travel (rad) from open to shut.
KNUCKLE_MAX = 0.8
#: Datasheet: 85 mm stroke.
MAX_WIDTH = 0.085
#: Mass (kg) of each slide's carriage: the finger drive's effective mass. The 2F-85's motor drives the fingers
#: through a self-locking gear, so a contact impulse meets the rotor's inertia times the squared gear ratio, not a
#: 15 g fingertip; with only the linkage's 58 g on the slide the closing velocity motor (100 iterations) pressed a
#: box resting on the table with about 130 N of a 235 N setting, with 0.5 kg all of it (the squeeze that holds a
#: lifted object is `Robotiq2F85.squeeze`). Its weight is cancelled every step (`Robotiq2F85._drive_fingers`).
CARRIAGE_MASS = 0.5
#: Force limit (N) and error reduction of the constraint that makes both slides travel together.
COUPLING_FORCE = 10000.0
COUPLING_ERP = 0.5
#: While closing, each slide's velocity target is corrected by this gain (1/s) times the other slide's lead, so
#: that the motors agree with the coupling instead of fighting it: without it the coupling drifted 2-3 mm apart on
#: the arm at 100 solver iterations and a screwdriver shaft turned in the fingers in 3 of 12 scenes (0 of 12 with).
CENTRING_GAIN = 100.0
#: Fingertip friction (silicone-like pads).
PAD_FRICTION = 1.0
#: Torsional friction of the pad's rubber patch, as PyBullet's `spinningFriction` (a length: the torque limit about
#: the contact normal is this x the object's friction x the normal force). A patch with friction mu and normal
#: force N resists twist with mu N times its mean contact radius; the narrowest patch a 2F-85 pad makes is a line
#: across its 22 mm width (a round handle), whose mean radius is 22 mm / 4 = 5.5 mm (a flat face under the whole
#: pad gives more). PyBullet's point contacts alone hold almost no twist.
PAD_SPINNING_FRICTION = 0.0055
PAD_ROLLING_FRICTION = 0.0001


@dataclass(frozen=True)
class GripperSettings:
    """Actuation: `grip_force` (N, the 2F-85's setting within `GRIP_FORCE_RANGE`) limits each closing slide's
    velocity motor and is the force each slide pushes with once the fingers stall; closing speed (m/s per pad: the
    datasheet's 20-150 mm/s), stall detection, and the servo forces of the lifts and the knuckle followers."""

    grip_force: float = DEFAULT_GRIP_FORCE
    closing_speed: float = 0.075
    stall_travel: float = 0.0002  # m a slide moves at most over `stall_steps` steps once it has stalled
    stall_steps: int = 8
    lift_force: float = 500.0
    follower_force: float = 50.0

    def __post_init__(self) -> None:
        low, high = GRIP_FORCE_RANGE
        if not low <= self.grip_force <= high:
            raise ValueError(f"grip_force must be within the 2F-85's {low:g}-{high:g} N, got {self.grip_force}")


# --- the simulated description ------------------------------------------------------------------------------------

def _origin(joint: ET.Element) -> np.ndarray:
    """A URDF joint's origin as a 4x4 pose (rpy: fixed-axis roll, pitch, yaw)."""
    element = joint.find("origin")
    xyz = [float(v) for v in element.get("xyz", "0 0 0").split()] if element is not None else [0.0] * 3
    rpy = [float(v) for v in element.get("rpy", "0 0 0").split()] if element is not None else [0.0] * 3
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    T[:3, 3] = xyz
    return T


def _rotation_about(joint: ET.Element, angle: float) -> np.ndarray:
    T = np.eye(4)
    axis = np.array([float(v) for v in joint.find("axis").get("xyz").split()])
    T[:3, :3] = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)).as_matrix()
    return T


def finger_arc(robot: ET.Element, side: tuple[str, ...], angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The linkage's kinematics of one side: the inner finger's frame at knuckle angle 0 in the gripper body frame,
    and its displacement (n x 3, that frame's axes) at each knuckle angle, the inner finger counter-rotating."""
    joints = {j.get("name"): j for j in robot.iter("joint")}
    by_child = {j.find("child").get("link"): j for j in robot.iter("joint")}
    knuckle, inner_finger = joints[side[0]], joints[side[2]]
    between = np.eye(4)  # outer knuckle -> inner finger joint's parent, through fixed joints
    link = inner_finger.find("parent").get("link")
    while link != knuckle.find("child").get("link"):
        joint = by_child[link]
        if joint.get("type") != "fixed":
            raise ValueError(f"unexpected {joint.get('type')} joint {joint.get('name')!r} in the 2F-85 finger")
        between = _origin(joint) @ between
        link = joint.find("parent").get("link")
    if knuckle.find("parent").get("link") != GRIPPER_BODY_LINK:
        raise ValueError(f"{side[0]!r} does not hang from {GRIPPER_BODY_LINK!r}")

    def pose(angle: float) -> np.ndarray:
        return (_origin(knuckle) @ _rotation_about(knuckle, angle) @ between @ _origin(inner_finger)
                @ _rotation_about(inner_finger, -angle))

    T_body_finger0 = pose(0.0)
    displacement = np.array([(np.linalg.inv(T_body_finger0) @ pose(a))[:3, 3] for a in angles])
    return T_body_finger0, displacement


def _inertial(mass: float, inertia: float = 1e-6) -> ET.Element:
    """An <inertial> element: `mass` (kg) at the link frame with a diagonal `inertia` (kg m^2)."""
    inertial = ET.Element("inertial")
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=f"{mass:g}")
    ET.SubElement(inertial, "inertia", ixx=f"{inertia:g}", ixy="0", ixz="0", iyy=f"{inertia:g}", iyz="0", izz=f"{inertia:g}")
    return inertial


ARC_ANGLES = np.linspace(0.0, KNUCKLE_MAX, 33)


def slide_arc(robot: ET.Element, side: tuple[str, ...]) -> tuple[np.ndarray, float, np.ndarray, np.ndarray]:
    """One side's arc as the slides trace it: (inner finger frame at knuckle angle 0 in the body frame, the closing
    direction along that frame's y (+1/-1), slide travel and lift at each of `ARC_ANGLES`)."""
    T_body_finger0, displacement = finger_arc(robot, side, ARC_ANGLES)
    if np.abs(displacement[:, 0]).max() > 1e-6:
        raise ValueError(f"the 2F-85 finger of {side[0]!r} does not move in its y-z plane")
    return T_body_finger0, float(np.sign(displacement[-1, 1])), np.abs(displacement[:, 1]), displacement[:, 2]


@lru_cache(maxsize=None)
def description_arcs(urdf_name: str) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """(slide travel, lift) over `ARC_ANGLES` of each side of the 2F-85 in a description of assets/robots/."""
    robot = ET.parse(ROBOT_ASSETS / urdf_name).getroot()
    return tuple(slide_arc(robot, side)[2:] for side in SIDES)


def slide_fingertips(robot: ET.Element) -> None:
    """Re-hang each inner finger of a 2F-85 description (in place) from the gripper body on a closing slide and a
    lift, both traced from `finger_arc`: slide travel = the arc's closing component, lift = its approach component."""
    for side in SIDES:
        joint = next(j for j in robot.iter("joint") if j.get("name") == side[2])
        T_body_finger0, closing, travel, lift = slide_arc(robot, side)
        carriage = side[3].replace("slide", "carriage")
        robot.remove(joint)
        link = ET.SubElement(robot, "link", name=carriage)
        link.append(_inertial(CARRIAGE_MASS))
        xyz = " ".join(f"{v:.9g}" for v in T_body_finger0[:3, 3])
        rpy = " ".join(f"{v:.12g}" for v in Rotation.from_matrix(T_body_finger0[:3, :3]).as_euler("xyz"))
        for name, parent, child, axis, origin, (low, high) in (
            (side[3], GRIPPER_BODY_LINK, carriage, f"0 {closing:g} 0", (xyz, rpy), (0.0, travel.max())),
            (side[4], carriage, joint.find("child").get("link"), "0 0 1", ("0 0 0", "0 0 0"),
             (min(lift.min(), 0.0), lift.max())),
        ):
            slide = ET.SubElement(robot, "joint", name=name, type="prismatic")
            ET.SubElement(slide, "parent", link=parent)
            ET.SubElement(slide, "child", link=child)
            ET.SubElement(slide, "origin", xyz=origin[0], rpy=origin[1])
            ET.SubElement(slide, "axis", xyz=axis)
            ET.SubElement(slide, "limit", lower=f"{low:.9g}", upper=f"{high:.9g}", effort="1000", velocity="1")


def simulated_robot(urdf_name: str) -> ET.Element:
    """A description from assets/robots/ as the twin simulates it: absolute mesh paths, the 2F-85's fingertips on
    slides (`slide_fingertips`)."""
    robot = ET.parse(ROBOT_ASSETS / urdf_name).getroot()
    for mesh in robot.iter("mesh"):
        mesh.set("filename", str(ROBOT_ASSETS / mesh.get("filename")))
    slide_fingertips(robot)
    return robot


def write_urdf(robot: ET.Element, name: str) -> Path:
    """Write a description to a temporary file removed when the process exits."""
    directory = tempfile.mkdtemp(prefix="seggrasp-robot-")
    atexit.register(shutil.rmtree, directory, ignore_errors=True)
    path = Path(directory) / name
    ET.ElementTree(robot).write(path, encoding="unicode", xml_declaration=True)
    return path


@lru_cache(maxsize=None)
def simulated_urdf(urdf_name: str) -> Path:
    """`simulated_robot` written once per process."""
    return write_urdf(simulated_robot(urdf_name), urdf_name)


class Robotiq2F85:
    """Drives the 2F-85 joints of a body (the floating gripper or the arm with the gripper on its flange) loaded
    from the `simulated_urdf` of `description`."""

    def __init__(
        self, world: World, body: int, base_link: int, description: str, settings: GripperSettings | None = None,
    ) -> None:
        self.world = world
        self.body = body
        self.base_link = base_link
        self.settings = settings or GripperSettings()
        c = world.client
        names = {c.getJointInfo(body, j)[1].decode(): j for j in range(c.getNumJoints(body))}
        links = {c.getJointInfo(body, j)[12].decode(): j for j in range(c.getNumJoints(body))}
        self.slides = tuple(names[side[3]] for side in SIDES)
        self.lifts = tuple(names[side[4]] for side in SIDES)
        self.knuckles = tuple((names[side[0]], names[side[1]]) for side in SIDES)
        self.arcs = description_arcs(description)
        self._slide_drive = "held"  # "held" at a set travel, "closing" at the closing speed, or "squeezing"
        self.pad_links = tuple(links[n] for n in PAD_LINKS)
        self.fingertip_links = tuple(tuple(links[n] for n in side) for side in FINGERTIP_LINKS)
        self.carriages = tuple(links[side[3].replace("slide", "carriage")] for side in SIDES)
        coupling = c.createConstraint(body, self.slides[0], body, self.slides[1], pybullet.JOINT_GEAR, [0, 0, 0],
                                      [0, 0, 0], [0, 0, 0])
        # one motor drives both fingers: the slides move together (PyBullet's gear: travel_left = travel_right)
        c.changeConstraint(coupling, gearRatio=-1, maxForce=COUPLING_FORCE, erp=COUPLING_ERP)
        world.pre_step_hooks.append(self._drive_fingers)
        for link in (link for side in self.fingertip_links for link in side):
            c.changeDynamics(
                body, link, lateralFriction=PAD_FRICTION, spinningFriction=PAD_SPINNING_FRICTION,
                rollingFriction=PAD_ROLLING_FRICTION, frictionAnchor=1,
            )
        self._calibrate()

    # --- geometry -------------------------------------------------------------------------------------------

    def _calibrate(self) -> None:
        """Tabulate pad gap and pad-centre height over the slide travel (the left side's arc) by forward kinematics
        of the loaded body."""
        self._arc_travel = self.arcs[0][0]
        saved = self.joint_positions()
        gaps, heights = [], []
        T_base_world = np.linalg.inv(self.world.link_pose(self.body, self.base_link))
        for travel in self._arc_travel:
            self.set_travel(travel)
            left, right = (T_base_world @ self.world.link_pose(self.body, link) for link in self.pad_links)
            gaps.append(np.linalg.norm(left[:3, 3] - right[:3, 3]) - PAD_THICKNESS)
            heights.append(0.5 * (left[2, 3] + right[2, 3]))
        self._restore(saved)
        self._gaps = np.asarray(gaps)  # decreasing with the travel
        self._heights = np.asarray(heights)

    def travel_for_width(self, width: float) -> float:
        """Slide travel (m, each side) whose pad gap is `width` (clipped to the stroke)."""
        width = float(np.clip(width, self._gaps[-1], self._gaps[0]))
        return float(np.interp(width, self._gaps[::-1], self._arc_travel[::-1]))

    def width_for_travel(self, travel: float) -> float:
        return float(np.interp(travel, self._arc_travel, self._gaps))

    @property
    def max_width(self) -> float:
        return float(self._gaps[0])

    @property
    def max_travel(self) -> float:
        return float(self._arc_travel[-1])

    def T_base_tcp(self, width: float) -> np.ndarray:
        """Gripper base -> TCP (between the pad centres) when the gripper is opened to `width`."""
        T = np.eye(4)
        T[2, 3] = float(np.interp(self.travel_for_width(width), self._arc_travel, self._heights))
        return T

    # --- state ------------------------------------------------------------------------------------------------

    def _joints(self) -> list[int]:
        return [*self.slides, *self.lifts, *(j for pair in self.knuckles for j in pair)]

    def joint_positions(self) -> dict[int, float]:
        c = self.world.client
        return {j: c.getJointState(self.body, j)[0] for j in self._joints()}

    def _restore(self, positions: dict[int, float]) -> None:
        for joint, value in positions.items():
            self.world.client.resetJointState(self.body, joint, value)

    def _arc(self, side: int, travel: float) -> tuple[float, float]:
        """(lift m, knuckle angle rad) of a side whose slide has travelled `travel`."""
        travels, lifts = self.arcs[side]
        return float(np.interp(travel, travels, lifts)), float(np.interp(travel, travels, ARC_ANGLES))

    def _drive_fingers(self) -> None:
        """Before every physics step: drive each side's lift and knuckles to the arc of its slide's travel, while
        closing drive both slides towards closed (centred: `CENTRING_GAIN`), and cancel the carriages' weight
        (`CARRIAGE_MASS`)."""
        c = self.world.client
        travel = self.travel()
        targets, forces = [], []
        for side, (lift, knuckles) in enumerate(zip(self.lifts, self.knuckles)):
            height, angle = self._arc(side, travel[side])
            targets += [(lift, height), *((k, angle) for k in knuckles)]
            forces += [self.settings.lift_force] + [self.settings.follower_force] * len(knuckles)
        c.setJointMotorControlArray(
            self.body, [j for j, _ in targets], pybullet.POSITION_CONTROL, targetPositions=[t for _, t in targets],
            forces=forces,
        )
        if self._slide_drive == "squeezing":
            c.setJointMotorControlArray(self.body, list(self.slides), pybullet.TORQUE_CONTROL,
                                        forces=[self.settings.grip_force] * 2)
        elif self._slide_drive == "closing":
            correction = CENTRING_GAIN * (travel[1] - travel[0])
            c.setJointMotorControlArray(
                self.body, list(self.slides), pybullet.VELOCITY_CONTROL,
                targetVelocities=[self.settings.closing_speed + correction, self.settings.closing_speed - correction],
                forces=[self.settings.grip_force] * 2,
            )
        for link in self.carriages:
            centre = c.getLinkState(self.body, link)[0]
            c.applyExternalForce(self.body, link, [0.0, 0.0, -CARRIAGE_MASS * self.world.physics.gravity], centre,
                                 pybullet.WORLD_FRAME)

    def set_travel(self, travel: float) -> None:
        """Place both fingers at a slide travel instantly (no physics) and hold them there; used at reset and for
        calibration."""
        c = self.world.client
        self._slide_drive = "held"
        for side, (slide, lift, knuckles) in enumerate(zip(self.slides, self.lifts, self.knuckles)):
            height, angle = self._arc(side, travel)
            c.resetJointState(self.body, slide, travel)
            c.resetJointState(self.body, lift, height)
            for knuckle in knuckles:
                c.resetJointState(self.body, knuckle, angle)
        c.setJointMotorControlArray(
            self.body, list(self.slides), pybullet.POSITION_CONTROL, targetPositions=[travel] * 2,
            forces=[self.settings.grip_force] * 2,
        )

    def set_width(self, width: float) -> None:
        self.set_travel(self.travel_for_width(width))

    def travel(self) -> tuple[float, float]:
        """Each slide's travel (m) from fully open."""
        c = self.world.client
        return tuple(float(c.getJointState(self.body, slide)[0]) for slide in self.slides)

    def width(self) -> float:
        """Current pad gap in metres."""
        return self.max_width - sum(self.travel())

    def finger_asymmetry(self) -> float:
        """Distance (m) between the two pad centres' offsets from the gripper's centre plane, i.e. how far the
        fingers are from mirror symmetry about the base's y-z plane."""
        T_base_world = np.linalg.inv(self.world.link_pose(self.body, self.base_link))
        left, right = (T_base_world @ self.world.link_pose(self.body, link) for link in self.pad_links)
        return float(np.linalg.norm(left[:3, 3] * np.array([-1.0, 1.0, 1.0]) - right[:3, 3]))

    # --- actuation --------------------------------------------------------------------------------------------

    def command_close(self) -> None:
        """From the next physics step until the next `set_travel`, velocity control of both slides towards closed
        at the closing speed with the grip force as the force limit (`_drive_fingers`)."""
        self._slide_drive = "closing"

    def squeeze(self) -> None:
        """From the next physics step until the next `set_travel`, push both slides closed with the grip force, as
        the 2F-85's motor does once its fingers stall on an object.

        A velocity motor with the grip force as its limit reaches that force only when the solver converges: it
        gains at most a carriage's mass times the closing speed per iteration, and a light object between the pads
        passes on its own mass times that. At 100-300 iterations the pads squeezed 30-100 N of a 235 N setting, and
        light objects crept out of the fingers (`bench/bench_replay.py`). The force itself is exact every step."""
        self.world.client.setJointMotorControlArray(self.body, list(self.slides), pybullet.VELOCITY_CONTROL,
                                                    targetVelocities=[0.0, 0.0], forces=[0.0, 0.0])
        self._slide_drive = "squeezing"

    def close_until_stall(self, on_step=None, max_steps: int = 240) -> int:
        """Close until both fingers stall (contact: from then on they `squeeze`) or the gripper is shut; returns the
        number of physics steps."""
        self.command_close()
        history: list[tuple[float, float]] = []
        window = self.settings.stall_steps
        shut = self.max_travel - 0.0005
        for step in range(1, max_steps + 1):
            if on_step is not None:
                on_step()
            self.world.step()
            travel = self.travel()
            if min(travel) >= shut:
                return step
            history.append(travel)
            if step > 10 and all(
                abs(now - then) < self.settings.stall_travel for now, then in zip(history[-1], history[-1 - window])
            ):
                self.squeeze()
                return step
        return max_steps


#: The floating gripper's slides: force limit (N) and the mass (kg) of each carriage.
SLIDE_FORCE = 1000.0
SLIDE_MASS = 1.0
#: Position and velocity gains of the slides' servo while following a path.
SLIDE_GAINS = (0.05, 1.0)


@lru_cache(maxsize=1)
def gantry_urdf() -> Path:
    """The simulated 2F-85 (`simulated_robot` of assets/robots/robotiq_2f85.urdf) mounted on three prismatic slides
    (x, y, z of a fixed anchor), written once per process."""
    robot = simulated_robot(GRIPPER_DESCRIPTION)
    if not any(link.get("name") == GANTRY_TOOL_LINK for link in robot.iter("link")):
        raise ValueError(f"{ROBOT_ASSETS / GRIPPER_DESCRIPTION} has no link {GANTRY_TOOL_LINK!r}")
    parent = "gantry_anchor"
    ET.SubElement(robot, "link", name=parent).append(_inertial(0.0))
    for name, axis, child in (("x", "1 0 0", "gantry_x_carriage"), ("y", "0 1 0", "gantry_y_carriage"), ("z", "0 0 1", GANTRY_TOOL_LINK)):
        if child != GANTRY_TOOL_LINK:
            ET.SubElement(robot, "link", name=child).append(_inertial(SLIDE_MASS, 1e-3))
        joint = ET.SubElement(robot, "joint", name=f"gantry_{name}", type="prismatic")
        ET.SubElement(joint, "parent", link=parent)
        ET.SubElement(joint, "child", link=child)
        ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
        ET.SubElement(joint, "axis", xyz=axis)
        ET.SubElement(joint, "limit", lower="-2", upper="2", effort=f"{SLIDE_FORCE:g}", velocity="1")
        parent = child
    return write_urdf(robot, "robotiq_2f85_gantry.urdf")


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
        self.gripper = Robotiq2F85(world, self.body, joints["gantry_z"], GRIPPER_DESCRIPTION, settings)  # the slide z carries the gripper
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
