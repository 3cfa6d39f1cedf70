"""The twin behind the emulated lab cell: `SimCell`'s PyBullet scene, its UR5 as the controller's `ArmModel`
(`TwinArm`, sim/lab/twin_arm.py) and its 2F-85 as the URCap's `FingerModel` (`TwinFingers`, sim/lab/twin_fingers.py),
stepped in real time by a clock thread, with the control-channel commands `place`, `truth`, `camera_stop` and
`twin_state` (`twin_models` is what `python -m sim.lab serve` runs).

Cameras. By default the recordings are rendered once per placement. With `render_at_rest` (implied by a
calibration board, sim/lab/board.py) they are rendered again whenever a motion of the arm has ended, and the
controller reports that motion as finished only once the new recordings are in place: a client that captures after
its moveL returns (`hardware.calibration.collect_samples`) sees the arm, and the board it carries, where the motion
left them, as a real camera would, with no wait in the client.

Frames. ur_rtde speaks the controller's base frame (the UR's DH base); the URDF's `base_link` is that frame turned
by pi about z (`sim.robot.T_BASELINK_DHBASE`). After every placement the twin's UR5 body is turned so that its
`base_link` sits at `T_WORLD_BASELINK` = T_DHBASE_BASELINK in the PyBullet world, which makes the world the RTDE
base frame: the wire's joints are PyBullet's, home has q0 = pi (`HOME_Q_WIRE`, the moving links exactly where
SimCell's `HOME_Q` puts them), and the table, the object and the cameras keep SimCell's numbers. A placement is
`SimCell.reset(seed, object_id)` itself, so the wire and the twin backend see the same scene for a seed.
"""

from __future__ import annotations

import logging
import threading
import time
from pathlib import Path

import numpy as np

from sim.cell import SimCell
from sim.gripper import Robotiq2F85
from sim.lab.board import BoardBodies, CalibrationBoard
from sim.lab.cameras import write_instance_masks, write_recordings
from sim.lab.control import register
from sim.lab.twin_arm import TwinArm
from sim.lab.twin_fingers import TwinFingers
from sim.robot import UR5Arm, dh_forward

log = logging.getLogger(__name__)

#: The clock drops its backlog (and counts it as lag) when it falls this far (s) behind the wall clock.
MAX_BACKLOG = 0.25
#: Serial numbers of the twin's cameras (SimCell's rig, in order); hardware/cell.emulated.yaml names the same.
CAMERA_SERIALS = ("941000000001", "941000000002")
#: Where the twin writes its cameras' recordings unless told otherwise (hardware/cell.emulated.yaml reads them there).
RECORDINGS = Path("~/.cache/seggrasp/lab").expanduser()
#: Where the lost object lands (x, y on the table, beside the workspace).
LOST_OBJECT_SPOT = (0.5, 0.45)


