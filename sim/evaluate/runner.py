"""The runner: for each object, the harness picks the cell, the detector and the ground truth, hands them to one
`seggrasp.episode.Episode`, and appends what it returns to the result files."""

from __future__ import annotations

import ctypes
import logging
import multiprocessing
import os
import signal
import sys
import threading
import time
import traceback
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

from seggrasp.cell import Cell, GraspOutcome
from seggrasp.episode import Episode, EpisodeContext, EpisodeSettings, Slot, TrialRecord, grasp_key
from seggrasp.grasp.antipodal import AntipodalConfig, AntipodalSampler
from seggrasp.method import PartPlan
from seggrasp.objects import ObjectModel
from seggrasp.target import object_name
from seggrasp.metrics import part_ious, shape_miou
from seggrasp.truth import DetectorSpec, GroundTruth
from sim.evaluate.config import DEFAULT_OBJECTS_PER_SCENE, RunConfig, prompts_of, scene_seed_of
from sim.evaluate.emulated import real_cell, twin_objects
from sim.evaluate.records import (
    RESULT_FILES,
    STORAGE_ERRORS,
    JsonLines,
    VoteCache,
    curve_key,
    error_message,
    read_unique,
    robot_of,
    seed_of,
    segmentation_key,
    trial_key,
)
from sim.evaluate.strips import caption_strip, film, strip_path

if TYPE_CHECKING:
    from sim.evaluate.twin import TwinObject

LOG = logging.getLogger("sim.evaluate")
#: Runs of a task whose worker process died (the local engine's pool broke) before it is reported as a crash.
MAX_ATTEMPTS = 3


class RunStopped(Exception):
    """The run was stopped from outside (a signal): the records written so far are kept."""

    def __init__(self, message: str, exit_code: int) -> None:
        super().__init__(message)
        self.exit_code = exit_code


@dataclass
class Recorded:
    """What the output folder already holds for one (object, seed): its trials, the methods whose segmentation is
    recorded, and whether its threshold curve is."""

    trials: list[dict] = field(default_factory=list)
    segmented: set[tuple[str, str]] = field(default_factory=set)  # (robot, method)
    curves: set[str] = field(default_factory=set)  # robots

    def of_robot(self, robot: str) -> "Recorded":
        """What is recorded of one robot system: its trials, segmented methods and curve."""
        return Recorded([r for r in self.trials if robot_of(r) == robot],
                        {(b, m) for b, m in self.segmented if b == robot}, self.curves & {robot})


@dataclass
class ObjectTask:
    """One (object, seed) of a run: every method, prompt and slot of the object in the scene of that seed."""

    object_id: str
    seed: int
    config: RunConfig
    out: str
    recorded: Recorded | None = None  # None: read from `out`
    parallel: bool = False  # other tasks run at the same time: one CoACD process per task
    collect: bool = False  # return the new records instead of appending them to `out` (the driver writes them)
    twin: TwinObject | None = None  # the object's data shipped by the driver (else read from the installed twin)


class Sink:
    """Where `run_object` puts new records: appended to `out`'s files one by one, or (`collect`) kept in
    `collected` ({file name: records}) for a driver to write."""

    def __init__(self, out: Path, collect: bool = False) -> None:
        self.out, self.collect = Path(out), collect
        self.collected: dict[str, list[dict]] = {}

    def add(self, name: str, record: dict) -> None:
        if self.collect:
            self.collected.setdefault(name, []).append(record)
        else:
            JsonLines(self.out / name).append(record)


def recorded_index(out: Path) -> Callable[[str, int], Recorded]:
    """Read `out`'s result files once; returns what they hold for a given (object, seed)."""
    index: dict[tuple, Recorded] = {}

    def entry(record: dict) -> Recorded:
        return index.setdefault((record["object_id"], seed_of(record)), Recorded())

    for record in read_unique(out / "trials.jsonl", trial_key):
        entry(record).trials.append(record)
    for record in read_unique(out / "segmentations.jsonl", segmentation_key):
        entry(record).segmented.add((robot_of(record), record["method"]))
    for record in read_unique(out / "curves.jsonl", curve_key):
        entry(record).curves.add(robot_of(record))
    return lambda object_id, seed: index.get((object_id, int(seed)), Recorded())


