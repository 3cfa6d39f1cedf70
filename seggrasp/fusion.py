"""GeoFusion and GeoSpreading: refine the coarse face x prompt scores with a sweep of convex decompositions.

Notation (paper section III-B). `S` (F x P) is the coarse score matrix of eq. 1 (one row per face), `a_i` the area
of face i, and P(k, th_w) the k-th convex part of the decomposition at threshold th_w, with l = |P(k, th_w)| faces.

Multi-fusion:      S_hat_i = S_i + sum_w sum_k S_rev(k, th_w) [i in P(k, th_w)]
                   where the literal reading of the paper's area-weighted part score is
                   S_rev(k, th_w) = 1/l * (sum_{i in P(k)} a_i S_i) / (sum_{i in P(k)} a_i).
Fine-grained opt.: on the finest decomposition every part takes one label, the prompt with the largest
                   area-weighted score sum_{i in P(k, th_min)} a_i S_hat_i over the part.
Labels:            R_i = argmax_j S_hat_ij (`seggrasp.vote.labels_from_scores`, -1 for all-zero rows).

`refine_scores` returns scores whose row argmax is the refined label: for the fine-grained optimisation every face
gets the area-weighted mean S_hat of its finest part, so all faces of a part share one argmax.

Modes (the paper's Table III ablation plus Fig. 6): "none" = coarse S; "multi" = S_hat only; "opt" = fine-grained
optimisation of S; "full" = fine-grained optimisation of S_hat (GeoFusion); "spread" = GeoSpreading.

GeoSpreading (eq. 5, as read here): instead of fusing scores, the coarse *labels* R0 = argmax S are spread over
the parts: every part of every decomposition votes with the area fractions of the coarse labels inside it, and a
face sums the votes of the parts that contain it, S_spread_i = sum_w h(k(i, th_w)), h_j(k) = (sum_{i in P(k),
R0_i = j} a_i) / (sum_{i in P(k)} a_i). Faces with an unknown coarse label take part through their parts only.

Normalisation of S_rev (`normalisation`): "literal" (shipped) is the formula above, 1/l times the area-weighted
mean; "area_mean" drops 1/l; "partition_mean" divides the area-weighted mean by W (the number of decompositions).
The 1/l factor weights a part's vote by the inverse of its size: small parts (which rarely straddle a part
boundary) pull their faces together, big parts (a one-piece coarse decomposition) add almost nothing. Without 1/l
the coarse decompositions (one to three parts) add the object-wide mean score to every face and pull faces to the
majority label, and multi-fusion falls below coarse voting. Measured by mIoU with `bench/bench_seg.py --rescore`
on two twin objects: the literal reading is both the paper's formula and the best of the three (numbers in
docs/results/fusion.md).

Prompt anchoring (`anchor_prompts`, anchoring mode "hard"; not in the paper; the default is the soft form below:
`SegmentationConfig.anchor`, `python -m seggrasp segment --no-anchor` turns anchoring off). The argmax labelling lets a small part lose every face: boxes around a
big part (or around the whole object, a detector's most common failure on part prompts) also cover the small part,
so its faces collect more votes for the big part's prompt than for their own. On the twin with the `typical`
detector about a fifth of the prompted parts came out of full GeoFusion with no face at all (docs/results/fusion.md),
and a prompt without faces gets no grasp. Every prompt names a part the
object has, and a part is a geometric unit, so anchoring takes the coarsest decomposition with at least one part per
prompt, turns each part's area-weighted mean scores into its distribution over the prompts (dividing by their sum,
which removes how much the part was seen and boxed at all), scales each prompt's column by its best part, and gives
every prompt its own part (the assignment with the largest summed scaled score, `assign_parts_to_prompts`); the
faces of those parts take their prompt, every other face keeps its GeoFusion label.
Measured (category-mean mIoU on the twin, `typical` detector, four run seeds, against coarse voting, GeoFusion,
ShapeGrasp's labels and three alternative anchorings): docs/results/fusion.md.
The assignment is still wrong for about a quarter of the prompts (the detector's evidence allows no better here), and
a wrong anchor would send all of a prompt's grasps to the wrong part; the default grasp selection therefore reads
per-face probabilities that also weigh the GeoFusion scores and the coarse votes (`seggrasp.grasp.policy`), and
`agreed_labels` serves the `seggrasp-agree` ablation (see `seggrasp.method`).

Soft anchoring (`soft_anchor_prompts`, anchoring mode "soft", the default of `refine_labels`). Hard anchoring is a
gamble where the detector's evidence is weak: with two parts and two prompts whose part distributions are nearly
equal the assignment is a coin flip, and a lost flip gives a whole part (sometimes most of the object) to the wrong
prompt; on objects whose small part is no convex part at the coarsest level (a mug's handle split into pieces) it
gives the small prompt a piece of the big part. The soft form turns the assignment into a prior instead of a
verdict, on several levels instead of one: each face's refined scores become its distribution over the prompts
(divided by their sum), and on each of the ANCHOR_LEVELS coarsest decompositions with a part per prompt the part
assigned to a prompt (`assign_parts_to_prompts`, as above) adds ANCHOR_PRIOR / ANCHOR_LEVELS to that prompt's share
on its faces; the label is the argmax of share plus priors. A face the fused evidence holds firmly for another prompt
keeps it (the prior only decides where the evidence is close: the fallback to GeoFusion), a part anchored to the
same prompt on every level takes it outright, and a prompt that GeoFusion left without faces still gets the faces
where its share is within the prior of the winner's.

Evidence gate (`competing_prompts`, ANCHOR_MIN_RATIO). A prompt whose share is far below the leading prompt's on
every part of a level has no part there that its evidence picks out: typically a thin part (a scissors' pivot
screw, an eyeglass bridge) that is no convex part at the coarse levels and is boxed mostly by whole-object boxes.
Scaled by its own best part (as `assign_parts_to_prompts` does), such a prompt still wins the assignment of the part
its little evidence leans to, usually a big part another prompt holds, and pushes that prompt onto a wrong part.
So on each level only the prompts whose share reaches ANCHOR_MIN_RATIO times the leading share on at least one
part take part in the assignment; the others get no prior there and keep their GeoFusion faces (the fallback to
GeoFusion, per prompt and level).
Measured against GeoFusion, hard and ungated soft anchoring on the twin (with its multi-part categories) and on the
labelled YCB scans over twenty detector/camera seeds: `python bench/bench_seg.py --quality --seeds 20 --meshes twin` and
`--meshes ycb` (results in docs/results/seg-quality-*.md).

Absent prompts (`found_prompts`, `anchoring_levels`). A prompt is found when some box of it covered a face (its
column of S has a positive entry). A prompt that is not found keeps a zero column through every refinement mode, so
it gets no face, and it takes no part in anchoring, whose levels are chosen by the number of found prompts: prompts
the detector never boxes change no label (`python -m seggrasp segment` reports them as not found). Anchoring needs a
level with a part per found prompt; when no decomposition of the sweep has that many parts (more prompts than the
object has convex parts, such as a long list of candidate part names), anchoring is skipped and the GeoFusion labels
stand. A prompt that is boxed although it names no part of the object (a hallucinated whole-object or stray box)
cannot be told from a weakly seen real part by its votes, and takes part like one: each such prompt anchored to a
part takes that part's faces where its share is close, so a handful of them costs the present parts some IoU; with
every prompt naming a part of the object nothing changes.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from seggrasp.decompose import Partition
from seggrasp.vote import labels_from_scores

REFINE_MODES = ("none", "multi", "opt", "full", "spread")
NORMALISATIONS = ("literal", "area_mean", "partition_mean")
#: The literal reading of the paper; measured best of NORMALISATIONS (docs/results/fusion.md).
SHIPPED_NORMALISATION = "literal"
#: Soft anchoring: the prior added to a prompt's score share on its anchored part, spread over this many of the
#: coarsest levels with a part per prompt (a face anchored to the same prompt on every level always takes it).
ANCHOR_PRIOR = 1.0
ANCHOR_LEVELS = 2
#: Soft anchoring's evidence gate: a prompt joins a level's assignment only if on some part of it its share is at
#: least this fraction of the leading prompt's share (module docstring, "Evidence gate"; docs/results/fusion.md).
ANCHOR_MIN_RATIO = 0.3


def _check_inputs(scores: np.ndarray, partitions: Sequence[Partition], face_areas: np.ndarray) -> None:
    if scores.ndim != 2:
        raise ValueError(f"scores must be an (F, P) matrix, got shape {scores.shape}")
    if face_areas.shape != (scores.shape[0],):
        raise ValueError(f"face_areas has shape {face_areas.shape}, expected ({scores.shape[0]},)")
    if (face_areas < 0).any() or not np.isfinite(face_areas).all():
        raise ValueError("face_areas must be finite and non-negative")
    for partition in partitions:
        if partition.part_of_face.shape != (scores.shape[0],):
            raise ValueError(
                f"partition at threshold {partition.threshold} has {partition.part_of_face.size} faces, "
                f"scores have {scores.shape[0]}"
            )


def part_mean_scores(scores: np.ndarray, part_of_face: np.ndarray, face_areas: np.ndarray) -> np.ndarray:
    """(K, P) area-weighted mean score of every part (zero for a part of zero area)."""
    scores = np.asarray(scores, dtype=np.float64)
    part_of_face = np.asarray(part_of_face, dtype=np.int64)
    face_areas = np.asarray(face_areas, dtype=np.float64)
    if scores.ndim != 2 or not (len(scores) == len(part_of_face) == len(face_areas)):
        raise ValueError(
            f"need per-face scores (F, P), parts (F,) and areas (F,); got {scores.shape}, {part_of_face.shape}, "
            f"{face_areas.shape}"
        )
    n_parts = int(part_of_face.max()) + 1
    weighted = np.zeros((n_parts, scores.shape[1]))
    np.add.at(weighted, part_of_face, scores * face_areas[:, None])
    area = np.bincount(part_of_face, weights=face_areas, minlength=n_parts)
    return np.divide(weighted, area[:, None], out=np.zeros_like(weighted), where=area[:, None] > 0)


def part_scores(
    scores: np.ndarray, partition: Partition, face_areas: np.ndarray, normalisation: str, n_partitions: int
) -> np.ndarray:
    """S_rev(k, th) for every part k of one decomposition, (K, P), under the given normalisation."""
    means = part_mean_scores(scores, partition.part_of_face, face_areas)
    if normalisation == "literal":
        face_count = np.bincount(partition.part_of_face, minlength=len(means))
        return means / np.maximum(face_count, 1)[:, None]
    if normalisation == "area_mean":
        return means
    if normalisation == "partition_mean":
        return means / n_partitions
    raise ValueError(f"unknown normalisation {normalisation!r}; use one of {NORMALISATIONS}")


def multi_fusion(
    scores: np.ndarray, partitions: Sequence[Partition], face_areas: np.ndarray,
    normalisation: str = SHIPPED_NORMALISATION,
) -> np.ndarray:
    """S_hat = S + sum_w S_rev(k(i, th_w), th_w) for every face i."""
    fused = scores.astype(np.float64).copy()
    for partition in partitions:
        fused += part_scores(scores, partition, face_areas, normalisation, len(partitions))[partition.part_of_face]
    return fused


def fine_grained(scores: np.ndarray, finest: Partition, face_areas: np.ndarray) -> np.ndarray:
    """Every face takes the area-weighted mean score of its part in the finest decomposition (one label per part)."""
    return part_mean_scores(scores, finest.part_of_face, face_areas)[finest.part_of_face]


def geo_spreading(scores: np.ndarray, partitions: Sequence[Partition], face_areas: np.ndarray) -> np.ndarray:
    """GeoSpreading: sum over decompositions of the area fractions of the coarse labels in each face's part."""
    n_prompts = scores.shape[1]
    coarse = np.where(scores.max(axis=1) > 0, scores.argmax(axis=1), -1)
    one_hot = np.zeros_like(scores, dtype=np.float64)
    known = coarse >= 0
    one_hot[np.flatnonzero(known), coarse[known]] = 1.0
    spread = np.zeros((scores.shape[0], n_prompts))
    for partition in partitions:
        spread += part_mean_scores(one_hot, partition.part_of_face, face_areas)[partition.part_of_face]
    return spread


