"""`SegGrasp-v0`: a one-step Gymnasium environment around a robot cell (the PyBullet twin or the real robot).

Episode: `reset(seed=..., options={"object_id": ..., "prompt": ...})` sets up the scene with one object (seeded
random unless given) and picks a prompt (one of the object's parts, seeded random unless given). The observation is
a `Dict`:

- `"prompt"`: `Text` - the part to grasp (e.g. "handle");
- `"cam0"`, `"cam1"`, ...: `Dict` with `"rgb"` (H, W, 3) uint8, `"depth"` (H, W) float32 metres (0 = no reading),
  `"K"` (3, 3) and `"T_world_cam"` (4, 4, OpenCV camera -> world);
- `"mesh"` (only with `include_mesh=True`): `"vertices"` (V, 3) object frame, `"faces"` (F, 3), and `"T_world_obj"`.

Action: `Box(7,)` float32 = grasp position x, y, z in the world frame (m), grasp orientation as a rotation vector
(rad; gripper z = approach, x = closing direction), and the expected grasp width (m, 0..0.085). `step` executes the
grasp-and-lift and ends the episode (`terminated=True`). Reward (sim): 1.0 when the object was lifted and most
faces the pads touched belong to the prompted part (ground truth), else 0.0. With `backend="real"` contacts are not
observed, so the reward is 1.0 for a lift and `info["on_part"]` is None. `info["outcome"]` is the `GraspOutcome` as
JSON.
"""

from __future__ import annotations

import string
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from scipy.spatial.transform import Rotation

from seggrasp.cell import Frame, GraspOutcome
from seggrasp.objects import ObjectModel

ENV_ID = "SegGrasp-v0"
PROMPT_CHARSET = string.ascii_letters + string.digits + " _-'"
PROMPT_MAX_LENGTH = 64
#: Observation bounds: depth range of a D435 (m), intrinsics entries (px), coordinates in the cell (m).
MAX_DEPTH = 10.0
MAX_INTRINSIC = 1.0e4
MAX_COORDINATE = 10.0
#: Action bounds: position (m), rotation vector (rad), width (m).
ACTION_LOW = np.array([0.0, -0.7, -0.05, -np.pi, -np.pi, -np.pi, 0.0], dtype=np.float32)
ACTION_HIGH = np.array([1.0, 0.7, 0.7, np.pi, np.pi, np.pi, 0.085], dtype=np.float32)


def register_envs() -> None:
    """Register `SegGrasp-v0` with Gymnasium (idempotent; also the `gymnasium.envs` entry point)."""
    if ENV_ID not in gym.registry:
        gym.register(id=ENV_ID, entry_point="sim.env:SegGraspEnv", max_episode_steps=1)


def action_to_grasp(action: np.ndarray) -> tuple[np.ndarray, float]:
    """Action vector -> (T_world_grasp 4x4, width)."""
    action = np.asarray(action, dtype=np.float64)
    if action.shape != (7,) or not np.all(np.isfinite(action)):
        raise ValueError(f"action must be 7 finite numbers (x, y, z, rx, ry, rz, width), got {action!r}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(action[3:6]).as_matrix()
    T[:3, 3] = action[:3]
    return T, float(action[6])


def grasp_to_action(T_world_grasp: np.ndarray, width: float) -> np.ndarray:
    """(T_world_grasp, width) -> action vector (the inverse of `action_to_grasp`)."""
    rotvec = Rotation.from_matrix(np.asarray(T_world_grasp)[:3, :3]).as_rotvec()
    return np.concatenate([np.asarray(T_world_grasp)[:3, 3], rotvec, [width]]).astype(np.float32)


def on_prompted_part(model: ObjectModel, outcome: GraspOutcome, prompt: str) -> bool:
    """True when most faces the pads touched carry the prompted part's ground-truth label."""
    if model.labels is None or len(outcome.touched_faces) == 0:
        return False
    part = model.labels.part_index(prompt)
    labels = model.labels.face_labels[outcome.touched_faces]
    return bool(np.mean(labels == part) >= 0.5)


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
        self.action_space = spaces.Box(ACTION_LOW, ACTION_HIGH, dtype=np.float32)
        self.prompt: str | None = None

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

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = set(options) - {"object_id", "prompt"}
        if unknown:
            raise ValueError(f"unknown reset options {sorted(unknown)}; use 'object_id' and 'prompt'")
        cell_seed = int(self.np_random.integers(2**31 - 1))
        self.cell.reset(seed=cell_seed, object_id=options.get("object_id"))
        prompt = options.get("prompt")
        if self.backend == "sim":
            model = self.cell.current_object
            parts = model.labels.parts if model.labels is not None else model.prompts
            if prompt is None:
                labelled = sorted(set(model.labels.face_labels[model.labels.face_labels >= 0].tolist())) if model.labels else []
                candidates = [parts[i] for i in labelled] or list(model.prompts)
                prompt = candidates[int(self.np_random.integers(len(candidates)))]
            elif prompt.lower() not in [p.lower() for p in parts]:
                raise ValueError(f"object {model.object_id!r} has no part {prompt!r}; parts: {parts}")
        elif prompt is None:
            raise ValueError('the real backend needs options={"prompt": ...}: it does not know the object\'s parts')
        if not self.observation_space["prompt"].contains(prompt):
            raise ValueError(f"prompt {prompt!r} must be 1-{PROMPT_MAX_LENGTH} characters from {PROMPT_CHARSET!r}")
        self.prompt = prompt
        info = {"object_id": getattr(self.cell.current_object, "object_id", None), "prompt": prompt}
        return self._observation(), info

    def step(self, action: np.ndarray):
        if self.prompt is None:
            raise RuntimeError("call reset() before step()")
        T_world_grasp, width = action_to_grasp(action)
        outcome = self.cell.execute(T_world_grasp, width)
        if self.backend == "sim":
            on_part: bool | None = on_prompted_part(self.cell.current_object, outcome, self.prompt)
            reward = 1.0 if outcome.lifted and on_part else 0.0
        else:
            on_part = None
            reward = 1.0 if outcome.lifted else 0.0
        info = {"outcome": outcome.to_json(), "on_part": on_part, "prompt": self.prompt}
        return self._observation(), reward, True, False, info

    def render(self):
        if self.render_mode == "rgb_array":
            if self.backend == "sim":
                return self.cell.render()
            return self.cell.capture()[0].rgb
        return None

    def close(self) -> None:
        if getattr(self, "cell", None) is not None:
            self.cell.close()
            self.cell = None
