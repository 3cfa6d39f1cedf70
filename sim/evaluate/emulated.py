"""The emulated lab cell behind `python -m sim.evaluate --backend real`.

A cell.yaml with an `emulator:` section (hardware/cell.emulated.yaml) describes the cell that `python -m sim.lab`
emulates: the twin behind the real wire (ur_rtde, the Robotiq URCap socket, pyrealsense2 recordings). Such a run
- executes inside the emulator: `run_inside_emulator` runs the same command again under `python -m sim.lab run
  <the section's serve options> -- python -m sim.evaluate ...`, unless an emulated cell already answers on the
  control channel (the command was started inside `python -m sim.lab run`);
- drives the unchanged `hardware.RealCell` (`EmulatedCell` wraps it) and replaces only the person who places the
  object: `EmulatedCell.reset` moves the arm home as RealCell does, then asks the emulator to `place` the object,
  which builds the scene `SimCell.reset(seed, object)` builds and rewrites the cameras' recordings;
- runs on twin objects and scores against their ground truth: the true pose is the one the emulator placed
  (`EmulatedCell.true_pose`), so the simulated detector and the oracle run as on the twin backend; with `--scene`
  the emulator lays the object among the twin's others and tells which body is which (`EmulatedCell.scene_truth`,
  the frames' body masks), and the run finds the object from the cameras as a real cell's would;
- records a protective stop during a grasp as a failed trial (`collision`, the stop named) after releasing it
  as an operator would (control channel `release`, then `URArm.reconnect` uploads the control script again),
  and one while putting the object back as the grasp was judged after the hold; on the real cell the stop ends
  the object's task.
"""

from __future__ import annotations

import functools
import logging
import os
import socket
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from seggrasp.cell import Frame, GraspOutcome
from seggrasp.truth import SceneTruth

if TYPE_CHECKING:
    from hardware.cell import RealCell
    from hardware.config import CellConfig
    from sim.evaluate.config import RunConfig

log = logging.getLogger("sim.evaluate")

#: Options of the `emulator:` section, as `python -m sim.lab serve` takes them.
EMULATOR_OPTIONS = ("controller", "polyscope")
#: Set in the environment of the evaluation `run_inside_emulator` starts (it must not start another emulator).
INSIDE_ENV = "SEGGRASP_EMULATED_RUN"
#: s a placement may take: resetting the twin, rendering and recording both cameras on a loaded machine.
PLACE_TIMEOUT = 120.0


@functools.cache
def _config(path: str) -> CellConfig:
    from hardware.config import load_config

    return load_config(path)


def declared(config_path: str | None) -> bool:
    """Whether the cell.yaml at `config_path` describes the emulated cell (has an `emulator:` section)."""
    return config_path is not None and _config(str(config_path)).emulator is not None


def twin_objects(config: RunConfig) -> bool:
    """Whether the run's objects are twin objects with ground truth: the twin backend, or the emulated cell."""
    return config.backend == "sim" or declared(config.config)


def serve_options(config: CellConfig) -> list[str]:
    """The `python -m sim.lab serve` options of a config's `emulator:` section, with `--recordings` the folder its
    cameras play (ValueError naming the field when the section or the cameras do not fit the emulator)."""
    options = []
    for key, value in config.emulator.items():
        if key not in EMULATOR_OPTIONS:
            raise ValueError(f"{config.path}: emulator.{key}: not an emulator option; use {', '.join(EMULATOR_OPTIONS)}")
        options += [f"--{key}", str(value)]
    return options + ["--recordings", str(recordings_folder(config))]


