"""`python -m sim.evaluate`: the benchmark on the bundled twin (or a real cell) — segmentation, part selection and
grasp success per method, as the paper's Tables I-III.

For each object: segment once per method (coarse votes and decompositions shared), sample grasps once, and for
each prompt execute the method's top-k grasps on the selected part, each from a fresh reset of the same scene.
Outputs in `--out`:

- `trials.jsonl`       one JSON line per trial (appended, flushed and fsynced one by one; a torn last line left by a
                       killed run is dropped on `--resume`, and trials already recorded are skipped);
- `segmentations.jsonl` one line per (object, method): mIoU (area and face count) and per-part IoU;
- `curves.jsonl`       one line per object: GeoSpreading vs GeoFusion mIoU over the decomposition thresholds;
- `cache/`             coarse votes per object (so a resumed run does not render and detect again);
- `summary.json`, `summary.md`, `plots/*.png`.

A failed grasp is data; an exception while evaluating an object is a crash: the other objects go on, the summary
is written, and the exit code is 1.
"""

from __future__ import annotations

import argparse
import fcntl
import json
import logging
import multiprocessing
import os
import sys
import time
import traceback
import zlib
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from seggrasp.cell import GraspOutcome
from seggrasp.episode import (
    METHODS,
    REFINEMENT_OF_METHOD,
    DetectorSpec,
    EpisodeContext,
    ObjectSegmenter,
    execute_slot,
    ground_truth_on_mesh,
    grasp_key,
    observe,
    plan_trials,
    table_plane_in_object_frame,
)
from seggrasp.grasp import AntipodalSampler
from seggrasp.grasp.select import TOP_K
from seggrasp.io import atomic_save_npz, atomic_write_json, atomic_write_text
from seggrasp.metrics import mean_over_categories, part_ious, quaternion_variance, shape_miou

LOG = logging.getLogger("sim.evaluate")

DEFAULT_METHODS = ("seggrasp", "coarse", "multi", "opt", "geofusion", "anchored", "oracle", "shapegrasp")
SIMULATED_PRESETS = ("perfect", "typical", "hard")
REAL_DETECTORS = ("grounding-dino", "owlv2")
QUICK_METHODS = ("oracle", "seggrasp", "coarse")
QUICK_CATEGORIES = ("mug", "knife", "hammer")  # --quick: the first twin object of each
QUICK_TOP_K = 3
ABLATION_METHODS = ("coarse", "multi", "opt", "geofusion", "anchored", "seggrasp")
#: Settings a resumed run must share with the run it continues.
RESUME_KEYS = ("detector", "weights", "embodiment", "seed", "top_k", "backend", "perceive")


@dataclass
class RunConfig:
    """Everything that defines one evaluation run."""

    methods: list[str]
    objects: list[str]
    detector: str = "typical"
    weights: str | None = None
    embodiment: str = "floating"
    seed: int = 0
    top_k: int = TOP_K
    backend: str = "sim"
    config: str | None = None
    perceive: bool = False
    dry_run: bool = False
    quick: bool = False
    prompts: list[str] = field(default_factory=list)

    def detector_spec(self) -> DetectorSpec:
        if self.detector in SIMULATED_PRESETS:
            return DetectorSpec("simulated", preset=self.detector, seed=self.seed)
        return DetectorSpec(self.detector, weights=self.weights, seed=self.seed)


# --------------------------------------------------------------------------------------------- results files


