"""The twin's 2F-85 behind the URCap socket (`TwinFingers`, the `FingerModel` of sim/lab/robotiq.py).

A request closing the fingers uses the twin's closing drive (`Robotiq2F85.command_close` at the requested speed and
force, then its squeeze once both slides stall, as `close_until_stall`); an opening request drives the slides open
at the requested speed. OBJ follows from the stall (2 closing, 1 opening) or the request being reached (3); POS is
the pad gap on the registers' linear scale (`OPEN_REGISTER`..`CLOSED_REGISTER` of sim/lab/robotiq.py). The scene
(sim/lab/twin.py) steps them and holds its lock around every call.
"""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pybullet

from sim.gripper import Robotiq2F85
from sim.lab.robotiq import (
    CLOSED_REGISTER,
    OBJ_AT_POSITION,
    OBJ_MOVING,
    OBJ_STOPPED_CLOSING,
    OBJ_STOPPED_OPENING,
    OPEN_REGISTER,
    finger_speed,
    grip_force,
)

if TYPE_CHECKING:
    from sim.lab.twin import TwinScene


#: A slide this close (m) to its stroke's end is shut (as `Robotiq2F85.close_until_stall`).
SHUT_MARGIN = 0.0005
#: Steps a finger motion runs before its stall is judged (as `Robotiq2F85.close_until_stall`).
STALL_WARMUP = 10
#: The slides must move on this far (m) past where they stalled for a held object to count as lost.
LOST_TRAVEL = 0.002


class TwinFingers:
    """The twin's 2F-85 behind the URCap socket (the FingerModel of sim/lab/robotiq.py): registers in, POS and OBJ
    out (module docstring). `fault` is the FLT code the server reports."""

    def __init__(self, scene: TwinScene) -> None:
        self.scene = scene
        self.fault = 0
        self._request: tuple[int, int, int] | None = None
        self._position = OPEN_REGISTER
        self._object = OBJ_AT_POSITION
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

    def request(self, position_register: int, speed_register: int, force_register: int) -> None:
        """Go to POS `position_register` at SPE `speed_register` with FOR `force_register` (0-255)."""
        with self.scene.lock:
            self._request = (int(position_register), int(speed_register), int(force_register))
            self._begin(self.scene.gripper)

    def lose_object(self) -> None:
        """Let go of what the fingers hold: the object drops out of the hand (`TwinScene.lose_object`)."""
        self.scene.lose_object()

    def _begin(self, gripper: Robotiq2F85) -> None:
        position, speed, force = self._request
        span = CLOSED_REGISTER - OPEN_REGISTER
        gap = float(np.clip((CLOSED_REGISTER - position) / span, 0.0, 1.0)) * gripper.max_width
        self._goal = gripper.travel_for_width(gap)
        self._speed, self._force = finger_speed(speed), grip_force(force)
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
            self._mode, self._object = "idle", OBJ_AT_POSITION

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
                    self._mode, self._object = "idle", OBJ_AT_POSITION
                elif stalled:
                    gripper.squeeze()
                    self._mode, self._object, self._stall = "holding", OBJ_STOPPED_CLOSING, min(travel)
            elif max(travel) <= self._goal:
                gripper.set_travel(self._goal)
                self._mode, self._object = "idle", OBJ_AT_POSITION
            elif stalled:
                gripper.set_travel(float(np.mean(travel)))
                self._mode, self._object = "idle", OBJ_STOPPED_OPENING
        elif self._mode == "holding" and min(travel) > self._stall + LOST_TRAVEL:
            gripper.command_close()  # the object slipped out: the fingers carry on to the request
            self._mode, self._object, self._history = "closing", OBJ_MOVING, []
        self._read(gripper)

    def _read(self, gripper: Robotiq2F85) -> None:
        self._travel = float(np.mean(gripper.travel()))
        fraction = gripper.width() / gripper.max_width
        self._position = int(np.clip(round(CLOSED_REGISTER - fraction * (CLOSED_REGISTER - OPEN_REGISTER)), 0, 255))