def recordings_folder(config: CellConfig) -> Path:
    """The one folder holding every camera's recording as `<serial>.db3`, as the emulator writes them."""
    folders = set()
    for index, camera in enumerate(config.cameras):
        if camera.recording is None or camera.recording.name != f"{camera.serial}.db3":
            raise ValueError(f"{config.path}: cameras[{index}].recording: the emulated cell's camera {camera.serial} "
                             f"plays <folder>/{camera.serial}.db3 (the emulator writes one per serial), got "
                             f"{camera.recording}")
        folders.add(camera.recording.parent)
    if len(folders) != 1:
        raise ValueError(f"{config.path}: cameras: the recordings must share one folder (the emulator writes to one), "
                         f"got {sorted(map(str, folders))}")
    return folders.pop()


def _emulator_answers() -> bool:
    """Whether something listens on the control channel here (an emulated cell started by `python -m sim.lab`)."""
    from sim.lab.control import CONTROL_PORT

    try:
        with socket.create_connection(("127.0.0.1", CONTROL_PORT), timeout=1.0):
            return True
    except OSError:
        return False


def run_inside_emulator(config_path: str, objects: Sequence[str], argv: Sequence[str]) -> int | None:
    """For an emulated cell's config: run `python -m sim.evaluate argv` inside a fresh emulator and return its exit
    code; None when this process runs the evaluation itself (a real cell, or already inside an emulator)."""
    if not declared(config_path) or os.environ.get(INSIDE_ENV) == "1" or _emulator_answers():
        return None
    from seggrasp.objects import asset_ids

    first = next(iter(objects), None) or asset_ids()[0]
    command = [sys.executable, "-m", "sim.lab", "run", *serve_options(_config(str(config_path))),
               "--object", first, "--", sys.executable, "-m", "sim.evaluate", *argv]
    log.info("starting the emulated cell: %s", " ".join(command))
    return subprocess.call(command, env={**os.environ, INSIDE_ENV: "1"})


def real_cell(config: RunConfig):
    """The run's real cell: `EmulatedCell` when its config declares the emulator, else `hardware.RealCell`."""
    from hardware import RealCell  # lazy: the real cell's drivers are optional on a sim-only machine
    from sim.evaluate.config import DEFAULT_OBJECTS_PER_SCENE

    if declared(config.config):
        return EmulatedCell.from_config(config.config, dry_run=config.dry_run, scene=config.scene,
                                        objects_per_scene=config.objects_per_scene or DEFAULT_OBJECTS_PER_SCENE)
    return RealCell.from_config(config.config, dry_run=config.dry_run)


