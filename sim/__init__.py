"""The PyBullet twin of the SegGrasp cell: UR5 + Robotiq 2F-85, virtual RealSense D435s, grasp-and-lift, and the
Gymnasium environment `SegGrasp-v0` (registered on import)."""

from sim.env import register_envs

register_envs()
