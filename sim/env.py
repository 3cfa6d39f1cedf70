"""`SegGrasp-v0`: a one-step Gymnasium environment around a robot cell (the PyBullet twin or the real robot).

Episode: `reset(seed=..., options={"object_id": ..., "prompt": ...})` sets up the scene with one object (seeded
random unless given) and picks a prompt (one of the object's parts, seeded random unless given). The observation is
a `Dict`:

- `"prompt"`: `Text` - the part to grasp (e.g. "handle");
- `"cam0"`, `"cam1"`, ...: `Dict` with `"rgb"` (H, W, 3) uint8, `"depth"` (H, W) float32 metres (0 = no reading),
  `"K"` (3, 3) and `"T_world_cam"` (4, 4, OpenCV camera -> world);
- `"mesh"` (only with `include_mesh=True`): `"vertices"` (V, 3) object frame, `"faces"` (F, 3), and `"T_world_obj"`.

Action: `Box(7,)` float32 = grasp position x, y, z in the world frame (m), grasp orientation as a rotation vector
(rad; gripper z = approach, x = closing direction), and the expected grasp width (m, 0 to the hand's stroke:
`seggrasp.hands`, the cell's `hand`). `step` executes the
grasp-and-lift through the same `seggrasp.episode.Episode` the benchmark and the real cell run, and ends the episode
(`terminated=True`; `truncated` is always False: there is no time limit). Reward (sim): 1.0 when the object was
lifted and the prompted part carries most of what the pads touched (ground truth), else 0.0. With `backend="real"`
contacts are not observed, so the reward is 1.0 for a lift and `info["on_part"]` is None. `info["outcome"]` is the
`GraspOutcome` as JSON and `info["record"]` the episode's `TrialRecord` as JSON. `scene="packed" | "pile"` (and
`objects_per_scene`, `sim.cell.SimCell`) puts the object among others; the outcome then has how far each moved and
`info["scene"]` the scene's objects and poses.

Misuse is refused with a clear error before anything moves: `step` before a successful `reset`, after the episode
ended or after `close`, an action that is not 7 real numbers inside `action_space` (a complex action is refused, not
cut to its real part), `options` that are not a dict, a prompt that is not a string or not a part, an `image_size`
that is not a (width, height) pair of whole pixels within IMAGE_WIDTH_RANGE. An environment made by `gym.make` whose
first `reset` failed refuses every `step`: gymnasium's passive env checker, which `gym.make` wraps around it, keeps
no reset observation after that failure and would raise TypeError after every step, once the grasp has run; make a
new environment.
"""

from __future__ import annotations

import string
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from scipy.spatial.transform import Rotation

from seggrasp.cell import Frame
from seggrasp.episode import Episode, EpisodeContext, action_slot
from seggrasp.hands import ROBOTIQ_2F85, Hand
from seggrasp.labels import find_prompt
from seggrasp.objects import ObjectModel
from seggrasp.truth import GroundTruth

PROMPT_CHARSET = string.ascii_letters + string.digits + " _-'"
PROMPT_MAX_LENGTH = 64
#: Observation bounds: depth range of a D435 (m), intrinsics entries (px), coordinates in the cell (m).
MAX_DEPTH = 10.0
MAX_INTRINSIC = 1.0e4
MAX_COORDINATE = 10.0
#: Action bounds: position (m), rotation vector (rad), width (m: up to the hand's stroke, `action_high`; ACTION_HIGH
#: is the 2F-85's).
ACTION_LOW = np.array([0.0, -0.7, -0.05, -np.pi, -np.pi, -np.pi, 0.0], dtype=np.float32)


def action_high(hand: Hand) -> np.ndarray:
    """The action's upper bounds for a cell with `hand`: its stroke is the widest grasp."""
    return np.array([1.0, 0.7, 0.7, np.pi, np.pi, np.pi, hand.stroke], dtype=np.float32)


ACTION_HIGH = action_high(ROBOTIQ_2F85)
#: Camera image widths (pixels; the height is 3/4 of it): up to the D435 colour stream's widest mode.
IMAGE_WIDTH_RANGE = (16, 1920)


def action_to_grasp(action: np.ndarray) -> tuple[np.ndarray, float]:
    """Action vector -> (T_world_grasp 4x4, width)."""
    action = real_action(action)
    if action.shape != (7,) or not np.all(np.isfinite(action)):
        raise ValueError(f"action must be 7 finite numbers (x, y, z, rx, ry, rz, width), got {action!r}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(action[3:6]).as_matrix()
    T[:3, 3] = action[:3]
    return T, float(action[6])


def real_action(action: Any) -> np.ndarray:
    """`action` as float64; ValueError for anything but real numbers (a complex value is not cut to its real part,
    booleans and text are no coordinates)."""
    given = np.asarray(action)
    if given.dtype.kind not in "iuf":
        raise ValueError(f"action must be real numbers (x, y, z, rx, ry, rz, width), got {given.dtype} values "
                         f"{given.tolist()!r}; nothing was executed")
    return given.astype(np.float64)


def check_image_size(image_size: Any) -> tuple[int, int]:
    """(width, height) as ints; ValueError unless a pair of whole pixel counts with the width in IMAGE_WIDTH_RANGE
    (the 4:3 aspect is checked by the camera model)."""
    try:
        width, height = image_size
    except (TypeError, ValueError):
        raise ValueError(f"image_size must be a (width, height) pair of pixels, got {image_size!r}") from None
    for value in (width, height):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"image_size must be whole pixels, got {image_size!r}")
    low, high = IMAGE_WIDTH_RANGE
    if not low <= width <= high:
        raise ValueError(f"image_size {width}x{height}: the width must be {low}..{high} pixels (4:3, e.g. 640x480)")
    return int(width), int(height)


