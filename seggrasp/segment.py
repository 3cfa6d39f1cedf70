"""The segmentation pipeline: render views -> detector boxes -> per-face votes -> (CoACD sweep -> GeoFusion).

`segment` works on the repaired working mesh of a `PreparedMesh` and returns labels and scores in the INPUT file's
face order. Views, detections and partitions in the result refer to the working mesh (`PreparedMesh.mesh`).
"""

from __future__ import annotations

import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

import numpy as np

from seggrasp.detect.base import Detections, Detector
from seggrasp.labels import check_prompts
from seggrasp.mesh import PreparedMesh
from seggrasp.render import DEFAULT_IMAGE_SIZE, camera_rig, render_views
from seggrasp.views import View
from seggrasp.vote import labels_from_scores, vote

if TYPE_CHECKING:
    from seggrasp.decompose import DecompositionConfig, Partition

logger = logging.getLogger(__name__)


@dataclass
class SegmentationConfig:
    """Settings of one segmentation run.

    `refine` is a mode of `seggrasp.fusion.refine_scores` ("none" keeps the coarse votes); `anchor` gives every
    prompt a convex part after refinement (`seggrasp.fusion.anchor_prompts`; ignored without refinement);
    `decomposition`, `cache_dir` and `workers` go to `seggrasp.decompose.decompose_sweep` (None: its defaults). `seed` turns the
    camera rig.
    """

    n_views: int = 10
    image_size: int = DEFAULT_IMAGE_SIZE
    refine: str = "full"
    anchor: bool = True
    decomposition: DecompositionConfig | None = None
    cache_dir: str | os.PathLike | None = None
    workers: int | None = None
    seed: int = 0

    def __post_init__(self) -> None:
        if self.n_views < 1:
            raise ValueError(f"n_views must be at least 1, got {self.n_views}")
        if self.image_size < 8:
            raise ValueError(f"image_size must be at least 8 pixels, got {self.image_size}")
        if self.workers is not None and self.workers < 1:
            raise ValueError(f"workers must be at least 1, got {self.workers}")


@dataclass
class SegmentationResult:
    """Labels and scores of every input face, plus what produced them.

    `labels` (int, -1 = unknown) and `scores` (faces x prompts) follow the input file's face order, as do the
    coarse (eq. 1 only) versions. Without anchoring `labels` is the row argmax of `scores`; anchored parts take
    their prompt whatever their scores. `views`, `detections` and `partitions` refer to the working mesh's faces.
    `timings` holds seconds per stage ("render", "detect", "vote", and with refinement "decompose", "fusion").
    """

    prompts: list[str]
    labels: np.ndarray
    scores: np.ndarray
    coarse_labels: np.ndarray
    coarse_scores: np.ndarray
    views: list[View]
    detections: list[Detections]
    detector: str
    refine: str
    anchored: bool = False
    partitions: list[Partition] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)


def segment(
    mesh: PreparedMesh, prompts: Sequence[str], detector: Detector, config: SegmentationConfig | None = None
) -> SegmentationResult:
    """Segment `mesh` into the prompted parts; see `SegmentationResult` for what comes back."""
    config = config or SegmentationConfig()
    prompts = check_prompts(prompts)
    if config.refine != "none":
        from seggrasp.decompose import decompose_sweep
        from seggrasp.fusion import REFINE_MODES, refine_labels

        if config.refine not in REFINE_MODES:
            raise ValueError(f"unknown refine mode {config.refine!r}; choose one of {REFINE_MODES}")
    working = mesh.mesh
    timings: dict[str, float] = {}

    # Progress: on a mesh of millions of faces every stage takes seconds (each logs its own end).
    logger.info("rendering %d views of %d faces at %d px", config.n_views, len(working.faces), config.image_size)
    start = time.perf_counter()
    views = render_views(working, camera_rig(config.n_views, seed=config.seed), image_size=config.image_size)
    timings["render"] = time.perf_counter() - start

    start = time.perf_counter()
    detections = list(detector.detect(views, prompts))
    timings["detect"] = time.perf_counter() - start
    if len(detections) != len(views):
        raise ValueError(f"detector {detector.name!r} returned {len(detections)} results for {len(views)} views")

    start = time.perf_counter()
    coarse = vote(views, detections, len(working.faces), len(prompts))
    timings["vote"] = time.perf_counter() - start

    coarse_labels = labels_from_scores(coarse)
    scores, labels, partitions = coarse, coarse_labels, []
    if config.refine != "none":
        logger.info("decomposing %d faces (CoACD sweep)", len(working.faces))
        start = time.perf_counter()
        partitions = decompose_sweep(working, config.decomposition, Path(config.cache_dir) if config.cache_dir
                                     else None, config.workers)
        timings["decompose"] = time.perf_counter() - start
        logger.info("fusing the votes over %d partitions (refine=%s)", len(partitions), config.refine)
        start = time.perf_counter()
        scores, labels = refine_labels(coarse, partitions, np.asarray(working.area_faces), config.refine,
                                       config.anchor)
        timings["fusion"] = time.perf_counter() - start

    logger.info(
        "segmented %d faces into %s with %s (refine=%s): %s", mesh.n_source_faces, prompts, detector.name,
        config.refine, ", ".join(f"{stage} {seconds:.2f}s" for stage, seconds in timings.items()),
    )
    return SegmentationResult(
        prompts=prompts,
        labels=mesh.to_source(labels),
        scores=mesh.to_source(scores),
        coarse_labels=mesh.to_source(coarse_labels),
        coarse_scores=mesh.to_source(coarse),
        views=views,
        detections=detections,
        detector=detector.name,
        refine=config.refine,
        anchored=config.refine != "none" and config.anchor,
        partitions=partitions,
        timings=timings,
    )