_CELLS: dict[str, Cell] = {}  # this worker process's cells, one per robot system (the real cell: one)
_CELL_OBJECTS: dict[str, ObjectModel] = {}  # the twin objects its twin cells hold (those its tasks brought)


def _get_cell(config: RunConfig, model: ObjectModel | None = None) -> Cell:
    """This process's cell of `config`'s one robot: the real one, or a twin cell holding `model` (the twin cells
    are rebuilt with it added, once per object)."""
    if config.backend == "real":
        if "real" not in _CELLS:
            _CELLS["real"] = real_cell(config)  # hardware.RealCell, or the emulated cell wrapping it
        return _CELLS["real"]
    if model.object_id not in _CELL_OBJECTS:
        objects = dict(_CELL_OBJECTS, **{model.object_id: model})
        if config.scene is not None:  # the distractors: the installed twin's other objects
            from seggrasp.objects import load_asset_set

            objects = {o.object_id: o for o in load_asset_set()} | objects
        close_cell()
        _CELL_OBJECTS.update(objects)
    if config.robot not in _CELLS:
        from sim.cell import SimCell
        from sim.gripper import GripperSettings

        _CELLS[config.robot] = SimCell(
            objects=list(_CELL_OBJECTS.values()), embodiment=config.embodiment, seed=config.seed, robot=config.robot,
            gripper=GripperSettings(grip_force=config.hand_grip_force, hand=config.hand), scene=config.scene,
            objects_per_scene=config.objects_per_scene or DEFAULT_OBJECTS_PER_SCENE)
    return _CELLS[config.robot]


def close_cell() -> None:
    """Close this process's cells (those opened)."""
    for cell in _CELLS.values():
        cell.close()
    _CELLS.clear()
    _CELL_OBJECTS.clear()


def evaluate_object(task: ObjectTask) -> dict:
    """All methods, prompts and trials of one object; returns a status dict (never raises)."""
    started = time.time()
    sink = Sink(Path(task.out), collect=task.collect)
    head = {"object_id": task.object_id, "seed": task.seed}
    try:
        seeded = task.config.at_seed(task.seed)
        model, decomposition_cache = _object_of(task, seeded)
        n_new = 0
        for robot in seeded.robots:
            config = seeded.at_robot(robot)
            cell = _get_cell(config, model)
            context, truth = subject_of(task.object_id, config, cell, model)
            n_new += run_object(cell, context, truth, config, Path(task.out), parallel=task.parallel,
                                recorded=task.recorded, sink=sink, decomposition_cache=decomposition_cache)
        status = dict(head, ok=True, new_trials=n_new, seconds=time.time() - started)
    except OSError as exc:
        status = dict(head, ok=False, error=error_message(exc), traceback=traceback.format_exc(),
                      seconds=time.time() - started, fatal=exc.errno in STORAGE_ERRORS)
    except Exception as exc:  # a crash of one object must not lose the others' results
        status = dict(head, ok=False, error=f"{type(exc).__name__}: {exc}", traceback=traceback.format_exc(),
                      seconds=time.time() - started)
    if task.collect:  # records of a crashed task are complete lines too: keep them
        status["records"] = sink.collected
    return status


def _object_of(task: ObjectTask, config: RunConfig) -> tuple[ObjectModel | None, Path | None]:
    """The task's twin object and the decomposition cache folder its data came with (None: the user's cache and the
    bundled one): unpacked from the shipped data, or read from the installed twin; (None, None) on the real cell."""
    if not twin_objects(config):
        return None, None
    if task.twin is not None:
        from sim.evaluate.twin import unpack

        return unpack(task.twin)
    from seggrasp.objects import load_asset

    return load_asset(task.object_id), None


def subject_of(object_id: str, config: RunConfig, cell: Cell,
               model: ObjectModel | None = None) -> tuple[EpisodeContext, GroundTruth | None]:
    """What the harness knows about an object: its context and, for a twin object (`model`, default: read from
    the installed twin), its ground truth."""
    scene_seed = scene_seed_of(object_id, config.seed)
    if not twin_objects(config):
        # the detector finds it among others by the name the run gives it ("--objects coffee_mug": "coffee mug")
        return EpisodeContext(object_id, "real", list(config.prompts), scene_seed, name=object_name(object_id)), None
    from seggrasp.objects import load_asset

    model = model or load_asset(object_id)
    context = EpisodeContext.from_object(model, scene_seed, prompts=config.prompts or None)
    true_pose = cell.true_pose if config.backend == "real" else lambda: cell.object_mesh()[1]  # emulated: placed
    scene = cell.scene_truth if config.scene is not None else None
    return context, GroundTruth.of_object(model, context.prompts, true_pose=true_pose, scene=scene)


