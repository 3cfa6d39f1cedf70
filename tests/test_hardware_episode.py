"""One slot run by `sim.evaluate`'s runner and by the gym env `SegGrasp-v0`, on the twin and on `RealCell` with
fakes, gives the same record: the same episode code (seggrasp.episode.Episode) everywhere. On the real cell the
cameras replay frames recorded from the simulated D435s, the mesh comes from seggrasp.perception, the arm is a fake
RTDE pair and the gripper a fake URCap server holding an object of the cylinder's width."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from fakes_hardware import FakeAlign, FakePipeline, FakeRobotiqServer, FakeUR, example_config, write_config
from hardware.ur import matrix_from_ur_pose
from scipy.spatial.transform import Rotation
from seggrasp.detect.base import Detections
from seggrasp.episode import EpisodeContext
from seggrasp.truth import DetectorSpec, GroundTruth
from sim.env import SegGraspEnv
from sim.evaluate import JsonLines, RunConfig, run_object
from sim.primitives import primitive_object

#: Every test here runs whole episodes: none is in the fast loop.
pytestmark = pytest.mark.slow

pytest.importorskip("seggrasp.perception")

RADIUS, HEIGHT = 0.03, 0.11
HOME_FACING_PLUS_X = [np.pi, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0]


class WholeViewDetector:
    """Boxes the whole image for the first prompt (the typical 'part prompt boxed as the whole object' answer)."""

    name = "whole-view"

    def detect(self, views, prompts):
        return [Detections(np.array([[0, 0, v.rgb.shape[1] - 1, v.rgb.shape[0] - 1]]), np.array([0.9]),
                           np.array([0])) for v in views]


@dataclass(frozen=True)
class WholeViewSpec(DetectorSpec):
    """A detector spec that needs no weights and no ground truth (the real cell has none)."""

    name: str = "whole-view"

    def build(self, gt_labels):
        assert gt_labels is None  # the real cell has no ground truth
        return WholeViewDetector()


@pytest.fixture(scope="module")
def sim_frames(tmp_path_factory):
    """Frames of a cylinder on the table from the twin's virtual D435s."""
    from sim.cell import SimCell

    model = primitive_object("cylinder", (RADIUS, HEIGHT), tmp_path_factory.mktemp("objects"), mass=0.2)
    with SimCell([model], embodiment="floating", seed=0, image_size=(320, 240)) as cell:
        frames = cell.capture()
        _, T_world_obj = cell.object_mesh()
    return frames, T_world_obj


def real_cell_config(tmp_path, frames, server) -> tuple[str, FakeUR, dict]:
    """cell.yaml for the fakes, the fake arm, and the keyword arguments that plug the fakes into `RealCell`."""
    data = example_config()
    data["robot"]["home_joints"] = HOME_FACING_PLUS_X
    data["gripper"].update(host="127.0.0.1", port=server.port)
    data["workspace"] = {"min": [0.25, -0.25, 0.0], "max": [0.75, 0.25, 0.5]}
    data["motion"]["hold_time"] = 0.05
    data["cameras"] = [{"serial": f"sim{i}", "name": frame.name} for i, frame in enumerate(frames)]
    data["calibration"] = {"T_world_cam": {f"sim{i}": frame.T_world_cam.tolist() for i, frame in enumerate(frames)}}
    path = write_config(tmp_path / "cell.yaml", data)
    ur = FakeUR("ur5", np.array(HOME_FACING_PLUS_X))
    fakes = dict(control_factory=ur.control, receive_factory=ur.receive, align_factory=FakeAlign,
                 pipeline_factory=lambda serial: FakePipeline([frames[int(serial[3:])]]), camera_warmup_frames=0)
    return str(path), ur, fakes


#: Fields that say where a grasp came from (a method's plan, or the env's action); all others must agree.
PROVENANCE = {"method", "detector", "rank", "n_candidates", "grasp_score", "contacts_on_part", "extra"}


def _action(T_world_grasp: np.ndarray, width: float) -> np.ndarray:
    return np.r_[T_world_grasp[:3, 3], Rotation.from_matrix(T_world_grasp[:3, :3]).as_rotvec(), width]


def _spy_on_execute(cell) -> list:
    """Keep every (pose, width) the cell is asked to execute, and execute poses at 1e-6 resolution (as a UR
    controller takes them): the twin's contacts answer even a 1e-16 change of pose (the action's rotation vector
    round trip) with a different lift, so without this the env's step could not replay the runner's grasp."""
    calls, execute = [], cell.execute

    def spied(T, width):
        calls.append((np.array(T), width))
        return execute(np.round(T, 6), width)

    cell.execute = spied
    return calls


