"""The runner: for each object, the harness picks the cell, the detector and the ground truth, hands them to one
`seggrasp.episode.Episode`, and appends what it returns to the result files."""

from __future__ import annotations

import logging
import multiprocessing
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from seggrasp.cell import Cell, GraspOutcome
from seggrasp.episode import Episode, EpisodeContext, EpisodeSettings, Slot, TrialRecord, grasp_key
from seggrasp.metrics import part_ious, shape_miou
from seggrasp.truth import DetectorSpec, GroundTruth
from sim.evaluate.config import RunConfig, scene_seed_of
from sim.evaluate.records import JsonLines, VoteCache, curve_key, read_unique, segmentation_key, trial_key

LOG = logging.getLogger("sim.evaluate")


@dataclass
class ObjectTask:
    object_id: str
    config: RunConfig
    out: str
    parallel: bool = False  # other objects are evaluated at the same time: one CoACD process per object


_CELL = None  # one cell per worker process


def _get_cell(config: RunConfig) -> Cell:
    global _CELL
    if _CELL is None:
        if config.backend == "real":
            from hardware import RealCell  # lazy: the real cell's drivers are optional on a sim-only machine

            _CELL = RealCell.from_config(config.config, dry_run=config.dry_run)
        else:
            from sim.cell import SimCell

            _CELL = SimCell(embodiment=config.embodiment, seed=config.seed)
    return _CELL


def close_cell() -> None:
    """Close this process's cell (if one was opened)."""
    global _CELL
    if _CELL is not None:
        _CELL.close()
        _CELL = None


def evaluate_object(task: ObjectTask) -> dict:
    """All methods, prompts and trials of one object; returns a status dict (never raises)."""
    started = time.time()
    try:
        cell = _get_cell(task.config)
        context, truth = subject_of(task.object_id, task.config, cell)
        n_new = run_object(cell, context, truth, task.config, Path(task.out), parallel=task.parallel)
        return {"object_id": task.object_id, "ok": True, "new_trials": n_new, "seconds": time.time() - started}
    except Exception as exc:  # a crash of one object must not lose the others' results
        return {
            "object_id": task.object_id, "ok": False, "error": f"{type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc(), "seconds": time.time() - started,
        }


def subject_of(object_id: str, config: RunConfig, cell: Cell) -> tuple[EpisodeContext, GroundTruth | None]:
    """What the harness knows about an object: its context and, for a twin object, its ground truth."""
    scene_seed = scene_seed_of(object_id, config.seed)
    if config.backend == "real":
        return EpisodeContext(object_id, "real", list(config.prompts), scene_seed), None
    from seggrasp.objects import load_asset

    model = load_asset(object_id)
    context = EpisodeContext.from_object(model, scene_seed, prompts=config.prompts or None)
    return context, GroundTruth.of_object(model, context.prompts, true_pose=lambda: cell.object_mesh()[1])


def run_object(
    cell: Cell,
    context: EpisodeContext,
    truth: GroundTruth | None,
    config: RunConfig,
    out: Path,
    detector: DetectorSpec | None = None,
    parallel: bool = False,
) -> int:
    """Run every method's episode slots of one object that `out` does not hold yet; returns how many were added."""
    trials_file, seg_file = JsonLines(out / "trials.jsonl"), JsonLines(out / "segmentations.jsonl")
    existing = [r for r in read_unique(trials_file.path, trial_key) if r["object_id"] == context.object_id]
    done = {trial_key(r) for r in existing}
    seg_done = {segmentation_key(r) for r in seg_file.read() if r["object_id"] == context.object_id}
    settings = EpisodeSettings(
        seed=config.seed, top_k=config.top_k, perceive=config.perceive,
        workspace=workspace_of(cell) if config.perceive else None, decomposition_workers=1 if parallel else None,
    )
    episode = Episode(
        cell, context, detector or config.object_detector(context.object_id), truth, settings,
        vote_cache=VoteCache(out / "cache" / context.object_id), outcome_cache=_reusable_outcomes(existing, config),
    )
    if config.record and not hasattr(cell, "record_next"):
        raise ValueError(f"--record needs a cell that records picture strips; {type(cell).__name__} does not")
    n_new = 0
    for method in config.methods:
        plan = episode.plan(method)
        if episode.truth_on_mesh is not None and (context.object_id, method) not in seg_done:
            seg_file.append(segmentation_record(context, plan.method, plan.detector, plan.labels, episode))
        recorded = 0
        for slot in episode.slots(plan):
            prompt = context.prompts[slot.prompt_index]
            if (context.object_id, method, prompt, slot.rank) in done:
                continue
            if recorded < config.record and _runs_the_cell(episode, slot):
                cell.record_next(strip_path(out, method, context.object_id, prompt, slot.rank))
                recorded += 1
            record = episode.execute(slot)
            record_extra(record, config)
            trials_file.append(record.to_json())
            n_new += 1
    _append_curve(episode, config, out)
    return n_new


def _runs_the_cell(episode: Episode, slot: Slot) -> bool:
    """Whether executing `slot` moves the cell: it has a grasp whose outcome is not reused from the cache."""
    if slot.grasp is None:
        return False
    key = grasp_key(slot.grasp.poses[0], float(slot.grasp.widths[0]))
    return episode.outcome_cache is None or key not in episode.outcome_cache


