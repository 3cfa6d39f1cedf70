"""GeoFusion and GeoSpreading against hand-computed values on a tiny two-part mesh with known decompositions.

Faces 0, 1 form ground-truth part 0 and faces 2, 3 part 1; face areas 1, 1, 2, 2. The finest decomposition
(threshold 0.01) splits the two parts, the coarse one (0.2) is one piece.
"""

import numpy as np
import pytest

from seggrasp.decompose import Partition
from seggrasp.fusion import (
    ANCHOR_MODES,
    DEFAULT_ANCHOR,
    REFINE_MODES,
    agreed_labels,
    anchor_prompts,
    assign_parts_to_prompts,
    coarsest_with_parts,
    competing_prompts,
    refine_labels,
    refine_scores,
    soft_anchor_prompts,
)
from seggrasp.vote import labels_from_scores

AREAS = np.array([1.0, 1.0, 2.0, 2.0])
PARTITIONS = [Partition(0.01, np.array([0, 0, 1, 1])), Partition(0.2, np.array([0, 0, 0, 0]))]
# Coarse votes: face 1 and face 3 are wrong (argmax 1 and 0).
SCORES = np.array([[2.0, 0.0], [0.0, 1.0], [1.0, 3.0], [1.0, 0.0]])
# Area-weighted part means: finest part 0 [1, 0.5], part 1 [1, 1.5]; coarse part [1, 7/6].
FINE_MEANS = np.array([[1.0, 0.5], [1.0, 1.5]])
COARSE_MEAN = np.array([1.0, 7.0 / 6.0])


def test_none_returns_the_coarse_scores():
    np.testing.assert_array_equal(refine_scores(SCORES, PARTITIONS, AREAS, "none"), SCORES)
    np.testing.assert_array_equal(labels_from_scores(SCORES), [0, 1, 1, 0])


def test_multi_fusion_literal_reading():
    # S_rev = area-weighted mean / l: finest parts have l = 2, the coarse part l = 4.
    expected = SCORES + FINE_MEANS[[0, 0, 1, 1]] / 2 + COARSE_MEAN / 4
    fused = refine_scores(SCORES, PARTITIONS, AREAS, "multi", normalisation="literal")
    np.testing.assert_allclose(fused, expected)
    np.testing.assert_allclose(fused[1], [0.75, 1.0 + 0.25 + 7 / 24])
    np.testing.assert_array_equal(labels_from_scores(fused), [0, 1, 1, 0])  # too weak to repair anything


def test_multi_fusion_area_mean_and_partition_mean():
    area_mean = refine_scores(SCORES, PARTITIONS, AREAS, "multi", normalisation="area_mean")
    np.testing.assert_allclose(area_mean, SCORES + FINE_MEANS[[0, 0, 1, 1]] + COARSE_MEAN)
    shipped = refine_scores(SCORES, PARTITIONS, AREAS, "multi", normalisation="partition_mean")
    expected = SCORES + (FINE_MEANS[[0, 0, 1, 1]] + COARSE_MEAN) / 2
    np.testing.assert_allclose(shipped, expected)
    np.testing.assert_allclose(shipped[3], [2.0, 0.75 + 7 / 12])
    np.testing.assert_array_equal(labels_from_scores(shipped), [0, 1, 1, 0])


def test_fine_grained_optimisation_gives_one_label_per_finest_part():
    opt = refine_scores(SCORES, PARTITIONS, AREAS, "opt")
    np.testing.assert_allclose(opt, FINE_MEANS[[0, 0, 1, 1]])
    np.testing.assert_array_equal(labels_from_scores(opt), [0, 0, 1, 1])


def test_full_geofusion_hand_computed():
    s_hat = SCORES + (FINE_MEANS[[0, 0, 1, 1]] + COARSE_MEAN) / 2
    # Rows of s_hat: [3, 5/6], [1, 11/6], [2, 13/3], [2, 4/3]; area-weighted means per finest part:
    np.testing.assert_allclose(s_hat, [[3.0, 5 / 6], [1.0, 11 / 6], [2.0, 13 / 3], [2.0, 4 / 3]])
    expected = np.array([[2.0, 4 / 3], [2.0, 4 / 3], [2.0, 17 / 6], [2.0, 17 / 6]])
    full = refine_scores(SCORES, PARTITIONS, AREAS, "full", normalisation="partition_mean")
    np.testing.assert_allclose(full, expected)
    np.testing.assert_array_equal(labels_from_scores(full), [0, 0, 1, 1])


