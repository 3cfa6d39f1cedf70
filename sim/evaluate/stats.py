"""Intervals of a run over objects and seeds: the per-method metrics and the paired differences between methods.

Method: a percentile cluster bootstrap over objects (scipy.stats.bootstrap, `N_RESAMPLES` resamples, fixed seed).
The object is the unit that is sampled: the twin's objects stand for the objects a user would hand the robot, and
the trials of one object (its prompts, slots and seeds) are correlated, since they share its shape, its part
layout and its decompositions. So each resample draws objects with replacement and every drawn object brings all
its records of every seed; the seeds' spread is inside each object's contribution (resampling the top level only of
a nested design, as is usual). The statistic of a resample is the point estimate's own formula: rates pooled over
slots (Part Sel., Suc.), mIoU averaged within each category and then over categories. A paired difference is the
difference of the two methods' statistics on the same resampled objects, over the (object, seed) pairs both
methods have, so an object that is hard for both cancels out.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Callable, Iterable, Sequence

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
N_RESAMPLES = 2000
BOOTSTRAP_SEED = 0


def _bool_or_none(value) -> float | None:
    return None if value is None else float(bool(value))


#: Grasp metrics: value of a trial record (None: the trial does not count for the metric). All-slot ones first.
GRASP_METRICS: dict[str, Callable[[dict], float | None]] = {
    "part_selection_all_slots": lambda r: _bool_or_none(r["contacts_on_part"]),
    "success_all_slots": lambda r: _bool_or_none(r["success"]),
    "success_top1": lambda r: _bool_or_none(r["success"]) if r["rank"] == 0 else None,
    "part_selection": lambda r: _bool_or_none(r["contacts_on_part"]) if r["executed"] else None,
    "success": lambda r: _bool_or_none(r["success"]) if r["executed"] else None,
    # over the requests the hand can hold (`infeasible` False: judged feasible before the robot moved)
    "success_feasible": lambda r: _bool_or_none(r["success"]) if r.get("infeasible") is False else None,
}
#: Segmentation metrics (one value per segmentation record), averaged per category, then over categories.
SEGMENTATION_METRICS: dict[str, Callable[[dict], float | None]] = {
    "miou": lambda r: r["miou"],
    "miou_faces": lambda r: r["miou_faces"],
}


def grouped_mean(num: np.ndarray, den: np.ndarray, group: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Σ num / Σ den within each group, averaged over the groups present, with objects counted `weights` times.

    num, den, group: one value per object; weights: (..., objects) (a bootstrap resample's counts). Returns (...).
    """
    groups = np.unique(group)
    onehot = (group[:, None] == groups[None, :]).astype(np.float64)  # (objects, groups)
    top, bottom = weights @ (onehot * num[:, None]), weights @ (onehot * den[:, None])
    present = bottom > 0
    rates = np.where(present, top / np.where(present, bottom, 1.0), 0.0)
    return rates.sum(axis=-1) / np.maximum(present.sum(axis=-1), 1)


def _counts(indices: np.ndarray, n: int) -> np.ndarray:
    """How often each of n objects occurs in each resample: (..., n) indices -> (..., n) counts."""
    flat = indices.reshape(-1, indices.shape[-1])
    counts = np.zeros((flat.shape[0], n))
    np.add.at(counts, (np.repeat(np.arange(flat.shape[0]), flat.shape[1]), flat.ravel()), 1.0)
    return counts.reshape(*indices.shape[:-1], n)


def bootstrap_interval(statistic: Callable[[np.ndarray], np.ndarray], n_objects: int,
                       confidence: float = CONFIDENCE, n_resamples: int = N_RESAMPLES,
                       seed: int = BOOTSTRAP_SEED) -> tuple[float, float | None, float | None]:
    """(estimate, low, high) of `statistic(weights)` (weights: (..., n_objects) object counts; all ones is the
    estimate) by the percentile bootstrap over objects. With fewer than two objects there is no interval (None,
    None): one object says nothing about the spread between objects."""
    estimate = float(statistic(np.ones(n_objects)))
    if n_objects < 2:
        return estimate, None, None
    result = stats.bootstrap(
        (np.arange(n_objects),), lambda idx, axis=-1: statistic(_counts(np.asarray(idx), n_objects)),
        vectorized=True, n_resamples=n_resamples, confidence_level=confidence, method="percentile",
        rng=np.random.default_rng(seed),
    )
    return estimate, float(result.confidence_interval.low), float(result.confidence_interval.high)


