"""CoACD decomposition sweep: convex parts at several concavity thresholds, mapped back to the mesh's own faces.

The refinement of SegGrasp (paper section III-B) needs, for a sweep of CoACD concavity thresholds, a partition of
the ORIGINAL mesh faces into convex parts. `decompose_sweep` returns the distinct partitions, finest first.

Face -> hull mapping. CoACD returns convex hulls, not face sets. Each hull is turned into its facet planes
(n . x <= d inside) and every face centroid is tested against all planes of every hull at once (a vectorised
half-space test, no per-face distance queries). The signed value `max_j (n_j . c - d_j)` is <= 0 inside a hull and
otherwise a lower bound of the distance to it. A face takes the hull that contains its centroid (within a small
tolerance, so faces on hull boundaries count as inside); when several hulls contain it (CoACD hulls may overlap) the
smallest hull wins, so thin parts (a handle) keep the faces they overlap a big part with; when none contains it
(small faces off a decimated surface) it takes the nearest hull. Every face therefore gets a part. Part ids are
renumbered in order of first appearance so that equal partitions compare equal.

Modes (`DecompositionConfig.mode`):
- "reference": the paper's sweep, literally: thresholds 0.01..0.25 step 0.01, CoACD defaults, one run after the
  other, on the full-resolution mesh.
- "fast" (default): the paper's grid without 0.01 (by far the slowest run; see FAST_THRESHOLDS), and (1) the mesh
  is simplified (manifold3d, within 0.2 % of its diagonal) before CoACD and the hulls are mapped back to the
  full-resolution faces, (2) coarser CoACD search settings and no CoACD preprocessing (remeshing) of the verified
  closed manifold that the simplification returns, and (3) only the thresholds needed to find every distinct
  partition of the grid are run: the two ends and a few anchors first, then bisection inside every interval whose end
  partitions differ; an interval whose ends give the same partition is taken to be constant (CoACD's partition
  coarsens monotonically with the threshold in practice), at most FAST_MAX_RUNS runs, (4) runs of one round go to
  parallel worker processes. Measured (bench/bench_seg.py --meshes big,hammer_claw,knife_chef,mug_classic
  --compare reference --seeds 20): 25.5x faster in total (15.9 s vs 403.5 s), full-GeoFusion mIoU 0.493 vs 0.491
  over detector seeds 0-19; the 30k-face knife cold in 2.4 s.

Caching. Every CoACD run is cached on disk under a key hashing the mesh geometry (`seggrasp.mesh.mesh_hash`), the
threshold, every CoACD parameter, the decimation target and the mapping version; the file holds the compact
face -> part array. The writable cache lives in `$SEGGRASP_CACHE` or `~/.cache/seggrasp` (`decompositions/`);
`assets/decompositions/` holds precomputed runs for the twin and is searched read-only
(`python -m seggrasp.decompose --precompute-assets` regenerates it).
"""

from __future__ import annotations

import argparse
import concurrent.futures
import dataclasses
import faulthandler
import hashlib
import json
import logging
import multiprocessing
import multiprocessing.connection
import os
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull, QhullError

from seggrasp.io import atomic_save_npz
from seggrasp.mesh import mesh_hash

logger = logging.getLogger(__name__)

MODES = ("fast", "reference")
#: The paper's sweep: 0.01..0.25 in steps of 0.01.
PAPER_THRESHOLDS: tuple[float, ...] = tuple(round(0.01 * k, 2) for k in range(1, 26))
#: Log levels CoACD's C++ side accepts; anything else aborts the interpreter inside `coacd.set_log_level`.
COACD_LOG_LEVELS = ("off", "critical", "error", "warn", "warning", "info", "debug")
PREPROCESS_MODES = ("auto", "on", "off")
#: Bump when the face -> hull mapping changes: old cache entries then no longer match.
MAPPING_VERSION = 1
#: A centroid within this fraction of the mesh's bounding-box diagonal outside a hull counts as inside it.
CONTAINMENT_TOLERANCE = 1e-3
ASSET_CACHE_DIR = Path(__file__).resolve().parents[1] / "assets" / "decompositions"

