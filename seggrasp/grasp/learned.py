"""Adapter slot for a learned grasp network (e.g. Contact-GraspNet, as in the paper).

SegGrasp ships no learned weights. A lab plugs its checkpoint in by writing a small class with a `predict` method
(the `PointCloudGraspModel` protocol) around its network and wrapping it in `LearnedGraspGenerator`:

    class MyContactGraspNet:
        def __init__(self, checkpoint_dir): ...  # load the network once
        def predict(self, points, seed):
            poses, widths, scores, contacts = run_network(points)   # in the point cloud's frame
            return GraspPrediction(poses, widths, scores, contacts)

    generator = LearnedGraspGenerator(MyContactGraspNet("ckpt/"), n_points=30000,
                                      T_model_grasp=T)  # T: our gripper frame expressed in the model's
    grasps = generator.generate(mesh, seed=0)          # a GraspSet, usable wherever AntipodalSampler is

Conventions: SegGrasp's gripper frame has z = approach, x = closing direction, origin between the fingertip pads.
A network whose pose origin is elsewhere (Contact-GraspNet reports the gripper *base*, about 10 cm behind the
fingertips, with z = approach and x = baseline) passes `T_model_grasp`, the transform that maps our gripper frame
into the network's, e.g. a pure translation along +z by the base-to-pads distance of its gripper model. Networks
that predict a single contact point (Contact-GraspNet does) return contacts of shape (N, 3); the second contact is
then placed `width` along the closing axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np
import trimesh

from seggrasp.grasp.types import GraspSet
from seggrasp.hands import ROBOTIQ_2F85, Hand


@dataclass
class GraspPrediction:
    """Raw network output in the point cloud's frame: poses (N, 4, 4) in the model's gripper convention, widths
    (N,), scores (N,), contacts (N, 3) one contact each or (N, 2, 3) both."""

    poses: np.ndarray
    widths: np.ndarray
    scores: np.ndarray
    contacts: np.ndarray


@runtime_checkable
class PointCloudGraspModel(Protocol):
    """A learned grasp network: object point cloud (N, 3) in, grasp proposals out."""

    def predict(self, points: np.ndarray, seed: int) -> GraspPrediction:
        """Grasps for the object whose surface is sampled by `points` (same frame as the output)."""


class LearnedGraspGenerator:
    """`GraspGenerator` around a `PointCloudGraspModel`: sample the mesh into a cloud, predict, convert frames."""

    name = "learned"

    def __init__(
        self,
        model: PointCloudGraspModel,
        n_points: int = 30000,
        T_model_grasp: np.ndarray | None = None,
        gripper: Hand = ROBOTIQ_2F85,
        name: str | None = None,
    ) -> None:
        if not isinstance(model, PointCloudGraspModel):
            raise ValueError(f"{type(model).__name__} does not implement predict(points, seed)")
        if n_points < 1:
            raise ValueError(f"n_points must be at least 1, got {n_points}")
        self.model = model
        self.n_points = n_points
        self.T_model_grasp = np.eye(4) if T_model_grasp is None else np.asarray(T_model_grasp, dtype=np.float64)
        if self.T_model_grasp.shape != (4, 4):
            raise ValueError(f"T_model_grasp must be 4x4, got {self.T_model_grasp.shape}")
        self.gripper = gripper
        if name is not None:
            self.name = name

    def generate(
        self,
        mesh: trimesh.Trimesh,
        seed: int = 0,
        table_plane: np.ndarray | None = None,
        center_of_mass: np.ndarray | None = None,
        mass: float | None = None,
    ) -> GraspSet:
        """Predicted grasps in the mesh frame, best first; those wider than the stroke or whose origin lies below
        `table_plane` (a, b, c, d; normal up) are dropped. The model sees geometry only: `center_of_mass` and `mass`
        are accepted for the `GraspGenerator` protocol and not used."""
        points, _ = trimesh.sample.sample_surface(mesh, self.n_points, seed=seed)
        return self.from_points(np.asarray(points), seed=seed, table_plane=table_plane)

    def from_points(self, points: np.ndarray, seed: int = 0, table_plane: np.ndarray | None = None) -> GraspSet:
        """Predicted grasps for a point cloud (e.g. fused from cameras), in the cloud's frame, best first."""
        points = np.asarray(points, dtype=np.float64)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
            raise ValueError(f"expected a non-empty (N, 3) point cloud, got shape {points.shape}")
        raw = self.model.predict(points, seed)
        poses = np.asarray(raw.poses, dtype=np.float64).reshape(-1, 4, 4) @ self.T_model_grasp
        widths = np.asarray(raw.widths, dtype=np.float64).reshape(-1)
        contacts = np.asarray(raw.contacts, dtype=np.float64)
        if contacts.ndim == 2 and contacts.shape[1:] == (3,):
            contacts = np.stack([contacts, contacts + widths[:, None] * poses[:, :3, 0]], axis=1)
        grasps = GraspSet(poses, widths, raw.scores, contacts)
        keep = grasps.widths <= self.gripper.stroke
        if table_plane is not None:
            plane = np.asarray(table_plane, dtype=np.float64).reshape(4)
            keep &= grasps.poses[:, :3, 3] @ plane[:3] + plane[3] >= 0.0
        return grasps.subset(np.flatnonzero(keep)).sorted_by_score()