def test_full_geofusion_literal_reading_is_the_default():
    # Literal S_hat rows: [11/4, 13/24], [3/4, 37/24], [7/4, 97/24], [7/4, 25/24]; means over the finest parts:
    expected = np.array([[7 / 4, 25 / 24], [7 / 4, 25 / 24], [7 / 4, 61 / 24], [7 / 4, 61 / 24]])
    full = refine_scores(SCORES, PARTITIONS, AREAS, "full")
    np.testing.assert_allclose(full, expected)
    np.testing.assert_array_equal(labels_from_scores(full), [0, 0, 1, 1])


def test_geo_spreading_hand_computed():
    scores = np.array([[2.0, 0.0], [0.0, 1.0], [0.0, 3.0], [0.0, 0.0]])  # coarse labels 0, 1, 1, unknown
    # finest part 0: label area fractions [1/2, 1/2]; part 1: [0, 2/4] (face 3 is unknown);
    # coarse part: label 0 area 1, label 1 area 3, of 6 -> [1/6, 1/2].
    expected = np.array([[0.5 + 1 / 6, 1.0], [0.5 + 1 / 6, 1.0], [1 / 6, 1.0], [1 / 6, 1.0]])
    spread = refine_scores(scores, PARTITIONS, AREAS, "spread")
    np.testing.assert_allclose(spread, expected)
    np.testing.assert_array_equal(labels_from_scores(spread), [1, 1, 1, 1])


def test_finest_partition_is_found_whatever_the_order_and_zero_parts_stay_unknown():
    scores = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 3.0], [1.0, 0.0]])
    opt = refine_scores(scores, PARTITIONS[::-1], AREAS, "opt")
    np.testing.assert_array_equal(labels_from_scores(opt), [-1, -1, 1, 1])


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="mode"):
        refine_scores(SCORES, PARTITIONS, AREAS, "best")
    with pytest.raises(ValueError, match="normalisation"):
        refine_scores(SCORES, PARTITIONS, AREAS, "multi", normalisation="softmax")
    with pytest.raises(ValueError, match="faces"):
        refine_scores(SCORES, [Partition(0.01, np.array([0, 1]))], AREAS, "full")
    with pytest.raises(ValueError, match="face_areas"):
        refine_scores(SCORES, PARTITIONS, AREAS[:3], "full")
    for mode in REFINE_MODES[1:]:
        with pytest.raises(ValueError, match="decomposition"):
            refine_scores(SCORES, [], AREAS, mode)


def test_coarsest_partition_with_a_part_per_prompt():
    def parts(*counts):
        return [Partition(0.01 * (i + 1), np.arange(8) % c) for i, c in enumerate(counts)]

    assert coarsest_with_parts(parts(8, 2, 1), n_prompts=2).n_parts == 2
    assert coarsest_with_parts(parts(8, 4, 3), n_prompts=3).n_parts == 3
    assert coarsest_with_parts(parts(1, 1), n_prompts=2).threshold == 0.01  # none has enough: the finest
    with pytest.raises(ValueError, match="no partitions"):
        coarsest_with_parts([], n_prompts=2)


def test_each_prompt_gets_its_own_part():
    # a whole-object box votes for both prompts on the big part 0; prompt 1 is relatively strongest on part 2
    votes = np.array([[1.0, 0.9], [0.2, 0.1], [0.1, 0.6]])
    assert assign_parts_to_prompts(votes).tolist() == [0, 2]
    assert assign_parts_to_prompts(np.array([[1.0, 0.0], [0.5, 0.0]])).tolist() == [0, -1]  # prompt 1: no votes
    assert assign_parts_to_prompts(np.array([[1.0, 0.8]])).tolist() == [0, 0]  # one part for two prompts


