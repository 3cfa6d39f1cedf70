"""Decomposition settings: CoACD parameters of the two sweep modes, their threshold grids and `DecompositionConfig`."""

from __future__ import annotations

import hashlib
import json
import numbers
from dataclasses import dataclass
from pathlib import Path

MODES = ("fast", "reference")
#: Seeds are whole numbers 0 .. 2**31 - 1 (what CoACD's and numpy's generators take).
MAX_SEED = 2**31 - 1
#: The paper's sweep: 0.01..0.25 in steps of 0.01.
PAPER_THRESHOLDS: tuple[float, ...] = tuple(round(0.01 * k, 2) for k in range(1, 26))
#: Log levels CoACD's C++ side accepts; anything else aborts the interpreter inside `coacd.set_log_level`.
COACD_LOG_LEVELS = ("off", "critical", "error", "warn", "warning", "info", "debug")
PREPROCESS_MODES = ("auto", "on", "off")
#: Bump when the face -> hull mapping changes: old cache entries then no longer match.
MAPPING_VERSION = 1
#: A centroid within this fraction of the mesh's bounding-box diagonal outside a hull counts as inside it.
CONTAINMENT_TOLERANCE = 1e-3
ASSET_CACHE_DIR = Path(__file__).resolve().parents[2] / "assets" / "decompositions"

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
#: Fast mode: coarser CoACD search and no CoACD preprocessing. CoACD's preprocessing remeshes the input on a voxel
#: grid, which on manifold3d's simplified twin knife moved the finest cut off the blade/handle boundary and cost time;
#: without it the finest partition follows the part boundary. "off" is only used on meshes manifold3d verified as
#: closed manifolds (`simplify`); any other mesh is decomposed with "auto", since CoACD may abort on non-manifold
#: input. Lighter search settings saved CPU time at a small mIoU cost. Numbers: docs/results/decomposition.md.
FAST_COACD = dict(COACD_DEFAULTS, preprocess_mode="off", resolution=500, mcts_nodes=15, mcts_iterations=60,
                  mcts_max_depth=2)
#: Fast mode's grid: the paper's without 0.01, which is by far the slowest threshold and bought nothing measurable
#: (docs/results/decomposition.md).
FAST_THRESHOLDS: tuple[float, ...] = PAPER_THRESHOLDS[1:]
#: manifold3d simplification tolerance (fraction of the bounding-box diagonal): well below the finest concavity;
#: coarser tolerances lowered the mug's mIoU (docs/results/decomposition.md).
FAST_SIMPLIFY_TOLERANCE = 0.002
#: Thresholds the fast mode runs before bisecting (indices into the grid are derived from these values).
FAST_ANCHORS = (0.02, 0.04, 0.08, 0.25)
#: At most this many CoACD runs per sweep in fast mode (bisection stops there; the finest threshold is always run).
#: Full GeoFusion hardly depends on the coarser partitions (docs/results/decomposition.md).
FAST_MAX_RUNS = 5
#: Time budget of one CoACD run (CPU seconds) by mode: a run that exceeds it is killed and the sweep goes on
#: without it.
RUN_TIMEOUT_S = {"fast": 60.0, "reference": 600.0}
#: CoACD never sees more faces than this: a larger working mesh is simplified more coarsely, then decimated, first
#: (bounded time and memory; a fast-mode run on a 20k-face working mesh took over a minute).
MAX_COACD_FACES = 10_000
#: Fast mode on a scan (a mesh over MAX_COACD_FACES, or one that is not a closed manifold): the grid values nearest
#: SCAN_FIRST_ROUND (and the coarsest) run first, in parallel; then the values nearest SCAN_FINER (and the finest),
#: from coarse to fine, only while the finest partition so far has fewer than SCAN_MAX_PARTS parts (those expected to
#: stay under it run together; `seggrasp.decompose.sweep.select_scan_thresholds`); no bisection. A run's CPU time
#: grows with its part count, and on thin-walled scans (the YCB mug, drill, a perceived mug) the finer runs cost most
#: while leaving full-GeoFusion mIoU unchanged (docs/results/cold-segmentation.md).
SCAN_FIRST_ROUND: tuple[float, ...] = (0.06, 0.11, 0.25)
SCAN_FINER: tuple[float, ...] = (0.04, 0.02)
SCAN_MAX_PARTS = 50
#: manifold3d simplification passes of a scan's working mesh (`seggrasp.decompose.workers.simplify`).
SCAN_SIMPLIFY_PASSES = 3
#: Fast mode on a scan: CoACD's tree search one cut deep instead of two (on top of FAST_COACD). On the thin-walled
#: YCB mug, drill and perceived mug it halved the CPU time of a run at the same mIoU; lighter searches (fewer
#: iterations or nodes) were pathological on an open tube's shell (docs/results/cold-segmentation.md).
SCAN_COACD = dict(mcts_max_depth=1)
#: Bump when the working mesh of a scan or its runs change (closed shell, part cap, SCAN_COACD): old cache entries of
#: scans then no longer match. Twin-like meshes (closed, at most MAX_COACD_FACES faces) keep their keys.
SCAN_RECIPE = 2


