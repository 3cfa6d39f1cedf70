"""The decomposition sweep: which thresholds to run, the cache, the working mesh, and the runs themselves."""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from seggrasp.decompose import workers as runner
from seggrasp.decompose.cache import default_cache_dir, load_cached, save_cached
from seggrasp.decompose.config import (
    ASSET_CACHE_DIR,
    FAST_ANCHORS,
    MAX_COACD_FACES,
    SCAN_FINER,
    SCAN_FIRST_ROUND,
    SCAN_SIMPLIFY_PASSES,
    DecompositionConfig,
)
from seggrasp.decompose.mapping import Partition, dedupe_partitions
from seggrasp.decompose.remesh import closed_shell
from seggrasp.mesh import mesh_hash

logger = logging.getLogger(__name__)


class SweepTimeout(RuntimeError):
    """Every CoACD run of a sweep exceeded its time budget."""


@dataclass
class SweepStats:
    """What a sweep did: seconds per CoACD run (cache misses only), the thresholds served from cache, those
    evaluated, and those whose run exceeded the time budget."""

    run_seconds: dict[float, float] = dataclasses.field(default_factory=dict)
    cached: list[float] = dataclasses.field(default_factory=list)
    evaluated: list[float] = dataclasses.field(default_factory=list)
    timed_out: list[float] = dataclasses.field(default_factory=list)


def _nearest(grid: Sequence[float], value: float) -> int:
    return int(np.argmin([abs(t - value) for t in grid]))


def select_thresholds(
    grid: Sequence[float],
    evaluate: Callable[[list[float]], dict[float, np.ndarray]],
    anchors: Sequence[float] = FAST_ANCHORS,
    max_runs: int | None = None,
) -> dict[float, np.ndarray]:
    """Find every distinct partition of `grid` while running few thresholds.

    `evaluate(thresholds)` returns {threshold: canonical part_of_face} for a batch (run in parallel by the caller);
    a threshold missing from its answer failed (time budget) and is not tried again. First the grid ends and the
    grid values nearest to `anchors` are evaluated; then, in rounds, the grid value nearest the midpoint of every
    interval between consecutive evaluated thresholds whose partitions differ. An interval whose two ends agree is
    assumed constant. With `max_runs`, the widest differing intervals are split first and the search stops after
    that many evaluations. Returns the evaluated {threshold: partition}.
    """
    grid = sorted(float(t) for t in grid)
    chosen = {0, len(grid) - 1} | {_nearest(grid, anchor) for anchor in anchors}
    results: dict[int, np.ndarray] = {}
    tried: set[int] = set()
    budget = len(grid) if max_runs is None else max(int(max_runs), 2)
    batch = sorted(chosen)
    if len(batch) > budget:  # keep the two ends and the anchors nearest the fine end
        batch = sorted([0, len(grid) - 1] + [i for i in batch if i not in (0, len(grid) - 1)][: budget - 2])
    while batch:
        found = evaluate([grid[i] for i in batch])
        tried.update(batch)
        results.update({i: found[grid[i]] for i in batch if grid[i] in found})
        done = sorted(results)
        splits = sorted((low - high, low, high) for low, high in zip(done, done[1:])
                        if high - low > 1 and not np.array_equal(results[low], results[high]))
        batch = []
        for _, low, high in splits:
            untried = [i for i in range(low + 1, high) if i not in tried]
            if untried and len(tried) + len(batch) < budget:
                batch.append(min(untried, key=lambda i: (abs(i - (low + high) / 2), i)))
        batch.sort()
    return {grid[i]: parts for i, parts in results.items()}


def select_scan_thresholds(
    grid: Sequence[float],
    evaluate: Callable[[list[float]], dict[float, np.ndarray]],
    max_parts: int,
    first: Sequence[float] = SCAN_FIRST_ROUND,
    finer: Sequence[float] = SCAN_FINER,
    max_runs: int | None = None,
) -> dict[float, np.ndarray]:
    """The thresholds of a scan, coarse to fine (`evaluate` as in `select_thresholds`).

    The grid values nearest `first` and the coarsest run as one batch; then the values nearest `finer` below them,
    and the finest grid value, from coarse to fine while the finest partition so far has fewer than `max_parts` parts
    (a run's time grows with its part count) and fewer than `max_runs` thresholds were tried. Each further step is
    expected to double the part count (measured: 1.4-2x per step), so the steps whose expected count stays below
    `max_parts` run together as one batch. Returns the evaluated {threshold: partition}.
    """
    grid = sorted(float(t) for t in grid)
    batch = sorted({len(grid) - 1} | {_nearest(grid, t) for t in first})
    steps = sorted(({0} | {_nearest(grid, t) for t in finer}) - set(batch), reverse=True)
    steps = [i for i in steps if i < batch[0]]
    budget = len(grid) if max_runs is None else max(int(max_runs), 1)
    results = evaluate([grid[i] for i in batch[-budget:]])
    tried = min(len(batch), budget)
    while steps and tried < budget:
        parts = results[min(results)].max() + 1 if results else 1
        if parts >= max_parts:
            logger.info("decomposition: %d parts at threshold %.2f (cap %d): no finer threshold is run",
                        parts, min(results), max_parts)
            break
        count = 1
        while count < min(len(steps), budget - tried) and parts * 2 ** count < max_parts:
            count += 1
        results.update(evaluate([grid[i] for i in steps[:count]]))
        steps, tried = steps[count:], tried + count
    return results


