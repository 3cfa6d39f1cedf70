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

Scans (fast mode). A mesh over MAX_COACD_FACES faces, or one that is not a closed manifold (a scan, a depth-fusion
mesh), is decomposed as a scan: an open one goes to CoACD as a closed shell around it (`remesh.closed_shell`)
instead of through CoACD's slow preprocessing; its working mesh gets up to SCAN_SIMPLIFY_PASSES manifold3d passes;
CoACD searches one cut deep (SCAN_COACD); the thresholds SCAN_FIRST_ROUND run as one parallel batch, then SCAN_FINER
from coarse to fine while the finest partition has fewer than SCAN_MAX_PARTS parts, without bisection
(`sweep.select_scan_thresholds`); its cache keys carry SCAN_RECIPE. Closed meshes of at most MAX_COACD_FACES faces
(the twin) are decomposed as above and keep their keys. Measured: docs/results/cold-segmentation.md.

Caching. Every CoACD run is cached on disk under a key hashing the mesh geometry (`seggrasp.mesh.mesh_hash`), the
threshold, every CoACD parameter, the decimation target and the mapping version; the file holds the compact
face -> part array. The writable cache lives in `$SEGGRASP_CACHE` or `~/.cache/seggrasp` (`decompositions/`);
`assets/decompositions/` holds precomputed runs for the twin and is searched read-only
(`python -m assets decompose` regenerates it).

Bounds. CoACD never sees more than MAX_COACD_FACES faces (a larger working mesh is quadric-decimated first), each
run has a time budget (`DecompositionConfig.run_timeout`; a run over it is killed and the sweep goes on without
it), and every run is logged with its threshold and time.

Layout: `config` (modes, CoACD parameters, `DecompositionConfig`), `mapping` (partitions, face -> hull), `cache`
(on-disk runs), `workers` (CoACD in child processes), `remesh` (closed shells of open meshes), `sweep` (threshold
selection and `decompose_sweep`).
"""

from seggrasp.decompose.cache import default_cache_dir
from seggrasp.decompose.config import (
    ASSET_CACHE_DIR,
    COACD_DEFAULTS,
    COACD_LOG_LEVELS,
    CONTAINMENT_TOLERANCE,
    FAST_ANCHORS,
    FAST_COACD,
    FAST_MAX_RUNS,
    FAST_SIMPLIFY_TOLERANCE,
    FAST_THRESHOLDS,
    MAPPING_VERSION,
    MAX_COACD_FACES,
    MODES,
    PAPER_THRESHOLDS,
    PREPROCESS_MODES,
    RUN_TIMEOUT_S,
    SCAN_COACD,
    SCAN_FINER,
    SCAN_FIRST_ROUND,
    SCAN_MAX_PARTS,
    SCAN_RECIPE,
    SCAN_SIMPLIFY_PASSES,
    DecompositionConfig,
)
from seggrasp.decompose.mapping import Partition, canonical_parts, dedupe_partitions, hull_planes, map_faces_to_hulls
from seggrasp.decompose.remesh import closed_shell
from seggrasp.decompose.sweep import (
    SweepStats,
    SweepTimeout,
    decompose_sweep,
    select_scan_thresholds,
    select_thresholds,
)
from seggrasp.decompose.workers import params_for, run_coacd_hulls, set_coacd_log_level, simplify
from seggrasp.mesh import mesh_hash

__all__ = [
    "ASSET_CACHE_DIR", "COACD_DEFAULTS", "COACD_LOG_LEVELS", "CONTAINMENT_TOLERANCE", "FAST_ANCHORS", "FAST_COACD",
    "FAST_MAX_RUNS", "FAST_SIMPLIFY_TOLERANCE", "FAST_THRESHOLDS", "MAPPING_VERSION", "MAX_COACD_FACES", "MODES",
    "PAPER_THRESHOLDS", "PREPROCESS_MODES", "RUN_TIMEOUT_S", "SCAN_COACD", "SCAN_FINER", "SCAN_FIRST_ROUND",
    "SCAN_MAX_PARTS", "SCAN_RECIPE", "SCAN_SIMPLIFY_PASSES",
    "DecompositionConfig", "closed_shell", "Partition", "SweepStats",
    "SweepTimeout", "canonical_parts", "decompose_sweep", "dedupe_partitions", "default_cache_dir", "hull_planes",
    "map_faces_to_hulls", "mesh_hash", "params_for", "run_coacd_hulls", "select_scan_thresholds", "select_thresholds",
    "set_coacd_log_level", "simplify",
]