class MetricUnits:
    """One metric of one method as sums per (object, seed): Σ value and count, and the object's group."""

    def __init__(self, records: Iterable[dict], value: Callable[[dict], float | None], by_category: bool) -> None:
        self.sums: dict[tuple[str, int], list[float]] = defaultdict(lambda: [0.0, 0.0])
        self.group: dict[str, str] = {}
        for r in records:
            v = value(r)
            if v is None:
                continue
            unit = self.sums[(r["object_id"], int(r.get("seed", 0)))]
            unit[0] += float(v)
            unit[1] += 1.0
            self.group[r["object_id"]] = r["category"] if by_category else ""

    def arrays(self, units: Sequence[tuple[str, int]]) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
        """Per object (over the given units): its ids, Σ values, counts and group index."""
        objects = sorted({o for o, _ in units})
        index = {o: i for i, o in enumerate(objects)}
        num, den = np.zeros(len(objects)), np.zeros(len(objects))
        for unit in units:
            i = index[unit[0]]
            num[i] += self.sums[unit][0]
            den[i] += self.sums[unit][1]
        names = sorted(set(self.group.values()))
        group = np.array([names.index(self.group[o]) for o in objects], dtype=np.int64)
        return objects, num, den, group

    def per_seed(self, units: Sequence[tuple[str, int]]) -> dict[str, float]:
        """The statistic of each seed alone (keys are seeds as strings, for JSON)."""
        result = {}
        for seed in sorted({s for _, s in units}):
            _, num, den, group = self.arrays([u for u in units if u[1] == seed])
            result[str(seed)] = float(grouped_mean(num, den, group, np.ones(len(num))))
        return result


def describe(a: MetricUnits, b: MetricUnits | None = None) -> dict | None:
    """mean, ci_low, ci_high, per_seed and n_objects of a metric, or (with `b`) of the paired difference a - b over
    the (object, seed) pairs both have; None when there are none."""
    units = sorted(set(a.sums) & set(b.sums)) if b is not None else sorted(a.sums)
    if not units:
        return None
    objects, num, den, group = a.arrays(units)
    if b is None:
        statistic = lambda w: grouped_mean(num, den, group, w)  # noqa: E731
        per_seed = a.per_seed(units)
    else:
        _, num_b, den_b, group_b = b.arrays(units)
        statistic = lambda w: grouped_mean(num, den, group, w) - grouped_mean(num_b, den_b, group_b, w)  # noqa: E731
        seeds_a, seeds_b = a.per_seed(units), b.per_seed(units)
        per_seed = {s: seeds_a[s] - seeds_b[s] for s in seeds_a}
    mean, low, high = bootstrap_interval(statistic, len(objects))
    return {"mean": mean, "ci_low": low, "ci_high": high, "per_seed": per_seed, "n_objects": len(objects)}


def describe_average(systems: Sequence[MetricUnits]) -> dict | None:
    """`describe` of the mean of one metric over several robot systems (the paper's Suc. over its two), over the
    (object, seed) pairs every system has: a resample draws objects, and each drawn object brings its records on
    every system. None when the systems share no pair."""
    units = sorted(set.intersection(*(set(u.sums) for u in systems))) if systems else []
    if not units:
        return None
    arrays = [u.arrays(units) for u in systems]
    statistic = lambda w: np.mean([grouped_mean(num, den, group, w) for _, num, den, group in arrays], axis=0)  # noqa: E731
    per_seed = [u.per_seed(units) for u in systems]
    mean, low, high = bootstrap_interval(statistic, len(arrays[0][0]))
    return {"mean": mean, "ci_low": low, "ci_high": high, "n_objects": len(arrays[0][0]),
            "per_seed": {seed: float(np.mean([p[seed] for p in per_seed])) for seed in per_seed[0]}}


def system_averages(trials: dict[str, list[dict]], segmentations: dict[str, list[dict]],
                    methods: Sequence[str]) -> dict:
    """{method: {metric: describe_average(...)}} over the robot systems `trials` holds ({robot: its records})."""
    result = {}
    for method in methods:
        units = [_units(trials[robot], segmentations.get(robot, []), method) for robot in trials]
        shared = set.intersection(*(set(u) for u in units)) if units else set()
        described = {name: describe_average([u[name] for u in units]) for name in sorted(shared)}
        result[method] = {name: d for name, d in described.items() if d is not None}
    return result


def _units(trials: list[dict], segmentations: list[dict], method: str) -> dict[str, MetricUnits]:
    rows = [r for r in trials if r["method"] == method]
    segs = [r for r in segmentations if r["method"] == method]
    units = {name: MetricUnits(segs, value, True) for name, value in SEGMENTATION_METRICS.items()}
    units.update({name: MetricUnits(rows, value, False) for name, value in GRASP_METRICS.items()})
    return {name: u for name, u in units.items() if u.sums}


def method_intervals(trials: list[dict], segmentations: list[dict], methods: Sequence[str]) -> dict:
    """{method: {metric: describe(...)}} for every method and every metric it has records for."""
    result = {}
    for method in methods:
        units = _units(trials, segmentations, method)
        result[method] = {name: describe(u) for name, u in units.items()}
    return result


def paired_differences(trials: list[dict], segmentations: list[dict], pairs: Sequence[tuple[str, str]]) -> dict:
    """{"a - b": {metric: describe(a, b)}} for each pair of methods that both have records."""
    result = {}
    for a, b in pairs:
        units_a, units_b = _units(trials, segmentations, a), _units(trials, segmentations, b)
        metrics = {name: describe(units_a[name], units_b[name]) for name in units_a if name in units_b}
        metrics = {name: d for name, d in metrics.items() if d is not None}
        if metrics:
            result[f"{a} - {b}"] = metrics
    return result
