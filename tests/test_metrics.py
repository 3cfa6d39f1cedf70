"""Metrics against hand-computed values."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from seggrasp.metrics import (
    mean_over_categories,
    part_ious,
    part_selection_accuracy,
    quaternion_variance,
    shape_miou,
    success_rate,
)


def test_face_count_iou_with_unknown_counted_only_in_unions():
    gt = np.array([0, 0, 0, 1, 1, 1])
    pred = np.array([0, 0, 1, 1, -1, -1])
    # part 0: inter 2, union {0,1,2} -> 2/3. part 1: inter {3}=1, union {2,3,4,5} = 4 -> 1/4.
    ious = part_ious(pred, gt, 2)
    np.testing.assert_allclose(ious, [2 / 3, 1 / 4])
    assert shape_miou(pred, gt, 2) == pytest.approx((2 / 3 + 1 / 4) / 2)


def test_area_weighted_iou():
    gt = np.array([0, 0, 1, 1])
    pred = np.array([0, 1, 1, -1])
    areas = np.array([1.0, 3.0, 2.0, 4.0])
    # part 0: inter 1, union (pred 0: 1) + (gt 0: 4) - 1 = 4 -> 0.25
    # part 1: inter 2, union (pred 1: 3+2) + (gt 1: 6) - 2 = 9 -> 2/9
    np.testing.assert_allclose(part_ious(pred, gt, 2, areas), [0.25, 2 / 9])
    assert shape_miou(pred, gt, 2, areas) == pytest.approx((0.25 + 2 / 9) / 2)


def test_absent_gt_part_is_nan_and_excluded_from_miou():
    gt = np.array([0, 0, 2, 2])
    pred = np.array([0, 1, 2, 2])
    ious = part_ious(pred, gt, 3)
    assert np.isnan(ious[1])
    np.testing.assert_allclose(ious[[0, 2]], [0.5, 1.0])
    assert shape_miou(pred, gt, 3) == pytest.approx(0.75)


def test_unknown_gt_faces_do_not_create_parts():
    gt = np.array([-1, 0, 0])
    pred = np.array([0, 0, 0])
    # the -1 gt face predicted as 0 enlarges part 0's union: 2/3
    np.testing.assert_allclose(part_ious(pred, gt, 1), [2 / 3])


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="labels"):
        part_ious(np.array([0, 1]), np.array([0]), 2)
    with pytest.raises(ValueError, match="outside"):
        part_ious(np.array([0, 5]), np.array([0, 1]), 2)
    with pytest.raises(ValueError, match="face_areas"):
        part_ious(np.array([0, 1]), np.array([0, 1]), 2, np.array([1.0]))
    with pytest.raises(ValueError, match="undefined"):
        shape_miou(np.array([0, 1]), np.array([-1, -1]), 2)


def test_mean_over_categories_means_shapes_then_categories():
    result = mean_over_categories({"mug": [0.2, 0.4], "knife": [0.9]})
    assert result["categories"] == {"knife": pytest.approx(0.9), "mug": pytest.approx(0.3)}
    assert result["overall"] == pytest.approx(0.6)
    assert result["n_shapes"] == 3
    pairs = mean_over_categories([("mug", 0.2), ("knife", 0.9), ("mug", 0.4)])
    assert pairs == result


def test_fractions():
    assert part_selection_accuracy([True, False, True, True]) == 0.75
    assert success_rate(np.array([0, 0, 1])) == pytest.approx(1 / 3)
    with pytest.raises(ValueError):
        success_rate([])


def test_quaternion_variance_hand_computed_and_sign_invariant():
    identical = np.repeat(np.eye(3)[None], 4, axis=0)
    assert quaternion_variance(identical) == pytest.approx(0.0, abs=1e-15)
    # Rotations about z by +-theta: q = (0, 0, +-sin(t/2), cos(t/2)); var of z component = sin^2(t/2), others 0.
    theta = 0.6
    rots = Rotation.from_rotvec([[0, 0, theta], [0, 0, -theta]]).as_matrix()
    assert quaternion_variance(rots) == pytest.approx(np.sin(theta / 2) ** 2)
    # A rotation by ~2*pi about z is the identity but scipy may return -q: sign alignment must make it count as 0.
    near_identity = Rotation.from_rotvec([[0, 0, 2 * np.pi - 1e-9], [0, 0, 0]]).as_matrix()
    assert quaternion_variance(near_identity) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError):
        quaternion_variance(np.eye(3))
