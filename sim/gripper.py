"""The Robotiq 2F-85 as simulated: the datasheet's numbers, its actuation settings and `Robotiq2F85`, which drives
the pads of the simulated description (`sim.gripper_urdf`: each inner finger on a closing slide and a lift).

The closing slides are actuated (velocity control at the closing speed with the grip force as its limit until the
fingers stall, then pushed with the grip force itself, as the 2F-85's motor squeezes; `Robotiq2F85.squeeze`), the
lifts servoed to the arc's height for the slide's travel. The knuckles and outer fingers stay as servoed followers
of the arc's angle: they are seen by the cameras and collide, but carry no squeeze.

Gripper frame (docs/design.md section 3): z = approach, x = closing direction, origin between the pad centres. The pad centres'
height above the gripper base depends on the opening (the arc), so `T_base_tcp(width)` gives the frame for the
width at which the pads will meet the object.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet

from seggrasp.hands import ROBOTIQ_2F85, Hand
from sim.gripper_urdf import ARC_ANGLES, CARRIAGE_MASS, FINGERTIP_LINKS, PAD_LINKS, SIDES, description_arcs
from sim.world import World

#: The 2F-85's pads and stroke (`seggrasp.hands.ROBOTIQ_2F85`).
PAD_THICKNESS = ROBOTIQ_2F85.pad_thickness
MAX_WIDTH = ROBOTIQ_2F85.stroke
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
#: force N resists twist with mu N times its mean contact radius; the narrowest patch a pad makes is a line
#: across its width (a round handle), whose mean radius is a quarter of the width (`Hand.torsion_radius`; a flat
#: face under the whole pad gives more). PyBullet's point contacts alone hold almost no twist.
PAD_SPINNING_FRICTION = ROBOTIQ_2F85.torsion_radius
PAD_ROLLING_FRICTION = 0.0001


@dataclass(frozen=True)
class GripperSettings:
    """Actuation of a hand (`hand`, `seggrasp.hands`; the 2F-85 by default): `grip_force` (N, within the hand's
    `grip_force_range`; None: its `default_grip_force`) limits each closing slide's velocity motor and is the force
    each slide pushes with once the fingers stall; closing speed (m/s per pad, within the hand's
    `finger_speed_range`; None: the hand's `closing_speed`), stall detection, and the servo forces of the 2F-85's
    lifts and knuckle followers."""

    grip_force: float | None = None
    closing_speed: float | None = None
    stall_travel: float = 0.0002  # m a slide moves at most over `stall_steps` steps once it has stalled
    stall_steps: int = 8
    lift_force: float = 500.0
    follower_force: float = 50.0
    hand: Hand = ROBOTIQ_2F85

    def __post_init__(self) -> None:
        if self.grip_force is None:
            object.__setattr__(self, "grip_force", self.hand.default_grip_force)
        if self.closing_speed is None:
            object.__setattr__(self, "closing_speed", self.hand.closing_speed)
        low, high = self.hand.grip_force_range
        if not low <= self.grip_force <= high:
            raise ValueError(f"grip_force must be within the {self.hand.name}'s {low:g}-{high:g} N, got {self.grip_force}")
        low, high = self.hand.finger_speed_range
        if not low <= self.closing_speed <= high:
            raise ValueError(f"closing_speed must be within the {self.hand.name}'s {low:g}-{high:g} m/s, got "
                             f"{self.closing_speed}")

    def for_hand(self, hand: Hand) -> "GripperSettings":
        """These settings on another hand: a grip force or closing speed left at this hand's default takes the
        other hand's default."""
        if hand == self.hand:
            return self
        force = None if self.grip_force == self.hand.default_grip_force else self.grip_force
        speed = None if self.closing_speed == self.hand.closing_speed else self.closing_speed
        return GripperSettings(force, speed, self.stall_travel, self.stall_steps, self.lift_force,
                               self.follower_force, hand)


class SlideDrive:
    """What the twin's parallel hands share: once the fingers stall on an object, the slides push with the grip
    force. A subclass drives its fingers in `_drive_fingers` and has `world`, `body`, `slides`, `settings`,
    `max_travel`, `max_width`, `travel()`, `travel_for_width()` and `set_travel()`."""

    def set_width(self, width: float) -> None:
        self.set_travel(self.travel_for_width(width))

    def width(self) -> float:
        """Current pad gap in metres."""
        return self.max_width - sum(self.travel())

    def command_close(self) -> None:
        """From the next physics step until the next `set_travel`, velocity control of both slides towards closed
        at the closing speed with the grip force as the force limit (`_drive_fingers`)."""
        self._slide_drive = "closing"

    def _drive_slides(self, travel: tuple[float, float], closing: float, carriages: tuple[int, ...]) -> None:
        """The slides' part of `_drive_fingers`: while closing drive both slides towards closed (centred:
        `CENTRING_GAIN`), while squeezing push them with the grip force, and cancel the drive mass's weight
        (`CARRIAGE_MASS`) on `carriages`. `closing` is the sign (+1 or -1) of a slide's joint motion towards
        closed."""
        c = self.world.client
        if self._slide_drive == "squeezing":
            c.setJointMotorControlArray(self.body, list(self.slides), pybullet.TORQUE_CONTROL,
                                        forces=[closing * self.settings.grip_force] * 2)
        elif self._slide_drive == "closing":
            correction = CENTRING_GAIN * (travel[1] - travel[0])
            c.setJointMotorControlArray(
                self.body, list(self.slides), pybullet.VELOCITY_CONTROL,
                targetVelocities=[closing * (self.settings.closing_speed + correction),
                                  closing * (self.settings.closing_speed - correction)],
                forces=[self.settings.grip_force] * 2,
            )
        for link in carriages:
            centre = c.getLinkState(self.body, link)[0]
            c.applyExternalForce(self.body, link, [0.0, 0.0, -CARRIAGE_MASS * self.world.physics.gravity], centre,
                                 pybullet.WORLD_FRAME)

    def squeeze(self) -> None:
        """From the next physics step until the next `set_travel`, push both slides closed with the grip force, as
        a hand's motor does once its fingers stall on an object.

        A velocity motor with the grip force as its limit reaches that force only when the solver converges: it
        gains at most a carriage's mass times the closing speed per iteration, and a light object between the pads
        passes on its own mass times that. At 100-300 iterations the 2F-85's pads squeezed 30-100 N of its full
        force, and light objects crept out of the fingers (`bench/bench_replay.py`). The force itself is exact every
        step."""
        self.world.client.setJointMotorControlArray(self.body, list(self.slides), pybullet.VELOCITY_CONTROL,
                                                    targetVelocities=[0.0, 0.0], forces=[0.0, 0.0])
        self._slide_drive = "squeezing"

    def close_until_stall(self, on_step=None, max_steps: int = 240) -> int:
        """Close until both fingers stall (contact: from then on they `squeeze`) or the hand is shut; returns the
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


class Robotiq2F85(SlideDrive):
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
        self._drive_slides(travel, 1.0, self.carriages)

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

    def travel(self) -> tuple[float, float]:
        """Each slide's travel (m) from fully open."""
        c = self.world.client
        return tuple(float(c.getJointState(self.body, slide)[0]) for slide in self.slides)

    def finger_asymmetry(self) -> float:
        """Distance (m) between the two pad centres' offsets from the gripper's centre plane, i.e. how far the
        fingers are from mirror symmetry about the base's y-z plane."""
        T_base_world = np.linalg.inv(self.world.link_pose(self.body, self.base_link))
        left, right = (T_base_world @ self.world.link_pose(self.body, link) for link in self.pad_links)
        return float(np.linalg.norm(left[:3, 3] * np.array([-1.0, 1.0, 1.0]) - right[:3, 3]))