def refine_scores(
    scores: np.ndarray,
    partitions: Sequence[Partition],
    face_areas: np.ndarray,
    mode: str = "full",
    normalisation: str = SHIPPED_NORMALISATION,
) -> np.ndarray:
    """Refined (F, P) scores; labels follow from `seggrasp.vote.labels_from_scores`.

    `partitions` are the distinct decompositions, finest first (as `decompose_sweep` returns them).
    """
    if mode not in REFINE_MODES:
        raise ValueError(f"unknown refinement mode {mode!r}; use one of {REFINE_MODES}")
    if normalisation not in NORMALISATIONS:
        raise ValueError(f"unknown normalisation {normalisation!r}; use one of {NORMALISATIONS}")
    scores = np.asarray(scores, dtype=np.float64)
    face_areas = np.asarray(face_areas, dtype=np.float64)
    _check_inputs(scores, partitions, face_areas)
    if mode == "none":
        return scores.copy()
    if not partitions:
        raise ValueError(f"refinement mode {mode!r} needs at least one decomposition")
    finest = min(partitions, key=lambda p: p.threshold)
    if mode == "multi":
        return multi_fusion(scores, partitions, face_areas, normalisation)
    if mode == "opt":
        return fine_grained(scores, finest, face_areas)
    if mode == "full":
        return fine_grained(multi_fusion(scores, partitions, face_areas, normalisation), finest, face_areas)
    return geo_spreading(scores, partitions, face_areas)


