"""Selection by the probability that both pads land on the prompted part (seggrasp.grasp.policy)."""

import numpy as np
import pytest
import trimesh

from seggrasp.grasp import GraspSet
from seggrasp.grasp.policy import PartPolicy, face_part_probabilities, one_hot, pad_probabilities, row_shares


@pytest.fixture(scope="module")
def bar() -> tuple[trimesh.Trimesh, np.ndarray]:
    """A 10 x 2 x 2 cm bar of small faces: part 0 at x < 0, part 1 at x > 0."""
    mesh = trimesh.creation.box((0.1, 0.02, 0.02))
    for _ in range(4):
        mesh = mesh.subdivide()
    labels = (mesh.triangles_center[:, 0] > 0).astype(int)
    return mesh, labels


def pinches(xs: list[float], scores: list[float] | None = None) -> GraspSet:
    """Grasps closing across the bar's y faces at the given x."""
    contacts = np.array([[[x, -0.01, 0.0], [x, 0.01, 0.0]] for x in xs])
    poses = np.repeat(np.eye(4)[None], len(xs), axis=0)
    poses[:, :3, 3] = contacts.mean(axis=1)
    return GraspSet(poses, np.full(len(xs), 0.02), scores if scores is not None else np.zeros(len(xs)), contacts)


def test_shares_and_probabilities_are_rows_that_sum_to_one_or_zero() -> None:
    evidence = [np.array([[2.0, 2.0], [0.0, 0.0], [3.0, 1.0]]), np.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0]])]
    probs = face_part_probabilities(evidence)
    np.testing.assert_allclose(probs, [[0.75, 0.25], [0.0, 0.0], [0.375, 0.625]])
    np.testing.assert_allclose(row_shares(np.array([[1.0, 3.0]])), [[0.25, 0.75]])
    np.testing.assert_array_equal(one_hot(np.array([1, -1]), 2), [[0, 1], [0, 0]])
    with pytest.raises(ValueError, match="non-negative"):
        row_shares(np.array([[-1.0, 1.0]]))
    with pytest.raises(ValueError, match="differ in shape"):
        face_part_probabilities([np.ones((2, 2)), np.ones((3, 2))])
    with pytest.raises(ValueError, match="one int per face"):
        one_hot(np.array([2]), 2)


def test_footprint_prefers_a_parts_core_over_its_border(bar) -> None:
    mesh, labels = bar
    probs = one_hot(labels, 2)
    grasps = pinches([-0.03, -0.002])  # deep inside part 0, and 2 mm from the border with part 1
    nearest = pad_probabilities(grasps, mesh, probs, footprint_radius=0.0)
    footprint = pad_probabilities(grasps, mesh, probs, footprint_radius=0.008)
    np.testing.assert_allclose(nearest[:, :, 0], 1.0)  # the nearest faces alone cannot tell them apart
    np.testing.assert_allclose(footprint[0, :, 0], 1.0)
    assert (footprint[1, :, 0] < 0.8).all() and (footprint[1, :, 0] > 0.3).all()
    np.testing.assert_allclose(footprint.sum(axis=2), 1.0)
    p_on = PartPolicy(footprint_radius=0.008).on_part(grasps, mesh, probs)
    assert p_on[0, 0] > p_on[1, 0]
    with pytest.raises(ValueError, match="face probabilities"):
        pad_probabilities(grasps, mesh, probs[:-1], 0.008)


def test_rank_fills_from_the_most_probable_region_in_score_order() -> None:
    policy = PartPolicy(region_fraction=0.5, min_probability=0.05)
    p_on = np.array([0.9, 0.6, 0.3, 0.2, 0.04, 0.5])
    scores = np.array([0.1, 0.8, 0.9, 0.95, 1.0, 0.5])
    # region (p >= 0.45): grasps 0, 1, 5 by score; then 2, 3 by probability; grasp 4 is implausible
    assert policy.rank(p_on, scores, top_k=10).tolist() == [1, 5, 0, 2, 3]
    assert policy.rank(p_on, scores, top_k=2).tolist() == [1, 5]
    assert policy.rank(np.array([0.01, 0.02]), np.array([1.0, 1.0])).tolist() == []  # abstains
    with pytest.raises(ValueError, match="one probability and one score"):
        policy.rank(p_on, scores[:2])
    with pytest.raises(ValueError, match="invalid policy"):
        PartPolicy(region_fraction=1.5)


def test_select_gives_every_prompt_its_grasps(bar) -> None:
    mesh, labels = bar
    grasps = pinches([-0.04, -0.02, 0.02, 0.04], scores=[0.1, 0.2, 0.3, 0.4])
    chosen = PartPolicy().select(grasps, mesh, one_hot(labels, 3), top_k=5)
    assert [c.tolist() for c in chosen] == [[1, 0], [3, 2], []]
    assert [len(c) for c in PartPolicy().select(GraspSet.empty(), mesh, one_hot(labels, 3))] == [0, 0, 0]
