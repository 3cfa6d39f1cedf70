"""The twin behind the emulated lab cell: `SimCell`'s PyBullet scene, its UR5 as the controller's `ArmModel`
(`TwinArm`) and its 2F-85 as the URCap's `FingerModel` (`TwinFingers`), stepped in real time by a clock thread,
with the control-channel commands `place` and `truth` (`twin_models` is what `python -m sim.lab serve` runs).

Frames. ur_rtde speaks the controller's base frame (the UR's DH base); the URDF's `base_link` is that frame turned
by pi about z (`sim.robot.T_BASELINK_DHBASE`). After every placement the twin's UR5 body is turned so that its
`base_link` sits at `T_WORLD_BASELINK` = T_DHBASE_BASELINK in the PyBullet world, which makes the world the RTDE
base frame: the wire's joints are PyBullet's, home has q0 = pi (`HOME_Q_WIRE`, the moving links exactly where
SimCell's `HOME_Q` puts them), and the table, the object and the cameras keep SimCell's numbers. A placement is
`SimCell.reset(seed, object_id)` itself, so the wire and the twin backend see the same scene for a seed.

Motion. A moveJ, moveL or stop is planned by the controller's kinematic model (`sim.lab.kinematic.KinematicArm`,
started at the arm's actual joints: trapezoidal profiles, inverse kinematics, joint limits, a safety plane at the
table top) and tracked every physics step by the UR5's joint servos (`UR5Arm._command`, as the twin's own
motions); a motion ends when the arm has settled on its end. The arm halts where it is on a safety stop: one the
controller sets, or a protective stop of its own when, during a motion, a link of the arm (upper arm to wrist)
touches the table, or the robot presses on the table, directly or through the object, with more than
`PROTECTIVE_FORCE` for `PROTECTIVE_STEPS` physics steps.

Fingers. A request closing the fingers uses the twin's closing drive (`Robotiq2F85.command_close` at the
requested speed and force, then its squeeze once both slides stall, as `close_until_stall`); an opening request
drives the slides open at the requested speed. OBJ follows from the stall (2 closing, 1 opening) or the request
being reached (3); POS is the pad gap on the registers' linear scale.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pybullet

from sim.cell import SimCell
from sim.gripper import Robotiq2F85
from sim.lab.cameras import write_recordings
from sim.lab.control import register
from sim.lab.controller import HOME_Q_WIRE
from sim.lab.kinematic import KinematicArm, pose_matrix, pose_vector
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
from sim.robot import T_BASELINK_DHBASE, UR5Arm, dh_forward
from sim.world import TABLE_TOP_Z, pose_to_pb

log = logging.getLogger(__name__)

#: Where the twin's URDF `base_link` sits in its world, the RTDE base frame (module docstring).
T_WORLD_BASELINK = np.linalg.inv(T_BASELINK_DHBASE)
#: Force (N) the robot may press on the table, directly or through the object, before the emulated controller
#: stops the arm: the tool force limit of the emulated safety configuration.
PROTECTIVE_FORCE = 150.0
#: Physics steps in a row the force must stay above the limit (one step's solver spike does not stop the arm).
PROTECTIVE_STEPS = 3
#: A motion has ended once every joint is this close (rad) to its end and slower than `SETTLED_SPEED` (rad/s), or
#: `SETTLE_TIME` (s) after its reference came to rest.
SETTLED_ERROR = 1e-3
SETTLED_SPEED = 0.01
SETTLE_TIME = 1.0
#: A slide this close (m) to its stroke's end is shut (as `Robotiq2F85.close_until_stall`).
SHUT_MARGIN = 0.0005
#: Steps a finger motion runs before its stall is judged (as `Robotiq2F85.close_until_stall`).
STALL_WARMUP = 10
#: The slides must move on this far (m) past where they stalled for a held object to count as lost.
LOST_TRAVEL = 0.002
#: The clock drops its backlog (and counts it as lag) when it falls this far (s) behind the wall clock.
MAX_BACKLOG = 0.25
#: Serial numbers of the twin's cameras (SimCell's rig, in order); hardware/cell.emulated.yaml names the same.
CAMERA_SERIALS = ("941000000001", "941000000002")
#: Where the twin writes its cameras' recordings unless told otherwise (hardware/cell.emulated.yaml reads them there).
RECORDINGS = Path("~/.cache/seggrasp/lab").expanduser()
#: Where the lost object lands (x, y on the table, beside the workspace).
LOST_OBJECT_SPOT = (0.5, 0.45)


# --- the arm ----------------------------------------------------------------------------------------------------

class TwinArm:
    """The twin's UR5 behind the emulated controller (an `ArmModel`): poses in the RTDE base frame with the active
    TCP, joints in rad. A command starts a `KinematicArm` at the arm's actual joints (the controller's motion
    planner: its profiles, inverse kinematics, joint limits and the table's safety plane); every physics step the
    joint servos track that reference. Getters return the state after the last physics step without touching
    PyBullet."""

    def __init__(self, scene: TwinScene) -> None:
        self.scene = scene
        self.safety_status = "normal"
        self.stop_reason = ""
        self._tcp = np.eye(4)
        self._q = HOME_Q_WIRE.copy()
        self._qd = np.zeros(6)
        self._reference: KinematicArm | None = None
        self._moving = False
        self._over_force = 0

    # --- state (cached) ---
    def step(self, dt: float) -> None:
        """Advance the physics by `dt` when no clock thread runs (tests); the clock steps it otherwise."""
        if not self.scene.clock_running:
            self.scene.advance(dt)

    def actual_q(self) -> list[float]:
        return [float(v) for v in self._q]

    def actual_qd(self) -> list[float]:
        return [float(v) for v in self._qd]

    def actual_tcp_pose(self) -> list[float]:
        return pose_vector(dh_forward(self._q) @ self._tcp)

    def is_moving(self) -> bool:
        return self._moving

    def set_tcp(self, pose: list[float]) -> None:
        self._tcp = pose_matrix(pose)

    # --- queries and commands, on the controller's kinematic model at the actual joints ---
    def _planner(self) -> KinematicArm:
        lower, upper = self.scene.joint_limits
        planner = KinematicArm(self._q, lower, upper, planes=(((0.0, 0.0, 1.0), TABLE_TOP_Z),))
        planner.set_tcp(pose_vector(self._tcp))
        return planner

    def joints_within_limits(self, q: list[float]) -> bool:
        return self._planner().joints_within_limits(q)

    def pose_within_limits(self, pose: list[float]) -> bool:
        """Reachable within the joint limits, with the TCP above the table plane (the emulated safety plane)."""
        return self._planner().pose_within_limits(pose)

    def ik_has_solution(self, pose: list[float], qnear: list[float] | None = None) -> bool:
        return self._planner().ik_has_solution(pose, qnear)

    def inverse_kinematics(self, pose: list[float], qnear: list[float] | None = None) -> list[float] | None:
        return self._planner().inverse_kinematics(pose, qnear)

    def move_joints(self, q: list[float], speed: float, acceleration: float) -> None:
        self._start(lambda planner: planner.move_joints(q, speed, acceleration))

    def move_linear(self, pose: list[float], speed: float, acceleration: float) -> None:
        self._start(lambda planner: planner.move_linear(pose, speed, acceleration))

    def _start(self, command) -> None:
        if self.safety_status != "normal":  # a stopped arm starts nothing (the controller has stopped the program)
            return
        with self.scene.lock:
            planner = self._planner()
            command(planner)
            if planner.is_moving():
                self._reference, self._moving = planner, True

    def stop(self, deceleration: float) -> None:
        """Decelerate the running motion to rest along its path (stopL / stopJ)."""
        with self.scene.lock:
            if self._reference is not None:
                self._reference.stop(deceleration)

    # --- per physics step (the scene's lock is held) ---
    def reload(self, robot: UR5Arm) -> None:
        """After a placement rebuilt the robot: turn its base into the RTDE frame and put the arm back where it
        was, at rest."""
        position, orientation = pose_to_pb(T_WORLD_BASELINK)
        robot.world.client.resetBasePositionAndOrientation(robot.body, position, orientation)
        robot.place(self._q)
        self._reference, self._moving, self._qd = None, False, np.zeros(6)

    def before_step(self, robot: UR5Arm, dt: float) -> None:
        """Command the joint servos for the next physics step."""
        reference = self._reference
        if reference is None:
            return
        if self.safety_status != "normal":
            self._halt(robot)
            return
        reference.step(dt)
        if reference.safety_status != "normal":  # the planner found no inverse kinematics on the line
            self._protective_stop(robot, "moveL: no inverse kinematics on the way (a singularity or out of reach)")
            return
        robot._command(np.asarray(reference.q), np.asarray(reference.qd))  # the UR5's servos, as the twin's moves

    def after_step(self, robot: UR5Arm, table: int, obj: int, weight: float) -> None:
        """Read the joints, end a motion once the arm has settled on its end, and watch for a protective stop."""
        states = robot.world.client.getJointStates(robot.body, robot.arm_joints)
        self._q = np.array([s[0] for s in states])
        self._qd = np.array([s[1] for s in states])
        reference = self._reference
        if reference is not None and not reference.is_moving():
            self._settling += self.scene.time_step
            settled = (np.abs(self._q - np.asarray(reference.q)).max() < SETTLED_ERROR
                       and np.abs(self._qd).max() < SETTLED_SPEED)
            if settled or self._settling > SETTLE_TIME:
                self._reference, self._moving = None, False
        else:
            self._settling = 0.0
        if self.safety_status == "normal" and reference is not None:  # the controller watches its own motions
            reason = self._collision(robot, table, obj, weight)
            if reason:
                self._protective_stop(robot, reason)

    def _protective_stop(self, robot: UR5Arm, reason: str) -> None:
        self.safety_status, self.stop_reason = "protective_stop", reason
        log.warning("protective stop: %s", reason)
        self._halt(robot)

    def _collision(self, robot: UR5Arm, table: int, obj: int, weight: float) -> str:
        """Why the controller would stop the arm: a link of the arm on the table, or the robot pressing down on the
        table (directly, or through the object: the table's push on it beyond its `weight`) with more than
        `PROTECTIVE_FORCE` for `PROTECTIVE_STEPS` steps; "" otherwise. (The contact forces between the fingers and
        the object do not sum to what the arm feels in PyBullet: the squeeze leaves tens of newtons of residue.)"""
        c = robot.world.client
        arm_links = set(range(robot.arm_joints[1], robot.gripper.base_link))  # upper arm to wrist 3
        press = 0.0
        for point in c.getContactPoints(bodyA=robot.body, bodyB=table):
            if point[3] in arm_links:
                return f"arm-table collision ({c.getJointInfo(robot.body, point[3])[12].decode()} touches the table)"
            press += point[9]
        press += max(0.0, sum(point[9] for point in c.getContactPoints(bodyA=obj, bodyB=table)) - weight)
        self._over_force = self._over_force + 1 if press > PROTECTIVE_FORCE else 0
        if self._over_force >= PROTECTIVE_STEPS:
            self._over_force = 0
            return f"the tool presses {press:.0f} N on the table, above the {PROTECTIVE_FORCE:.0f} N limit"
        return ""

    def _halt(self, robot: UR5Arm) -> None:
        """Brake where the arm is and end its motion."""
        robot._command(self._q, np.zeros(6))
        self._reference, self._moving = None, False


# --- the fingers ------------------------------------------------------------------------------------------------

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


# --- the scene --------------------------------------------------------------------------------------------------

class TwinScene:
    """The twin's world behind the emulated cell: one `SimCell` placed by `place(object_id, seed)`, the arm and
    fingers driven through `arm` / `fingers`, physics advanced by `advance` or by the clock thread (`start`).
    Every PyBullet call holds `lock`."""

    def __init__(self, object_id: str, seed: int, recordings: str | Path | None) -> None:
        self.lock = threading.RLock()
        self.recordings = None if recordings is None else Path(recordings)
        self.sim_time = 0.0
        self.arm = TwinArm(self)
        self.fingers = TwinFingers(self)
        self.cell: SimCell | None = None
        self.joint_limits: tuple[np.ndarray, np.ndarray] = (np.full(6, -2 * np.pi), np.full(6, 2 * np.pi))
        self._models: dict = {}
        self._placed: dict = {}
        self._frames: dict = {}
        self._clock: Clock | None = None
        self.place(object_id, seed)

    @property
    def gripper_options(self) -> dict:
        """How `python -m sim.lab serve` starts the URCap socket in front of `fingers`: the twin's clock moves
        them, not the server's."""
        return {"step_period": None}

    @property
    def gripper(self) -> Robotiq2F85:
        return self.cell.robot.gripper

    @property
    def clock_running(self) -> bool:
        return self._clock is not None and self._clock.is_alive()

    @property
    def time_step(self) -> float:
        return self.cell.world.physics.time_step

    def place(self, object_id: str, seed: int) -> dict:
        """Reset the scene as `SimCell.reset(seed, object_id)` does, with the arm and fingers where they are; render
        the cameras into recordings (none without a recordings folder). Returns `truth()` plus the recordings' paths by camera serial."""
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise ValueError(f"place: seed must be a non-negative integer, got {seed!r}")
        model = self._model(object_id)
        started = time.monotonic()
        with self.lock:
            cell = self._cell_with(model)
            cell.reset(seed, object_id)
            robot = cell.robot
            self.arm.reload(robot)
            self.fingers.reload(robot.gripper)
            self.joint_limits = _joint_limits(robot)
            self._placed = {"object": object_id, "seed": seed,
                            "T_world_obj": np.round(cell.object_mesh()[1], 9).tolist()}
            if self.recordings is not None:
                self._frames = dict(zip(CAMERA_SERIALS, cell.capture(), strict=True))
            if self._clock is not None:
                self._clock.resync(time.monotonic() - started)
            placed, frames = dict(self._placed), dict(self._frames)
        # written with the physics running again: the recordings take a second or more per camera
        paths = {} if self.recordings is None else write_recordings(frames, self.recordings)
        return dict(placed, recordings={serial: str(path) for serial, path in paths.items()})

    def stop_cameras(self) -> dict:
        """The `camera_stop` fault: each camera's recording is replaced by one frame set, so the client's stream
        stops during its next warm-up."""
        with self.lock:
            frames = dict(self._frames)
        if not frames:
            raise ValueError("camera_stop: this twin renders no cameras (it has no recordings folder)")
        paths = write_recordings(frames, self.recordings, n_frames=1)
        return {"recordings": {serial: str(path) for serial, path in paths.items()}}

    def handlers(self) -> dict:
        """The control-channel commands of the twin (sim/lab/control.py: request dict -> reply fields)."""
        return {
            "place": lambda request: self.place(request.get("object"), request.get("seed", 0)),
            "truth": lambda request: self.truth(),
            "camera_stop": lambda request: self.stop_cameras(),
            "twin_state": lambda request: {"safety_status": self.arm.safety_status,
                                           "stop_reason": self.arm.stop_reason, **self.stats()},
        }

    def truth(self) -> dict:
        """The object placed last and its pose now (`T_world_obj`, RTDE base frame), with where it was placed."""
        with self.lock:
            return {"object": self._placed["object"], "seed": self._placed["seed"],
                    "T_world_obj": np.round(self.cell.object_mesh()[1], 9).tolist(),
                    "T_world_obj_placed": self._placed["T_world_obj"]}

    def lose_object(self) -> None:
        """Take the object out of the hand: it lands on the table beside the workspace."""
        with self.lock:
            c, body = self.cell.world.client, self.cell.object_body
            position, orientation = c.getBasePositionAndOrientation(body)
            c.resetBasePositionAndOrientation(body, [*LOST_OBJECT_SPOT, position[2] - min(position[2], 0.0) + 0.1],
                                              orientation)
            c.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0])

    def _model(self, object_id: str):
        if object_id not in self._models:
            from seggrasp.objects import load_asset

            if not isinstance(object_id, str):
                raise ValueError(f"place: object must be a twin object id, got {object_id!r}")
            self._models[object_id] = load_asset(object_id)
        return self._models[object_id]

    def _cell_with(self, model) -> SimCell:
        if self.cell is None or model.object_id not in {o.object_id for o in self.cell.objects}:
            if self.cell is not None:
                self.cell.close()
            self.cell = SimCell(objects=list(self._models.values()), embodiment="arm")
        return self.cell

    # --- time ---
    def advance(self, seconds: float) -> None:
        """Run the physics for `seconds` of simulated time (whole time steps)."""
        for _ in range(max(1, round(seconds / self.time_step))):
            self.step_once()

    def step_once(self) -> None:
        """One physics step: the arm's and fingers' drives, the step, their state."""
        with self.lock:
            cell = self.cell
            robot, now = cell.robot, self.sim_time + self.time_step
            self.arm.before_step(robot, self.time_step)
            self.fingers.before_step(robot.gripper)
            cell.world.step()
            self.sim_time = now
            self.arm.after_step(robot, cell.world.table_id, cell.object_body,
                                cell.current_object.mass * -cell.world.physics.gravity)
            self.fingers.after_step(robot.gripper)

    def start(self) -> None:
        """Start the clock thread that keeps the physics in step with the wall clock."""
        if not self.clock_running:
            self._clock = Clock(self)
            self._clock.start()

    def stats(self) -> dict:
        """The clock's account (`Clock.stats`), or {} without a clock."""
        return self._clock.stats() if self._clock is not None else {}

    def close(self) -> None:
        if self._clock is not None:
            self._clock.stop()
        with self.lock:
            if self.cell is not None:
                self.cell.close()
                self.cell = None