def run_object(
    cell: Cell,
    context: EpisodeContext,
    truth: GroundTruth | None,
    config: RunConfig,
    out: Path,
    detector: DetectorSpec | None = None,
    parallel: bool = False,
    recorded: Recorded | None = None,
    sink: Sink | None = None,
    decomposition_cache: Path | None = None,
) -> int:
    """Run every method's episode slots of one object (at `config`'s one seed, on its one robot) that `recorded`
    (default: what `out` holds) lacks, handing new records to `sink` (default: appended to `out`); returns how many
    trials were added.
    `decomposition_cache`: the writable decomposition cache (default the user's; the bundled one is searched too)."""
    recorded = recorded if recorded is not None else recorded_index(out)(context.object_id, config.seed)
    recorded = recorded.of_robot(config.robot)
    sink = sink or Sink(out)
    settings = EpisodeSettings(
        seed=config.seed, top_k=config.top_k, perceive=config.perceive,
        workspace=workspace_of(cell) if config.perceive else None, among_others=config.scene is not None,
        decomposition_workers=1 if parallel else None,
        decomposition_seed=config.decomposition_seed,
        decomposition_cache=str(decomposition_cache) if decomposition_cache is not None else None,
    )
    episode = Episode(
        cell, context, detector or config.object_detector(context.object_id), truth, settings,
        generator=AntipodalSampler(AntipodalConfig.for_hand(cell.hand, grip_force=config.hand_grip_force), cell.hand),
        vote_cache=VoteCache(out / "cache" / context.object_id),
        outcome_cache=_reusable_outcomes(recorded.trials, config),
    )
    if config.record and not hasattr(cell, "record_next"):
        raise ValueError(f"--record needs a cell that records picture strips; {type(cell).__name__} does not")
    hooks = _Hooks(episode, config, out, sink, {trial_key(r) for r in recorded.trials})
    for method in config.methods:
        segment = (config.robot, method) not in recorded.segmented and episode.truth_on_mesh is not None
        hooks.filmed = 0
        episode.run(method, skip=hooks.skip, before=hooks.before, on_record=hooks.on_record,
                    on_plan=hooks.on_plan if segment else None)
    if not recorded.curves and episode.truth_on_mesh is not None and any(m != "oracle" for m in config.methods):
        sink.add("curves.jsonl", dict(threshold_curve(episode), seed=config.seed, robot=config.robot))
    return hooks.n_new


class _Hooks:
    """The benchmark's hooks into `Episode.run` for one object: the segmentation record of each plan, the slots
    `out` holds skipped, the first `config.record` slots with a grasp per method filmed, each record to the sink."""

    def __init__(self, episode: Episode, config: RunConfig, out: Path, sink: Sink, done: set[tuple]) -> None:
        self.episode, self.config, self.out, self.sink, self.done = episode, config, out, sink, done
        self.filmed = self.n_new = 0
        self.slot: Slot | None = None
        self.strip: Path | None = None

    def on_plan(self, plan: PartPlan) -> None:
        seg = segmentation_record(self.episode.context, plan.method, plan.detector, plan.labels, self.episode)
        self.sink.add("segmentations.jsonl", dict(seg, seed=self.config.seed, robot=self.config.robot))

    def _key(self, slot: Slot) -> tuple:
        context = self.episode.context
        return (context.object_id, self.config.seed, self.config.robot, slot.method, context.prompts[slot.prompt_index],
                slot.rank)

    def skip(self, slot: Slot) -> bool:
        return self._key(slot) in self.done

    def before(self, slot: Slot) -> None:
        self.slot, self.strip = slot, None
        if self.filmed < self.config.record and slot.grasp is not None:
            _, _, _, method, prompt, rank = self._key(slot)
            self.strip = strip_path(self.out, method, self.episode.context.object_id, prompt, rank, self.config.seed,
                                    self.config.robot)
            self.filmed += 1
            if self.episode.moves_cell(slot):
                self.episode.cell.record_next(self.strip)

    def on_record(self, record: TrialRecord) -> None:
        record_extra(record, self.config, self.episode.cell)
        if self.strip is not None:
            if record.reused_outcome:  # the cell did not move for it: film the same grasp in the same scene
                film(self.episode.cell, self.episode.context, self.slot, self.strip)
            caption_strip(self.strip, record)
        self.sink.add("trials.jsonl", dict(record.to_json(), robot=self.config.robot))
        self.n_new += 1