class JsonLines:
    """An append-only JSON Lines file that several processes may append to (one flushed, fsynced line at a time)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def repair(self) -> int:
        """Cut a torn last line (no trailing newline) left by a killed writer; returns the bytes removed."""
        if not self.path.exists():
            return 0
        data = self.path.read_bytes()
        if not data or data.endswith(b"\n"):
            return 0
        keep = data.rfind(b"\n") + 1
        with open(self.path, "r+b") as handle:
            handle.truncate(keep)
            handle.flush()
            os.fsync(handle.fileno())
        LOG.warning("%s: dropped a torn last line (%d bytes)", self.path, len(data) - keep)
        return len(data) - keep

    def read(self) -> list[dict]:
        """All complete records; a torn or corrupt last line is ignored, corruption elsewhere is an error."""
        if not self.path.exists():
            return []
        lines = self.path.read_text().split("\n")
        complete, tail = lines[:-1], lines[-1]
        records = []
        for number, line in enumerate(complete, start=1):
            if not line.strip():
                continue
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError as exc:
                raise ValueError(f"{self.path}:{number}: corrupt record ({exc}); not a torn last line") from exc
        if tail.strip():
            try:  # a final line without newline is either complete JSON or torn
                records.append(json.loads(tail))
            except json.JSONDecodeError:
                LOG.warning("%s: ignoring a torn last line", self.path)
        return records

    def append(self, record: dict) -> None:
        """Append one record as one line, under an exclusive lock, flushed and fsynced before returning."""
        line = (json.dumps(record, separators=(",", ":")) + "\n").encode("utf-8")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "ab") as handle:
            fcntl.flock(handle.fileno(), fcntl.LOCK_EX)
            try:
                handle.write(line)
                handle.flush()
                os.fsync(handle.fileno())
            finally:
                fcntl.flock(handle.fileno(), fcntl.LOCK_UN)


def trial_key(record: dict) -> tuple:
    return (record["object_id"], record["method"], record["prompt"], int(record["rank"]))


def segmentation_key(record: dict) -> tuple:
    return (record["object_id"], record["method"])


# --------------------------------------------------------------------------------------------- one object


@dataclass
class ObjectTask:
    object_id: str
    config: RunConfig
    out: str
    parallel: bool = False  # other objects are evaluated at the same time: one CoACD process per object


_CELL = None  # one simulated cell per worker process


def _get_cell(config: RunConfig):
    global _CELL
    if _CELL is None:
        if config.backend == "real":
            from hardware import RealCell  # lazy: the real cell's drivers are optional on a sim-only machine

            _CELL = RealCell.from_config(config.config, dry_run=config.dry_run)
        else:
            from sim.cell import SimCell

            _CELL = SimCell(embodiment=config.embodiment, seed=config.seed)
    return _CELL


def _close_cell() -> None:
    global _CELL
    if _CELL is not None:
        _CELL.close()
        _CELL = None


def evaluate_object(task: ObjectTask) -> dict:
    """All methods, prompts and trials of one object; returns a status dict (never raises)."""
    started = time.time()
    try:
        n_new = _evaluate_object(task)
        return {"object_id": task.object_id, "ok": True, "new_trials": n_new, "seconds": time.time() - started}
    except Exception as exc:  # a crash of one object must not lose the others' results
        return {
            "object_id": task.object_id, "ok": False, "error": f"{type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc(), "seconds": time.time() - started,
        }


def _evaluate_object(task: ObjectTask) -> int:
    from seggrasp.objects import load_asset

    config, out = task.config, Path(task.out)
    trials_file = JsonLines(out / "trials.jsonl")
    seg_file = JsonLines(out / "segmentations.jsonl")
    curve_file = JsonLines(out / "curves.jsonl")
    existing = [r for r in trials_file.read() if r["object_id"] == task.object_id]
    done = {trial_key(r) for r in existing}
    seg_done = {segmentation_key(r) for r in seg_file.read() if r["object_id"] == task.object_id}
    curve_done = any(r["object_id"] == task.object_id for r in curve_file.read())
    # a deterministic simulator gives the same outcome for the same grasp in the same scene: reuse it
    outcomes = None
    if config.backend == "sim":
        outcomes = {}
        for record in existing:
            if record["executed"] and not record["reused_outcome"]:
                outcomes[grasp_key(np.array(record["T_world_grasp"]), record["width"])] = _outcome_from(record)

    scene_seed = scene_seed_of(task.object_id, config.seed)
    if config.backend == "real":
        context = EpisodeContext(task.object_id, "real", list(config.prompts), scene_seed)
    else:
        context = EpisodeContext.from_object(load_asset(task.object_id), scene_seed, prompts=config.prompts or None)
    cell = _get_cell(config)
    cell.reset(seed=scene_seed, object_id=task.object_id)
    observation = observe(cell, perceive=config.perceive, workspace=_workspace(cell) if config.perceive else None)
    gt_on_mesh = ground_truth_on_mesh(cell, context, observation)

    cache = out / "cache" / task.object_id
    coarse_path = cache / "coarse.npz"
    coarse = np.load(coarse_path)["scores"] if coarse_path.exists() else None
    # Each object gets its own detector and camera-rig seed (derived from the run seed): with one shared seed every
    # object would see the same draws of the detector's error model (e.g. the same prompt boxed as the whole object
    # in the same view), so a whole run would be one correlated sample (overall coarse mIoU 0.34-0.58 across seeds).
    detector = replace(config.detector_spec(), seed=scene_seed)
    segmenter = ObjectSegmenter(
        observation.mesh, context.prompts, detector, gt_on_mesh, seed=config.seed,
        coarse_scores=coarse, decomposition_workers=1 if task.parallel else None,
    )
    grasps = None
    n_new = 0
    for method in config.methods:
        plan = segmenter.plan(method, observation.T_world_obj)
        if coarse is None and method != "oracle":
            coarse = segmenter.coarse_scores()
            atomic_save_npz(coarse_path, scores=coarse)
        if gt_on_mesh is not None and (task.object_id, method) not in seg_done:
            seg_file.append(_segmentation_record(context, plan, gt_on_mesh, observation.mesh))
        if plan.own_grasps is None and grasps is None:
            plane = table_plane_in_object_frame(observation.mesh, observation.T_world_obj)
            grasps = AntipodalSampler().generate(observation.mesh, seed=config.seed, table_plane=plane)
        slots = plan_trials(context, observation, plan, grasps, range(len(context.prompts)), config.top_k)
        for slot in slots:
            k, rank = slot[0], slot[1]
            if (task.object_id, method, context.prompts[k], rank) in done:
                continue
            record = execute_slot(cell, context, observation, plan, slot, config.seed, outcomes)
            record.extra = {"embodiment": config.embodiment, "backend": config.backend, "perceive": config.perceive}
            trials_file.append(record.to_json())
            n_new += 1
    if gt_on_mesh is not None and not curve_done and any(m != "oracle" for m in config.methods):
        curve_file.append(_threshold_curve(context, segmenter, gt_on_mesh))
    return n_new


def scene_seed_of(object_id: str, seed: int) -> int:
    """The scene (object pose) seed of an object: fixed for a run seed, different between objects."""
    return int(seed) * 100_003 + zlib.crc32(object_id.encode("utf-8")) % 100_000


def _workspace(cell):
    """Where the cameras look for the object: the real cell's configured box, or the twin's table area."""
    if getattr(cell, "workspace", None) is not None:
        return cell.workspace
    from seggrasp.perception import Workspace
    from sim.world import TABLE_TOP_Z, WORKSPACE_CENTER

    x, y = (float(v) for v in WORKSPACE_CENTER)
    return Workspace((x - 0.25, y - 0.25, TABLE_TOP_Z - 0.02), (x + 0.25, y + 0.25, TABLE_TOP_Z + 0.45), TABLE_TOP_Z)


def _outcome_from(record: dict) -> GraspOutcome:
    """The outcome stored in a trial record."""
    stored = dict(record["outcome"])
    stored["touched_faces"] = np.asarray(stored["touched_faces"], dtype=np.int64)
    stored["touched_weights"] = np.asarray(stored.get("touched_weights", []), dtype=np.float64)
    return GraspOutcome(**stored)


def _segmentation_record(context: EpisodeContext, plan, gt: np.ndarray, mesh) -> dict:
    n_parts = len(context.prompts)
    return {
        "object_id": context.object_id, "category": context.category, "method": plan.method,
        "detector": plan.detector, "prompts": context.prompts,
        "miou": shape_miou(plan.labels, gt, n_parts, mesh.area_faces),
        "miou_faces": shape_miou(plan.labels, gt, n_parts),
        "part_ious": [None if np.isnan(v) else float(v) for v in part_ious(plan.labels, gt, n_parts, mesh.area_faces)],
        "unknown_fraction": float((plan.labels < 0).mean()),
    }


def _threshold_curve(context: EpisodeContext, segmenter: ObjectSegmenter, gt: np.ndarray) -> dict:
    """mIoU of GeoSpreading on the partition at each threshold alone, and of GeoFusion from that threshold up."""
    from seggrasp.vote import labels_from_scores

    partitions = segmenter.partitions()
    areas = segmenter.mesh.area_faces
    n_parts = len(context.prompts)
    spread, full = [], []
    for index, partition in enumerate(partitions):
        spread.append(shape_miou(labels_from_scores(segmenter.refined_scores("spread", [partition])), gt, n_parts, areas))
        full.append(shape_miou(labels_from_scores(segmenter.refined_scores("full", partitions[index:])), gt, n_parts, areas))
    return {
        "object_id": context.object_id, "category": context.category, "detector": segmenter.detector.label,
        "thresholds": [float(p.threshold) for p in partitions], "spread": spread, "full": full,
    }


# --------------------------------------------------------------------------------------------- summary


def _method_order(config_methods: Sequence[str], seen: Iterable[str]) -> list[str]:
    ordered = [m for m in config_methods]
    ordered += sorted(set(seen) - set(ordered))
    return ordered


def summarise(trials: list[dict], segmentations: list[dict], curves: list[dict], methods: Sequence[str]) -> dict:
    """Tables I-III and the threshold curve as one JSON-ready dict."""
    summary: dict = {"methods": {}, "curve": _summarise_curves(curves)}
    for method in _method_order(methods, [r["method"] for r in trials] + [r["method"] for r in segmentations]):
        segs = [r for r in segmentations if r["method"] == method]
        rows = [r for r in trials if r["method"] == method]
        entry: dict = {"n_objects": len({r["object_id"] for r in rows} | {r["object_id"] for r in segs})}
        if segs:
            entry["miou"] = mean_over_categories([(r["category"], r["miou"]) for r in segs])
            entry["miou_faces"] = mean_over_categories([(r["category"], r["miou_faces"]) for r in segs])
        if rows:
            entry.update(_grasp_metrics(rows))
            by_category: dict[str, dict] = {}
            for category in sorted({r["category"] for r in rows}):
                by_category[category] = _grasp_metrics([r for r in rows if r["category"] == category])
            entry["categories"] = by_category
        detectors = sorted({r["detector"] for r in rows + segs})
        entry["detector"] = ", ".join(detectors)
        summary["methods"][method] = entry
    return summary


def _grasp_metrics(rows: list[dict]) -> dict:
    """Part Sel., Suc. and sigma^2 over the executed grasps (DESIGN.md section 5), plus how many of the top-k
    slots had a grasp to execute and the success rate over all slots (a slot without a grasp is a failure)."""
    from seggrasp.metrics import part_selection_accuracy, success_rate

    executed = [r for r in rows if r["executed"]]
    on_part = [r["contacts_on_part"] for r in executed if r["contacts_on_part"] is not None]
    success = [r["success"] for r in executed if r["success"] is not None]
    all_slots = [bool(r["success"]) for r in rows if r["success"] is not None]
    on_part_all_slots = [bool(r["contacts_on_part"]) for r in rows if r["contacts_on_part"] is not None]
    groups: dict[tuple, list[np.ndarray]] = {}
    for r in executed:
        groups.setdefault((r["object_id"], r["prompt"]), []).append(np.array(r["T_world_grasp"])[:3, :3])
    variances = [quaternion_variance(np.stack(g)) for g in groups.values() if len(g) >= 2]
    return {
        "trials": len(rows),
        "executed": len(executed),
        "reachable": int(sum(r["reachable"] for r in executed)),
        "part_selection": part_selection_accuracy(on_part) if on_part else None,
        "success": success_rate(success) if success else None,
        "success_all_slots": success_rate(all_slots) if all_slots else None,
        "part_selection_all_slots": part_selection_accuracy(on_part_all_slots) if on_part_all_slots else None,
        "sigma2": float(np.mean(variances)) if variances else None,
    }


def _summarise_curves(curves: list[dict]) -> dict:
    """Mean mIoU over objects at every threshold any object used (each object's partition at a threshold t is its
    partition with the largest threshold <= t, since identical partitions are stored once, at their finest)."""
    if not curves:
        return {}
    grid = sorted({t for c in curves for t in c["thresholds"]})
    spread, full = [], []
    for t in grid:
        s_values, f_values = [], []
        for c in curves:
            below = [i for i, ct in enumerate(c["thresholds"]) if ct <= t + 1e-12]
            if not below:
                continue
            index = max(below, key=lambda i: c["thresholds"][i])
            s_values.append(c["spread"][index])
            f_values.append(c["full"][index])
        spread.append(float(np.mean(s_values)) if s_values else None)
        full.append(float(np.mean(f_values)) if f_values else None)
    return {"thresholds": grid, "spread": spread, "full": full, "n_objects": len(curves)}


def _fmt(value: float | None, digits: int = 3) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def markdown_report(summary: dict, header: dict) -> str:
    """Tables I-III (+ the threshold curve) as Markdown."""
    methods = summary["methods"]
    lines = [
        "# SegGrasp evaluation",
        "",
        f"Detector: `{header['detector']}` · embodiment: `{header['embodiment']}` · backend: `{header['backend']}`"
        f" · perceive: {header['perceive']} · seed: {header['seed']} · top-k: {header['top_k']}"
        f" · objects: {header['n_objects']} · wall time: {header['wall_time_s']:.0f} s",
        "",
        "## Table I — segmentation mIoU (area-weighted) per category",
        "",
    ]
    categories = sorted({c for m in methods.values() if "miou" in m for c in m["miou"]["categories"]})
    lines += ["| method | " + " | ".join(categories) + " | overall | overall (face count) |"]
    lines += ["|---" * (len(categories) + 3) + "|"]
    for name, m in methods.items():
        if "miou" not in m:
            continue
        cells = [_fmt(m["miou"]["categories"].get(c)) for c in categories]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {_fmt(m['miou']['overall'])} | "
                     f"{_fmt(m['miou_faces']['overall'])} |")
    lines += ["", "## Table II — grasping", "",
              "Part Sel., Suc. and σ² over the executed grasps; *executed* = top-k slots that had a grasp on the "
              "selected part; the *all slots* columns count an empty slot as a miss (a method that leaves a prompt "
              "without grasps is not rewarded for it).", "",
              "| method | mIoU | Part Sel. | Suc. | σ² | executed / slots | reachable | Part Sel. (all slots) | "
              "Suc. (all slots) |",
              "|---|---|---|---|---|---|---|---|---|"]
    for name, m in methods.items():
        if "trials" not in m:
            continue
        miou = m["miou"]["overall"] if "miou" in m else None
        lines.append(f"| {name} | {_fmt(miou)} | {_fmt(m['part_selection'])} | {_fmt(m['success'])} | "
                     f"{_fmt(m['sigma2'], 4)} | {m['executed']} / {m['trials']} | {m['reachable']} | "
                     f"{_fmt(m['part_selection_all_slots'])} | {_fmt(m['success_all_slots'])} |")
    ablation = [a for a in ABLATION_METHODS if a in methods]
    if len(ablation) > 1:
        lines += ["", "## Table III — ablation", "",
                  "| method | multi-fusion | fine-grained opt. | prompt anchoring | grasps where labels agree with votes "
                  "| mIoU | Part Sel. | Suc. |",
                  "|---|---|---|---|---|---|---|---|"]
        for name in ablation:
            m = methods[name]
            miou = m["miou"]["overall"] if "miou" in m else None
            lines.append(f"| {name} | {' | '.join(_ablation_flags(name))} | {_fmt(miou)} | "
                         f"{_fmt(m.get('part_selection'))} | {_fmt(m.get('success'))} |")
    curve = summary.get("curve") or {}
    if curve.get("thresholds"):
        lines += ["", "## GeoSpreading vs GeoFusion over the decomposition threshold (mIoU)", "",
                  "| threshold | GeoSpreading | GeoFusion (from this threshold up) |", "|---|---|---|"]
        for t, s, f in zip(curve["thresholds"], curve["spread"], curve["full"]):
            lines.append(f"| {t:.3f} | {_fmt(s)} | {_fmt(f)} |")
    grasp_categories = sorted({c for m in methods.values() for c in m.get("categories", {})})
    if grasp_categories:
        lines += ["", "## Part Sel. / Suc. per category", "",
                  "| method | " + " | ".join(grasp_categories) + " |", "|---" * (len(grasp_categories) + 1) + "|"]
        for name, m in methods.items():
            if "categories" not in m:
                continue
            cells = [f"{_fmt(m['categories'][c]['part_selection'], 2)} / {_fmt(m['categories'][c]['success'], 2)}"
                     if c in m["categories"] else "—" for c in grasp_categories]
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def _ablation_flags(method: str) -> list[str]:
    """Table III ticks (multi-fusion, fine-grained opt., prompt anchoring, grasps on agreed labels) of a method."""
    mode, anchor, on_agreement = REFINEMENT_OF_METHOD[method]
    steps = (mode in ("multi", "full"), mode in ("opt", "full"), anchor, on_agreement)
    return ["✓" if step else "" for step in steps]


def write_plots(summary: dict, plot_dir: Path) -> list[Path]:
    """Per-category bars (mIoU, Part Sel., Suc.) and the threshold curve, as PNG files."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plot_dir.mkdir(parents=True, exist_ok=True)
    written = []
    methods = summary["methods"]
    panels = [
        ("miou", "mIoU", lambda m: m.get("miou", {}).get("categories", {})),
        ("part_selection", "Part Sel.", lambda m: {c: v["part_selection"] for c, v in m.get("categories", {}).items()}),
        ("success", "Suc.", lambda m: {c: v["success"] for c, v in m.get("categories", {}).items()}),
    ]
    for key, title, values_of in panels:
        per_method = {name: values_of(m) for name, m in methods.items() if values_of(m)}
        if not per_method:
            continue
        categories = sorted({c for v in per_method.values() for c in v})
        fig, ax = plt.subplots(figsize=(max(6.0, 1.2 * len(categories) + 2), 3.8))
        width = 0.8 / len(per_method)
        for i, (name, values) in enumerate(per_method.items()):
            heights = [values.get(c) if values.get(c) is not None else 0.0 for c in categories]
            ax.bar(np.arange(len(categories)) + i * width - 0.4 + width / 2, heights, width, label=name)
        ax.set_xticks(np.arange(len(categories)), categories, rotation=30, ha="right")
        ax.set_ylim(0, 1.05)
        ax.set_ylabel(title)
        ax.set_title(f"{title} per category")
        ax.legend(fontsize="small", ncols=min(len(per_method), 4))
        fig.tight_layout()
        path = plot_dir / f"{key}_per_category.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    curve = summary.get("curve") or {}
    if curve.get("thresholds"):
        fig, ax = plt.subplots(figsize=(5.5, 3.8))
        ax.plot(curve["thresholds"], curve["spread"], "o-", label="GeoSpreading (one decomposition)")
        ax.plot(curve["thresholds"], curve["full"], "s-", label="GeoFusion (from this threshold up)")
        ax.set_xscale("log")
        ax.set_xlabel("CoACD concavity threshold")
        ax.set_ylabel("mIoU")
        ax.set_title("GeoFusion vs GeoSpreading")
        ax.legend(fontsize="small")
        fig.tight_layout()
        path = plot_dir / "threshold_curve.png"
        fig.savefig(path, dpi=120)
        plt.close(fig)
        written.append(path)
    return written