class TwinScene:
    """The twin's world behind the emulated cell: one `SimCell` placed by `place(object_id, seed)`, the arm and
    fingers driven through `arm` / `fingers`, physics advanced by `advance` or by the clock thread (`start`).
    Every PyBullet call holds `lock`."""

    def __init__(self, object_id: str, seed: int, recordings: str | Path | None,
                 board: CalibrationBoard | None = None, render_at_rest: bool = False) -> None:
        self.lock = threading.RLock()
        self.recordings = None if recordings is None else Path(recordings)
        self.board = board
        #: whether the cameras are rendered again after every motion (module docstring)
        self.render_at_rest = (render_at_rest or board is not None) and self.recordings is not None
        self.renders = 0  # recordings written after a motion
        self._board_bodies: BoardBodies | None = None
        self._writing = threading.Lock()  # one recording writer at a time (they share the partial file names)
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

    def place(self, object_id: str, seed: int, scene: str | None = None, objects_per_scene: int = 4) -> dict:
        """Reset the scene as `SimCell.reset(seed, object_id)` does, with the arm and fingers where they are; render
        the cameras into recordings (none without a recordings folder). Returns `truth()` plus the recordings' paths
        by camera serial. With `scene` ("packed" or "pile", `sim.scenes`) the object lies among the twin's others,
        `objects_per_scene` in all: the reply adds the scene's plan and which body is which (`scene_truth`:
        `target` and `names` by body id), and each camera's body-per-pixel mask is written beside its recording
        (`sim.lab.cameras.write_instance_masks`, for the simulated object detector)."""
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise ValueError(f"place: seed must be a non-negative integer, got {seed!r}")
        model = self._model(object_id)
        started = time.monotonic()
        with self.lock:
            cell = self._cell_with(model, scene, objects_per_scene)
            cell.reset(seed, object_id)
            robot = cell.robot
            self.arm.reload(robot)
            self.fingers.reload(robot.gripper)
            self.joint_limits = _joint_limits(robot)
            self._board_bodies = None if self.board is None else BoardBodies(cell.world.client, self.board)
            self._place_board()
            self._placed = {"object": object_id, "seed": seed,
                            "T_world_obj": np.round(cell.object_mesh()[1], 9).tolist()}
            if scene is not None:
                truth = cell.scene_truth()
                self._placed.update(scene=cell.scene_plan.to_record(), scene_truth={
                    "target": truth.target, "names": {str(body): name for body, name in truth.names.items()}})
            if self.recordings is not None:
                self._frames = dict(zip(CAMERA_SERIALS, cell.capture(), strict=True))
            if self._clock is not None:
                self._clock.resync(time.monotonic() - started)
            placed, frames = dict(self._placed), dict(self._frames)
        # written with the physics running again: the recordings take a second or more per camera
        paths = {} if self.recordings is None else self._write(frames)
        return dict(placed, recordings={serial: str(path) for serial, path in paths.items()})

    def _write(self, frames: dict, **options) -> dict:
        """The frames' recordings (and, in a scene of several objects, their body masks) in `recordings`."""
        with self._writing:
            if self.cell is not None and self.cell.scene is not None:
                write_instance_masks(frames, self.recordings)
            return write_recordings(frames, self.recordings, **options)

    def _place_board(self) -> None:
        """Put the calibration board where the arm's actual joints put the flange (the lock is held)."""
        if self._board_bodies is not None:
            self._board_bodies.place(dh_forward(np.asarray(self.arm.actual_q())))

    def render_soon(self, done) -> None:
        """Render the cameras as the scene is now into new recordings, in a thread; then call `done()` (also when
        rendering failed: the failure is logged, the old recordings stay)."""
        threading.Thread(target=self._render_at_rest, args=(done,), name="twin-render", daemon=True).start()

    def _render_at_rest(self, done) -> None:
        try:
            started = time.monotonic()
            with self.lock:
                if self.cell is None:
                    return
                self._place_board()
                self._frames = frames = dict(zip(CAMERA_SERIALS, self.cell.capture(), strict=True))
                if self._clock is not None:
                    self._clock.resync(time.monotonic() - started)
            self._write(frames)
            self.renders += 1
        except Exception:
            log.exception("rendering the cameras after a motion failed; the recordings stay as they were")
        finally:
            done()

    def stop_cameras(self) -> dict:
        """The `camera_stop` fault: each camera's recording is replaced by one frame set, so the client's stream
        stops during its next warm-up."""
        with self.lock:
            frames = dict(self._frames)
        if not frames:
            raise ValueError("camera_stop: this twin renders no cameras (it has no recordings folder)")
        paths = self._write(frames, n_frames=1)
        return {"recordings": {serial: str(path) for serial, path in paths.items()}}

    def handlers(self) -> dict:
        """The control-channel commands of the twin (sim/lab/control.py: request dict -> reply fields)."""
        return {
            "place": lambda request: self.place(request.get("object"), request.get("seed", 0), request.get("scene"),
                                                request.get("objects_per_scene", 4)),
            "truth": lambda request: self.truth(),
            "camera_stop": lambda request: self.stop_cameras(),
            "twin_state": lambda request: {"safety_status": self.arm.safety_status,
                                           "stop_reason": self.arm.stop_reason, "renders": self.renders,
                                           **self.stats()},
            "board": lambda request: self.board_pose(),
        }

    def truth(self) -> dict:
        """The object placed last and its pose now (`T_world_obj`, RTDE base frame), with where it was placed."""
        with self.lock:
            return {"object": self._placed["object"], "seed": self._placed["seed"],
                    "T_world_obj": np.round(self.cell.object_mesh()[1], 9).tolist(),
                    "T_world_obj_placed": self._placed["T_world_obj"]}

    def board_pose(self) -> dict:
        """The calibration board (`board` command): its corners and square, `T_flange_board`, and `T_world_board`
        where the arm's actual joints put it now."""
        if self.board is None:
            raise ValueError("board: this twin carries no calibration board (start it with --calibration-board)")
        with self.lock:
            T_world_flange = dh_forward(np.asarray(self.arm.actual_q()))
        T = self.board.T_flange_board
        return {"columns": self.board.columns, "rows": self.board.rows, "square": self.board.square,
                "T_flange_board": np.round(T, 9).tolist(), "T_world_board": np.round(T_world_flange @ T, 9).tolist()}

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

    def _cell_with(self, model, scene: str | None, objects_per_scene: int) -> SimCell:
        """The twin cell holding `model`, alone or in `scene` among the installed twin's other objects."""
        cell = self.cell
        if (cell is None or model.object_id not in {o.object_id for o in cell.objects} or cell.scene != scene
                or (scene is not None and cell.objects_per_scene != objects_per_scene)):
            if cell is not None:
                cell.close()
            objects = list(self._models.values())
            if scene is not None:
                from seggrasp.objects import load_asset_set

                objects = list(({o.object_id: o for o in load_asset_set()} | self._models).values())
            self.cell = SimCell(objects=objects, embodiment="arm", scene=scene, objects_per_scene=objects_per_scene)
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
                                cell.current_object.mass * -cell.world.physics.gravity,
                                [body for body, _ in cell.neighbours])
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


def twin_models(object_id: str, seed: int = 0, recordings: str | Path | None = None,
                board: CalibrationBoard | None = None, render_at_rest: bool = False) -> TwinScene:
    """The twin for `python -m sim.lab serve` (without --kinematic): a `TwinScene` with `object_id` placed at
    `seed`, its recordings in `recordings` (default `RECORDINGS`), the calibration `board` on its flange if given
    (recordings rendered after every motion then, as with `render_at_rest`), and the control commands `place`,
    `truth`, `camera_stop`, `twin_state` (the arm's safety status, why it last stopped, the recordings rendered
    after motions, the clock's account) and `board` registered. The caller starts and closes it."""
    scene = TwinScene(object_id, seed, RECORDINGS if recordings is None else recordings, board=board,
                      render_at_rest=render_at_rest)
    for name, handler in scene.handlers().items():
        register(name, handler)
    return scene
