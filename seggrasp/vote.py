"""Per-face voting (paper eq. 1): every detector box votes for the faces it covers, weighted by its confidence.

`S[i, j] = sum over views v, over boxes b of prompt j in view v, of (pixels of face i inside b) x confidence(b)`.
A pixel is inside a box (pixel xyxy coordinates) when its centre (u + 0.5, v + 0.5) lies in the closed box, so a
box drawn tightly around a set of pixels, (min u, min v, max u + 1, max v + 1), contains exactly those columns and
rows.
"""

from __future__ import annotations

import logging
import time
from typing import Sequence

import numpy as np

from seggrasp.detect.base import Detections
from seggrasp.labels import UNKNOWN
from seggrasp.views import View

logger = logging.getLogger(__name__)


def vote(views: Sequence[View], detections: Sequence[Detections], n_faces: int, n_prompts: int) -> np.ndarray:
    """The (n_faces, n_prompts) score matrix S of eq. 1 from the views' face-id buffers and the detections."""
    if len(views) != len(detections):
        raise ValueError(f"got {len(views)} views but {len(detections)} detection sets; need one per view")
    if n_faces < 1 or n_prompts < 1:
        raise ValueError(f"need at least one face and one prompt, got n_faces={n_faces}, n_prompts={n_prompts}")
    started = time.perf_counter()
    flat_scores = np.zeros(n_faces * n_prompts)
    for index, (view, found) in enumerate(zip(views, detections)):
        if len(found) == 0:
            continue
        if found.prompt_index.min() < 0 or found.prompt_index.max() >= n_prompts:
            raise ValueError(f"view {index}: prompt index outside 0..{n_prompts - 1}: {found.prompt_index.tolist()}")
        if np.any(found.scores < 0) or not np.all(np.isfinite(found.boxes)):
            raise ValueError(f"view {index}: boxes must be finite with non-negative confidences")
        faces, inside = pixels_in_boxes(view, found.boxes)
        if len(faces) and faces.max() >= n_faces:
            raise ValueError(f"view {index} shows face {int(faces.max())} but the mesh has {n_faces} faces")
        box_of_hit, pixel_of_hit = np.nonzero(inside)
        flat_scores += np.bincount(
            faces[pixel_of_hit] * n_prompts + found.prompt_index[box_of_hit],
            weights=found.scores[box_of_hit],
            minlength=n_faces * n_prompts,
        )
    logger.info("voted %d boxes of %d views into %d faces x %d prompts in %.1f s", sum(len(d) for d in detections),
                len(views), n_faces, n_prompts, time.perf_counter() - started)
    return flat_scores.reshape(n_faces, n_prompts)


def pixels_in_boxes(view: View, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The face id of every object pixel of `view`, and the (boxes, pixels) mask of the pixels whose centres lie in
    each xyxy box (the module docstring's convention)."""
    rows, cols = np.nonzero(view.face_ids >= 0)
    centre_u, centre_v = cols + 0.5, rows + 0.5
    x0, y0, x1, y1 = (boxes[:, k, None] for k in range(4))
    inside = (x0 <= centre_u) & (centre_u <= x1) & (y0 <= centre_v) & (centre_v <= y1)
    return view.face_ids[rows, cols], inside


def labels_from_scores(scores: np.ndarray) -> np.ndarray:
    """Per-face label = the prompt with the highest score; -1 (unknown) where a face received no vote at all."""
    scores = np.asarray(scores, dtype=float)
    if scores.ndim != 2 or scores.shape[1] == 0:
        raise ValueError(f"scores must be a (faces, prompts) matrix with at least one prompt, got {scores.shape}")
    labels = np.argmax(scores, axis=1).astype(np.int64)
    labels[~(scores > 0).any(axis=1)] = UNKNOWN
    return labels