#: CoACD's own defaults (coacd 1.0.x `run_coacd` signature); the reference mode passes exactly these.
COACD_DEFAULTS = dict(
    max_convex_hull=-1,
    preprocess_mode="auto",
    preprocess_resolution=50,
    resolution=2000,
    mcts_nodes=20,
    mcts_iterations=150,
    mcts_max_depth=3,
    pca=False,
    merge=True,
    decimate=False,
    max_ch_vertex=256,
    extrude=False,
    extrude_margin=0.01,
    apx_mode="ch",
    real_metric=False,
)
#: Fast mode: coarser CoACD search (chosen by measurement, see bench/bench_seg.py) and no preprocessing. CoACD's
#: preprocessing remeshes the input on a voxel grid; in "auto" mode it did so on manifold3d's simplified twin knife
#: (a closed manifold), which moved the finest cut off the blade/handle boundary (majority-label mIoU of the finest
#: partition 0.966, i.e. one part straddling both) and took 1.4 s at 0.02; with preprocessing off the same run takes
#: 0.24 s and the partition is exact (1.000), as on the full mesh with CoACD defaults. On the 30k-face knife the
#: finest partition goes from 0.960 to 0.999 and the sweep from 7.2 s to 2.3 s; the hammer's and mug's partitions
#: are unchanged. "off" is only used on meshes manifold3d verified as closed manifolds (`simplify`); any other mesh
#: is decomposed with "auto", since CoACD may abort on non-manifold input. Lighter search settings measured on the mug
#: (detector seeds 0-19): mcts_iterations 30 or mcts_nodes 10 save a quarter of the CPU time but give full mIoU
#: 0.466 / 0.470 instead of 0.472; resolution 300 changes nothing.
FAST_COACD = dict(COACD_DEFAULTS, preprocess_mode="off", resolution=500, mcts_nodes=15, mcts_iterations=60,
                  mcts_max_depth=2)
#: Fast mode's grid: the paper's without 0.01. On the twin's mug 0.01 alone costs 46 s with the fast settings
#: (248 parts) against 9 s at 0.02 (96 parts), and it buys nothing measurable: on stored partitions of a
#: --compare run on an earlier twin (4 meshes x detector seeds 0-19) full GeoFusion gives 0.501 with 0.01 and 0.499
#: without (reference 0.490), and replaying the fast selection on the reference's own partitions 0.4893 with 0.01,
#: 0.5002 without.
FAST_THRESHOLDS: tuple[float, ...] = PAPER_THRESHOLDS[1:]
#: manifold3d simplification tolerance (fraction of the bounding-box diagonal): well below the finest concavity.
#: Coarser tolerances lower the mug's finest-partition majority-label mIoU (0.999 -> 0.991 at 0.004 and 0.008) and its
#: full mIoU (0.472 -> 0.469 / 0.463 over detector seeds 0-19).
FAST_SIMPLIFY_TOLERANCE = 0.002
#: Thresholds the fast mode runs before bisecting (indices into the grid are derived from these values).
FAST_ANCHORS = (0.02, 0.04, 0.08, 0.25)
#: At most this many CoACD runs per sweep in fast mode (bisection stops there; the finest threshold is always run).
#: Full GeoFusion hardly depends on the coarser partitions: replaying the selection on the reference sweep's
#: partitions (4 benchmark meshes x detector seeds 0-19) gave mIoU 0.4907 with 6 runs, 0.4920 with 5, 0.4919 with 4
#: or with only the two grid ends, against 0.4908 for all 25 thresholds. 5 runs instead of 6 save 17 % of the mug's
#: CoACD time (19.7 vs 23.7 CPU s) at the same mug mIoU.
FAST_MAX_RUNS = 5


