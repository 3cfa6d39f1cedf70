"""Grasp selection by the probability that both pads land on the prompted part.

Label-based selection (`seggrasp.grasp.select`) keeps a grasp only when the argmax labels of the two faces nearest
its contacts both name the prompt, so one wrong label (or a filter that blanks uncertain faces) leaves a request
without grasps. Here every face carries a probability per prompt instead (`face_part_probabilities`: the per-face
shares of several score matrices, e.g. GeoFusion, the coarse votes and the prompt-anchored labels, averaged), and a
grasp is ranked by

    p_on(grasp, k) = p_k(pad 1) * p_k(pad 2),

where p_k(pad) is the area-weighted mean probability of prompt k over the faces under the pad's footprint (face
centres within `footprint_radius` of the contact, plus the nearest face), so a grasp on a part's confident core
outranks one on its uncertain border. The top-k are filled from the most probable region: the candidates with p_on
at least `region_fraction` times the request's best come first, in the grasp generator's own order (its score
encodes what holds physically), then the rest by p_on. A request abstains only when no candidate reaches
`min_probability`. Measured: docs/results/grasp-selection.md.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from seggrasp.fusion import row_shares
from seggrasp.grasp.select import TOP_K, contact_faces
from seggrasp.grasp.types import GraspSet


def one_hot(labels: np.ndarray, n_prompts: int) -> np.ndarray:
    """(F, P) indicator of per-face labels (-1 = unknown gives an all-zero row)."""
    labels = np.asarray(labels, dtype=np.int64)
    if labels.ndim != 1 or (labels >= n_prompts).any() or (labels < -1).any():
        raise ValueError(f"labels must be one int per face in [-1, {n_prompts - 1}]")
    matrix = np.zeros((len(labels), n_prompts))
    known = labels >= 0
    matrix[np.flatnonzero(known), labels[known]] = 1.0
    return matrix


def face_part_probabilities(evidence: Sequence[np.ndarray]) -> np.ndarray:
    """(F, P) per-face probability of each prompt: the mean of the evidence matrices' row shares, renormalised
    (a face no evidence speaks for has an all-zero row)."""
    if not evidence:
        raise ValueError("need at least one evidence matrix")
    shares = [row_shares(e) for e in evidence]
    if len({s.shape for s in shares}) != 1:
        raise ValueError(f"evidence matrices differ in shape: {[s.shape for s in shares]}")
    return row_shares(np.sum(shares, axis=0))


def pad_probabilities(
    grasps: GraspSet, mesh: trimesh.Trimesh, face_probs: np.ndarray, footprint_radius: float
) -> np.ndarray:
    """(N, 2, P) per contact the area-weighted mean of `face_probs` over the faces under the pad: face centres
    within `footprint_radius` of the contact and the nearest face (only that one for a radius of 0)."""
    face_probs = np.asarray(face_probs, dtype=np.float64)
    if face_probs.ndim != 2 or len(face_probs) != len(mesh.faces):
        raise ValueError(f"need (F, P) face probabilities for {len(mesh.faces)} faces, got {face_probs.shape}")
    if footprint_radius < 0:
        raise ValueError(f"footprint_radius must be >= 0, got {footprint_radius}")
    nearest = contact_faces(grasps, mesh).reshape(-1)
    if footprint_radius == 0 or len(nearest) == 0:
        return face_probs[nearest].reshape(len(grasps), 2, -1)
    areas = mesh.area_faces
    neighbours = cKDTree(mesh.triangles_center).query_ball_point(grasps.contacts.reshape(-1, 3), footprint_radius)
    pads = np.empty((len(nearest), face_probs.shape[1]))
    for i, (faces, face) in enumerate(zip(neighbours, nearest)):
        under = np.asarray([*faces, face], dtype=np.int64)
        weights = areas[under]
        pads[i] = weights @ face_probs[under] / max(float(weights.sum()), 1e-18)
    return pads.reshape(len(grasps), 2, -1)


@dataclass(frozen=True)
class PartPolicy:
    """How grasps are chosen per prompt from per-face probabilities (module docstring). The defaults were chosen
    on the twin's seeds 0 and 1 (docs/results/grasp-selection.md)."""

    footprint_radius: float = 0.008  # m; about half the 2F-85's pad width (seggrasp.hands)
    region_fraction: float = 0.65
    min_probability: float = 0.05

    def __post_init__(self) -> None:
        if self.footprint_radius < 0 or not 0 <= self.region_fraction <= 1 or not 0 <= self.min_probability < 1:
            raise ValueError(f"invalid policy {self}: need footprint_radius >= 0, region_fraction and "
                             "min_probability in [0, 1]")

    def on_part(self, grasps: GraspSet, mesh: trimesh.Trimesh, face_probs: np.ndarray) -> np.ndarray:
        """(N, P) probability that both pads of each grasp land on each prompt's part."""
        pads = pad_probabilities(grasps, mesh, face_probs, self.footprint_radius)
        return pads[:, 0] * pads[:, 1]

    def rank(self, p_on: np.ndarray, scores: np.ndarray, top_k: int = TOP_K) -> np.ndarray:
        """Indices of the `top_k` grasps for one prompt: the most probable region (p_on >= region_fraction x the
        best) in score order, then the other plausible grasps (p_on > min_probability) by p_on; may be empty."""
        p_on, scores = np.asarray(p_on, dtype=np.float64), np.asarray(scores, dtype=np.float64)
        if p_on.shape != scores.shape or p_on.ndim != 1:
            raise ValueError(f"need one probability and one score per grasp, got {p_on.shape} and {scores.shape}")
        if top_k < 1:
            raise ValueError(f"top_k must be at least 1, got {top_k}")
        candidates = np.flatnonzero(p_on > self.min_probability)
        if len(candidates) == 0:
            return candidates
        p, s = p_on[candidates], np.nan_to_num(scores[candidates], nan=-np.inf)
        in_region = p >= self.region_fraction * p.max()
        order = np.lexsort((np.where(in_region, -s, -p), ~in_region))
        return candidates[order[:top_k]]

    def select(
        self, grasps: GraspSet, mesh: trimesh.Trimesh, face_probs: np.ndarray, top_k: int = TOP_K
    ) -> list[np.ndarray]:
        """For every prompt (column of `face_probs`) the indices of its top-k grasps (possibly none)."""
        if len(grasps) == 0:
            return [np.zeros(0, dtype=np.int64) for _ in range(np.shape(face_probs)[1])]
        p_on = self.on_part(grasps, mesh, face_probs)
        return [self.rank(p_on[:, k], grasps.scores, top_k) for k in range(p_on.shape[1])]
