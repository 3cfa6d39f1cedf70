"""Grasps: the `GraspSet` container, the `GraspGenerator` protocol, the antipodal sampler, a learned-generator
adapter slot, part assignment / per-prompt selection and whether a hand can hold a part at all (`feasibility`)."""

from seggrasp.grasp.antipodal import AntipodalConfig, AntipodalSampler
from seggrasp.grasp.feasibility import Feasibility, judge_requests
from seggrasp.grasp.footprint import PadFootprint
from seggrasp.grasp.learned import GraspPrediction, LearnedGraspGenerator, PointCloudGraspModel
from seggrasp.grasp.select import assign_parts, contact_faces, select_on_part, select_per_prompt
from seggrasp.grasp.types import ROBOTIQ_2F85, GraspGenerator, GraspSet, Hand

__all__ = [
    "AntipodalConfig",
    "AntipodalSampler",
    "Feasibility",
    "GraspGenerator",
    "GraspPrediction",
    "GraspSet",
    "Hand",
    "LearnedGraspGenerator",
    "PadFootprint",
    "PointCloudGraspModel",
    "ROBOTIQ_2F85",
    "assign_parts",
    "contact_faces",
    "judge_requests",
    "select_on_part",
    "select_per_prompt",
]