def test_anchoring_gives_a_small_part_its_prompt():
    # Faces 0-5 are a big part (area 1 each), faces 6-7 a small one (area 0.25). The detector's boxes around the
    # big part also cover the small one, so prompt 0 ("body") outvotes prompt 1 ("handle") on every face.
    areas = np.r_[np.ones(6), 0.25, 0.25]
    scores = np.zeros((8, 2))
    scores[:, 0] = 1.0
    scores[:6, 1] = 0.1
    scores[6:, 1] = 0.8
    fine = Partition(0.02, np.array([0, 0, 1, 1, 2, 2, 3, 3]))
    coarse = Partition(0.1, np.array([0, 0, 0, 0, 0, 0, 1, 1]))
    whole = Partition(0.2, np.zeros(8, dtype=int))
    refined, plain = refine_labels(scores, [fine, coarse, whole], areas, "full", anchor=False)
    assert (plain == 0).all()  # the argmax loses the small part entirely
    _, anchored = refine_labels(scores, [fine, coarse, whole], areas, "full", anchor=True)
    np.testing.assert_array_equal(anchored, [0, 0, 0, 0, 0, 0, 1, 1])
    np.testing.assert_array_equal(anchor_prompts(plain, refined, [fine, coarse, whole], areas), anchored)


def test_anchoring_keeps_labels_outside_the_anchored_parts():
    # three parts at the coarsest useful level, two prompts: the third part keeps its GeoFusion label (-1 here)
    scores = np.array([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [0.0, 1.0], [0.0, 0.0], [0.0, 0.0]])
    partition = Partition(0.1, np.array([0, 0, 1, 1, 2, 2]))
    labels = np.array([0, 0, 1, 1, -1, -1])
    np.testing.assert_array_equal(anchor_prompts(labels, scores, [partition], np.ones(6)), labels)


def test_anchoring_uses_each_parts_distribution_over_the_prompts():
    # Part 0 is seen and boxed a lot (big votes for both prompts), part 1 little but almost only as "handle".
    # Raw means make part 0 the best part for both prompts; the distribution (0.6/0.4 vs 0.1/0.9) gives
    # "handle" to part 1, and "body" keeps part 0.
    scores = np.array([[6.0, 4.0], [6.0, 4.0], [0.1, 0.9], [0.1, 0.9]])
    partition = Partition(0.1, np.array([0, 0, 1, 1]))
    anchored = anchor_prompts(np.zeros(4, dtype=int), scores, [partition], np.ones(4))
    np.testing.assert_array_equal(anchored, [0, 0, 1, 1])


# Six faces of equal area: the coarse level splits {0, 1, 2} from {3, 4, 5}, the finest has a part per face. Face 5
# is the small "handle", the rest is "body"; faces 3 and 4 are held firmly for "body" by the votes.
FIRM_SCORES = np.array([[0.9, 0.1], [0.9, 0.1], [0.9, 0.1], [0.95, 0.05], [0.95, 0.05], [0.3, 0.7]])
FIRM_PARTITIONS = [Partition(0.02, np.arange(6)), Partition(0.1, np.array([0, 0, 0, 1, 1, 1])),
                   Partition(0.2, np.zeros(6, dtype=int))]


def test_soft_anchoring_keeps_faces_the_evidence_holds_for_another_prompt():
    _, plain = refine_labels(FIRM_SCORES, FIRM_PARTITIONS, np.ones(6), "full", anchor="off")
    np.testing.assert_array_equal(plain, [0, 0, 0, 0, 0, 1])  # GeoFusion is right here
    _, hard = refine_labels(FIRM_SCORES, FIRM_PARTITIONS, np.ones(6), "full", anchor="hard")
    np.testing.assert_array_equal(hard, [0, 0, 0, 1, 1, 1])  # the hard anchor hands the whole coarse part over
    _, default = refine_labels(FIRM_SCORES, FIRM_PARTITIONS, np.ones(6))
    np.testing.assert_array_equal(default, plain)  # the default (soft) anchoring leaves the firm faces alone