class _Sweep:
    """The state of one `decompose_sweep` call: cache folders, the mesh's digest and face centroids, and the
    working mesh CoACD sees (made on the first cache miss)."""

    def __init__(self, mesh: trimesh.Trimesh, config: DecompositionConfig, writable: Path, bundled: bool,
                 workers: int, stats: SweepStats) -> None:
        self.mesh, self.config, self.workers, self.stats = mesh, config, workers, stats
        self.writable = writable
        self.search = [writable] + ([ASSET_CACHE_DIR] if bundled and ASSET_CACHE_DIR != writable else [])
        self.digest = mesh_hash(mesh)
        self.n_faces = len(mesh.faces)
        self.centroids = np.asarray(mesh.triangles_center, dtype=np.float64)
        self.scale = float(np.linalg.norm(mesh.extents))
        self.face_limit = MAX_COACD_FACES if self.n_faces > MAX_COACD_FACES else None
        self.working: tuple[np.ndarray, np.ndarray, bool] | None = None
        # A scan: over the face limit, or (checked only when it is small, where it is cheap) not a closed manifold.
        # The reference mode decomposes every mesh literally.
        self.scan = config.mode == "fast" and (self.face_limit is not None or not runner.is_closed_manifold(
            np.asarray(mesh.vertices), np.asarray(mesh.faces)))
        self.max_parts = config.effective_scan_max_parts if self.scan else None
        self.params = config.coacd_params(self.scan)

    def evaluate(self, thresholds: list[float]) -> dict[float, np.ndarray]:
        """{threshold: part_of_face} from the cache or from CoACD; thresholds whose run timed out are left out."""
        found: dict[float, np.ndarray] = {}
        missing = []
        for threshold in thresholds:
            parts = load_cached(self._key(threshold), self.n_faces, self.writable, self.search)
            if parts is None:
                missing.append(threshold)
            else:
                found[threshold] = parts
                self.stats.cached.append(threshold)
        for outcome in self._run(missing) if missing else []:
            if outcome.status == "timeout":
                self.stats.timed_out.append(outcome.threshold)
                continue
            found[outcome.threshold] = outcome.part_of_face
            self.stats.run_seconds[outcome.threshold] = outcome.seconds
            save_cached(self.writable, self._key(outcome.threshold), outcome.part_of_face,
                        outcome.threshold)
        self.stats.evaluated.extend(thresholds)
        return found

    def _key(self, threshold: float) -> str:
        return self.config.run_key(self.digest, threshold, self.face_limit, self.scan)

    def _working_mesh(self) -> tuple[np.ndarray, np.ndarray, bool]:
        """CoACD's input: the simplified mesh (coarser when over MAX_COACD_FACES), decimated to MAX_COACD_FACES when
        still larger; a scan that is not a closed manifold is first replaced by a closed shell around it
        (`seggrasp.decompose.remesh`). Also whether manifold3d verified it as a closed manifold (then CoACD skips its
        preprocessing)."""
        if self.working is None:
            started = time.perf_counter()
            tolerance = self.config.effective_simplify_tolerance
            passes = SCAN_SIMPLIFY_PASSES if self.scan else 1
            vertices, faces, closed = runner.simplify(self.mesh, tolerance, MAX_COACD_FACES, passes)
            if self.scan and not closed and (tolerance > 0 or not runner.is_closed_manifold(self.mesh.vertices,
                                                                                              self.mesh.faces)):
                shell = trimesh.Trimesh(*closed_shell(self.mesh.vertices, self.mesh.faces), process=False)
                vertices, faces, closed = runner.simplify(shell, tolerance, MAX_COACD_FACES, passes)
            if len(faces) > MAX_COACD_FACES:
                vertices, faces, closed = runner.limit_faces(vertices, faces, MAX_COACD_FACES)
            self.working = (vertices, faces, closed)
            logger.info("decomposition: %d-face working mesh from %d faces in %.1f s", len(faces), self.n_faces,
                        time.perf_counter() - started)
        return self.working

    def _run(self, thresholds: list[float]) -> list[runner.RunOutcome]:
        """CoACD at `thresholds` in child processes; crashed runs are retried once on the full mesh."""
        vertices, faces, closed = self._working_mesh()
        logger.info("decomposition: CoACD at thresholds %s on a %d-face working mesh (%d at a time)",
                    ", ".join(f"{t:.2f}" for t in thresholds), len(faces), self.workers)
        outcomes = self._jobs(vertices, faces, closed, thresholds)
        crashed = [o.threshold for o in outcomes if o.status == "crashed"]
        full = self.mesh.vertices, self.mesh.faces
        if crashed and len(faces) != self.n_faces and self.n_faces <= MAX_COACD_FACES:
            logger.warning("CoACD crashed on the simplified mesh at thresholds %s; retrying on the full mesh", crashed)
            outcomes = [o for o in outcomes if o.status != "crashed"] + self._jobs(*full, False, crashed)
        failed = sorted(o.threshold for o in outcomes if o.status == "crashed")
        if failed:
            raise RuntimeError(f"CoACD crashed (its process died) at thresholds {failed} on this mesh")
        return outcomes

    def _jobs(self, vertices, faces, closed: bool, thresholds: list[float]) -> list[runner.RunOutcome]:
        params = runner.params_for(self.params, closed)
        vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
        jobs = [runner.Job(vertices, faces, self.centroids, self.scale, t, params, self.config.log_level)
                for t in thresholds]
        return runner.run_jobs(jobs, self.workers, timeout=self.config.effective_run_timeout)


