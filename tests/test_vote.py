"""Voting (eq. 1) against a slow reference, and labels from scores."""

from __future__ import annotations

import numpy as np
import pytest

from seggrasp.detect.base import Detections
from seggrasp.views import View
from seggrasp.vote import labels_from_scores, vote


def _random_view(rng: np.random.Generator, n_faces: int, height: int, width: int) -> View:
    face_ids = rng.integers(0, n_faces, size=(height, width))
    face_ids[rng.random((height, width)) < 0.4] = -1
    return View(rgb=np.zeros((height, width, 3), np.uint8), face_ids=face_ids, K=np.eye(3), T_world_cam=np.eye(4))


def _random_detections(rng: np.random.Generator, n_prompts: int, height: int, width: int) -> Detections:
    n_boxes = int(rng.integers(0, 6))
    corners = rng.uniform(-5, [width + 5, height + 5, width + 5, height + 5], size=(n_boxes, 4))
    # Put some edges on pixel boundaries and some exactly through pixel centres (the closed-box tie case).
    on_boundary, through_centre = rng.random((2, n_boxes, 4)) < 0.3
    corners[on_boundary] = np.round(corners[on_boundary])
    corners[through_centre] = np.floor(corners[through_centre]) + 0.5
    boxes = np.column_stack([
        np.minimum(corners[:, 0], corners[:, 2]), np.minimum(corners[:, 1], corners[:, 3]),
        np.maximum(corners[:, 0], corners[:, 2]), np.maximum(corners[:, 1], corners[:, 3]),
    ])
    return Detections(boxes, rng.random(n_boxes), rng.integers(0, n_prompts, n_boxes))


def _slow_vote(views, detections, n_faces: int, n_prompts: int) -> np.ndarray:
    """Eq. 1 written out pixel by pixel."""
    scores = np.zeros((n_faces, n_prompts))
    for view, found in zip(views, detections):
        height, width = view.face_ids.shape
        for (x0, y0, x1, y1), confidence, prompt in zip(found.boxes, found.scores, found.prompt_index):
            for v in range(height):
                for u in range(width):
                    face = view.face_ids[v, u]
                    if face >= 0 and x0 <= u + 0.5 <= x1 and y0 <= v + 0.5 <= y1:
                        scores[face, prompt] += confidence
    return scores


@pytest.mark.parametrize("seed", range(5))
def test_vote_matches_slow_reference_on_random_data(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_faces, n_prompts, height, width = 40, 3, 17, 23
    views = [_random_view(rng, n_faces, height, width) for _ in range(4)]
    detections = [_random_detections(rng, n_prompts, height, width) for _ in views]
    scores = vote(views, detections, n_faces, n_prompts)
    assert scores.shape == (n_faces, n_prompts)
    np.testing.assert_allclose(scores, _slow_vote(views, detections, n_faces, n_prompts), rtol=1e-12, atol=1e-12)


def test_tight_box_counts_exactly_its_pixels() -> None:
    face_ids = -np.ones((6, 8), dtype=np.int64)
    face_ids[1:3, 2:5] = 0  # six pixels of face 0
    face_ids[4, 6] = 1  # one pixel of face 1, outside the box
    view = View(np.zeros((6, 8, 3), np.uint8), face_ids, np.eye(3), np.eye(4))
    tight = Detections(np.array([[2.0, 1.0, 5.0, 3.0]]), np.array([0.5]), np.array([1]))
    scores = vote([view], [tight], n_faces=3, n_prompts=2)
    np.testing.assert_allclose(scores, [[0.0, 3.0], [0.0, 0.0], [0.0, 0.0]])
    np.testing.assert_array_equal(labels_from_scores(scores), [1, -1, -1])


def test_votes_add_up_over_views_and_boxes() -> None:
    face_ids = np.zeros((4, 4), dtype=np.int64)
    view = View(np.zeros((4, 4, 3), np.uint8), face_ids, np.eye(3), np.eye(4))
    whole = [0.0, 0.0, 4.0, 4.0]
    both = Detections(np.array([whole, whole]), np.array([0.25, 0.5]), np.array([0, 0]))
    scores = vote([view, view], [both, Detections.empty()], n_faces=1, n_prompts=1)
    assert scores[0, 0] == pytest.approx(16 * 0.75)


def test_vote_rejects_inconsistent_input() -> None:
    view = View(np.zeros((2, 2, 3), np.uint8), np.array([[0, 5], [-1, 1]]), np.eye(3), np.eye(4))
    box = Detections(np.array([[0.0, 0.0, 2.0, 2.0]]), np.array([1.0]), np.array([0]))
    with pytest.raises(ValueError, match="one per view"):
        vote([view], [], n_faces=6, n_prompts=1)
    with pytest.raises(ValueError, match="shows face 5"):
        vote([view], [box], n_faces=3, n_prompts=1)
    with pytest.raises(ValueError, match="prompt index"):
        vote([view], [Detections(box.boxes, box.scores, np.array([2]))], n_faces=6, n_prompts=2)
    with pytest.raises(ValueError, match="non-negative"):
        vote([view], [Detections(box.boxes, np.array([-0.1]), box.prompt_index)], n_faces=6, n_prompts=1)


def test_labels_from_scores() -> None:
    scores = np.array([[0.0, 0.0, 0.0], [0.1, 0.3, 0.2], [2.0, 0.0, 1.0], [0.0, 0.0, 1e-9]])
    labels = labels_from_scores(scores)
    assert labels.dtype == np.int64
    np.testing.assert_array_equal(labels, [-1, 1, 0, 2])
    with pytest.raises(ValueError, match="faces, prompts"):
        labels_from_scores(np.zeros(4))
