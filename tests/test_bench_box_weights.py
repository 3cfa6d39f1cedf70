"""bench/bench_box_weights.py: how specific a box is, and eq. 1 with the boxes reweighted."""


import numpy as np
import pytest

from bench import bench_box_weights  # noqa: E402

from seggrasp.detect.base import Detections  # noqa: E402
from seggrasp.views import View  # noqa: E402
from seggrasp.vote import vote  # noqa: E402


def _view() -> View:
    """A 4 x 8 image: face 0 fills columns 0-1 (the 'part'), face 1 columns 2-7 (the rest), all rows."""
    face_ids = np.ones((4, 8), dtype=np.int64)
    face_ids[:, :2] = 0
    return View(np.zeros((4, 8, 3), np.uint8), face_ids, np.eye(3), np.eye(4))


def test_a_box_around_the_whole_object_is_less_specific_than_a_part_box():
    whole, part = [0.0, 0.0, 8.0, 4.0], [0.0, 0.0, 2.0, 4.0]
    found = Detections(np.array([whole, part]), np.array([0.5, 0.5]), np.array([0, 0]))
    weights = bench_box_weights.box_weights(_view(), found, "specificity", 1.0)
    assert weights == pytest.approx([1.0, 4.0])  # 32 object pixels over 32 and over 8 inside
    assert bench_box_weights.box_weights(_view(), found, "specificity", 0.5) == pytest.approx([1.0, 2.0])


def test_contrast_silences_a_region_two_prompts_claim_and_keeps_a_box_only_one_does():
    whole, part = [0.0, 0.0, 8.0, 4.0], [0.0, 0.0, 2.0, 4.0]
    found = Detections(np.array([whole, whole, part]), np.array([0.5, 0.5, 0.5]), np.array([0, 1, 0]))
    weights = bench_box_weights.box_weights(_view(), found, "contrast", 1.0)
    # the two whole-object boxes coincide; the part box overlaps prompt 1's whole box by IoU 8 / 32
    assert weights == pytest.approx([0.0, 0.0, 0.75])
    assert bench_box_weights.box_weights(_view(), found, "contrast", 0.5) == pytest.approx([0.5, 0.5, 0.875])
    with pytest.raises(ValueError, match="unknown box weighting"):
        bench_box_weights.box_weights(_view(), found, "area", 1.0)


def test_weighted_votes_scale_each_boxs_votes_and_keep_eq1_at_weight_one():
    view = _view()
    found = Detections(np.array([[0.0, 0.0, 8.0, 4.0], [0.0, 0.0, 2.0, 4.0]]), np.array([0.5, 0.8]), np.array([0, 1]))
    plain = vote([view], [found], 2, 2)
    assert bench_box_weights.weighted_votes([view], [found], 2, 2, "specificity", 0.0) == pytest.approx(plain)
    weighted = bench_box_weights.weighted_votes([view], [found], 2, 2, "specificity", 1.0)
    # prompt 1's part box (8 of 32 object pixels) counts 4x; prompt 0's whole-object box unchanged
    assert weighted[:, 1] == pytest.approx(4.0 * plain[:, 1])
    assert weighted[:, 0] == pytest.approx(plain[:, 0])
    assert weighted[1, 1] == 0.0  # face 1 lies outside the part box