@dataclass(frozen=True)
class DecompositionConfig:
    """Parameters of a decomposition sweep. Fields left at None take the value of the `mode`.

    `thresholds`: the grid (reference: 0.01..0.25 step 0.01; fast: 0.02..0.25).
    `coacd` overrides individual CoACD keyword arguments (keys as in `coacd.run_coacd`), on top of the mode's.
    `simplify_tolerance` simplifies the mesh before CoACD within that fraction of its diagonal (0 = never). `adaptive` runs only the thresholds needed to find
    every distinct partition of the grid (see the module docstring).
    """

    mode: str = "fast"
    seed: int = 0
    thresholds: tuple[float, ...] | None = None
    coacd: tuple[tuple[str, object], ...] = ()
    simplify_tolerance: float | None = None
    adaptive: bool | None = None
    max_runs: int | None = None
    log_level: str = "error"

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"unknown decomposition mode {self.mode!r}; use one of {MODES}")
        if isinstance(self.coacd, dict):
            object.__setattr__(self, "coacd", tuple(sorted(self.coacd.items())))
        if self.thresholds is None:
            object.__setattr__(self, "thresholds", PAPER_THRESHOLDS if self.mode == "reference" else FAST_THRESHOLDS)
        thresholds = tuple(float(t) for t in self.thresholds)
        if not thresholds or any(not (0.0 < t <= 1.0) for t in thresholds):
            raise ValueError(f"thresholds must be a non-empty list of values in (0, 1], got {self.thresholds}")
        if len(set(thresholds)) != len(thresholds):
            raise ValueError(f"thresholds must be distinct, got {self.thresholds}")
        object.__setattr__(self, "thresholds", tuple(sorted(thresholds)))
        if self.log_level not in COACD_LOG_LEVELS:
            raise ValueError(f"invalid CoACD log level {self.log_level!r}; use one of {COACD_LOG_LEVELS}")
        unknown = set(dict(self.coacd)) - set(COACD_DEFAULTS)
        if unknown:
            raise ValueError(f"unknown CoACD parameters {sorted(unknown)}; known: {sorted(COACD_DEFAULTS)}")
        params = self.coacd_params()
        if params["preprocess_mode"] not in PREPROCESS_MODES:
            raise ValueError(f"preprocess_mode must be one of {PREPROCESS_MODES}, got {params['preprocess_mode']!r}")
        if params["apx_mode"] not in ("ch", "box"):
            raise ValueError(f"apx_mode must be 'ch' or 'box', got {params['apx_mode']!r}")
        for key in ("resolution", "preprocess_resolution", "mcts_nodes", "mcts_iterations", "mcts_max_depth"):
            if int(params[key]) < 1:
                raise ValueError(f"CoACD parameter {key} must be >= 1, got {params[key]}")
        if self.max_runs is not None and self.max_runs < 2:
            raise ValueError(f"max_runs must be at least 2 (the two ends of the grid), got {self.max_runs}")
        if not (0.0 <= self.effective_simplify_tolerance < 0.1):
            raise ValueError(f"simplify_tolerance must be in [0, 0.1), got {self.simplify_tolerance}")

    def coacd_params(self) -> dict:
        """Keyword arguments for `coacd.run_coacd` except `threshold` (and with the seed)."""
        params = dict(COACD_DEFAULTS if self.mode == "reference" else FAST_COACD)
        params.update(dict(self.coacd))
        params["seed"] = int(self.seed)
        return params

    @property
    def effective_simplify_tolerance(self) -> float:
        if self.simplify_tolerance is not None:
            return float(self.simplify_tolerance)
        return 0.0 if self.mode == "reference" else FAST_SIMPLIFY_TOLERANCE

    @property
    def effective_max_runs(self) -> int | None:
        if self.max_runs is not None:
            return int(self.max_runs)
        return FAST_MAX_RUNS if self.mode == "fast" else None

    @property
    def effective_adaptive(self) -> bool:
        return self.mode == "fast" if self.adaptive is None else bool(self.adaptive)

    def run_key(self, mesh_digest: str, threshold: float) -> str:
        """Cache key of one CoACD run at `threshold` on a mesh with geometry hash `mesh_digest`."""
        payload = {
            "mesh": mesh_digest,
            "threshold": round(float(threshold), 6),
            "coacd": {k: (v if isinstance(v, (int, float, str)) else str(v)) for k, v in
                      sorted(self.coacd_params().items())},
            "simplify_tolerance": self.effective_simplify_tolerance,
            "mapping": MAPPING_VERSION,
        }
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]


