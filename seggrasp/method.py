"""The methods an episode can run: each turns a mesh, its prompts and a detector into per-face labels (and, for
`shapegrasp`, its own grasps). The method never sees ground truth: the harness builds the detector and scores the
result.

Methods (every record names its method and its detector):

- `seggrasp`: coarse voting + GeoFusion (multi-fusion and fine-grained optimisation) + soft prompt anchoring give
  the labels; grasps are chosen by the probability that both pads land on the prompted part
  (`seggrasp.grasp.policy.PartPolicy`), from per-face probabilities that average the shares of the GeoFusion scores,
  the coarse votes and the anchored labels (`face_probabilities`), over the faces under each pad's footprint;
  a request is left without grasps only when no candidate is plausibly on the part;
- `seggrasp-nearest`: the same probabilities read only at the face nearest each contact (ablation of the footprint);
- `seggrasp-agree`: the earlier default, grasps only where the anchored labels agree with the coarse votes' argmax
  (`seggrasp.fusion.agreed_labels`). What each choice gains: docs/results/grasp-selection.md;
- `coarse`: coarse voting only (the paper's baseline), the same grasps;
- `multi`, `opt`, `geofusion`: the ablations (multi-fusion only, fine-grained optimisation only, both = the paper's
  GeoFusion); `anchored`: GeoFusion + anchoring, grasps selected on its labels alone;
- `spread`: GeoSpreading (the paper's single-decomposition spreading), for the threshold study;
- `oracle`: the ground-truth labels, the ceiling: planned by the harness's `seggrasp.truth.GroundTruth`, not here;
- `shapegrasp`: seggrasp/baselines.py (convex parts, top-down grasp at the chosen part's centroid).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Sequence

import numpy as np
import trimesh

from seggrasp.baselines import shapegrasp_grasps, shapegrasp_labels
from seggrasp.decompose import DecompositionConfig, Partition, decompose_sweep
from seggrasp.detect.base import Detector
from seggrasp.fusion import agreed_labels, coarsest_with_parts, part_mean_scores, refine_labels, refine_scores
from seggrasp.grasp import GraspSet
from seggrasp.grasp.policy import PartPolicy, face_part_probabilities, one_hot
from seggrasp.hands import ROBOTIQ_2F85, Hand
from seggrasp.mesh import PreparedMesh, prepare_mesh
from seggrasp.segment import SegmentationConfig, segment
from seggrasp.vote import labels_from_scores

ORACLE = "oracle"
SHAPEGRASP = "shapegrasp"


class Recipe(NamedTuple):
    """How a voting method labels: the refinement mode of `seggrasp.fusion.refine_scores`, whether every prompt is
    anchored to a convex part, and how grasps are selected: only where the labels agree with the coarse votes
    (`on_agreement`), by per-face probabilities under `policy`, or (neither) on the labels."""

    refinement: str
    anchor: bool = False
    on_agreement: bool = False
    policy: PartPolicy | None = None

    @property
    def multi_fusion(self) -> bool:
        return self.refinement in ("multi", "full")

    @property
    def fine_grained(self) -> bool:
        return self.refinement in ("opt", "full")


#: The recipe of every method that labels by votes.
RECIPES: dict[str, Recipe] = {
    "coarse": Recipe("none"), "multi": Recipe("multi"), "opt": Recipe("opt"), "geofusion": Recipe("full"),
    "anchored": Recipe("full", anchor=True), "seggrasp": Recipe("full", anchor=True, policy=PartPolicy()),
    "seggrasp-nearest": Recipe("full", anchor=True, policy=PartPolicy(footprint_radius=0.0)),
    "seggrasp-agree": Recipe("full", anchor=True, on_agreement=True), "spread": Recipe("spread"),
}
METHODS = ("seggrasp", "coarse", "multi", "opt", "geofusion", "anchored", "spread", "seggrasp-nearest",
           "seggrasp-agree", ORACLE, SHAPEGRASP)


def check_method(method: str) -> str:
    """`method` if it is one of `METHODS`, else ValueError naming them."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
    return method


@dataclass
class PartPlan:
    """A method's per-face labels on the planning mesh, the labels its grasps are selected on (None: `labels`), for
    `shapegrasp` its own grasps per prompt, and, for a method that selects by probability, the (F, P) per-face
    prompt probabilities and the `PartPolicy` that turns them into grasps."""

    method: str
    detector: str
    labels: np.ndarray
    own_grasps: list[GraspSet] | None = None
    grasp_labels: np.ndarray | None = None
    face_probabilities: np.ndarray | None = None
    policy: PartPolicy | None = None

    @property
    def selection_labels(self) -> np.ndarray:
        """The labels grasps are selected on."""
        return self.labels if self.grasp_labels is None else self.grasp_labels