class EmulatedCell:
    """`hardware.RealCell` on the emulated cell, with the emulator placing the object (module docstring); with
    `scene` ("packed" or "pile") among `objects_per_scene - 1` of the twin's other objects."""

    models_scene = False

    def __init__(self, real: RealCell, scene: str | None = None, objects_per_scene: int = 4) -> None:
        from sim.lab.cameras import instance_mask_path

        self.real = real
        self.recordings = {camera.serial: camera.recording for camera in real.config.cameras}
        self._masks = {camera.name: instance_mask_path(camera.recording.parent, camera.serial)
                       for camera in real.config.cameras}
        recordings_folder(real.config)  # the cameras play what the emulator writes
        self.scene, self.objects_per_scene = scene, objects_per_scene
        self.scene_plan = None  # the `sim.scenes.ScenePlan` the emulator laid out last (None: the object alone)
        self._scene_truth: SceneTruth | None = None
        self._true_pose: np.ndarray | None = None

    @classmethod
    def from_config(cls, path: str | Path, dry_run: bool = False, scene: str | None = None,
                    objects_per_scene: int = 4) -> EmulatedCell:
        from hardware import RealCell

        return cls(RealCell.from_config(path, dry_run=dry_run), scene, objects_per_scene)

    @property
    def workspace(self):
        return self.real.workspace

    @property
    def table_height(self) -> float:
        return self.real.table_height

    @property
    def hand(self):
        return self.real.hand

    def reset(self, seed: int | None = None, object_id: str | None = None) -> None:
        """RealCell's reset (gripper open, arm home), then the emulator places `object_id` at `seed`."""
        from sim.lab.control import request

        if object_id is None:
            raise ValueError("the emulated cell places a twin object: name it (reset(seed, object_id))")
        self.real.reset(seed, object_id)
        reply = request("place", timeout=PLACE_TIMEOUT, object=object_id, seed=0 if seed is None else int(seed),
                        scene=self.scene, objects_per_scene=self.objects_per_scene)
        written = {serial: Path(path) for serial, path in reply["recordings"].items()}
        for serial, path in self.recordings.items():
            if written.get(serial) != path:
                raise ValueError(f"camera {serial} plays {path}, but the emulator wrote {written.get(serial)} (its "
                                 f"cameras are {sorted(written)}): start it with --recordings {path.parent}")
        self._true_pose = np.asarray(reply["T_world_obj"], dtype=np.float64)
        if "scene" in reply:
            from sim.scenes import ScenePlan

            self.scene_plan = ScenePlan.from_record(reply["scene"])
            truth = reply["scene_truth"]
            self._scene_truth = SceneTruth(int(truth["target"]),
                                           {int(body): name for body, name in truth["names"].items()})

    def scene_truth(self) -> SceneTruth:
        """Which of the emulator's bodies (the values of the frames' `instance_ids`) is which object, the requested
        one the target."""
        if self._scene_truth is None:
            raise ValueError("the emulated cell has laid out no scene of several objects (reset() with a scene)")
        return self._scene_truth

    def true_pose(self) -> np.ndarray:
        """`T_world_obj` of the object as the emulator placed it (what the cameras saw) in the RTDE base frame."""
        if self._true_pose is None:
            raise ValueError("the emulated cell has placed nothing yet: call reset() first")
        return self._true_pose.copy()

    def capture(self) -> list[Frame]:
        """RealCell's frames; in a scene of several objects each carries the twin's body per pixel, which the
        emulator wrote beside the camera's recording (`sim.lab.cameras.write_instance_masks`), for the simulated
        object detector."""
        frames = self.real.capture()
        if self.scene is None:
            return frames
        masked = []
        for frame in frames:
            path = self._masks[frame.name]
            try:
                mask = np.load(path)
            except OSError as exc:
                raise ValueError(f"camera {frame.name}: the emulator's body mask {path} cannot be read: {exc}") from exc
            if mask.shape != frame.depth.shape:
                raise ValueError(f"camera {frame.name}: the emulator's body mask {path} is {mask.shape}, the frame "
                                 f"{frame.depth.shape}")
            masked.append(replace(frame, instance_ids=mask))
        return masked

    def object_mesh(self):
        return self.real.object_mesh()

    def check_reach(self, T_world_grasp: np.ndarray, width: float) -> str:
        return self.real.check_reach(T_world_grasp, width)

    def execute(self, T_world_grasp: np.ndarray, width: float) -> GraspOutcome:
        """RealCell's grasp; a protective stop of the twin's arm on the way is released and recorded as a
        `collision`, or, while putting the object back, after the grasp's judgement as judged (any other stop is
        raised, as on the real cell)."""
        from hardware.errors import RobotStoppedError
        from sim.lab.control import request

        try:
            return self.real.execute(T_world_grasp, width)
        except RobotStoppedError as exc:
            state = request("twin_state")
            if state["safety_status"] != "protective_stop":  # an emergency stop is the operator's to release
                raise
            reason = state["stop_reason"] or "reason not reported"
            log.warning("%s (%s): releasing the stop and uploading the control script again", exc, reason)
            request("release")
            self.real.arm.reconnect()
            if exc.outcome is not None:  # stopped while putting the object back: the grasp was judged before
                return replace(exc.outcome, message=f"{exc.outcome.message}; then {exc} ({reason}), released")
            return GraspOutcome(reachable=True, lifted=False, lift_height=0.0, contacts_observed=False,
                                message=f"{exc} ({reason}); the emulator released the stop", failure="collision")

    def close(self) -> None:
        self.real.close()
