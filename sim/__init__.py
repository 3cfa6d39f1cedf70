"""The PyBullet twin of the SegGrasp cell: UR5 + Robotiq 2F-85, virtual RealSense D435s, grasp-and-lift, and the
Gymnasium environment `SegGrasp-v0`, registered on import by its entry point (`gym.make` imports `sim.env`)."""

import gymnasium

ENV_ID = "SegGrasp-v0"


def register_envs() -> None:
    """Register `SegGrasp-v0` with Gymnasium without importing `sim.env` (idempotent)."""
    if ENV_ID not in gymnasium.registry:
        # no max_episode_steps: its TimeLimit wrapper would mark the one step `truncated` as well as `terminated`
        gymnasium.register(id=ENV_ID, entry_point="sim.env:SegGraspEnv")


register_envs()