def _assert_same_record(runner: dict, env: dict) -> None:
    """Field by field; floats within 1e-5. The runner judged its request feasible; the env's action is not judged."""
    assert set(runner) == set(env)
    assert runner["infeasible"] is False and env["infeasible"] is None
    for name in sorted(set(runner) - PROVENANCE - {"infeasible"}):
        if isinstance(runner[name], float) or name in ("T_world_grasp", "quaternion_xyzw"):
            np.testing.assert_allclose(env[name], runner[name], atol=1e-5, err_msg=name)
        elif name == "outcome":
            for key, value in runner[name].items():
                if isinstance(value, float):
                    np.testing.assert_allclose(env[name][key], value, atol=1e-5, err_msg=f"outcome.{key}")
                else:
                    assert env[name][key] == value, f"outcome.{key}"
        else:
            assert env[name] == runner[name], name


def _runner_slot(cell, context, truth, config, tmp_path, executed, detector=None) -> tuple[dict, np.ndarray]:
    """The runner's record of the prompt "side" (top-1) and the action that executes the same grasp."""
    out = tmp_path / f"runner-{config.backend}"
    assert run_object(cell, context, truth, config, out, detector=detector) == len(context.prompts)
    (record,) = [r for r in JsonLines(out / "trials.jsonl").read() if r["prompt"] == "side"]
    (T, width), = [(T, w) for T, w in executed if np.array_equal(np.round(T, 6), record["T_world_grasp"])]
    return record, _action(T, width)


def _runner_then_env(env, context, truth, config, tmp_path, detector=None) -> tuple[dict, dict, float]:
    """On the env's own cell: the runner's record of the slot, then the env's record and reward for its grasp."""
    executed = _spy_on_execute(env.unwrapped.cell)
    runner, action = _runner_slot(env.unwrapped.cell, context, truth, config, tmp_path, executed, detector)
    assert runner["executed"], runner["message"]
    env.reset(seed=3, options={"object_id": "cylinder", "prompt": "side"})
    _, reward, _, _, step_info = env.step(action)
    return runner, step_info["record"], reward


def test_one_slot_is_the_same_record_from_the_runner_the_gym_env_and_the_real_backend(tmp_path, sim_frames):
    """Issue 14: `sim.evaluate`'s runner, `SegGrasp-v0` and the real backend run the same episode code."""
    # simulator, one cell: the runner's oracle slot, then the same grasp as the env's action in the same scene
    model = primitive_object("cylinder", (RADIUS, HEIGHT), tmp_path / "objects", mass=0.2, object_id="cylinder")
    env = SegGraspEnv([model], embodiment="floating", image_size=(160, 120))
    try:
        env.reset(seed=3, options={"object_id": "cylinder", "prompt": "side"})
        context = EpisodeContext.from_object(model, env.unwrapped.scene_seed, prompts=model.labels.parts)
        config = RunConfig(methods=["oracle"], objects=["cylinder"], top_k=1)
        truth = GroundTruth.of_object(model, context.prompts, true_pose=lambda: env.unwrapped.cell.object_mesh()[1])
        runner, stepped, reward = _runner_then_env(env, context, truth, config, tmp_path)
    finally:
        env.close()
    assert runner["outcome"]["contacts_observed"]
    _assert_same_record(runner, stepped)
    assert reward == float(runner["success"])

    # real backend (fakes), one cell: the runner's coarse slot on the perceived mesh, then the env's step with it
    frames, T_world_obj = sim_frames
    with FakeRobotiqServer(newline=True) as server:
        path, ur, fakes = real_cell_config(tmp_path, frames, server)
        env = SegGraspEnv(backend="real", config=path, **fakes)
        try:
            server.object_register = env.cell.gripper.width_to_register(2 * RADIUS)
            env.reset(seed=3, options={"object_id": "cylinder", "prompt": "side"})
            context = EpisodeContext("cylinder", "real", ["side"], env.unwrapped.scene_seed)
            config = RunConfig(methods=["coarse"], objects=["cylinder"], top_k=1, backend="real", perceive=True)
            real, stepped, reward = _runner_then_env(env, context, None, config, tmp_path, WholeViewSpec())
        finally:
            env.close()
    assert real["success"] is None and not real["outcome"]["contacts_observed"]  # no ground truth on a real cell
    assert real["reachable"] and real["lifted"] and real["lift_height"] == pytest.approx(0.2), real["message"]
    _assert_same_record(real, stepped)
    assert reward == float(real["lifted"])
    # the arm went exactly where the episode asked, once per harness, and that is on the perceived cylinder's side
    grasp = np.array(real["T_world_grasp"])
    commanded = [matrix_from_ur_pose(args[0]) for name, args in ur.motions if name == "moveL"]
    assert sum(np.allclose(T, grasp, atol=1e-6) for T in commanded) == 2
    assert np.linalg.norm(grasp[:2, 3] - T_world_obj[:2, 3]) < 0.015
    assert 0.0 < grasp[2, 3] < HEIGHT  # between the table (z = 0) and the cylinder's top
    assert 0.04 < real["width"] < 2 * RADIUS + 0.015  # across the perceived cylinder (+ any sampler margin)
