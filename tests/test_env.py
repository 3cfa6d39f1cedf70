"""SegGrasp-v0: registration, Gymnasium's env checker, determinism, reward on the prompted part."""

import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import sim  # noqa: F401  (registers SegGrasp-v0)
from sim.env import SegGraspEnv, action_to_grasp, grasp_to_action
from sim.primitives import primitive_object

SMALL = dict(image_size=(160, 120), n_cameras=2)


@pytest.fixture(scope="module")
def objects(tmp_path_factory):
    directory = tmp_path_factory.mktemp("objects")
    return [
        primitive_object("box", (0.05, 0.05, 0.08), directory, object_id="box"),
        primitive_object("cylinder", (0.025, 0.09), directory, object_id="cylinder"),
    ]


def test_import_sim_registers_the_env_without_importing_it():
    """`python -m sim.evaluate` and `python -m sim.lab` import `sim`: its registration must not load the env."""
    probe = ("import sys, gymnasium, sim; assert gymnasium.spec('SegGrasp-v0').entry_point == 'sim.env:SegGraspEnv'; "
             "print(sorted(m for m in ('sim.env', 'sim.cell', 'pybullet', 'trimesh') if m in sys.modules))")
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def side_grasp_action(obs) -> np.ndarray:
    """Top-down grasp 6 cm above the object's origin, closing along its x axis (touches the side faces)."""
    T_world_obj = obs["mesh"]["T_world_obj"]
    x = T_world_obj[:3, 0] * [1.0, 1.0, 0.0]
    x /= np.linalg.norm(x)
    z = np.array([0.0, 0.0, -1.0])
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2] = x, np.cross(z, x), z
    T[:3, 3] = T_world_obj[:3, 3] + [0.0, 0.0, 0.06]
    return grasp_to_action(T, 0.05)


@pytest.mark.parametrize("embodiment, include_mesh", [("arm", False), ("floating", True)])
def test_env_checker_passes(objects, embodiment, include_mesh):
    env = SegGraspEnv(objects, embodiment=embodiment, include_mesh=include_mesh, render_mode="rgb_array", **SMALL)
    try:
        check_env(env, skip_render_check=False)
    finally:
        env.close()


def test_gym_make_and_observation_layout(objects):
    env = gym.make("SegGrasp-v0", objects=objects, embodiment="floating", include_mesh=True, render_mode="rgb_array", **SMALL)
    try:
        obs, info = env.reset(seed=0, options={"object_id": "box", "prompt": "side"})
        assert obs["prompt"] == "side" and info["object_id"] == "box"
        assert set(obs) == {"prompt", "cam0", "cam1", "mesh"}
        assert obs["cam0"]["rgb"].shape == (120, 160, 3) and obs["cam0"]["depth"].shape == (120, 160)
        assert obs["cam1"]["K"][0, 0] == pytest.approx(615.0 / 4)
        assert env.observation_space.contains(obs)
        assert env.render().shape == (120, 160, 3)
        with pytest.raises(ValueError, match="no part"):
            env.reset(seed=0, options={"object_id": "box", "prompt": "handle"})
    finally:
        env.close()


def test_reward_is_for_a_lift_on_the_prompted_part(objects):
    env = SegGraspEnv(objects, embodiment="floating", include_mesh=True, **SMALL)
    try:
        obs, _ = env.reset(seed=4, options={"object_id": "box", "prompt": "side"})
        _, reward, terminated, truncated, info = env.step(side_grasp_action(obs))
        assert terminated and not truncated
        assert info["outcome"]["lifted"] and info["on_part"] and reward == 1.0

        obs, _ = env.reset(seed=4, options={"object_id": "box", "prompt": "top"})
        _, reward, _, _, info = env.step(side_grasp_action(obs))
        assert info["outcome"]["lifted"] and not info["on_part"] and reward == 0.0
    finally:
        env.close()