@dataclass(frozen=True)
class DecompositionConfig:
    """Parameters of a decomposition sweep. Fields left at None take the value of the `mode`.

    `thresholds`: the grid (reference: 0.01..0.25 step 0.01; fast: 0.02..0.25).
    `coacd` overrides individual CoACD keyword arguments (keys as in `coacd.run_coacd`), on top of the mode's.
    `simplify_tolerance` simplifies the mesh before CoACD within that fraction of its diagonal (0 = never).
    `adaptive` runs only the thresholds needed to find every distinct partition of the grid (see the package
    docstring). `scan_max_parts` caps the finest partition of a scan (None: SCAN_MAX_PARTS in fast mode).
    `run_timeout` is the time budget of one CoACD run in CPU seconds (None: RUN_TIMEOUT_S of the mode).
    """

    mode: str = "fast"
    seed: int = 0
    thresholds: tuple[float, ...] | None = None
    coacd: tuple[tuple[str, object], ...] = ()
    simplify_tolerance: float | None = None
    adaptive: bool | None = None
    max_runs: int | None = None
    log_level: str = "error"
    run_timeout: float | None = None
    scan_max_parts: int | None = None

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"unknown decomposition mode {self.mode!r}; use one of {MODES}")
        whole = isinstance(self.seed, numbers.Integral) and not isinstance(self.seed, bool)
        if not whole or not 0 <= self.seed <= MAX_SEED:
            raise ValueError(f"the decomposition seed must be a whole number 0..{MAX_SEED}, got {self.seed!r}")
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
        if self.scan_max_parts is not None and self.scan_max_parts < 1:
            raise ValueError(f"scan_max_parts must be at least 1, got {self.scan_max_parts}")
        if self.run_timeout is not None and not self.run_timeout > 0:
            raise ValueError(f"run_timeout must be a positive number of seconds, got {self.run_timeout}")
        if not (0.0 <= self.effective_simplify_tolerance < 0.1):
            raise ValueError(f"simplify_tolerance must be in [0, 0.1), got {self.simplify_tolerance}")

    def coacd_params(self, scan: bool = False) -> dict:
        """Keyword arguments for `coacd.run_coacd` except `threshold` (and with the seed); `scan`: for a mesh decomposed
        as a scan (fast mode only: SCAN_COACD on top of the mode's settings, below the config's own `coacd`)."""
        params = dict(COACD_DEFAULTS if self.mode == "reference" else FAST_COACD)
        if scan and self.mode == "fast":
            params.update(SCAN_COACD)
        params.update(dict(self.coacd))
        params["seed"] = int(self.seed)
        return params

    @property
    def effective_simplify_tolerance(self) -> float:
        if self.simplify_tolerance is not None:
            return float(self.simplify_tolerance)
        return 0.0 if self.mode == "reference" else FAST_SIMPLIFY_TOLERANCE

    @property
    def effective_run_timeout(self) -> float:
        return float(self.run_timeout) if self.run_timeout is not None else RUN_TIMEOUT_S[self.mode]

    @property
    def effective_max_runs(self) -> int | None:
        if self.max_runs is not None:
            return int(self.max_runs)
        return FAST_MAX_RUNS if self.mode == "fast" else None

    @property
    def effective_scan_max_parts(self) -> int | None:
        """The part cap of scans (None: no cap; the reference mode has none)."""
        if self.scan_max_parts is not None:
            return int(self.scan_max_parts)
        return SCAN_MAX_PARTS if self.mode == "fast" else None

    @property
    def effective_adaptive(self) -> bool:
        return self.mode == "fast" if self.adaptive is None else bool(self.adaptive)

    def run_key(self, mesh_digest: str, threshold: float, face_limit: int | None = None, scan: bool = False) -> str:
        """Cache key of one CoACD run at `threshold` on a mesh with geometry hash `mesh_digest`; `face_limit` is the
        CoACD face limit when the mesh has more faces than it (it then shapes the working mesh); `scan`: the mesh is
        decomposed as a scan (SCAN_RECIPE enters the key)."""
        payload = {
            "mesh": mesh_digest,
            "threshold": round(float(threshold), 6),
            "coacd": {k: (v if isinstance(v, (int, float, str)) else str(v)) for k, v in
                      sorted(self.coacd_params(scan).items())},
            "simplify_tolerance": self.effective_simplify_tolerance,
            "mapping": MAPPING_VERSION,
        }
        if face_limit is not None:
            payload["face_limit"] = int(face_limit)
        if scan:
            payload["scan_recipe"] = SCAN_RECIPE
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:32]