def coarsest_with_parts(partitions: Sequence[Partition], n_prompts: int) -> Partition:
    """The coarsest partition with at least one part per prompt (the finest if none has that many)."""
    if len(partitions) == 0:
        raise ValueError("no partitions to choose from")
    if n_prompts < 1:
        raise ValueError(f"need at least one prompt, got {n_prompts}")
    by_fineness = sorted(partitions, key=lambda p: p.threshold)
    enough = [p for p in by_fineness if p.n_parts >= n_prompts]
    return enough[-1] if enough else by_fineness[0]


def found_prompts(scores: np.ndarray) -> np.ndarray:
    """(P,) bool: the prompts with evidence, some positive score in the (F, P) `scores` (module docstring, "Absent
    prompts"); the others are not found."""
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim != 2:
        raise ValueError(f"scores must be an (F, P) matrix, got shape {scores.shape}")
    return (scores > 0).any(axis=0)


def anchoring_levels(partitions: Sequence[Partition], scores: np.ndarray, n_levels: int) -> list[Partition]:
    """The `n_levels` coarsest partitions with at least one part per found prompt of `scores` (`found_prompts`),
    coarsest first; none when no partition has that many parts or no prompt is found (then anchoring is skipped)."""
    n_found = int(found_prompts(scores).sum())
    if n_found == 0:
        return []
    return sorted((p for p in partitions if p.n_parts >= n_found), key=lambda p: -p.threshold)[:n_levels]