@dataclass
class Partition:
    """One decomposition: `part_of_face[i]` is the convex part (0..n_parts-1) of face i."""

    threshold: float
    part_of_face: np.ndarray

    @property
    def n_parts(self) -> int:
        return int(self.part_of_face.max()) + 1 if self.part_of_face.size else 0

    def same_as(self, other: "Partition") -> bool:
        return self.part_of_face.shape == other.part_of_face.shape and bool(
            np.array_equal(self.part_of_face, other.part_of_face)
        )


def canonical_parts(part_of_face: np.ndarray) -> np.ndarray:
    """Renumber part ids in order of first appearance (so equal partitions have equal arrays)."""
    part_of_face = np.asarray(part_of_face, dtype=np.int64)
    _, first, inverse = np.unique(part_of_face, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse.reshape(-1)]


def dedupe_partitions(partitions: Sequence[Partition]) -> list[Partition]:
    """Drop every partition equal to its predecessor in threshold order (the earlier threshold is kept)."""
    ordered = sorted(partitions, key=lambda p: p.threshold)
    kept: list[Partition] = []
    for partition in ordered:
        if not kept or not partition.same_as(kept[-1]):
            kept.append(partition)
    return kept


# ----------------------------------------------------------------------------------------------- face -> hull


def hull_planes(vertices: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Outward facet planes (K, 4) [n, -d] of the convex hull of `vertices` and its volume; None if degenerate."""
    try:
        hull = ConvexHull(np.asarray(vertices, dtype=np.float64))
    except (QhullError, ValueError):
        return None
    return hull.equations, float(hull.volume)


def map_faces_to_hulls(
    centroids: np.ndarray, hulls: Sequence[np.ndarray], scale: float, tolerance: float = CONTAINMENT_TOLERANCE
) -> np.ndarray:
    """Hull index for every face centroid (see the module docstring for the rule). `hulls` = vertex arrays."""
    centroids = np.asarray(centroids, dtype=np.float64)
    if len(hulls) == 0:
        raise ValueError("no hulls to map faces to")
    homogeneous = np.hstack([centroids, np.ones((len(centroids), 1))])
    outside = np.full((len(centroids), len(hulls)), np.inf)
    volumes = np.full(len(hulls), np.inf)
    for h, vertices in enumerate(hulls):
        planes = hull_planes(vertices)
        if planes is None:  # flat hull: fall back to distance from its bounding box
            low, high = np.min(vertices, axis=0), np.max(vertices, axis=0)
            outside[:, h] = np.linalg.norm(np.maximum(low - centroids, 0) + np.maximum(centroids - high, 0), axis=1)
            volumes[h] = 0.0
            continue
        equations, volumes[h] = planes
        outside[:, h] = (homogeneous @ equations.T).max(axis=1)
    inside = outside <= tolerance * scale
    # Among containing hulls the smallest wins; with none, the nearest (smallest outside value).
    by_volume = np.where(inside, volumes[None, :], np.inf)
    contained = inside.any(axis=1)
    return np.where(contained, by_volume.argmin(axis=1), outside.argmin(axis=1)).astype(np.int64)


# ------------------------------------------------------------------------------------------------ CoACD runs


def set_coacd_log_level(level: str) -> None:
    """Validate `level` and pass it to CoACD (an invalid string would abort the interpreter inside CoACD)."""
    if level not in COACD_LOG_LEVELS:
        raise ValueError(f"invalid CoACD log level {level!r}; use one of {COACD_LOG_LEVELS}")
    import coacd

    coacd.set_log_level(level)


def run_coacd_hulls(vertices: np.ndarray, faces: np.ndarray, threshold: float, params: dict) -> list[np.ndarray]:
    """Run CoACD once; returns the vertex array of every hull."""
    import coacd

    result = coacd.run_coacd(coacd.Mesh(vertices, faces), threshold=float(threshold), **params)
    return [np.asarray(hull_vertices, dtype=np.float64) for hull_vertices, _ in result]


def simplify(mesh: trimesh.Trimesh, tolerance: float) -> tuple[np.ndarray, np.ndarray, bool]:
    """Vertices and faces of `mesh` simplified with manifold3d within `tolerance` x its bounding-box diagonal, and
    whether the result is a closed manifold verified by manifold3d.

    manifold3d's edge collapses keep a closed manifold closed, so CoACD (which aborts on some non-manifold input)
    gets a valid mesh. A mesh that is not a closed manifold, or a tolerance of 0, is returned unchanged and
    unverified (False: CoACD then needs its own preprocessing).
    """
    # Fresh writable C-ordered copies: manifold3d refuses read-only views.
    vertices = np.array(mesh.vertices, dtype=np.float64, order="C")
    faces = np.array(mesh.faces, dtype=np.int64, order="C")
    if tolerance <= 0:
        return vertices, faces, False
    import manifold3d

    solid = manifold3d.Manifold(manifold3d.Mesh64(vertices, faces.astype(np.uint64)))
    if solid.status() != manifold3d.Error.NoError or solid.is_empty():
        logger.info("mesh is not a closed manifold (%s): decomposing it without simplification", solid.status())
        return vertices, faces, False
    simplified = solid.simplify(tolerance * float(np.linalg.norm(mesh.extents))).to_mesh64()
    return (np.asarray(simplified.vert_properties[:, :3], dtype=np.float64),
            np.asarray(simplified.tri_verts, np.int64), True)


def params_for(params: dict, closed_manifold: bool) -> dict:
    """CoACD arguments for one input mesh: preprocessing "off" becomes "auto" unless the mesh is a verified closed
    manifold (CoACD may abort on other input without its preprocessing)."""
    if params["preprocess_mode"] == "off" and not closed_manifold:
        return dict(params, preprocess_mode="auto")
    return params


def _decompose_once(job: tuple) -> tuple[float, np.ndarray, float]:
    """Worker: one CoACD run and its face mapping. Returns (threshold, part_of_face, seconds)."""
    vertices, faces, centroids, scale, threshold, params, log_level = job
    started = time.perf_counter()
    set_coacd_log_level(log_level)
    hulls = run_coacd_hulls(vertices, faces, threshold, params)
    parts = canonical_parts(map_faces_to_hulls(centroids, hulls, scale))
    return threshold, parts, time.perf_counter() - started


# ------------------------------------------------------------------------------------------------------ cache


def default_cache_dir() -> Path:
    """Writable cache: `$SEGGRASP_CACHE/decompositions` or `~/.cache/seggrasp/decompositions`."""
    root = os.environ.get("SEGGRASP_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "seggrasp") / "decompositions"


def _load_cached(key: str, n_faces: int, search: Sequence[Path]) -> np.ndarray | None:
    for folder in search:
        path = folder / f"{key}.npz"
        if not path.is_file():
            continue
        try:
            with np.load(path, allow_pickle=False) as data:
                parts = data["part_of_face"].astype(np.int64)
        except (OSError, ValueError, KeyError) as exc:
            logger.warning("ignoring unreadable decomposition cache %s: %s", path, exc)
            continue
        if parts.shape == (n_faces,):
            return parts
        logger.warning("ignoring decomposition cache %s: %d faces, expected %d", path, parts.size, n_faces)
    return None


def _compact(parts: np.ndarray) -> np.ndarray:
    return parts.astype(np.uint8 if parts.max(initial=0) < 256 else np.uint16 if parts.max() < 65536 else np.int32)


# ------------------------------------------------------------------------------------------------------ sweep


@dataclass
class SweepStats:
    """What a sweep did: seconds per CoACD run (cache misses only) and the thresholds served from cache."""

    run_seconds: dict[float, float] = dataclasses.field(default_factory=dict)
    cached: list[float] = dataclasses.field(default_factory=list)
    evaluated: list[float] = dataclasses.field(default_factory=list)


def select_thresholds(
    grid: Sequence[float],
    evaluate: Callable[[list[float]], dict[float, np.ndarray]],
    anchors: Sequence[float] = FAST_ANCHORS,
    max_runs: int | None = None,
) -> dict[float, np.ndarray]:
    """Find every distinct partition of `grid` while running few thresholds.

    `evaluate(thresholds)` returns {threshold: canonical part_of_face} for a batch (run in parallel by the caller).
    First the grid ends and the grid values nearest to `anchors` are evaluated; then, in rounds, the midpoint of
    every interval between consecutive evaluated thresholds whose partitions differ. An interval whose two ends
    agree is assumed constant. With `max_runs`, the widest differing intervals are split first and the search stops
    after that many evaluations. Returns the evaluated {threshold: partition}.
    """
    grid = sorted(float(t) for t in grid)
    chosen = {0, len(grid) - 1}
    for anchor in anchors:
        chosen.add(int(np.argmin([abs(t - anchor) for t in grid])))
    results: dict[int, np.ndarray] = {}
    budget = len(grid) if max_runs is None else max(int(max_runs), 2)
    batch = sorted(chosen)
    if len(batch) > budget:  # keep the two ends and the anchors nearest the fine end
        batch = sorted([0, len(grid) - 1] + [i for i in batch if i not in (0, len(grid) - 1)][: budget - 2])
    while batch:
        found = evaluate([grid[i] for i in batch])
        for i in batch:
            results[i] = found[grid[i]]
        done = sorted(results)
        splits = [(high - low, low, high) for low, high in zip(done, done[1:])
                  if high - low > 1 and not np.array_equal(results[low], results[high])]
        splits.sort(key=lambda s: (-s[0], s[1]))
        batch = sorted((low + high) // 2 for _, low, high in splits[: budget - len(results)])
    return {grid[i]: parts for i, parts in results.items()}


def decompose_sweep(
    mesh: trimesh.Trimesh,
    config: DecompositionConfig | None = None,
    cache_dir: str | os.PathLike | None = None,
    workers: int | None = None,
    stats: SweepStats | None = None,
    bundled: bool = True,
) -> list[Partition]:
    """Distinct CoACD partitions of `mesh`'s faces over the configured thresholds, finest (lowest) first.

    Cached on disk (see the module docstring). `workers` = parallel CoACD processes (default: 1 in reference
    mode, else the CPU count). Pass a `SweepStats` to learn the per-threshold times. `bundled=False` ignores the
    precomputed caches in assets/decompositions/ (for cold-run benchmarks).
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
    search = [writable] + ([ASSET_CACHE_DIR] if bundled and ASSET_CACHE_DIR != writable else [])
    digest = mesh_hash(mesh)
    n_faces = len(mesh.faces)
    centroids = np.asarray(mesh.triangles_center, dtype=np.float64)
    scale = float(np.linalg.norm(mesh.extents))
    params = config.coacd_params()
    coarse: tuple[np.ndarray, np.ndarray, bool] | None = None

    def evaluate(thresholds: list[float]) -> dict[float, np.ndarray]:
        nonlocal coarse
        found: dict[float, np.ndarray] = {}
        missing = []
        for threshold in thresholds:
            parts = _load_cached(config.run_key(digest, threshold), n_faces, search)
            if parts is None:
                missing.append(threshold)
            else:
                found[threshold] = parts
                stats.cached.append(threshold)
        if missing:
            if coarse is None:
                coarse = simplify(mesh, config.effective_simplify_tolerance)
            run_params = params_for(params, coarse[2])
            jobs = [(coarse[0], coarse[1], centroids, scale, t, run_params, config.log_level) for t in missing]
            outcomes = _run_jobs(jobs, workers)
            crashed = [t for t, outcome in zip(missing, outcomes) if outcome is None]
            if crashed and len(coarse[1]) != n_faces:
                logger.warning("CoACD crashed on the simplified mesh at thresholds %s; retrying on the full mesh", crashed)
                full = (np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64))
                retry = [(full[0], full[1], centroids, scale, t, params_for(params, False), config.log_level)
                         for t in crashed]
                outcomes = [o for o in outcomes if o is not None] + _run_jobs(retry, workers)
            if any(outcome is None for outcome in outcomes):
                failed = sorted(set(missing) - {o[0] for o in outcomes if o is not None})
                raise RuntimeError(f"CoACD crashed (its process died) at thresholds {failed} on this mesh")
            for threshold, parts, seconds in outcomes:
                found[threshold] = parts
                stats.run_seconds[threshold] = seconds
                atomic_save_npz(writable / f"{config.run_key(digest, threshold)}.npz", part_of_face=_compact(parts),
                                threshold=np.float64(threshold))
        stats.evaluated.extend(thresholds)
        return found

    if config.effective_adaptive:
        evaluated = select_thresholds(config.thresholds, evaluate, max_runs=config.effective_max_runs)
    else:
        evaluated = evaluate(list(config.thresholds))
    partitions = dedupe_partitions([Partition(t, parts) for t, parts in evaluated.items()])
    logger.info("decomposition sweep: %d distinct partitions from %d runs (%d cached)", len(partitions),
                len(evaluated), len(stats.cached))
    return partitions