def _reusable_outcomes(existing: list[dict], config: RunConfig) -> dict | None:
    """A deterministic simulator gives the same outcome for the same grasp in the same scene: reuse recorded ones."""
    if config.backend != "sim":
        return None
    outcomes = {}
    for record in existing:
        if record["executed"] and not record.get("reused_outcome"):
            outcomes[grasp_key(np.array(record["T_world_grasp"]), record["width"])] = outcome_from(record)
    return outcomes


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
    stored["disturbance"] = tuple(stored.get("disturbance", ()))
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


def worker_init(uses_torch: bool = False) -> None:
    """Set up a worker process: one torch thread when the run's detector is a torch model (importing torch costs
    a second or more per process, so a run of simulated detectors leaves it alone)."""
    if not uses_torch:
        return
    try:
        import torch

        torch.set_num_threads(1)
    except ImportError:  # a real detector then reports the missing torch itself
        pass


def pool_worker_init(uses_torch: bool, driver: int) -> None:
    """Set up a local pool's worker: it ends with its `driver` process (`die_with_parent`) and leaves a Ctrl-C to
    the driver, which ends the pool (`_run_pool`); then `worker_init`."""
    die_with_parent(driver)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    worker_init(uses_torch)


def die_with_parent(parent: int) -> None:
    """On Linux, have the kernel end this process when its parent dies (prctl PR_SET_PDEATHSIG), and end it now if
    `parent` died already (while this process started): a run killed outright (SIGKILL, the OOM killer) leaves no
    worker writing records into its --out behind it."""
    if sys.platform.startswith("linux") and ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM) != 0:
        LOG.warning("a worker cannot follow its parent's death (prctl: errno %d)", ctypes.get_errno())
    if os.getppid() != parent:
        os._exit(1)


def is_complete(recorded: Recorded, object_id: str, config: RunConfig) -> bool:
    """Whether `out` already holds every trial of the object's (one seed) run on every robot and, on the twin,
    every method's segmentation and the threshold curve of each robot: then its task has nothing to add."""
    if not recorded.trials:  # a fresh (object, seed): nothing to compare, no asset to load
        return False
    prompts = prompts_of(config, object_id)
    have = {(robot_of(r), r["method"], r["prompt"], int(r["rank"])) for r in recorded.trials}
    if any((b, m, p, k) not in have for b in config.robots for m in config.methods for p in prompts
           for k in range(config.top_k)):
        return False
    if not twin_objects(config):
        return True
    return all({(b, m) for m in config.methods} <= recorded.segmented
               and (b in recorded.curves or set(config.methods) <= {"oracle"}) for b in config.robots)


def make_tasks(config: RunConfig, out: Path, parallel: bool, collect: bool = False) -> tuple[list[ObjectTask], list]:
    """One task per (object, seed), seed by seed (a run stopped early holds whole seeds), with what `out` already
    holds for it; returns (tasks to run, the statuses of the (object, seed) pairs `out` holds completely)."""
    recorded = recorded_index(out)
    tasks, complete = [], []
    for seed in config.seeds:
        for object_id in config.objects:
            held = recorded(object_id, seed)
            if is_complete(held, object_id, config.at_seed(seed)):
                complete.append({"object_id": object_id, "seed": seed, "ok": True, "new_trials": 0, "seconds": 0.0})
            else:
                tasks.append(ObjectTask(object_id, seed, config, str(out), held, parallel, collect))
    return tasks, complete