def assign_parts_to_prompts(part_scores: np.ndarray) -> np.ndarray:
    """(P,) the part chosen for each prompt from (K, P) part scores, -1 for a prompt no part scores for.

    Each prompt's scores are scaled by their maximum, then distinct parts go to the prompts (the assignment with
    the largest summed scaled score); with fewer parts than prompts each prompt takes its best part.
    """
    part_scores = np.asarray(part_scores, dtype=np.float64)
    chosen = np.full(part_scores.shape[1], -1, dtype=np.int64)
    prompts = np.flatnonzero((part_scores > 0).any(axis=0))
    if len(prompts) == 0:
        return chosen
    scaled = part_scores[:, prompts] / part_scores[:, prompts].max(axis=0)
    if part_scores.shape[0] >= len(prompts):
        parts, columns = linear_sum_assignment(-scaled)
        chosen[prompts[columns]] = parts
    else:
        chosen[prompts] = np.argmax(scaled, axis=0)
    return chosen


def anchor_prompts(
    labels: np.ndarray, scores: np.ndarray, partitions: Sequence[Partition], face_areas: np.ndarray
) -> np.ndarray:
    """Labels in which every found prompt owns at least one convex part (module docstring, "Prompt anchoring" and
    "Absent prompts").

    On the coarsest partition with a part per found prompt (`anchoring_levels`; none: `labels` unchanged), the
    parts `assign_parts_to_prompts` gives the prompts (from each part's distribution of area-weighted mean `scores`
    over the prompts) take those prompts; every other face keeps its label from `labels`.
    """
    scores = np.asarray(scores, dtype=np.float64)
    anchored = np.asarray(labels, dtype=np.int64).copy()
    _check_inputs(scores, partitions, np.asarray(face_areas, dtype=np.float64))
    levels = anchoring_levels(partitions, scores, 1)
    if not levels:
        return anchored
    (partition,) = levels
    means = part_mean_scores(scores, partition.part_of_face, face_areas)
    distributions = means / np.maximum(means.sum(axis=1, keepdims=True), 1e-18)
    for prompt, part in enumerate(assign_parts_to_prompts(distributions)):
        if part >= 0:
            anchored[partition.part_of_face == part] = prompt
    return anchored