class ObjectSegmenter:
    """Segments one mesh for several methods, sharing the coarse votes and the decomposition sweep.

    The coarse votes come from `seggrasp.segment.segment` (refine="none") on `prepared` (the repaired working mesh
    of `mesh`, made here when not given) with `detector`, and are lifted to `mesh`'s face order; the decomposition
    sweep and the fusion then run on `mesh` itself, the mesh the bundled decomposition caches were computed for.
    `coarse_scores` (from an earlier run with the same mesh, prompts and detector) replace rendering and detection:
    then `detector` may be None. `seed` seeds the decomposition sweep and `view_seed` the camera rig; `hand` is the
    gripper ShapeGrasp plans its grasps for.
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        prompts: Sequence[str],
        detector: Detector | None,
        detector_label: str,
        *,
        seed: int = 0,
        view_seed: int = 0,
        prepared: PreparedMesh | None = None,
        coarse_scores: np.ndarray | None = None,
        decomposition_cache: str | None = None,
        decomposition_workers: int | None = None,
        partitions: list[Partition] | None = None,
        hand: Hand = ROBOTIQ_2F85,
    ) -> None:
        if detector is None and coarse_scores is None:
            raise ValueError("a segmenter needs a detector or precomputed coarse scores")
        self.mesh = mesh
        self.prepared = prepared if prepared is not None else prepare_mesh(mesh.vertices, mesh.faces, name="object")
        self.prompts = list(prompts)
        self.detector = detector
        self.detector_label = detector_label
        self.seed = seed
        self.view_seed = view_seed
        self.decomposition_cache = decomposition_cache
        self.decomposition_workers = decomposition_workers
        self.hand = hand
        self._coarse = None if coarse_scores is None else np.asarray(coarse_scores, dtype=np.float64)
        self._partitions = partitions

    @property
    def has_coarse_scores(self) -> bool:
        return self._coarse is not None

    def coarse_scores(self) -> np.ndarray:
        """The (F, P) coarse vote matrix S in `mesh`'s face order (computed once)."""
        if self._coarse is None:
            config = SegmentationConfig(refine="none", seed=self.view_seed)
            result = segment(self.prepared, self.prompts, self.detector, config)
            self._coarse = np.asarray(result.coarse_scores, dtype=np.float64)
        return self._coarse

    def partitions(self) -> list[Partition]:
        """`mesh`'s distinct decompositions, finest first (cached on disk by seggrasp.decompose)."""
        if self._partitions is None:
            config = DecompositionConfig(seed=self.seed)
            self._partitions = decompose_sweep(
                self.mesh, config, cache_dir=self.decomposition_cache, workers=self.decomposition_workers
            )
        return self._partitions

    def refined_scores(self, mode: str, partitions: list[Partition] | None = None) -> np.ndarray:
        """Coarse votes refined with one of `seggrasp.fusion.REFINE_MODES` (over `partitions`, default all),
        in `mesh`'s face order."""
        scores = self.coarse_scores()
        if mode == "none":
            return scores
        parts = self.partitions() if partitions is None else partitions
        return refine_scores(scores, parts, self.mesh.area_faces, mode)

    def plan(self, method: str, T_world_obj: np.ndarray) -> PartPlan:
        """Face labels (and, for shapegrasp, grasps) of `method` on this mesh."""
        check_method(method)
        if method == ORACLE:
            raise ValueError("the oracle method is planned from ground truth by the harness, not by a segmenter")
        if method == SHAPEGRASP:
            part_of_face = coarsest_with_parts(self.partitions(), len(self.prompts)).part_of_face
            votes = part_mean_scores(self.coarse_scores(), part_of_face, self.mesh.area_faces)
            grasps = shapegrasp_grasps(self.mesh, votes, part_of_face, T_world_obj, self.hand)
            return PartPlan(method, self.detector_label, shapegrasp_labels(votes, part_of_face), grasps)
        recipe = RECIPES[method]
        partitions = [] if recipe.refinement == "none" else self.partitions()
        refined, labels = refine_labels(self.coarse_scores(), partitions, self.mesh.area_faces, recipe.refinement,
                                        recipe.anchor)
        plan = PartPlan(method, self.detector_label, labels)
        if recipe.on_agreement:
            plan.grasp_labels = agreed_labels(labels, labels_from_scores(self.coarse_scores()))
        if recipe.policy is not None:
            plan.face_probabilities = face_probabilities(refined, self.coarse_scores(), labels)
            plan.policy = recipe.policy
        return plan


def face_probabilities(refined: np.ndarray, coarse: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(F, P) per-face prompt probabilities of the `seggrasp` method: the mean of the shares of the refined
    (GeoFusion) scores, of the coarse votes and of the (anchored) labels as one-hot rows."""
    return face_part_probabilities([refined, coarse, one_hot(labels, np.shape(coarse)[1])])