# --------------------------------------------------------------------------------------------- CLI


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m sim.evaluate", description=__doc__.split("\n\n")[0])
    parser.add_argument("--methods", help=f"comma-separated, from {','.join(METHODS)} (default: {','.join(DEFAULT_METHODS)})")
    parser.add_argument("--objects", help="comma-separated object ids (default: the whole twin)")
    parser.add_argument("--categories", help="comma-separated categories of the twin")
    parser.add_argument("--detector", default="typical",
                        help=f"simulated preset ({'|'.join(SIMULATED_PRESETS)}) or {'|'.join(REAL_DETECTORS)} with --weights")
    parser.add_argument("--weights", help="local weights directory (or hub id) for a real detector")
    parser.add_argument("--embodiment", choices=("arm", "floating"), default="arm")
    parser.add_argument("--workers", type=int, default=1, help="processes evaluating objects in parallel")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--top-k", type=int, default=None, help=f"grasps executed per prompt (default {TOP_K}; --quick {QUICK_TOP_K})")
    parser.add_argument("--out", default=None, help="output folder (default results/evaluate-<detector>-<embodiment>)")
    parser.add_argument("--resume", action="store_true", help="continue a run in --out, skipping recorded trials")
    parser.add_argument("--quick", action="store_true",
                        help=f"CI profile: the first object of the categories {','.join(QUICK_CATEGORIES)}, methods "
                        f"{','.join(QUICK_METHODS)}, top-{QUICK_TOP_K}, floating gripper unless --embodiment is given")
    parser.add_argument("--backend", choices=("sim", "real"), default="sim")
    parser.add_argument("--config", help="cell.yaml of the real cell (--backend real)")
    parser.add_argument("--dry-run", action="store_true", help="real backend: plan and check, never move the robot")
    parser.add_argument("--perceive", action="store_true", help="plan on a mesh fused from the cameras, not the twin's")
    parser.add_argument("--prompts", help="comma-separated part names (default: each object's own; required for real)")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    args.embodiment_given = any(a == "--embodiment" or a.startswith("--embodiment=") for a in (argv or sys.argv[1:]))
    return args


