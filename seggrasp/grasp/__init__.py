"""Grasps: the `GraspSet` container, the `GraspGenerator` protocol, the antipodal sampler, a learned-generator
adapter slot and part assignment / per-prompt selection."""

from seggrasp.grasp.antipodal import AntipodalConfig, AntipodalSampler
from seggrasp.grasp.types import ROBOTIQ_2F85, GraspGenerator, GraspSet, GripperGeometry

__all__ = ["AntipodalConfig", "AntipodalSampler", "GraspGenerator", "GraspSet", "GripperGeometry", "ROBOTIQ_2F85"]
