"""Part assignment and per-prompt grasp selection.

A grasp's part is the label of the mesh face nearest to its contact points (the paper). We look up BOTH contacts
and require them to agree: a grasp whose fingers straddle two parts (or touch an unlabelled face) gets -1 and is
never selected. This is the strict reading of Part Sel., which counts a grasp only if the finger contacts lie on
the prompted part. With a `PadFootprint`, the grasps whose pads each press mostly on the part, under them and where
they first land, and land deeper than the hand's `pad_end_margin` into the pads (`seggrasp.grasp.footprint`: two
contacts on a wine glass's stem say nothing of the bowl under the pads' edge), come first; the others fill the
top-k only where too few do, so the check never leaves a request with fewer grasps.
"""

from __future__ import annotations

import numpy as np
import trimesh

from seggrasp.grasp.footprint import PadFootprint, contact_faces
from seggrasp.grasp.types import GraspSet

UNASSIGNED = -1
TOP_K = 10
#: Grasps whose footprint is checked at once while filling a prompt's top-k.
FOOTPRINT_CHUNK = 16


def assign_parts(grasps: GraspSet, mesh: trimesh.Trimesh, face_labels: np.ndarray) -> np.ndarray:
    """Per-grasp part label: the common label of both contacts' nearest faces, or -1 if they differ or are -1."""
    face_labels = np.asarray(face_labels, dtype=np.int64)
    if face_labels.shape != (len(mesh.faces),):
        raise ValueError(f"need one label per mesh face: {len(mesh.faces)} faces, got labels of shape {face_labels.shape}")
    labels = face_labels[contact_faces(grasps, mesh)]
    if len(labels) == 0:
        return np.zeros(0, dtype=np.int64)
    return np.where(labels[:, 0] == labels[:, 1], labels[:, 0], UNASSIGNED)


def select_on_part(grasps: GraspSet, grasp_parts: np.ndarray, part: int, top_k: int = TOP_K) -> np.ndarray:
    """Indices of the `top_k` best-scored grasps whose part is `part`, best first (ties: generation order)."""
    grasp_parts = np.asarray(grasp_parts)
    if grasp_parts.shape != (len(grasps),):
        raise ValueError(f"need one part per grasp: {len(grasps)} grasps, got {grasp_parts.shape}")
    if part < 0:
        raise ValueError(f"part index must be >= 0, got {part}")
    if top_k < 1:
        raise ValueError(f"top_k must be at least 1, got {top_k}")
    candidates = np.flatnonzero(grasp_parts == part)
    order = np.argsort(-grasps.scores[candidates], kind="stable")
    return candidates[order[:top_k]]


def select_per_prompt(
    grasps: GraspSet, mesh: trimesh.Trimesh, face_labels: np.ndarray, n_prompts: int, top_k: int = TOP_K,
    footprint: PadFootprint | None = None,
) -> list[np.ndarray]:
    """For every prompt k, the indices of the top-k grasps on the faces labelled k (possibly fewer, even none),
    best first; with a `footprint`, those whose pads hold the faces labelled k (`PadSurface.holds`) first, then the
    others."""
    parts = assign_parts(grasps, mesh, face_labels)
    if footprint is None:
        return [select_on_part(grasps, parts, k, top_k) for k in range(n_prompts)]
    labels, surface = np.asarray(face_labels), footprint.on(mesh)
    chosen = []
    for k in range(n_prompts):
        ranked = select_on_part(grasps, parts, k, top_k=max(len(grasps), 1))
        is_part = labels == k
        pressing: list[int] = []
        others: list[int] = []
        for start in range(0, len(ranked), FOOTPRINT_CHUNK):
            if len(pressing) >= top_k:
                break
            block = ranked[start : start + FOOTPRINT_CHUNK]
            on_part = surface.holds(grasps.subset(block), is_part)
            pressing += block[on_part].tolist()
            others += block[~on_part].tolist()
        chosen.append(np.asarray((pressing + others)[:top_k], dtype=np.int64))
    return chosen