def _job_process(conn, job: tuple) -> None:
    faulthandler.disable()  # a CoACD abort is reported by the parent; no interpreter dump from the child
    conn.send(_decompose_once(job))
    conn.close()


def _run_jobs(jobs: list[tuple], workers: int) -> list[tuple[float, np.ndarray, float] | None]:
    """Run every job in its own child process, at most `workers` at a time; None for a run whose process died.

    CoACD aborts the whole interpreter on some inputs (failed C++ assertions), so no run shares a process with the
    caller or with another run.
    """
    context = multiprocessing.get_context("fork" if sys.platform.startswith("linux") else "spawn")
    results: list[tuple[float, np.ndarray, float] | None] = [None] * len(jobs)
    pending = list(range(len(jobs)))
    running: dict[int, tuple] = {}
    while pending or running:
        while pending and len(running) < workers:
            index = pending.pop(0)
            receive, send = context.Pipe(duplex=False)
            process = context.Process(target=_job_process, args=(send, jobs[index]), daemon=True)
            process.start()
            send.close()
            running[index] = (process, receive)
        ready = multiprocessing.connection.wait([receive for _, receive in running.values()])
        for index, (process, receive) in list(running.items()):
            if receive not in ready:
                continue
            try:
                results[index] = receive.recv()
            except EOFError:  # the child died (CoACD abort) before sending
                results[index] = None
            process.join()
            receive.close()
            del running[index]
    return results


# -------------------------------------------------------------------------------------------------------- CLI


def precompute_assets(config: DecompositionConfig, workers: int | None = None) -> list[str]:
    """Fill assets/decompositions/ with the sweeps of every twin object (the committed warm cache)."""
    from seggrasp.objects import load_asset_set

    done = []
    for model in load_asset_set():
        started = time.perf_counter()
        partitions = decompose_sweep(model.mesh, config, cache_dir=ASSET_CACHE_DIR, workers=workers)
        logger.info("%s: %d partitions in %.1f s", model.object_id, len(partitions), time.perf_counter() - started)
        done.append(f"{model.object_id}: {len(model.mesh.faces)} faces, {len(partitions)} distinct partitions, "
                    f"{time.perf_counter() - started:.1f} s")
    return done


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m seggrasp.decompose", description=__doc__.splitlines()[0])
    parser.add_argument("--precompute-assets", action="store_true",
                        help="decompose every twin object into assets/decompositions/ (the bundled warm cache)")
    parser.add_argument("--mode", choices=MODES, default="fast")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=None)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if not args.precompute_assets:
        parser.error("nothing to do: pass --precompute-assets")
    for line in precompute_assets(DecompositionConfig(mode=args.mode, seed=args.seed), workers=args.workers):
        print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