def _split(text: str | None) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()] if text else []


def build_config(args: argparse.Namespace) -> RunConfig:
    """Validate the arguments into a RunConfig (ValueError naming the problem)."""
    methods = _split(args.methods) or list(QUICK_METHODS if args.quick else DEFAULT_METHODS)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {unknown}; choose from {list(METHODS)}")
    if args.detector not in SIMULATED_PRESETS + REAL_DETECTORS:
        raise ValueError(f"unknown detector {args.detector!r}; use {list(SIMULATED_PRESETS + REAL_DETECTORS)}")
    if args.detector in REAL_DETECTORS and not args.weights:
        raise ValueError(f"--detector {args.detector} needs --weights (a local weights directory or hub id)")
    if args.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {args.workers}")
    top_k = args.top_k if args.top_k is not None else (QUICK_TOP_K if args.quick else TOP_K)
    if top_k < 1:
        raise ValueError(f"--top-k must be at least 1, got {top_k}")
    embodiment = "floating" if args.quick and not args.embodiment_given else args.embodiment
    prompts = _split(args.prompts)
    if args.backend == "real":
        if not args.config:
            raise ValueError("--backend real needs --config cell.yaml")
        if args.detector in SIMULATED_PRESETS:
            raise ValueError("--backend real needs a real detector (--detector grounding-dino|owlv2 --weights DIR)")
        if not prompts or not args.objects:
            raise ValueError("--backend real needs --objects (names for the records) and --prompts")
        if "oracle" in methods:
            raise ValueError("the oracle method needs ground-truth labels, which a real object does not have")
        objects = _split(args.objects)
    else:
        objects = _select_objects(_split(args.objects), _split(args.categories), args.quick)
    return RunConfig(
        methods=methods, objects=objects, detector=args.detector, weights=args.weights, embodiment=embodiment,
        seed=args.seed, top_k=top_k, backend=args.backend, config=args.config,
        perceive=bool(args.perceive or args.backend == "real"), dry_run=args.dry_run, quick=args.quick,
        prompts=prompts,
    )