def grasp_to_action(T_world_grasp: np.ndarray, width: float) -> np.ndarray:
    """(T_world_grasp, width) -> action vector (the inverse of `action_to_grasp`)."""
    rotvec = Rotation.from_matrix(np.asarray(T_world_grasp)[:3, :3]).as_rotvec()
    return np.concatenate([np.asarray(T_world_grasp)[:3, 3], rotvec, [width]]).astype(np.float32)


class SegGraspEnv(gym.Env):
    """Grasp the prompted part of one object: one action (a grasp), one reward (lifted on the part or not)."""

    metadata = {"render_modes": ["rgb_array", "human"], "render_fps": 4}

    def __init__(
        self,
        objects: list[ObjectModel] | None = None,
        embodiment: str = "arm",
        n_cameras: int = 2,
        image_size: tuple[int, int] = (640, 480),
        include_mesh: bool = False,
        render_mode: str | None = None,
        backend: str = "sim",
        config: str | None = None,
        dry_run: bool = False,
        **cell_kwargs: Any,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        image_size = check_image_size(image_size)
        self.render_mode = render_mode
        self.include_mesh = include_mesh
        self.backend = backend
        if backend == "sim":
            from sim.cell import SimCell

            self.cell = SimCell(
                objects, embodiment=embodiment, gui=render_mode == "human", n_cameras=n_cameras,
                image_size=image_size, **cell_kwargs,
            )
            frames = self.cell.capture()
        elif backend == "real":
            if config is None:
                raise ValueError('backend="real" needs config=PATH to the cell configuration')
            if include_mesh:
                raise ValueError("include_mesh needs the twin's ground truth; the real cell cannot provide it")
            from hardware import RealCell

            self.cell = RealCell.from_config(config, dry_run=dry_run, **cell_kwargs)
            frames = self.cell.capture()
        else:
            raise ValueError(f"unknown backend {backend!r}; use 'sim' or 'real'")
        self._camera_names = [f.name for f in frames]
        self.observation_space = self._make_observation_space(frames)
        self.action_space = spaces.Box(ACTION_LOW, action_high(self.cell.hand), dtype=np.float32)
        self.prompt: str | None = None
        self._episode: Episode | None = None  # set by a successful reset, cleared when the step ends the episode
        self.scene_seed: int | None = None  # the cell's scene seed of the last successful reset
        self._reset_outcomes: list[bool] = []  # whether each reset succeeded (the first one matters, see `step`)

    def _make_observation_space(self, frames: list[Frame]) -> spaces.Dict:
        entries: dict[str, spaces.Space] = {
            "prompt": spaces.Text(max_length=PROMPT_MAX_LENGTH, min_length=1, charset=PROMPT_CHARSET)
        }
        for frame in frames:
            height, width = frame.depth.shape
            entries[frame.name] = spaces.Dict({
                "rgb": spaces.Box(0, 255, (height, width, 3), dtype=np.uint8),
                "depth": spaces.Box(0.0, MAX_DEPTH, (height, width), dtype=np.float32),
                "K": spaces.Box(0.0, MAX_INTRINSIC, (3, 3), dtype=np.float64),
                "T_world_cam": spaces.Box(-MAX_COORDINATE, MAX_COORDINATE, (4, 4), dtype=np.float64),
            })
        if self.include_mesh:
            entries["mesh"] = spaces.Dict({
                "vertices": spaces.Sequence(spaces.Box(-MAX_COORDINATE, MAX_COORDINATE, (3,), dtype=np.float64), stack=True),
                "faces": spaces.Sequence(spaces.Box(0, np.iinfo(np.int64).max, (3,), dtype=np.int64), stack=True),
                "T_world_obj": spaces.Box(-MAX_COORDINATE, MAX_COORDINATE, (4, 4), dtype=np.float64),
            })
        return spaces.Dict(entries)

    def _observation(self) -> dict[str, Any]:
        observation: dict[str, Any] = {"prompt": self.prompt}
        for frame in self.cell.capture():
            observation[frame.name] = {
                "rgb": frame.rgb, "depth": frame.depth.astype(np.float32),
                "K": np.asarray(frame.K, dtype=np.float64), "T_world_cam": np.asarray(frame.T_world_cam, dtype=np.float64),
            }
        if self.include_mesh:
            mesh, T_world_obj = self.cell.object_mesh()
            observation["mesh"] = {
                "vertices": np.array(mesh.vertices, dtype=np.float64),  # copies: never hand out the model's arrays
                "faces": np.array(mesh.faces, dtype=np.int64),
                "T_world_obj": np.asarray(T_world_obj, dtype=np.float64),
            }
        return observation

    def _check_open(self) -> None:
        if getattr(self, "cell", None) is None:
            raise RuntimeError("this SegGrasp environment is closed; make a new one")

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        self._check_open()
        self._episode = None  # a reset that fails leaves no episode to step
        self._reset_outcomes.append(False)
        result = self._reset(seed, options)
        self._reset_outcomes[-1] = True
        return result

    def _reset(self, seed: int | None, options: dict[str, Any] | None):
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"options must be a dict such as {{'object_id': ..., 'prompt': ...}} or None, got "
                             f"{type(options).__name__} {options!r}")
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"object_id", "prompt"}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; use 'object_id' and 'prompt'")
        prompt = options.get("prompt")
        if prompt is not None and not isinstance(prompt, str):
            raise ValueError(f"the prompt must be a string (a part name), got {type(prompt).__name__} {prompt!r}")
        scene_seed = int(self.np_random.integers(2**31 - 1))
        self.cell.reset(seed=scene_seed, object_id=options.get("object_id"))
        if self.backend == "sim":
            context, truth, prompt = self._twin_subject(scene_seed, prompt)
        elif prompt is None:
            raise ValueError('the real backend needs options={"prompt": ...}: it does not know the object\'s parts')
        else:
            context, truth = EpisodeContext(options.get("object_id") or "object", "real", [prompt], scene_seed), None
        if not self.observation_space["prompt"].contains(prompt):
            raise ValueError(f"prompt {prompt!r} must be 1-{PROMPT_MAX_LENGTH} characters from {PROMPT_CHARSET!r}")
        self.prompt = prompt
        self._episode = Episode(self.cell, context, truth=truth)
        self._prompt_index = find_prompt(context.prompts, prompt)
        self.scene_seed = scene_seed
        info = {"object_id": getattr(self.cell.current_object, "object_id", None), "prompt": prompt}
        return self._observation(), info

    def _twin_subject(self, scene_seed: int, prompt: str | None) -> tuple[EpisodeContext, GroundTruth | None, str]:
        """The twin object's context (its parts as prompts), its ground truth, and the prompt (drawn if None)."""
        model = self.cell.current_object
        parts = model.labels.parts if model.labels is not None else list(model.prompts)
        if prompt is None:
            labelled = sorted(set(model.labels.face_labels[model.labels.face_labels >= 0].tolist())) if model.labels else []
            candidates = [parts[i] for i in labelled] or list(model.prompts)
            prompt = candidates[int(self.np_random.integers(len(candidates)))]
        elif find_prompt(parts, prompt) is None:
            raise ValueError(f"object {model.object_id!r} has no part {prompt!r}; parts: {parts}")
        context = EpisodeContext.from_object(model, scene_seed, prompts=parts)
        return context, GroundTruth.of_object(model, parts, true_pose=lambda: self.cell.object_mesh()[1]), prompt

    def step(self, action: np.ndarray):
        self._check_open()
        if self.spec is not None and self._reset_outcomes[:1] == [False]:
            raise RuntimeError("this environment's first reset() failed; gymnasium's env checker, which gym.make "
                               "wraps around it, then fails every step after the grasp has run, so no step runs: "
                               "make a new environment with gym.make")
        if self._episode is None:
            raise RuntimeError("no episode to step: call reset() first (after a failed reset, or once the step "
                               "ended the episode)")
        checked = real_action(action)
        if checked.shape != (7,) or not np.all(np.isfinite(checked)) or not self.action_space.contains(
                checked.astype(np.float32)):
            raise ValueError(f"action {np.asarray(action).tolist()} is outside the action space "
                             f"(low {ACTION_LOW.tolist()}, high {ACTION_HIGH.tolist()}); nothing was executed")
        T_world_grasp, width = action_to_grasp(checked)
        episode, self._episode = self._episode, None  # one grasp per episode, even if executing it raises
        record = episode.execute(action_slot(self._prompt_index, T_world_grasp, width), reset=False)
        reward = float(record.success) if record.success is not None else float(record.lifted)
        info = {"outcome": record.outcome, "on_part": record.touched_on_part, "prompt": self.prompt,
                "record": dict(record.to_json(), robot=self.cell.robot_name)}  # as sim.evaluate records it
        if getattr(self.cell, "scene_plan", None) is not None:  # a twin scene of several objects
            info["scene"] = self.cell.scene_plan.to_record()
        return self._observation(), reward, True, False, info

    def render(self):
        if self.render_mode == "rgb_array":
            if self.backend == "sim":
                return self.cell.render()
            return self.cell.capture()[0].rgb
        return None

    def close(self) -> None:
        self._episode = None
        if getattr(self, "cell", None) is not None:
            self.cell.close()
            self.cell = None