def test_soft_anchoring_prior_decides_close_faces_and_agreeing_levels_decide_outright():
    # one level, two parts; face shares of "handle" 0.45 (close) and 0.1 (firmly "body") on the handle's part
    scores = np.array([[1.0, 0.0], [1.0, 0.0], [0.55, 0.45], [0.9, 0.1]])
    levels = [Partition(0.1, np.array([0, 0, 1, 1]))]
    start = np.zeros(4, dtype=int)
    np.testing.assert_array_equal(soft_anchor_prompts(start, scores, levels, np.ones(4), prior=0.5), [0, 0, 1, 0])
    np.testing.assert_array_equal(soft_anchor_prompts(start, scores, levels, np.ones(4), prior=0.0), start)
    # the same part anchored on both levels: the full prior, enough for any face
    both = levels + [Partition(0.05, np.array([0, 1, 2, 2]))]
    np.testing.assert_array_equal(soft_anchor_prompts(start, scores, both, np.ones(4), prior=1.0, n_levels=2),
                                  [0, 0, 1, 1])
    with pytest.raises(ValueError, match="prior"):
        soft_anchor_prompts(start, scores, levels, np.ones(4), prior=-1.0)


def test_competing_prompts_need_a_part_where_their_share_nears_the_leader():
    # prompt 2 (a thin part) reaches at most 0.07 / 0.5 = 0.14 of the leading share; prompt 1 at least 0.4
    distributions = np.array([[0.7, 0.29, 0.01], [0.43, 0.5, 0.07], [0.6, 0.38, 0.02]])
    assert competing_prompts(distributions, 0.3).tolist() == [True, True, False]
    assert competing_prompts(distributions, 0.1).tolist() == [True, True, True]
    assert competing_prompts(np.array([[1.0, 0.0]]), 0.0).tolist() == [True, False]  # no evidence: never competes
    with pytest.raises(ValueError, match="min_ratio"):
        competing_prompts(distributions, 1.5)


# Scissors-like: three convex parts of two faces each, A and C of the handle, B the blade; prompts handle, blade,
# pivot. The pivot (a thin part inside no convex part here) has little evidence anywhere, most of it on the blade.
WEAK_PROMPT_SCORES = np.repeat([[0.7, 0.29, 0.01], [0.43, 0.5, 0.07], [0.6, 0.38, 0.02]], 2, axis=0)
WEAK_PROMPT_LEVEL = [Partition(0.1, np.array([0, 0, 1, 1, 2, 2]))]


def test_soft_anchoring_leaves_a_prompt_without_competing_evidence_out_of_the_assignment():
    geofusion = labels_from_scores(WEAK_PROMPT_SCORES)
    np.testing.assert_array_equal(geofusion, [0, 0, 1, 1, 0, 0])
    # scaled by its own best part, the pivot wins the blade's part and pushes the blade onto a handle part
    ungated = soft_anchor_prompts(geofusion, WEAK_PROMPT_SCORES, WEAK_PROMPT_LEVEL, np.ones(6), min_ratio=0.0)
    np.testing.assert_array_equal(ungated, [0, 0, 2, 2, 1, 1])
    # the default gate keeps the pivot out: the blade keeps its part, the pivot keeps its (empty) GeoFusion faces
    gated = soft_anchor_prompts(geofusion, WEAK_PROMPT_SCORES, WEAK_PROMPT_LEVEL, np.ones(6))
    np.testing.assert_array_equal(gated, geofusion)


def test_anchoring_modes():
    assert DEFAULT_ANCHOR in ANCHOR_MODES and "off" in ANCHOR_MODES and "hard" in ANCHOR_MODES
    _, off = refine_labels(FIRM_SCORES, FIRM_PARTITIONS, np.ones(6), anchor=False)
    _, default = refine_labels(FIRM_SCORES, FIRM_PARTITIONS, np.ones(6), anchor=True)
    _, named = refine_labels(FIRM_SCORES, FIRM_PARTITIONS, np.ones(6), anchor=DEFAULT_ANCHOR)
    np.testing.assert_array_equal(default, named)
    np.testing.assert_array_equal(off, refine_labels(FIRM_SCORES, FIRM_PARTITIONS, np.ones(6), anchor="off")[1])
    with pytest.raises(ValueError, match="anchoring mode"):
        refine_labels(FIRM_SCORES, FIRM_PARTITIONS, np.ones(6), anchor="always")


def test_agreed_labels_keep_only_what_all_labellings_say():
    np.testing.assert_array_equal(agreed_labels(np.array([0, 1, 1, -1]), np.array([0, 0, 1, -1])), [0, -1, 1, -1])
    np.testing.assert_array_equal(agreed_labels(np.array([2, 1])), [2, 1])
    with pytest.raises(ValueError, match="shape"):
        agreed_labels(np.array([0, 1]), np.array([0]))