def strip_path(out: Path, method: str, object_id: str, prompt: str, rank: int) -> Path:
    """Where `--record` writes the picture strip of one slot: OUT/strips/<method>-<object>-<prompt>-<rank>.png."""
    safe_prompt = "".join(c if c.isalnum() or c in "_." else "_" for c in prompt)
    return out / "strips" / f"{method}-{object_id}-{safe_prompt}-{rank}.png"


def _reusable_outcomes(existing: list[dict], config: RunConfig) -> dict | None:
    """A deterministic simulator gives the same outcome for the same grasp in the same scene: reuse recorded ones."""
    if config.backend != "sim":
        return None
    outcomes = {}
    for record in existing:
        if record["executed"] and not record["reused_outcome"]:
            outcomes[grasp_key(np.array(record["T_world_grasp"]), record["width"])] = outcome_from(record)
    return outcomes


def _append_curve(episode: Episode, config: RunConfig, out: Path) -> None:
    curve_file = JsonLines(out / "curves.jsonl")
    if episode.truth_on_mesh is None or not any(m != "oracle" for m in config.methods):
        return
    if any(curve_key(r) == (episode.context.object_id,) for r in curve_file.read()):
        return
    curve_file.append(threshold_curve(episode))


def workspace_of(cell: Cell):
    """Where the cameras look for the object: the real cell's configured box, or the twin's table area."""
    if getattr(cell, "workspace", None) is not None:
        return cell.workspace
    from seggrasp.perception import Workspace
    from sim.world import TABLE_TOP_Z, WORKSPACE_CENTER

    x, y = (float(v) for v in WORKSPACE_CENTER)
    return Workspace((x - 0.25, y - 0.25, TABLE_TOP_Z - 0.02), (x + 0.25, y + 0.25, TABLE_TOP_Z + 0.45), TABLE_TOP_Z)


def outcome_from(record: dict) -> GraspOutcome:
    """The outcome stored in a trial record."""
    stored = dict(record["outcome"])
    stored["touched_faces"] = np.asarray(stored["touched_faces"], dtype=np.int64)
    stored["touched_weights"] = np.asarray(stored.get("touched_weights", []), dtype=np.float64)
    return GraspOutcome(**stored)


def segmentation_record(context: EpisodeContext, method: str, detector: str, labels: np.ndarray, episode: Episode) -> dict:
    """mIoU (area and face count) and per-part IoU of one method's labels against the truth on the planning mesh."""
    n_parts, gt, mesh = len(context.prompts), episode.truth_on_mesh, episode.observation.mesh
    return {
        "object_id": context.object_id, "category": context.category, "method": method,
        "detector": detector, "prompts": context.prompts,
        "miou": shape_miou(labels, gt, n_parts, mesh.area_faces),
        "miou_faces": shape_miou(labels, gt, n_parts),
        "part_ious": [None if np.isnan(v) else float(v) for v in part_ious(labels, gt, n_parts, mesh.area_faces)],
        "unknown_fraction": float((labels < 0).mean()),
    }


def threshold_curve(episode: Episode) -> dict:
    """mIoU of GeoSpreading on the partition at each threshold alone, and of GeoFusion from that threshold up."""
    from seggrasp.vote import labels_from_scores

    segmenter, gt, context = episode.segmenter, episode.truth_on_mesh, episode.context
    episode.coarse_scores()
    partitions = segmenter.partitions()
    areas = segmenter.mesh.area_faces
    n_parts = len(context.prompts)
    spread, full = [], []
    for index, partition in enumerate(partitions):
        spread.append(shape_miou(labels_from_scores(segmenter.refined_scores("spread", [partition])), gt, n_parts, areas))
        full.append(shape_miou(labels_from_scores(segmenter.refined_scores("full", partitions[index:])), gt, n_parts, areas))
    return {
        "object_id": context.object_id, "category": context.category, "detector": episode.detector.label,
        "thresholds": [float(p.threshold) for p in partitions], "spread": spread, "full": full,
    }


def _worker_init() -> None:
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # torch only matters for the real detectors
        pass


def evaluate_objects(config: RunConfig, out: Path, workers: int, on_status) -> list[dict]:
    """Evaluate every object of the run (in `workers` processes); `on_status` sees each object's status. Returns
    the crashes."""
    tasks = [ObjectTask(object_id, config, str(out), parallel=workers > 1) for object_id in config.objects]
    crashes = []
    if workers == 1:
        _worker_init()
        for status in map(evaluate_object, tasks):
            crashes += on_status(status)
        close_cell()
        return crashes
    # not multiprocessing.Pool: its daemonic workers may not start the CoACD processes of a decomposition
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(workers, mp_context=context, initializer=_worker_init) as pool:
        for status in as_completed([pool.submit(evaluate_object, task) for task in tasks]):
            crashes += on_status(status.result())
    return crashes


def record_extra(record: TrialRecord, config: RunConfig) -> None:
    """What the harness adds to every trial record: the embodiment, backend and whether the mesh was perceived."""
    record.extra = {"embodiment": config.embodiment, "backend": config.backend, "perceive": config.perceive}