def test_same_seed_same_observation_and_outcome(objects):
    env = SegGraspEnv(objects, embodiment="floating", include_mesh=True, **SMALL)
    try:
        runs = []
        for _ in range(2):
            obs, info = env.reset(seed=21)
            step = env.step(side_grasp_action(obs))
            runs.append((obs, info, step))
        (obs_a, info_a, step_a), (obs_b, info_b, step_b) = runs
        assert info_a == info_b
        for name in ("cam0", "cam1"):
            np.testing.assert_array_equal(obs_a[name]["rgb"], obs_b[name]["rgb"])
            np.testing.assert_array_equal(obs_a[name]["depth"], obs_b[name]["depth"])
        assert step_a[1] == step_b[1] and step_a[4] == step_b[4]
        other, _ = env.reset(seed=22)
        assert not np.array_equal(other["mesh"]["T_world_obj"], obs_a["mesh"]["T_world_obj"])
    finally:
        env.close()


def test_action_round_trip_and_validation():
    T = np.eye(4)
    T[:3, :3] = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    T[:3, 3] = [0.5, 0.1, 0.2]
    T_back, width = action_to_grasp(grasp_to_action(T, 0.04))
    np.testing.assert_allclose(T_back, T, atol=1e-6)
    assert width == pytest.approx(0.04)
    with pytest.raises(ValueError, match="7 finite numbers"):
        action_to_grasp(np.zeros(6))


def test_real_backend_needs_a_config():
    with pytest.raises(ValueError, match="config"):
        SegGraspEnv(backend="real")
    with pytest.raises(ValueError, match="backend"):
        SegGraspEnv(backend="mujoco")


def test_one_step_ends_the_episode_and_a_second_step_is_refused(objects):
    """Issue 13 finding 5: terminated only (no truncation), no second grasp in the same scene."""
    env = gym.make("SegGrasp-v0", objects=objects, embodiment="floating", include_mesh=True, **SMALL)
    try:
        obs, _ = env.reset(seed=4, options={"object_id": "box", "prompt": "side"})
        _, _, terminated, truncated, info = env.step(side_grasp_action(obs))
        assert terminated and not truncated
        assert info["record"]["prompt"] == "side" and info["record"]["executed"]
        with pytest.raises(RuntimeError, match="reset"):
            env.step(side_grasp_action(obs))
    finally:
        env.close()


def test_an_action_outside_the_action_space_is_refused_before_it_moves(objects):
    env = SegGraspEnv(objects, embodiment="floating", include_mesh=True, **SMALL)
    try:
        obs, _ = env.reset(seed=4, options={"object_id": "box", "prompt": "side"})
        executed = []
        env.cell.execute = lambda *args: executed.append(args)  # nothing may reach the cell
        for bad in ([5.0, 0.0, 0.1, 0.0, 0.0, 0.0, 0.05], [0.5, 0.0, 0.1, 0.0, 0.0, 0.0, 0.2]):
            with pytest.raises(ValueError, match="outside the action space"):
                env.step(np.array(bad, dtype=np.float32))
        assert executed == []
    finally:
        env.close()


def test_misuse_before_reset_after_a_failed_reset_and_after_close_is_refused(objects):
    """Issue 13 finding 7: no grasp runs after a failed reset; clear errors for a wrong prompt type and a closed env."""
    env = gym.make("SegGrasp-v0", objects=objects, embodiment="floating", include_mesh=True, **SMALL)
    action = np.array([0.5, 0.0, 0.1, np.pi, 0.0, 0.0, 0.05], dtype=np.float32)
    executed = []
    env.unwrapped.cell.execute = lambda *args: executed.append(args)
    env.reset(seed=0, options={"object_id": "box", "prompt": "side"})  # a good episode, then a failed reset
    with pytest.raises(ValueError, match="no part"):
        env.reset(seed=0, options={"object_id": "box", "prompt": "handle"})
    with pytest.raises(RuntimeError, match="reset"):
        env.step(action)
    with pytest.raises(ValueError, match="must be a string"):
        env.reset(seed=0, options={"object_id": "box", "prompt": 3})
    with pytest.raises(RuntimeError, match="reset"):
        env.step(action)
    assert executed == []
    env.close()
    with pytest.raises(RuntimeError, match="closed"):
        env.reset(seed=0)
    with pytest.raises(RuntimeError, match="closed"):
        env.unwrapped.step(action)