def _select_objects(object_ids: list[str], categories: list[str], quick: bool) -> list[str]:
    from seggrasp.objects import asset_ids

    if quick:
        if object_ids or categories:
            raise ValueError("--quick picks its own objects; drop --objects/--categories or --quick")
        return [asset_ids([category])[0] for category in QUICK_CATEGORIES]
    known = asset_ids(categories or None)
    if not known:
        raise ValueError(f"no twin objects in categories {categories}")
    if object_ids:
        missing = [o for o in object_ids if o not in known]
        if missing:
            raise ValueError(f"unknown object id(s) {missing}; the twin has {known}")
        return object_ids
    return known


def _prepare_out(out: Path, config: RunConfig, resume: bool) -> None:
    run_file = out / "run.json"
    trials = out / "trials.jsonl"
    if run_file.exists() and trials.exists() and trials.stat().st_size > 0:
        if not resume:
            raise ValueError(f"{out} already holds results; pass --resume to continue them or choose another --out")
        previous = json.loads(run_file.read_text())
        changed = {k: (previous.get(k), getattr(config, k)) for k in RESUME_KEYS if previous.get(k) != getattr(config, k)}
        if changed:
            raise ValueError(f"cannot resume {out}: settings differ from the recorded run: {changed}")
    out.mkdir(parents=True, exist_ok=True)
    for name in ("trials.jsonl", "segmentations.jsonl", "curves.jsonl"):
        JsonLines(out / name).repair()
    atomic_write_json(run_file, asdict(config))