def anchor_mode(anchor: bool | str) -> str:
    """The anchoring mode `anchor` names: True = DEFAULT_ANCHOR, False = "off", else one of ANCHOR_MODES."""
    if anchor is True:
        return DEFAULT_ANCHOR
    if anchor is False:
        return "off"
    if anchor not in ANCHOR_MODES:
        raise ValueError(f"unknown anchoring mode {anchor!r}; use one of {ANCHOR_MODES} (or True / False)")
    return anchor


def refine_labels(
    scores: np.ndarray,
    partitions: Sequence[Partition],
    face_areas: np.ndarray,
    mode: str = "full",
    anchor: bool | str = True,
) -> tuple[np.ndarray, np.ndarray]:
    """(refined scores, labels): `refine_scores`, its argmax, then (if there are partitions) prompt anchoring of
    the refined scores in the mode `anchor` names (`anchor_mode`)."""
    anchor = anchor_mode(anchor)
    refined = refine_scores(scores, partitions, face_areas, mode)
    labels = labels_from_scores(refined)
    if anchor != "off" and partitions:
        labels = ANCHORS[anchor](labels, refined, partitions, face_areas)
    return refined, labels


def competing_prompts(distributions: np.ndarray, min_ratio: float = ANCHOR_MIN_RATIO) -> np.ndarray:
    """(P,) bool: the prompts whose share reaches `min_ratio` times the leading prompt's share on at least one part
    of (K, P) part `distributions` (module docstring, "Evidence gate")."""
    distributions = np.asarray(distributions, dtype=np.float64)
    if distributions.ndim != 2:
        raise ValueError(f"distributions must be a (parts, prompts) matrix, got shape {distributions.shape}")
    if not 0.0 <= min_ratio <= 1.0:
        raise ValueError(f"min_ratio must lie in [0, 1], got {min_ratio}")
    leading = distributions.max(axis=1, keepdims=True)
    ratio = np.divide(distributions, leading, out=np.zeros_like(distributions), where=leading > 0)
    return (ratio >= min_ratio).any(axis=0) & (distributions > 0).any(axis=0)


