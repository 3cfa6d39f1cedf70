"""The episode runner shared by the simulated and the real backend.

One episode for one object: reset the cell, get the object's mesh (the cell's own, or reconstructed from its
cameras), segment it into the prompted parts with a method, sample grasps on the mesh, keep per prompt the top-k
grasps on the faces labelled with that prompt, move them into the world (`T_world_obj @ T_obj_grasp`) and execute
each one from a fresh reset of the same scene. Every trial becomes one `TrialRecord`.

Methods (every record names its method and its detector):

- `seggrasp`: the full method: coarse voting + GeoFusion (multi-fusion and fine-grained optimisation) + prompt
  anchoring (`seggrasp.fusion.anchor_prompts`: every prompt owns a convex part) give the labels; grasps are selected
  only where those labels agree with the coarse votes' argmax (`seggrasp.fusion.agreed_labels`), so that a wrong
  anchor or a wrong fused label does not send grasps to the wrong part (the paper selects on its labels alone).
  Measured without the simulator (twin, `typical`, 4 run seeds, antipodal grasps, top-10 per prompt, both contacts
  on the true part): Part Sel. coarse 0.681, GeoFusion 0.671, anchored 0.628, anchored where it agrees with the
  votes 0.812 (with GeoFusion instead of the votes 0.757), on-part grasps per slot 0.436 / 0.441 / 0.544 / 0.450;
- `coarse`: coarse voting only (the paper's baseline), the same grasps;
- `multi`, `opt`, `geofusion`: the ablations (multi-fusion only, fine-grained optimisation only, both = the paper's
  GeoFusion); `anchored`: GeoFusion + anchoring, grasps selected on its labels alone;
- `spread`: GeoSpreading (the paper's single-decomposition spreading), for the threshold study;
- `oracle`: the ground-truth labels (needs a labelled object), the ceiling;
- `shapegrasp`: seggrasp/baselines.py (convex parts, top-down grasp at the chosen part's centroid).

Ground truth, when the object has labels: a trial's `contacts_on_part` says whether both planned finger contacts
lie on faces whose true label is the prompt (Part Sel.); `touched_on_part` whether most faces the pads actually
touched are on it; `success` = lifted and touched the part (contacts as planned when the backend cannot observe
them).
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import asdict, dataclass, field
from typing import Callable, Sequence

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from seggrasp.baselines import shapegrasp_grasps, shapegrasp_labels
from seggrasp.cell import Cell, GraspOutcome
from seggrasp.decompose import DecompositionConfig, Partition, decompose_sweep
from seggrasp.detect import make_detector
from seggrasp.detect.base import Detector
from seggrasp.fusion import agreed_labels, coarsest_with_parts, part_mean_scores, refine_labels, refine_scores
from seggrasp.grasp import AntipodalSampler, GraspGenerator, GraspSet, select_per_prompt
from seggrasp.grasp.select import TOP_K
from seggrasp.labels import PartLabels
from seggrasp.mesh import prepare_mesh
from seggrasp.objects import ObjectModel
from seggrasp.segment import SegmentationConfig, segment
from seggrasp.vote import labels_from_scores

LOG = logging.getLogger(__name__)

#: (refinement mode of `seggrasp.fusion.refine_scores`, prompt anchoring, grasps only where the labels agree with the
#: coarse votes) of every method that labels by votes.
REFINEMENT_OF_METHOD = {
    "coarse": ("none", False, False), "multi": ("multi", False, False), "opt": ("opt", False, False),
    "geofusion": ("full", False, False), "anchored": ("full", True, False), "seggrasp": ("full", True, True),
    "spread": ("spread", False, False),
}
METHODS = ("seggrasp", "coarse", "multi", "opt", "geofusion", "anchored", "spread", "oracle", "shapegrasp")


@dataclass(frozen=True)
class DetectorSpec:
    """How to build the detector for an object: `name` as `make_detector` takes it; `preset`/`seed` for the
    simulated detector (which needs the object's ground-truth labels), `weights` for the real ones."""

    name: str = "simulated"
    preset: str = "typical"
    weights: str | None = None
    seed: int = 0

    @property
    def label(self) -> str:
        """How results name the detector, e.g. `simulated:typical` or `owlv2`."""
        return f"{self.name}:{self.preset}" if self.name == "simulated" else self.name

    def build(self, gt_labels: PartLabels | None) -> Detector:
        """The detector; `gt_labels` (one per face of the rendered working mesh) is required for `simulated`."""
        if self.name == "simulated" and gt_labels is None:
            raise ValueError("the simulated detector needs ground-truth labels; this object has none")
        return make_detector(self.name, weights=self.weights, gt_labels=gt_labels, preset=self.preset, seed=self.seed)


@dataclass
class Observation:
    """The mesh the episode plans on and its pose. A perceived mesh is already in the world (`T_world_obj` = I)."""

    mesh: trimesh.Trimesh
    T_world_obj: np.ndarray
    perceived: bool = False


@dataclass
class PartPlan:
    """A method's per-face labels on the planning mesh, the labels its grasps are selected on (None: `labels`) and,
    for `shapegrasp`, its own grasps per prompt."""

    method: str
    detector: str
    labels: np.ndarray
    own_grasps: list[GraspSet] | None = None
    grasp_labels: np.ndarray | None = None


@dataclass
class TrialRecord:
    """One executed (or impossible) grasp: JSON-ready with `to_json`."""

    object_id: str
    category: str
    method: str
    detector: str
    prompt: str
    prompt_index: int
    rank: int
    seed: int
    scene_seed: int
    n_candidates: int
    executed: bool
    grasp_score: float | None = None
    width: float | None = None
    T_world_grasp: list | None = None
    quaternion_xyzw: list | None = None
    contacts_on_part: bool | None = None
    reachable: bool = False
    lifted: bool = False
    lift_height: float = 0.0
    outcome: dict | None = None
    touched_on_part: bool | None = None
    success: bool | None = None
    reused_outcome: bool = False
    message: str = ""
    extra: dict = field(default_factory=dict)

    def to_json(self) -> dict:
        return asdict(self)


def table_plane_in_object_frame(mesh: trimesh.Trimesh, T_world_obj: np.ndarray) -> np.ndarray:
    """The table top (z-up world plane through the object's lowest point) as (a, b, c, d) in the object frame."""
    T = np.asarray(T_world_obj, dtype=np.float64)
    world_z = mesh.vertices @ T[2, :3] + T[2, 3]
    normal = T[2, :3]  # world z expressed in object coordinates: R^T e_z
    # plane: (R p + t)_z - z_min = normal . p + t_z - z_min
    return np.r_[normal, T[2, 3] - float(world_z.min())]


def observe(cell: Cell, perceive: bool = False, workspace=None) -> Observation:
    """The object's mesh and pose from the cell, or, with `perceive`, a mesh fused from `cell.capture()`."""
    if perceive:
        from seggrasp.perception import perceive_object  # only episodes that perceive need it

        mesh = perceive_object(cell.capture(), workspace)
        return Observation(mesh, np.eye(4), perceived=True)
    mesh, T_world_obj = cell.object_mesh()
    return Observation(mesh, np.asarray(T_world_obj, dtype=np.float64))


def transfer_labels(
    source_mesh: trimesh.Trimesh, source_labels: np.ndarray, target_mesh: trimesh.Trimesh, T_source_target: np.ndarray
) -> np.ndarray:
    """Labels of `target_mesh`'s faces from the nearest face of `source_mesh` (e.g. the twin -> a perceived mesh)."""
    centres = target_mesh.triangles_center @ T_source_target[:3, :3].T + T_source_target[:3, 3]
    _, _, nearest = trimesh.proximity.closest_point(source_mesh, centres)
    return np.asarray(source_labels, dtype=np.int64)[nearest]


class ObjectSegmenter:
    """Segments one mesh for several methods, sharing the coarse votes and the decomposition sweep.

    The coarse votes come from `seggrasp.segment.segment` (refine="none") and are lifted to `mesh`'s face order;
    the decomposition sweep and the fusion then run on `mesh` itself, in its own face order, which is the mesh the
    bundled decomposition caches (assets/decompositions/) were computed for. `gt_labels` (prompt indices per face
    of `mesh`, -1 elsewhere) feed the simulated detector and the oracle; `coarse_scores` (from an earlier run with
    the same object, detector and seed) skips rendering and detection, `partitions` (finest first) the decomposition
    sweep. `seed` seeds the decomposition sweep; the camera rig and the detector's draws follow `detector.seed`.
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        prompts: Sequence[str],
        detector: DetectorSpec,
        gt_labels: np.ndarray | None = None,
        seed: int = 0,
        decomposition_cache: str | None = None,
        coarse_scores: np.ndarray | None = None,
        decomposition_workers: int | None = None,
        partitions: list[Partition] | None = None,
    ) -> None:
        self.mesh = mesh
        self.prepared = prepare_mesh(mesh.vertices, mesh.faces, name="object")
        self.prompts = list(prompts)
        self.detector = detector
        self.gt_labels = None if gt_labels is None else np.asarray(gt_labels, dtype=np.int64)
        self.seed = seed
        self.decomposition_cache = decomposition_cache
        self.decomposition_workers = decomposition_workers
        self._coarse = None if coarse_scores is None else np.asarray(coarse_scores, dtype=np.float64)
        self._partitions = partitions

    def coarse_scores(self) -> np.ndarray:
        """The (F, P) coarse vote matrix S in `mesh`'s face order (computed once)."""
        if self._coarse is None:
            gt = None
            if self.gt_labels is not None:
                gt = PartLabels(self.prompts, self.prepared.from_source(self.gt_labels))
            detector = self.detector.build(gt)
            # The camera rig is part of what the detector sees: it follows the detector's seed.
            config = SegmentationConfig(refine="none", seed=self.detector.seed)
            result = segment(self.prepared, self.prompts, detector, config)
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
        if method not in METHODS:
            raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
        if method == "oracle":
            if self.gt_labels is None:
                raise ValueError("the oracle method needs ground-truth labels; this object has none")
            return PartPlan(method, "ground-truth", self.gt_labels.copy())
        if method == "shapegrasp":
            part_of_face = coarsest_with_parts(self.partitions(), len(self.prompts)).part_of_face
            votes = part_mean_scores(self.coarse_scores(), part_of_face, self.mesh.area_faces)
            grasps = shapegrasp_grasps(self.mesh, votes, part_of_face, T_world_obj)
            return PartPlan(method, self.detector.label, shapegrasp_labels(votes, part_of_face), grasps)
        mode, anchor, on_agreement = REFINEMENT_OF_METHOD[method]
        partitions = [] if mode == "none" else self.partitions()
        _, labels = refine_labels(self.coarse_scores(), partitions, self.mesh.area_faces, mode, anchor)
        grasp_labels = agreed_labels(labels, labels_from_scores(self.coarse_scores())) if on_agreement else None
        return PartPlan(method, self.detector.label, labels, grasp_labels=grasp_labels)


def grasp_key(T_world_grasp: np.ndarray, width: float) -> str:
    """Content key of a world grasp (for reusing outcomes of a deterministic backend)."""
    digest = hashlib.sha1(np.round(np.asarray(T_world_grasp, dtype=np.float64), 6).tobytes())
    digest.update(np.round(np.float64(width), 6).tobytes())
    return digest.hexdigest()


def ground_truth_on_part(
    contacts_obj: np.ndarray, gt_mesh: trimesh.Trimesh, gt_labels: np.ndarray, prompt_index: int
) -> np.ndarray:
    """(N,) both contacts (object frame, (N, 2, 3)) nearest to a face whose true label is `prompt_index`."""
    contacts_obj = np.asarray(contacts_obj, dtype=np.float64).reshape(-1, 2, 3)
    _, _, nearest = trimesh.proximity.closest_point(gt_mesh, contacts_obj.reshape(-1, 3))
    faces = np.asarray(nearest, dtype=np.int64).reshape(-1, 2)
    return (np.asarray(gt_labels)[faces] == prompt_index).all(axis=1)


def touched_part(outcome: GraspOutcome, gt_labels: np.ndarray | None, prompt_index: int) -> bool | None:
    """Whether the prompt's true part carries most of what the pads touched (None if unknown or unobserved).

    Each touched face counts with its `touched_weights` entry (contact force or area) when the cell reports them,
    else with weight one.
    """
    if gt_labels is None or not outcome.contacts_observed:
        return None
    touched = np.asarray(outcome.touched_faces, dtype=np.int64)
    if len(touched) == 0:
        return False
    weights = np.asarray(outcome.touched_weights, dtype=np.float64)
    if len(weights) != len(touched) or weights.sum() <= 0:
        weights = np.ones(len(touched))
    on_part = np.asarray(gt_labels)[touched] == prompt_index
    return bool(weights[on_part].sum() >= 0.5 * weights.sum())


@dataclass
class EpisodeContext:
    """Everything about the object an episode needs besides the cell."""

    object_id: str
    category: str
    prompts: list[str]
    scene_seed: int
    gt_mesh: trimesh.Trimesh | None = None  # the labelled mesh (object frame), for ground-truth checks
    gt_labels: np.ndarray | None = None  # prompt index per face of gt_mesh, -1 elsewhere
    center_of_mass: np.ndarray | None = None  # object frame (the URDF's inertial origin), for the grasp sampler
    mass: float | None = None  # kg

    @classmethod
    def from_object(cls, model: ObjectModel, scene_seed: int, prompts: Sequence[str] | None = None) -> "EpisodeContext":
        """Context for a twin object (its prompts and, when labelled, its ground truth)."""
        prompts = list(prompts) if prompts is not None else list(model.prompts)
        gt = model.labels.remap_to(prompts) if model.labels is not None else None
        return cls(model.object_id, model.category, prompts, scene_seed, model.mesh, gt, model.center_of_mass,
                   model.mass)


def plan_trials(
    context: EpisodeContext,
    observation: Observation,
    plan: PartPlan,
    grasps: GraspSet,
    targets: Sequence[int],
    top_k: int = TOP_K,
) -> list[tuple[int, int, GraspSet | None, int]]:
    """(prompt index, rank, world grasp or None, n_candidates) for each of the top-k slots of each target prompt."""
    if plan.own_grasps is not None:
        per_prompt = [plan.own_grasps[k] for k in range(len(context.prompts))]
    else:
        labels = plan.labels if plan.grasp_labels is None else plan.grasp_labels
        chosen_per_prompt = select_per_prompt(grasps, observation.mesh, labels, len(context.prompts), top_k)
        per_prompt = [grasps.subset(chosen) for chosen in chosen_per_prompt]
    slots = []
    for k in targets:
        chosen = per_prompt[k].transformed(observation.T_world_obj)
        for rank in range(top_k):
            if plan.own_grasps is not None and len(chosen):
                # shapegrasp plans one grasp per part: every slot executes it again, as repeated trials
                slots.append((k, rank, chosen.subset([rank % len(chosen)]), len(chosen)))
            elif rank < len(chosen):
                slots.append((k, rank, chosen.subset([rank]), len(chosen)))
            else:  # fewer grasps on the part than slots: the missing ones count as failures
                slots.append((k, rank, None, len(chosen)))
    return slots


def execute_slot(
    cell: Cell,
    context: EpisodeContext,
    observation: Observation,
    plan: PartPlan,
    slot: tuple[int, int, GraspSet | None, int],
    seed: int,
    outcome_cache: dict | None = None,
) -> TrialRecord:
    """Reset the scene and execute one slot's grasp (or record that the method found none)."""
    k, rank, grasp, n_candidates = slot
    record = TrialRecord(
        object_id=context.object_id, category=context.category, method=plan.method, detector=plan.detector,
        prompt=context.prompts[k], prompt_index=k, rank=rank, seed=seed, scene_seed=context.scene_seed,
        n_candidates=n_candidates, executed=False,
    )
    if grasp is None:
        record.contacts_on_part = False if context.gt_labels is not None else None
        record.success = False if context.gt_labels is not None else None
        record.message = "no grasp on the selected part"
        return record
    T_world_grasp, width = grasp.poses[0], float(grasp.widths[0])
    record.grasp_score = float(grasp.scores[0])
    record.width = width
    record.T_world_grasp = np.round(T_world_grasp, 6).tolist()
    record.quaternion_xyzw = Rotation.from_matrix(T_world_grasp[:3, :3]).as_quat().tolist()
    T_obj_world = np.linalg.inv(observation.T_world_obj)
    if context.gt_labels is not None:
        # contacts in the labelled mesh's frame: a perceived mesh lives in the world, the twin in the object frame
        T_gt_world = T_obj_world if not observation.perceived else np.linalg.inv(true_object_pose(cell))
        contacts = grasp.contacts[0] @ T_gt_world[:3, :3].T + T_gt_world[:3, 3]
        record.contacts_on_part = bool(ground_truth_on_part(contacts[None], context.gt_mesh, context.gt_labels, k)[0])
    key = grasp_key(T_world_grasp, width)
    if outcome_cache is not None and key in outcome_cache:
        outcome = outcome_cache[key]
        record.reused_outcome = True
    else:
        cell.reset(seed=context.scene_seed, object_id=context.object_id)
        outcome = cell.execute(T_world_grasp, width)
        if outcome_cache is not None:
            outcome_cache[key] = outcome
    record.executed = True
    record.reachable = bool(outcome.reachable)
    record.lifted = bool(outcome.lifted)
    record.lift_height = float(outcome.lift_height)
    record.outcome = outcome.to_json()
    record.message = outcome.message
    record.touched_on_part = touched_part(outcome, context.gt_labels, k)
    if context.gt_labels is not None:
        on_part = record.touched_on_part if record.touched_on_part is not None else record.contacts_on_part
        record.success = bool(outcome.lifted and on_part)
    return record


def true_object_pose(cell: Cell) -> np.ndarray:
    """The labelled twin's pose in the world, for scoring a perceived mesh (only a simulator knows it)."""
    _, T_world_obj = cell.object_mesh()
    return np.asarray(T_world_obj, dtype=np.float64)


def run_episode(
    cell: Cell,
    context: EpisodeContext,
    method: str,
    detector: DetectorSpec,
    *,
    targets: Sequence[str] | None = None,
    seed: int = 0,
    perceive: bool = False,
    workspace=None,
    generator: GraspGenerator | None = None,
    top_k: int = TOP_K,
    decomposition_cache: str | None = None,
    outcome_cache: dict | None = None,
    on_record: Callable[[TrialRecord], None] | None = None,
) -> list[TrialRecord]:
    """Segment, select and execute the top-k grasps for each target prompt (default: all of the context's prompts).

    `outcome_cache` (a dict) lets a deterministic backend reuse the outcome of an identical grasp from the same
    scene; pass None on real hardware. `on_record` is called with each record as soon as it exists.
    """
    target_indices = _target_indices(context.prompts, targets)
    cell.reset(seed=context.scene_seed, object_id=context.object_id)
    observation = observe(cell, perceive=perceive, workspace=workspace)
    gt_on_mesh = ground_truth_on_mesh(cell, context, observation)
    segmenter = ObjectSegmenter(
        observation.mesh, context.prompts, detector, gt_on_mesh, seed=seed, decomposition_cache=decomposition_cache
    )
    plan = segmenter.plan(method, observation.T_world_obj)
    grasps = GraspSet.empty()
    if plan.own_grasps is None:
        grasps = sample_grasps(context, observation, generator, seed)
    records = []
    for slot in plan_trials(context, observation, plan, grasps, target_indices, top_k):
        record = execute_slot(cell, context, observation, plan, slot, seed, outcome_cache)
        records.append(record)
        if on_record is not None:
            on_record(record)
    return records


def sample_grasps(
    context: EpisodeContext, observation: Observation, generator: GraspGenerator | None = None, seed: int = 0
) -> GraspSet:
    """Grasps on the observed mesh above the table. The antipodal sampler gets the object's centre of mass and
    mass when the mesh is the twin's own (object frame); for a perceived mesh it estimates them at uniform density,
    as the real cell does."""
    generator = generator or AntipodalSampler()
    plane = table_plane_in_object_frame(observation.mesh, observation.T_world_obj)
    if isinstance(generator, AntipodalSampler) and not observation.perceived:
        return generator.generate(observation.mesh, seed=seed, table_plane=plane,
                                  center_of_mass=context.center_of_mass, mass=context.mass)
    return generator.generate(observation.mesh, seed=seed, table_plane=plane)


def _target_indices(prompts: Sequence[str], targets: Sequence[str] | None) -> list[int]:
    if targets is None:
        return list(range(len(prompts)))
    lowered = [p.lower() for p in prompts]
    indices = []
    for target in targets:
        if target.lower() not in lowered:
            raise ValueError(f"target prompt {target!r} is not among the prompts {list(prompts)}")
        indices.append(lowered.index(target.lower()))
    return indices


def ground_truth_on_mesh(cell: Cell, context: EpisodeContext, observation: Observation) -> np.ndarray | None:
    """Ground-truth prompt labels per face of the planning mesh (transferred from the twin when the mesh was
    perceived; None when the object has no labels)."""
    if context.gt_labels is None:
        return None
    if not observation.perceived:
        if len(observation.mesh.faces) != len(context.gt_labels):
            raise ValueError(
                f"{context.object_id}: the cell's mesh has {len(observation.mesh.faces)} faces but the labels "
                f"{len(context.gt_labels)}"
            )
        return context.gt_labels
    T_obj_world = np.linalg.inv(true_object_pose(cell))
    return transfer_labels(context.gt_mesh, context.gt_labels, observation.mesh, T_obj_world)