def _worker_init() -> None:
    os.environ.setdefault("PYOPENGL_PLATFORM", "osmesa")
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # torch only matters for the real detectors
        pass


def run(config: RunConfig, out: Path, workers: int = 1, resume: bool = False) -> tuple[dict, list[dict]]:
    """Evaluate every object (in `workers` processes), then write the summary; returns (summary, crashes)."""
    from tqdm import tqdm

    _prepare_out(out, config, resume)
    started = time.time()
    tasks = [ObjectTask(object_id, config, str(out), parallel=workers > 1) for object_id in config.objects]
    crashes = []
    with tqdm(total=len(tasks), desc="objects", unit="obj") as bar:
        if workers == 1:
            _worker_init()
            results = map(evaluate_object, tasks)
            for status in results:
                crashes += _report(status, bar)
            _close_cell()
        else:
            # not multiprocessing.Pool: its daemonic workers may not start the CoACD processes of a decomposition
            context = multiprocessing.get_context("spawn")
            with ProcessPoolExecutor(workers, mp_context=context, initializer=_worker_init) as pool:
                for status in as_completed([pool.submit(evaluate_object, task) for task in tasks]):
                    crashes += _report(status.result(), bar)
    wall = time.time() - started
    summary = write_summary(config, out, wall, crashes)
    return summary, crashes