def anchor_priors(
    scores: np.ndarray, partitions: Sequence[Partition], face_areas: np.ndarray,
    prior: float = ANCHOR_PRIOR, n_levels: int = ANCHOR_LEVELS, min_ratio: float = ANCHOR_MIN_RATIO,
) -> np.ndarray:
    """(F, P) soft-anchoring priors: on each of the `n_levels` coarsest partitions with a part per found prompt
    (`anchoring_levels`; none: all zero), the part `assign_parts_to_prompts` gives each of the `competing_prompts`
    adds `prior / n_levels` to that prompt on its faces (`scores` are the refined scores whose part distributions
    decide)."""
    scores = np.asarray(scores, dtype=np.float64)
    face_areas = np.asarray(face_areas, dtype=np.float64)
    _check_inputs(scores, partitions, face_areas)
    if prior < 0 or n_levels < 1:
        raise ValueError(f"need prior >= 0 and n_levels >= 1, got {prior} and {n_levels}")
    priors = np.zeros_like(scores)
    levels = anchoring_levels(partitions, scores, n_levels)
    for partition in levels:
        means = part_mean_scores(scores, partition.part_of_face, face_areas)
        distributions = means / np.maximum(means.sum(axis=1, keepdims=True), 1e-18)
        competing = np.flatnonzero(competing_prompts(distributions, min_ratio))
        if len(competing) == 0:
            continue
        for prompt, part in zip(competing, assign_parts_to_prompts(distributions[:, competing])):
            if part >= 0:
                priors[partition.part_of_face == part, prompt] += prior / len(levels)
    return priors


def row_shares(scores: np.ndarray) -> np.ndarray:
    """Each row of a non-negative (F, P) matrix divided by its sum (all-zero rows stay zero)."""
    scores = np.asarray(scores, dtype=np.float64)
    if scores.ndim != 2 or (scores < 0).any() or not np.isfinite(scores).all():
        raise ValueError(f"need a finite non-negative (F, P) score matrix, got shape {scores.shape}")
    total = scores.sum(axis=1, keepdims=True)
    return np.divide(scores, total, out=np.zeros_like(scores), where=total > 0)


def soft_anchor_prompts(
    labels: np.ndarray, scores: np.ndarray, partitions: Sequence[Partition], face_areas: np.ndarray,
    prior: float = ANCHOR_PRIOR, n_levels: int = ANCHOR_LEVELS, min_ratio: float = ANCHOR_MIN_RATIO,
) -> np.ndarray:
    """Labels after soft anchoring (module docstring, "Soft anchoring" and "Evidence gate"): faces that
    `anchor_priors` touches take the argmax of their score distribution (each row of `scores` divided by its sum)
    plus priors, every other face keeps its label from `labels`."""
    scores = np.asarray(scores, dtype=np.float64)
    priors = anchor_priors(scores, partitions, face_areas, prior, n_levels, min_ratio)
    anchored = np.asarray(labels, dtype=np.int64).copy()
    touched = priors.any(axis=1)
    anchored[touched] = np.argmax(row_shares(scores) + priors, axis=1)[touched]
    return anchored


#: Anchoring modes of `refine_labels`: "off" = the paper's GeoFusion labels, "hard" = `anchor_prompts` (one part
#: per prompt on the coarsest level, assigned outright), "soft" = `soft_anchor_prompts`.
ANCHORS = {"hard": anchor_prompts, "soft": soft_anchor_prompts}
ANCHOR_MODES = ("off", *ANCHORS)
#: What `refine_labels(anchor=True)` (the default) does; measured on the twin and the YCB scans (docs/results/).
DEFAULT_ANCHOR = "soft"


def agreed_labels(*labellings: np.ndarray) -> np.ndarray:
    """Per face the label all `labellings` agree on, -1 where any two differ (or all are -1)."""
    if not labellings:
        raise ValueError("need at least one labelling")
    first = np.asarray(labellings[0], dtype=np.int64)
    agree = np.ones(first.shape, dtype=bool)
    for other in labellings[1:]:
        other = np.asarray(other, dtype=np.int64)
        if other.shape != first.shape:
            raise ValueError(f"labellings differ in shape: {first.shape} vs {other.shape}")
        agree &= other == first
    return np.where(agree, first, -1)