def _joint_limits(robot: UR5Arm) -> tuple[np.ndarray, np.ndarray]:
    """The arm joints' limits from its description (rad)."""
    c = robot.world.client
    info = [c.getJointInfo(robot.body, j) for j in robot.arm_joints]
    return np.array([i[8] for i in info]), np.array([i[9] for i in info])


class Clock(threading.Thread):
    """Steps a scene's physics so that simulated time keeps up with the wall clock: when it falls behind it runs
    steps back to back, and a backlog beyond `MAX_BACKLOG` is dropped and counted as lag."""

    def __init__(self, scene: TwinScene) -> None:
        super().__init__(name="twin-clock", daemon=True)
        self.scene = scene
        self._stopped = threading.Event()
        self._resync = threading.Event()
        self._guard = threading.Lock()
        self.started_at = time.monotonic()
        self.sim_started = scene.sim_time
        self.busy = 0.0
        self.paused = 0.0
        self.dropped = 0.0
        self.longest_step = 0.0

    def run(self) -> None:
        dt = self.scene.time_step
        origin, steps = time.monotonic(), 0
        while not self._stopped.is_set():
            if self._resync.is_set():
                self._resync.clear()
                origin = time.monotonic() - steps * dt
            due = int((time.monotonic() - origin) / dt) - steps
            if due <= 0:
                self._stopped.wait(max(0.0, origin + (steps + 1) * dt - time.monotonic()))
                continue
            if due * dt > MAX_BACKLOG:
                with self._guard:
                    self.dropped += (due - 1) * dt
                origin += (due - 1) * dt
            began = time.monotonic()
            try:
                self.scene.step_once()
            except Exception:  # a broken step must not kill the clock silently
                log.exception("twin physics step failed; the clock stops")
                return
            spent = time.monotonic() - began
            with self._guard:
                self.busy += spent
                self.longest_step = max(self.longest_step, spent)
            steps += 1

    def resync(self, paused: float) -> None:
        """Forget the time the physics stood still (a placement) instead of catching up with it."""
        with self._guard:
            self.paused += paused
        self._resync.set()

    def stop(self) -> None:
        self._stopped.set()
        if self.is_alive() and threading.current_thread() is not self:
            self.join(timeout=5.0)

    def stats(self) -> dict:
        """Simulated vs wall time since the clock started: `real_time_factor` = simulated / (wall - paused),
        `headroom` = simulated / time spent stepping, the lag dropped and the longest step."""
        with self._guard:
            wall = time.monotonic() - self.started_at
            simulated = self.scene.sim_time - self.sim_started
            running = max(wall - self.paused, 1e-9)
            return {"simulated_s": simulated, "wall_s": wall, "paused_s": self.paused, "dropped_s": self.dropped,
                    "real_time_factor": simulated / running, "headroom": simulated / max(self.busy, 1e-9),
                    "longest_step_ms": 1000.0 * self.longest_step}


def twin_models(object_id: str, seed: int = 0, recordings: str | Path | None = None) -> TwinScene:
    """The twin for `python -m sim.lab serve` (without --kinematic): a `TwinScene` with `object_id` placed at
    `seed`, its recordings in `recordings` (default `RECORDINGS`), and the control commands `place`, `truth`,
    `camera_stop` and `twin_state` (the arm's safety status, why it last stopped, the clock's account) registered. The caller starts and closes it."""
    scene = TwinScene(object_id, seed, RECORDINGS if recordings is None else recordings)
    for name, handler in scene.handlers().items():
        register(name, handler)
    return scene