def _report(status: dict, bar) -> list[dict]:
    bar.update(1)
    if status["ok"]:
        bar.set_postfix_str(f"{status['object_id']}: {status['new_trials']} trials in {status['seconds']:.0f} s")
        return []
    LOG.error("object %s crashed: %s\n%s", status["object_id"], status["error"], status["traceback"])
    return [status]


def expected_trials(config: RunConfig) -> int:
    """How many trial records a complete run holds."""
    total = 0
    for object_id in config.objects:
        n_prompts = len(config.prompts) if config.prompts else _n_prompts(object_id)
        total += n_prompts * len(config.methods) * config.top_k
    return total


def _n_prompts(object_id: str) -> int:
    from seggrasp.objects import load_asset

    return len(load_asset(object_id).prompts)


def write_summary(config: RunConfig, out: Path, wall_time: float, crashes: list[dict]) -> dict:
    """Read the result files back and write summary.json, summary.md and the plots."""
    trials = JsonLines(out / "trials.jsonl").read()
    wanted = set(config.objects)
    trials = [r for r in trials if r["object_id"] in wanted and r["method"] in config.methods]
    segmentations = [r for r in JsonLines(out / "segmentations.jsonl").read()
                     if r["object_id"] in wanted and r["method"] in config.methods]
    curves = [r for r in JsonLines(out / "curves.jsonl").read() if r["object_id"] in wanted]
    summary = summarise(trials, segmentations, curves, config.methods)
    header = {
        "detector": config.detector_spec().label, "embodiment": config.embodiment, "backend": config.backend,
        "perceive": config.perceive, "seed": config.seed, "top_k": config.top_k, "n_objects": len(config.objects),
        "wall_time_s": wall_time,
    }
    expected = expected_trials(config)
    summary["run"] = dict(header, methods=config.methods, objects=config.objects, expected_trials=expected,
                          recorded_trials=len(trials), crashed_objects=[c["object_id"] for c in crashes])
    atomic_write_json(out / "summary.json", summary)
    markdown = markdown_report(summary, header)
    atomic_write_text(out / "summary.md", markdown)
    write_plots(summary, out / "plots")
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        config = build_config(args)
        out = Path(args.out or f"results/evaluate-{config.detector}-{config.embodiment}{'-quick' if config.quick else ''}")
        summary, crashes = run(config, out, workers=args.workers, resume=args.resume)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print((out / "summary.md").read_text())
    run_info = summary["run"]
    print(f"{run_info['recorded_trials']}/{run_info['expected_trials']} trials recorded in {out} "
          f"({run_info['wall_time_s']:.0f} s)")
    if crashes:
        print(f"error: {len(crashes)} object(s) crashed: {', '.join(c['object_id'] for c in crashes)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