def evaluate_objects(config: RunConfig, out: Path, workers: int, on_status) -> list[dict]:
    """Evaluate every (object, seed) of the run that `out` does not hold completely, in `workers` local processes;
    `on_status` sees each pair's status and returns it as a crash (a one-item list) or not. Returns the crashes.
    A worker process that dies (killed, out of memory) breaks the pool: the tasks it left unfinished run again from
    what `out` holds (their finished trials are kept), each at most `MAX_ATTEMPTS` times, then count as crashed."""
    tasks, complete = make_tasks(config, out, parallel=workers > 1)
    for status in complete:
        on_status(status)
    crashes = []
    if workers == 1:
        worker_init(config.uses_torch)
        try:
            for status in map(evaluate_object, tasks):
                crashes += on_status(status)
        finally:
            close_cell()
        return crashes
    attempts: dict[tuple, int] = {}

    def collect(status: dict) -> None:
        crashes.extend(on_status(status))

    while tasks:
        unfinished = _run_pool(tasks, workers, config.uses_torch, collect)
        if not unfinished:
            break
        for task in unfinished:
            attempts[task.object_id, task.seed] = attempts.get((task.object_id, task.seed), 0) + 1
        for name in RESULT_FILES:  # the dead worker may have been cut mid-line
            JsonLines(out / name).repair()
        given_up = [t for t in unfinished if attempts[t.object_id, t.seed] >= MAX_ATTEMPTS]
        for task in given_up:
            crashes += on_status({"object_id": task.object_id, "seed": task.seed, "ok": False, "seconds": 0.0,
                                  "error": f"its worker process died {MAX_ATTEMPTS} times", "traceback": ""})
        retry = {(t.object_id, t.seed) for t in unfinished} - {(t.object_id, t.seed) for t in given_up}
        LOG.warning("a worker process died; %d unfinished task(s) run again from what %s holds", len(retry), out)
        recorded = recorded_index(out)
        tasks = [ObjectTask(o, s, config, str(out), recorded(o, s), parallel=True) for o, s in sorted(retry)]
    return crashes


def _run_pool(tasks: list[ObjectTask], workers: int, uses_torch: bool, on_status) -> list[ObjectTask]:
    """Run `tasks` in a pool of `workers` processes, handing each status to `on_status`; returns the tasks left
    unfinished because a worker process died."""
    # not multiprocessing.Pool: its daemonic workers may not start the CoACD processes of a decomposition
    context = multiprocessing.get_context("spawn")
    unfinished = []
    with _stopped_by_signals(), ProcessPoolExecutor(
        min(workers, len(tasks)), mp_context=context, initializer=pool_worker_init, initargs=(uses_torch, os.getpid())
    ) as pool:
        futures = {pool.submit(evaluate_object, task): task for task in tasks}
        try:
            for future in as_completed(futures):
                try:
                    status = future.result()
                except BrokenProcessPool:
                    unfinished.append(futures[future])
                    continue
                on_status(status)
        except BaseException:  # stop now: the other tasks' finished trials are in `out` already
            for process in list((getattr(pool, "_processes", None) or {}).values()):  # no public way before 3.14
                process.terminate()
            pool.shutdown(wait=False, cancel_futures=True)
            raise
    return unfinished


@contextmanager
def _stopped_by_signals():
    """While active (on the main thread), SIGTERM raises `RunStopped`, so that the pool's workers are ended with
    the run (`_run_pool`) instead of running on, orphaned, after its default death; SIGINT raises
    KeyboardInterrupt as always."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum: int, frame) -> None:
        raise RunStopped(f"stopped by {signal.Signals(signum).name}", 128 + signum)

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def record_extra(record: TrialRecord, config: RunConfig, cell: Cell) -> None:
    """What the harness adds to every trial record: the embodiment, backend, whether the mesh was perceived and the
    hand (the robot system is the record's own `robot` field); in a scene run, the scene (`sim.scenes.ScenePlan`)."""
    record.extra = {"embodiment": config.embodiment, "backend": config.backend, "perceive": config.perceive,
                    "decomposition_seed": config.decomposition_seed, "hand": config.hand.name}
    if config.scene is not None:  # a real cell's operator laid out the table: only its kind is known
        record.extra["scene"] = cell.scene_plan.to_record() if twin_objects(config) else {"kind": config.scene}
