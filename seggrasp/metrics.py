"""Evaluation metrics (docs/design.md section 5): part IoU / mIoU for segmentation, and the grasp metrics.

Segmentation. For a shape with ground-truth labels `gt` and predicted labels `pred` (one int per face, -1 =
unknown), the IoU of ground-truth part k is |pred=k AND gt=k| / |pred=k OR gt=k|, measured in face area
(`face_areas` given) or in face count (`face_areas=None`). A face predicted as unknown (-1) never matches, so it
only enlarges the union of its ground-truth part ("unknown counts as wrong"). The shape mIoU is the mean over the
ground-truth parts present on the shape; category mIoU is the mean over the category's shapes and the overall mIoU
the mean over categories.

Grasps. Part selection accuracy and success rate are plain fractions; the orientation spread is the variance of
unit quaternions after aligning their signs to a reference, summed over the four components.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

UNKNOWN = -1


def _check_labels(pred: np.ndarray, gt: np.ndarray, n_parts: int, face_areas: np.ndarray | None) -> np.ndarray:
    if pred.ndim != 1 or gt.ndim != 1:
        raise ValueError(f"pred and gt must be 1-D label arrays, got shapes {pred.shape} and {gt.shape}")
    if pred.shape != gt.shape:
        raise ValueError(f"pred has {pred.shape[0]} labels but gt has {gt.shape[0]}")
    if n_parts < 1:
        raise ValueError(f"n_parts must be at least 1, got {n_parts}")
    for name, labels in (("pred", pred), ("gt", gt)):
        bad = (labels < UNKNOWN) | (labels >= n_parts)
        if bad.any():
            raise ValueError(f"{name} has labels outside -1..{n_parts - 1} (first: {int(labels[bad][0])})")
    if face_areas is None:
        return np.ones(pred.shape[0])
    weights = np.asarray(face_areas, dtype=np.float64)
    if weights.shape != pred.shape:
        raise ValueError(f"face_areas has shape {weights.shape}, expected ({pred.shape[0]},)")
    if not np.isfinite(weights).all() or (weights < 0).any():
        raise ValueError("face_areas must be finite and non-negative")
    return weights


def part_ious(
    pred: np.ndarray, gt: np.ndarray, n_parts: int, face_areas: np.ndarray | None = None
) -> np.ndarray:
    """IoU of every part 0..n_parts-1 (area-weighted if `face_areas` is given, else by face count).

    Returns an (n_parts,) float array; parts absent from `gt` get NaN (they do not enter the shape mIoU).
    """
    pred = np.asarray(pred).astype(np.int64)
    gt = np.asarray(gt).astype(np.int64)
    weights = _check_labels(pred, gt, n_parts, face_areas)
    # Shift by one so that unknown (-1) lands in bin 0 and is dropped.
    inter = np.bincount(gt[pred == gt] + 1, weights=weights[pred == gt], minlength=n_parts + 1)[1:]
    pred_total = np.bincount(pred + 1, weights=weights, minlength=n_parts + 1)[1:]
    gt_total = np.bincount(gt + 1, weights=weights, minlength=n_parts + 1)[1:]
    gt_count = np.bincount(gt + 1, minlength=n_parts + 1)[1:]
    union = pred_total + gt_total - inter
    ious = np.full(n_parts, np.nan)
    present = gt_count > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        ious[present] = np.where(union[present] > 0, inter[present] / union[present], 0.0)
    return ious


def shape_miou(pred: np.ndarray, gt: np.ndarray, n_parts: int, face_areas: np.ndarray | None = None) -> float:
    """Mean IoU over the ground-truth parts present on the shape; ValueError if gt has no labelled face."""
    ious = part_ious(pred, gt, n_parts, face_areas)
    if np.isnan(ious).all():
        raise ValueError("ground truth labels no face with a part: the shape mIoU is undefined")
    return float(np.nanmean(ious))


def mean_over_categories(shape_scores: Mapping[str, Sequence[float]] | Iterable[tuple[str, float]]) -> dict:
    """Category and overall mean of per-shape scores.

    `shape_scores` is either {category: [score per shape]} or an iterable of (category, score) pairs. Returns
    {"categories": {category: mean over its shapes}, "overall": mean over categories, "n_shapes": total}.
    """
    grouped: dict[str, list[float]] = {}
    items = shape_scores.items() if isinstance(shape_scores, Mapping) else None
    if items is not None:
        for category, scores in items:
            grouped.setdefault(str(category), []).extend(float(s) for s in scores)
    else:
        for category, score in shape_scores:
            grouped.setdefault(str(category), []).append(float(score))
    grouped = {c: s for c, s in grouped.items() if s}
    if not grouped:
        raise ValueError("no shape scores given")
    categories = {c: float(np.mean(s)) for c, s in sorted(grouped.items())}
    return {
        "categories": categories,
        "overall": float(np.mean(list(categories.values()))),
        "n_shapes": int(sum(len(s) for s in grouped.values())),
    }


def _fraction(flags: Sequence[bool] | np.ndarray, what: str) -> float:
    values = np.asarray(flags)
    if values.ndim != 1 or values.size == 0:
        raise ValueError(f"{what} needs a non-empty 1-D sequence of booleans, got shape {values.shape}")
    return float(values.astype(bool).mean())


def part_selection_accuracy(on_part: Sequence[bool] | np.ndarray) -> float:
    """Fraction of executed grasps whose finger contacts lie on the prompted (ground-truth) part."""
    return _fraction(on_part, "part_selection_accuracy")


def success_rate(successes: Sequence[bool] | np.ndarray) -> float:
    """Fraction of executed grasps that lifted and held the object while touching the prompted part."""
    return _fraction(successes, "success_rate")


def quaternion_variance(rotations: np.ndarray, reference: np.ndarray | None = None) -> float:
    """Orientation spread sigma^2 of grasps: variance of their unit quaternions, summed over the 4 components.

    `rotations` is (N, 3, 3). Quaternions q and -q are the same rotation, so each is flipped onto the hemisphere of
    `reference` (a 3x3 rotation; default: the first grasp) before the (population) variance is taken.
    """
    rotations = np.asarray(rotations, dtype=np.float64)
    if rotations.ndim != 3 or rotations.shape[1:] != (3, 3) or len(rotations) == 0:
        raise ValueError(f"rotations must be a non-empty (N, 3, 3) array, got shape {rotations.shape}")
    quats = Rotation.from_matrix(rotations).as_quat()
    ref = quats[0] if reference is None else Rotation.from_matrix(np.asarray(reference, dtype=np.float64)).as_quat()
    quats = np.where((quats @ ref < 0)[:, None], -quats, quats)
    return float(quats.var(axis=0).sum())


def surface_distances(a: trimesh.Trimesh, b: trimesh.Trimesh, n: int = 20000, seed: int = 1) -> tuple[float, float]:
    """Mean symmetric surface distance (Chamfer) between two meshes and the 95th percentile of both directions, in
    the meshes' units; `n` evenly spread surface samples per mesh (seeded)."""
    points_a, _ = trimesh.sample.sample_surface_even(a, n, seed=seed)
    points_b, _ = trimesh.sample.sample_surface_even(b, n, seed=seed + 1)
    d_ab, _ = cKDTree(points_b).query(points_a)
    d_ba, _ = cKDTree(points_a).query(points_b)
    return float((d_ab.mean() + d_ba.mean()) / 2), float(np.percentile(np.concatenate([d_ab, d_ba]), 95))
