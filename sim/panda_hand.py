"""The Franka Hand as simulated: `FrankaHandDrive` drives the two finger slides of pybullet_data's Franka Panda
(`sim.panda.panda_urdf`), with the same care as the 2F-85 (`sim.gripper.Robotiq2F85`).

The Franka Hand's fingers are two prismatic joints already (`panda_finger_joint1/2`, half the stroke each, one motor and a
rack moving both): no linkage to re-hang. As on the 2F-85 the fingers are coupled by a gear constraint (one motor),
close with velocity control at the closing speed with the grip force as its limit until they stall, then push with
the grip force itself (`squeeze`), so the pads hold with the set force through the lift and hold and stop on the
surface. Each finger carries the drive's effective mass (`sim.gripper_urdf.CARRIAGE_MASS`, as the 2F-85's carriages:
a geared motor meets a contact impulse with its rotor's inertia, not a 100 g finger), its weight cancelled every
step, and the rubber-like pad friction and torsional friction of the 2F-85's pads (`sim.gripper`).

Gripper frame (docs/design.md section 3): z = the hand's z (approach), x = the hand's y (the fingers close along
it), origin between the pad centres; `T_base_tcp` maps the hand link (`panda_hand`) to it.
"""

from __future__ import annotations

import numpy as np
import pybullet

from sim.gripper import (COUPLING_ERP, COUPLING_FORCE, PAD_FRICTION, PAD_ROLLING_FRICTION,
                         GripperSettings, SlideDrive)
from sim.world import World

#: The description's finger joints (left, right) and links, and the hand link they hang from.
FINGER_JOINTS = ("panda_finger_joint1", "panda_finger_joint2")
FINGER_LINKS = ("panda_leftfinger", "panda_rightfinger")
HAND_LINK = "panda_hand"


class FrankaHandDrive(SlideDrive):
    """Drives the Franka Hand's fingers on a body loaded from `sim.panda.panda_urdf` (module docstring); the same
    interface as `sim.gripper.Robotiq2F85` for the grasp primitive and the cell. `pad_centre_z` is the pads' centre
    above the hand link along its z (from the finger mesh, `sim.panda.pad_centre_height`)."""

    def __init__(self, world: World, body: int, pad_centre_z: float, settings: GripperSettings) -> None:
        self.world = world
        self.body = body
        self.settings = settings
        self.hand = settings.hand
        c = world.client
        names = {c.getJointInfo(body, j)[1].decode(): j for j in range(c.getNumJoints(body))}
        links = {c.getJointInfo(body, j)[12].decode(): j for j in range(c.getNumJoints(body))}
        self.base_link = links[HAND_LINK]
        self.slides = tuple(names[n] for n in FINGER_JOINTS)
        self.pad_links = tuple(links[n] for n in FINGER_LINKS)
        self.fingertip_links = tuple((link,) for link in self.pad_links)
        self._open = 0.5 * self.hand.stroke  # each finger's joint position when open (the description's upper limit)
        self._slide_drive = "held"
        coupling = c.createConstraint(body, self.slides[0], body, self.slides[1], pybullet.JOINT_GEAR, [0, 0, 0],
                                      [0, 0, 0], [0, 0, 0])
        c.changeConstraint(coupling, gearRatio=-1, maxForce=COUPLING_FORCE, erp=COUPLING_ERP)
        world.pre_step_hooks.append(self._drive_fingers)
        for link in self.pad_links:
            c.changeDynamics(
                body, link, lateralFriction=PAD_FRICTION, spinningFriction=self.hand.torsion_radius,
                rollingFriction=PAD_ROLLING_FRICTION, frictionAnchor=1,
            )
        self._T_base_tcp = np.eye(4)
        self._T_base_tcp[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]  # x_tcp = the hand's y
        self._T_base_tcp[2, 3] = pad_centre_z

    # --- geometry -------------------------------------------------------------------------------------------

    @property
    def max_width(self) -> float:
        return self.hand.stroke

    @property
    def max_travel(self) -> float:
        return self._open

    def travel_for_width(self, width: float) -> float:
        """Each finger's travel (m) from fully open for a pad gap of `width` (clipped to the stroke)."""
        return float(self._open - 0.5 * np.clip(width, 0.0, self.hand.stroke))

    def width_for_travel(self, travel: float) -> float:
        return float(self.hand.stroke - 2.0 * travel)

    def T_base_tcp(self, width: float) -> np.ndarray:
        """Hand link -> TCP (between the pad centres); the pads move straight, so the same for every width."""
        return self._T_base_tcp.copy()

    # --- state ------------------------------------------------------------------------------------------------

    def joint_positions(self) -> dict[int, float]:
        c = self.world.client
        return {j: c.getJointState(self.body, j)[0] for j in self.slides}

    def travel(self) -> tuple[float, float]:
        """Each finger's travel (m) from fully open."""
        c = self.world.client
        return tuple(self._open - float(c.getJointState(self.body, j)[0]) for j in self.slides)

    def finger_asymmetry(self) -> float:
        """Distance (m) between the two pad centres' offsets from the hand's centre plane (mirror symmetry about
        the hand's x-z plane)."""
        T_base_world = np.linalg.inv(self.world.link_pose(self.body, self.base_link))
        left, right = (T_base_world @ self.world.link_pose(self.body, link) for link in self.pad_links)
        return float(np.linalg.norm(left[:3, 3] * np.array([1.0, -1.0, 1.0]) - right[:3, 3]))

    # --- actuation --------------------------------------------------------------------------------------------

    def _drive_fingers(self) -> None:
        """Before every physics step: while closing, drive both fingers towards closed (centred, as the 2F-85's),
        and cancel the fingers' drive mass's weight."""
        self._drive_slides(self.travel(), -1.0, self.pad_links)

    def set_travel(self, travel: float) -> None:
        """Place both fingers at a travel instantly (no physics) and hold them there."""
        c = self.world.client
        self._slide_drive = "held"
        position = self._open - float(np.clip(travel, 0.0, self._open))
        for joint in self.slides:
            c.resetJointState(self.body, joint, position)
        c.setJointMotorControlArray(self.body, list(self.slides), pybullet.POSITION_CONTROL,
                                    targetPositions=[position] * 2, forces=[self.settings.grip_force] * 2)