def decompose_sweep(
    mesh: trimesh.Trimesh,
    config: DecompositionConfig | None = None,
    cache_dir: str | os.PathLike | None = None,
    workers: int | None = None,
    stats: SweepStats | None = None,
    bundled: bool = True,
) -> list[Partition]:
    """Distinct CoACD partitions of `mesh`'s faces over the configured thresholds, finest (lowest) first.

    Cached on disk (`seggrasp.decompose.cache`). `workers` = parallel CoACD processes (default: 1 in reference
    mode, else the CPU count). Pass a `SweepStats` to learn the per-threshold times. `bundled=False` ignores the
    precomputed caches in assets/decompositions/ (for cold-run benchmarks). A run exceeding the configured time
    budget is dropped with a warning; SweepTimeout if every run did.
    """
    config = config or DecompositionConfig()
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError("decompose_sweep needs a non-empty trimesh.Trimesh")
    if workers is None:
        workers = 1 if config.mode == "reference" else max(1, os.cpu_count() or 1)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    stats = stats if stats is not None else SweepStats()
    writable = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    sweep = _Sweep(mesh, config, writable, bundled, workers, stats)
    started = time.perf_counter()
    if config.effective_adaptive and sweep.max_parts is not None:
        evaluated = select_scan_thresholds(config.thresholds, sweep.evaluate, sweep.max_parts,
                                           max_runs=config.effective_max_runs)
    elif config.effective_adaptive:
        evaluated = select_thresholds(config.thresholds, sweep.evaluate, max_runs=config.effective_max_runs)
    else:
        evaluated = sweep.evaluate(list(config.thresholds))
    if not evaluated:
        raise SweepTimeout(
            f"every CoACD run exceeded its time budget of {config.effective_run_timeout:.0f} CPU s (thresholds "
            f"{sorted(stats.timed_out)}); give a larger budget (--coacd-timeout) or skip refinement (--refine none)")
    partitions = dedupe_partitions([Partition(t, parts) for t, parts in evaluated.items()])
    logger.info("decomposition sweep: %d distinct partitions from %d runs (%d cached, %d over budget) in %.1f s",
                len(partitions), len(evaluated), len(stats.cached), len(stats.timed_out),
                time.perf_counter() - started)
    return partitions


def sweep_cache_keys(mesh: trimesh.Trimesh, config: DecompositionConfig | None = None) -> list[str]:
    """The cache keys (`<key>.npz` entries) that `decompose_sweep(mesh, config)` may read: one per configured
    threshold (an adaptive sweep reads a subset). For shipping a mesh's cached runs to a machine without them."""
    config = config or DecompositionConfig()
    sweep = _Sweep(mesh, config, default_cache_dir(), False, 1, SweepStats())
    return [sweep._key(t) for t in config.thresholds]
