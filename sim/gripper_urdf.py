"""The 2F-85's description as the twin simulates it: each inner finger re-hung from the gripper body on slides.

The 2F-85 is a parallel-pad gripper: its six-bar linkage moves each inner finger (with its pad) along an arc of
the outer knuckle's pivot without turning it. The description (assets/robots/) has that linkage opened into a tree
of revolute joints, which PyBullet's iterative solver does not converge under a squeeze: at 100 iterations the
pads splayed 3.5-5 deg apart, a thin shaft rolled between them and the grip force never exceeded ~100 N
(docs/results/archive/twin-physics-round4-roll.md). `simulated_urdf` therefore re-hangs each inner finger from the
gripper body on two prismatic joints traced from the linkage's own kinematics (`finger_arc`): a closing slide (the
arc's closing component, actuated by `sim.gripper.Robotiq2F85`) and a lift (its approach component, servoed to the
arc's height for the slide's travel). The pads keep the 2F-85's geometry and arc, stay parallel by construction, and
the squeeze passes one joint to the gripper body.
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
import xml.etree.ElementTree as ET
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from sim.world import ROBOT_ASSETS

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
#: The 2F-85's root link: on the arm's flange, or carried by the floating gripper's gantry.
GRIPPER_BASE_LINK = "robotiq_base_link"
PAD_LINKS = ("left_inner_finger_pad", "right_inner_finger_pad")
#: The rigid fingertip of each side: the inner finger and the pad mounted on it (both touch what is grasped).
FINGERTIP_LINKS = (("left_inner_finger", "left_inner_finger_pad"), ("right_inner_finger", "right_inner_finger_pad"))
#: The outer knuckle's travel (rad) from open to shut.
KNUCKLE_MAX = 0.8
#: Mass (kg) of each slide's carriage: the finger drive's effective mass. The 2F-85's motor drives the fingers
#: through a self-locking gear, so a contact impulse meets the rotor's inertia times the squared gear ratio, not a
#: 15 g fingertip; with only the linkage's 58 g on the slide the closing velocity motor (100 iterations) pressed a
#: box resting on the table with about 130 N of its full-force setting, with 0.5 kg all of it (the squeeze that holds a
#: lifted object is `sim.gripper.Robotiq2F85.squeeze`). Its weight is cancelled every step
#: (`Robotiq2F85._drive_fingers`).
CARRIAGE_MASS = 0.5


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


def inertial_element(mass: float, inertia: float | tuple[float, ...] = 1e-6,
                     com: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> ET.Element:
    """An <inertial> element: `mass` (kg) at `com` (m, link frame) with `inertia` (kg m^2) about it, one number for
    a diagonal one or (ixx, iyy, izz, ixy, ixz, iyz)."""
    ixx, iyy, izz, ixy, ixz, iyz = (inertia, inertia, inertia, 0.0, 0.0, 0.0) if np.isscalar(inertia) else inertia
    inertial = ET.Element("inertial")
    ET.SubElement(inertial, "origin", xyz=" ".join(f"{v:g}" for v in com), rpy="0 0 0")
    ET.SubElement(inertial, "mass", value=f"{mass:g}")
    ET.SubElement(inertial, "inertia", ixx=f"{ixx:g}", ixy=f"{ixy:g}", ixz=f"{ixz:g}", iyy=f"{iyy:g}", iyz=f"{iyz:g}",
                  izz=f"{izz:g}")
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
        link.append(inertial_element(CARRIAGE_MASS))
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
