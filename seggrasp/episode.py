"""The episode: the one piece of code `python -m sim.evaluate`, the gym env `SegGrasp-v0` and the real cell run.

One episode for one object in one scene: reset the cell, get the object's mesh (the cell's own, or reconstructed
from its cameras), let a method (seggrasp/method.py) label it into the prompted parts, sample grasps on the mesh,
keep per prompt the top-k grasps the method's selection chooses for that prompt, move them into the world
(`T_world_obj @ T_obj_grasp`), put those the cell would execute (`Cell.check_reach`) first, as a real planner skips a
grasp it has no motion for, and execute each one from a fresh reset of the same scene. Every trial slot becomes one
`TrialRecord`. A harness chooses the cell, the detector (`seggrasp.truth.DetectorSpec`) and, for a labelled object,
the ground truth (`seggrasp.truth.GroundTruth`), and passes them in.

Scoring, when there is ground truth: a trial's `contacts_on_part` says whether both planned finger contacts lie on
faces whose true label is the prompt (Part Sel.); `touched_on_part` whether the true part carries most of what the
pads touched; `success` = lifted and touched the part (contacts as planned when the backend cannot observe them);
`failure` names why a trial failed (`seggrasp.cell.FAILURES`).

Before any slot moves the robot, each request is judged (`seggrasp.grasp.feasibility`): can any grasp candidate of
the cell's hand hold the part (contacts on it, pads pressing on it)? The part is the true one when there is ground
truth (the twin), else the plan's selection. The slots of an infeasible request are not executed: their records
say `failure="infeasible"` and why in `message`.

Among several objects on the table (`EpisodeSettings.among_others`, with `perceive`), the observation splits the
perceived points into instances and finds the requested one with the harness's detector on the camera images, the
object's name the prompt (`seggrasp.target`); only that instance's mesh is reconstructed. When the detector finds
it in none, nothing is planned: every slot of every request records `failure="not_found"`. Records say whether
the target was found and, with the twin's truth of the scene (`GroundTruth.scene`), the chosen instance's IoU
(`seggrasp.target.instance_iou`). Every grasp must keep the hand clear of the other instances' points, open along
its approach and closed (`Episode.clears_others`): one that would not is never sent to the cell and records
`failure="collision"`, as a real cell, whose planner knows only the table and the arm, needs.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Callable, NamedTuple, Protocol, Sequence

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from seggrasp.cell import Cell, GraspOutcome
from seggrasp.detect.base import Detector
from seggrasp.grasp import AntipodalSampler, GraspGenerator, GraspSet, select_per_prompt
from seggrasp.grasp.antipodal import AntipodalConfig
from seggrasp.grasp.clearance import clear_of
from seggrasp.grasp.feasibility import Feasibility, judge_requests
from seggrasp.grasp.footprint import PadFootprint, contact_faces
from seggrasp.grasp.select import TOP_K
from seggrasp.hands import Hand
from seggrasp.labels import prompt_index
from seggrasp.mesh import mesh_hash, prepare_mesh
from seggrasp.method import ORACLE, ObjectSegmenter, PartPlan, check_method
from seggrasp.objects import ObjectModel
from seggrasp.target import object_name
from seggrasp.truth import ORACLE_DETECTOR, DetectorSpec, GroundTruth

if TYPE_CHECKING:
    from seggrasp.perception import OrientedCloud
    from seggrasp.target import TargetSearch

LOG = logging.getLogger(__name__)
#: Slot planning looks this many times top-k deep into each prompt's ranked grasps for ones the arm reaches, and
#: at least `MIN_REACH_DEPTH` deep (a top-1 request still gets the best grasp among its 30 best the cell executes).
REACH_DEPTH = 3
MIN_REACH_DEPTH = 30


@dataclass
class Observation:
    """The mesh the episode plans on and its pose. A perceived mesh is already in the world (`T_world_obj` = I).
    Among several objects: the perceived `instances` and the `search` for the target among them; a target not
    found leaves `mesh` None."""

    mesh: trimesh.Trimesh | None
    T_world_obj: np.ndarray
    perceived: bool = False
    instances: list[OrientedCloud] = field(default_factory=list)
    search: TargetSearch | None = None

    @property
    def found(self) -> bool:
        """Whether there is a mesh to plan on (False only for a target not found among several objects)."""
        return self.mesh is not None


@dataclass
class EpisodeContext:
    """What the harness says about the object: its id, category, the prompts and the scene seed, and, when it
    knows them (the twin), the object's centre of mass (object frame) and mass for the grasp sampler. `name` is what
    the detector is asked for to find it among others on the table (None: its category's, "frying pan")."""

    object_id: str
    category: str
    prompts: list[str]
    scene_seed: int
    center_of_mass: np.ndarray | None = None
    mass: float | None = None
    name: str | None = None

    @property
    def object_name(self) -> str:
        """What a prompt calls the object (`name`, else its category's name: `seggrasp.target.object_name`)."""
        return self.name if self.name is not None else object_name(self.category)

    @classmethod
    def from_object(cls, model: ObjectModel, scene_seed: int, prompts: Sequence[str] | None = None) -> "EpisodeContext":
        """Context for a twin object (its own prompts unless given)."""
        prompts = list(prompts) if prompts is not None else list(model.prompts)
        return cls(model.object_id, model.category, prompts, scene_seed, model.center_of_mass, model.mass)


@dataclass(frozen=True)
class EpisodeSettings:
    """How an episode runs: the grasp-sampling and decomposition seed, grasps per prompt, whether the mesh is
    perceived from the cameras (inside `workspace`), and where/how decompositions are computed."""

    seed: int = 0
    top_k: int = TOP_K
    perceive: bool = False
    workspace: object | None = None  # seggrasp.perception.Workspace when perceiving
    among_others: bool = False  # the table holds other objects too: perceiving finds the target (seggrasp.target)
    decomposition_cache: str | None = None
    decomposition_workers: int | None = None
    decomposition_seed: int | None = None  # CoACD's seed (None: `seed`); a harness may keep it at the bundled one


class VoteStore(Protocol):
    """Where a harness keeps coarse votes between runs (e.g. `sim.evaluate.records.VoteCache`)."""

    def load(self, key: str, shape: tuple[int, int]) -> np.ndarray | None: ...

    def save(self, key: str, scores: np.ndarray) -> None: ...


class Slot(NamedTuple):
    """One trial slot: the `rank`-th grasp a method chose for prompt `prompt_index` (world frame; None when the
    method had fewer grasps on the part than slots) among `n_candidates`. `planned`: the grasp's contacts were
    planned (NaN ones touch nothing); False for a grasp given from outside, which has none to score.
    `feasibility`: the request's judgement (None: not judged); an infeasible request's slots have no grasp."""

    method: str
    detector: str
    prompt_index: int
    rank: int
    grasp: GraspSet | None
    n_candidates: int
    planned: bool = True
    feasibility: Feasibility | None = None


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
    failure: str = ""
    infeasible: bool | None = None  # the request was judged infeasible (None: not judged, e.g. a gym action)
    target_found: bool | None = None  # among several objects: the target was found (None: nothing to find)
    target_iou: float | None = None  # ...and the chosen instance's IoU against the twin's truth (None: unknown)
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


def observe(
    cell: Cell, perceive: bool = False, workspace=None, detector: Detector | None = None, name: str = ""
) -> Observation:
    """The object's mesh and pose from the cell, or, with `perceive`, a mesh fused from `cell.capture()`; with a
    `detector` too, the table holds several objects: the mesh of the instance the detector's boxes for `name`
    cover most (`seggrasp.target.find_target`), None when it boxes none."""
    if not perceive:
        if detector is not None:
            raise ValueError("finding the object among others needs perception (perceive=True)")
        mesh, T_world_obj = cell.object_mesh()
        return Observation(mesh, np.asarray(T_world_obj, dtype=np.float64))
    from seggrasp.perception import mesh_of, perceive_object, split_instances  # only episodes that perceive

    if detector is None:
        return Observation(perceive_object(cell.capture(), workspace), np.eye(4), perceived=True)
    from seggrasp.target import find_target

    search = find_target(split_instances(cell.capture(), workspace), detector, name)
    mesh = mesh_of(search.instances[search.index]) if search.found else None
    return Observation(mesh, np.eye(4), True, search.instances, search)


def grasp_key(T_world_grasp: np.ndarray, width: float) -> str:
    """Content key of a world grasp (for reusing outcomes of a deterministic backend)."""
    digest = hashlib.sha1(np.round(np.asarray(T_world_grasp, dtype=np.float64), 6).tobytes())
    digest.update(np.round(np.float64(width), 6).tobytes())
    return digest.hexdigest()


def plan_slots(
    plan: PartPlan, grasps: GraspSet, observation: Observation, n_prompts: int, targets: Sequence[int], top_k: int,
    reaches: Callable[[np.ndarray, float], bool] | None = None, footprint: PadFootprint = PadFootprint(),
) -> list[Slot]:
    """The top-k slots of each target prompt: the plan's own grasps (shapegrasp) or the grasps of `grasps` the plan
    ranks first (`rank_per_prompt`, with `footprint`, the cell's hand's); moved into the world. With `reaches`
    (world pose, width -> whether the cell would execute the grasp), the reachable grasps among the best
    `REACH_DEPTH` x top-k (at least `MIN_REACH_DEPTH`) come first, in rank order; unreachable ones fill the slots
    left."""
    depth = top_k if reaches is None else max(REACH_DEPTH * top_k, MIN_REACH_DEPTH)
    if plan.own_grasps is not None:
        per_prompt = [plan.own_grasps[k] for k in range(n_prompts)]
    else:
        per_prompt = [grasps.subset(chosen)
                      for chosen in rank_per_prompt(plan, grasps, observation.mesh, n_prompts, depth, footprint)]
    slots = []
    for k in targets:
        chosen = per_prompt[k].transformed(observation.T_world_obj)
        if plan.own_grasps is None:
            chosen = chosen.subset(_reachable_first(chosen, reaches, top_k))
        for rank in range(top_k):
            if plan.own_grasps is not None and len(chosen):
                # shapegrasp plans one grasp per part: every slot executes it again, as repeated trials
                grasp = chosen.subset([rank % len(chosen)])
            else:  # fewer grasps on the part than slots: the missing ones count as failures
                grasp = chosen.subset([rank]) if rank < len(chosen) else None
            slots.append(Slot(plan.method, plan.detector, k, rank, grasp, len(chosen)))
    return slots


def rank_per_prompt(
    plan: PartPlan, grasps: GraspSet, mesh: trimesh.Trimesh, n_prompts: int, depth: int, footprint: PadFootprint,
) -> list[np.ndarray]:
    """Per prompt, the indices of the `depth` grasps of `grasps` (object frame, on `mesh`) the plan ranks first: its
    policy's most probably on the part (those whose pads land only on their ends last), or `select_per_prompt`'s
    on the faces the plan selects on, those whose pads hold them first."""
    if plan.policy is None:
        return select_per_prompt(grasps, mesh, plan.selection_labels, n_prompts, depth, footprint)
    chosen_per_prompt = plan.policy.select(grasps, mesh, plan.face_probabilities, depth)
    if footprint.gripper.pad_end_margin > 0:  # those whose pads land only on their ends go last
        surface = footprint.on(mesh)
        chosen_per_prompt = [chosen[np.argsort(~surface.lands_on_pads(grasps.subset(chosen)), kind="stable")]
                             for chosen in chosen_per_prompt]
    return chosen_per_prompt


def _reachable_first(grasps: GraspSet, reaches: Callable[[np.ndarray, float], bool] | None, top_k: int) -> np.ndarray:
    """Indices of the first `top_k` grasps (rank order) that `reaches` accepts, then of the first ones it refuses
    to fill up to `top_k`; only as many are checked as it takes (all first top-k without `reaches`)."""
    if reaches is None:
        return np.arange(min(top_k, len(grasps)))
    reachable: list[int] = []
    unreachable: list[int] = []
    for i in range(len(grasps)):
        if len(reachable) == top_k:
            break
        (reachable if reaches(grasps.poses[i], float(grasps.widths[i])) else unreachable).append(i)
    return np.asarray((reachable + unreachable)[:top_k], dtype=np.int64)


def failure_of(outcome: GraspOutcome | None, success: bool | None, on_part: bool | None) -> str:
    """The failure name of a trial (`seggrasp.cell.FAILURES`): `no_grasp` without an outcome, the cell's own
    failure, `wrong_part` for a lift on another part than the prompted one; "" for a success or when unknown."""
    if outcome is None:
        return "no_grasp"
    if outcome.failure:
        return outcome.failure
    if outcome.lifted and on_part is False and not success:
        return "wrong_part"
    return ""


class Episode:
    """One object in one scene: observe once, plan per method, execute slots; every backend runs this.

    `outcome_cache` (a dict) lets a deterministic backend reuse the outcome of an identical grasp from the same
    scene (pass None on real hardware); `vote_cache` keeps coarse votes under `votes_key()` (the planning mesh,
    the prompts in order and the detector), so a later run on the same input skips rendering and detection.
    """

    def __init__(
        self,
        cell: Cell,
        context: EpisodeContext,
        detector: DetectorSpec | None = None,
        truth: GroundTruth | None = None,
        settings: EpisodeSettings = EpisodeSettings(),
        *,
        generator: GraspGenerator | None = None,
        vote_cache: VoteStore | None = None,
        outcome_cache: dict | None = None,
    ) -> None:
        self.cell, self.context, self.detector, self.truth, self.settings = cell, context, detector, truth, settings
        self.hand: Hand = cell.hand
        self.generator = generator or AntipodalSampler(gripper=self.hand)
        self.footprint = PadFootprint(gripper=self.hand)
        self.vote_cache = vote_cache
        self.outcome_cache = outcome_cache
        self._observation: Observation | None = None
        #: the IoU of the instance chosen as the target against the twin's truth (`seggrasp.target.instance_iou`),
        #: set on observing; None when nothing was searched, the target was not found or the scene has no truth
        self.target_iou: float | None = None
        self._truth_on_mesh: np.ndarray | None = None
        self._segmenter: ObjectSegmenter | None = None
        self._grasps: GraspSet | None = None
        # `part_grasps` per part (its faces, packed): its first draw, and all its draws
        self._first_part_draw: dict[bytes, GraspSet] = {}
        self._part_grasps: dict[bytes, GraspSet] = {}
        self._true_feasibility: dict[int, Feasibility] = {}
        self._reach: dict[str, bool] = {}
        self._others: np.ndarray | None = None  # the other objects' perceived points (world), among others
        self._clears: dict[str, bool] = {}  # `clears_others` per grasp key
        self._scene_fresh = False  # the cell's scene is as `reset` left it (no grasp executed since)

    @property
    def observation(self) -> Observation:
        """The planning mesh (the scene is reset and observed on first use)."""
        if self._observation is None:
            self._reset_scene()
            s = self.settings
            self._observation = o = observe(self.cell, s.perceive, s.workspace, self._object_detector(),
                                            self.context.object_name)
            if self.truth is not None and o.found:
                self._truth_on_mesh = self.truth.on_mesh(o.mesh, o.T_world_obj, o.perceived, self.context.object_id)
                if o.search is not None and self.truth.scene is not None:
                    from seggrasp.target import instance_iou

                    self.target_iou = instance_iou(o.instances, o.search.index, self.truth.scene().target)
        return self._observation

    def _object_detector(self) -> Detector | None:
        """The detector that finds the object among others on the camera images (None: the object is alone, or
        the episode does not perceive)."""
        if not (self.settings.perceive and self.settings.among_others):
            return None
        if self.detector is None:
            raise ValueError("finding the object among others needs a detector; this episode was given none")
        scene = self.truth.scene() if self.truth is not None and self.truth.scene is not None else None
        return self.detector.for_scene(scene)

    @property
    def truth_on_mesh(self) -> np.ndarray | None:
        """True prompt index per face of the planning mesh (None without ground truth)."""
        _ = self.observation
        return self._truth_on_mesh

    @property
    def segmenter(self) -> ObjectSegmenter:
        """The method's segmenter on the planning mesh; the detector is built only when votes must be computed."""
        if self._segmenter is None:
            if self.detector is None:
                raise ValueError("this episode was given no detector: it can execute grasps but not segment")
            mesh = self.observation.mesh
            prepared = prepare_mesh(mesh.vertices, mesh.faces, name="object")
            shape = (len(mesh.faces), len(self.context.prompts))
            coarse = self.vote_cache.load(self.votes_key(), shape) if self.vote_cache is not None else None
            detector = None
            if coarse is None:
                detector = self.detector.for_mesh(self.context.prompts, prepared, self.truth_on_mesh)
            self._segmenter = ObjectSegmenter(
                mesh, self.context.prompts, detector, self.detector.label, seed=self._decomposition_seed(),
                view_seed=self.detector.seed, prepared=prepared, coarse_scores=coarse, hand=self.hand,
                decomposition_cache=self.settings.decomposition_cache,
                decomposition_workers=self.settings.decomposition_workers,
            )
        return self._segmenter

    def _decomposition_seed(self) -> int:
        seed = self.settings.decomposition_seed
        return self.settings.seed if seed is None else seed

    def votes_key(self) -> str:
        """Content key of the coarse votes: planning mesh, prompts in order, detector settings."""
        payload = {"mesh": mesh_hash(self.observation.mesh), "prompts": list(self.context.prompts),
                   "detector": dict(asdict(self.detector), kind=type(self.detector).__name__)}
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode("utf-8")).hexdigest()

    def coarse_scores(self) -> np.ndarray:
        """The coarse votes on the planning mesh (computed once; stored in the vote cache when there is one)."""
        computed_now = not self.segmenter.has_coarse_scores
        scores = self.segmenter.coarse_scores()
        if computed_now and self.vote_cache is not None:
            self.vote_cache.save(self.votes_key(), scores)
        return scores

    def plan(self, method: str) -> PartPlan:
        """`method`'s labels on the planning mesh (`oracle`: the ground truth's)."""
        check_method(method)
        if method == ORACLE:
            if self.truth is None:
                raise ValueError("the oracle method needs ground-truth labels; this object has none")
            return self.truth.oracle_plan(self.truth_on_mesh)
        self.coarse_scores()
        return self.segmenter.plan(method, self.observation.T_world_obj)

    def grasps(self) -> GraspSet:
        """Grasp candidates on the planning mesh, object frame (sampled once)."""
        if self._grasps is None:
            self._grasps = self._generate()
        return self._grasps

    def _generate(self, seed: int | None = None, **part) -> GraspSet:
        """The generator's grasps on the planning mesh with `seed` (default: the episode's), its table and mass
        (`part`: the sampler's `on_faces`)."""
        o = self.observation
        plane = table_plane_in_object_frame(o.mesh, o.T_world_obj)
        com, mass = self._weight()
        seed = self.settings.seed if seed is None else seed
        return self.generator.generate(o.mesh, seed=seed, table_plane=plane, center_of_mass=com, mass=mass, **part)

    def _weight(self) -> tuple[np.ndarray | None, float | None]:
        """The object's centre of mass (planning mesh's frame) and mass as planning knows them. The context's centre
        of mass is in the twin's object frame; a perceived mesh lives in the world, so there both are None and the
        planner estimates them (the antipodal sampler: uniform density, as on the real cell)."""
        return (None, None) if self.observation.perceived else (self.context.center_of_mass, self.context.mass)

    def planning_grasps(self, plan: PartPlan, prompts: Sequence[int]) -> GraspSet:
        """The episode's candidates (`grasps`) and, for each prompt in `prompts` whose part (the faces the plan
        selects on) fewer of the plan's top-k of them hold (`rank_per_prompt`, `PadSurface.holds`) than top-k,
        the candidates `part_grasps` samples on that part; only an `AntipodalSampler` samples on a part."""
        grasps = self.grasps()
        if not prompts or not isinstance(self.generator, AntipodalSampler):
            return grasps
        mesh, top_k = self.observation.mesh, self.settings.top_k
        labels = np.asarray(plan.selection_labels)
        chosen = rank_per_prompt(plan, grasps, mesh, len(self.context.prompts), top_k, self.footprint)
        surface = self.footprint.on(mesh)
        more = []
        for k in prompts:
            is_part = labels == k
            if is_part.any() and surface.holds(grasps.subset(chosen[k]), is_part).sum() < top_k:
                more.append(self.part_grasps(is_part))
        return GraspSet.concatenate([grasps, *more])

    def part_grasps(self, is_part: np.ndarray, fill: bool = True) -> GraspSet:
        """Candidates whose first contact is drawn on or next to the faces `is_part` marks (`AntipodalSampler`'s
        `on_faces`; object frame; each draw made once per part): the draw with the episode's seed, and with `fill`
        the draws with seeds derived from it that follow until top-k of them hold the part (`PadSurface.holds`) or
        `AntipodalConfig.part_draw_rounds` draws are in. The plan fills its slots from all of them; the feasibility
        judgement reads the first only, because more draws turn up lone holds the plan does not rank first (the
        UR5's gooseneck kettle body, held only across its top)."""
        key = np.packbits(is_part).tobytes()
        if key not in self._first_part_draw:
            self._first_part_draw[key] = self._generate(on_faces=is_part)
        if not fill:
            return self._first_part_draw[key]
        if key not in self._part_grasps:
            mesh, surface = self.observation.mesh, self.footprint.on(self.observation.mesh)

            def holding(grasps: GraspSet) -> int:  # those with both contacts on the part whose pads hold it
                on_part = grasps.subset(np.flatnonzero(is_part[contact_faces(grasps, mesh)].all(axis=1)))
                return int(surface.holds(on_part, is_part).sum())

            draws = [self._first_part_draw[key]]
            held = holding(draws[0])
            for draw in range(1, self.generator.config.part_draw_rounds):
                if held >= self.settings.top_k:
                    break
                seed = int(np.random.SeedSequence([self.settings.seed, draw]).generate_state(1)[0])
                draws.append(self._generate(seed, on_faces=is_part))
                held += holding(draws[-1])
            self._part_grasps[key] = GraspSet.concatenate(draws)
        return self._part_grasps[key]

    def target_indices(self, targets: Sequence[str] | None) -> list[int]:
        """Prompt indices of `targets` (default: every prompt)."""
        if targets is None:
            return list(range(len(self.context.prompts)))
        return [prompt_index(self.context.prompts, t, "prompts") for t in targets]

    def slots(self, plan: PartPlan, targets: Sequence[str] | None = None) -> list[Slot]:
        """The plan's top-k slots for each target prompt; those of a request `feasibility` judges infeasible have
        no grasp (and no candidates) and carry the judgement."""
        indices = self.target_indices(targets)
        judged = self.feasibility(plan, indices)
        feasible = [k for k in indices if judged[k].feasible]
        grasps = GraspSet.empty() if plan.own_grasps is not None else \
            self.planning_grasps(plan, feasible)
        planned = plan_slots(plan, grasps, self.observation, len(self.context.prompts), feasible, self.settings.top_k,
                             self.reaches, self.footprint)
        slots = []
        for k in indices:
            if judged[k].feasible:
                slots += [s._replace(feasibility=judged[k]) for s in planned if s.prompt_index == k]
            else:
                slots += [Slot(plan.method, plan.detector, k, rank, None, 0, feasibility=judged[k])
                          for rank in range(self.settings.top_k)]
        return slots

    def feasibility(self, plan: PartPlan, indices: Sequence[int]) -> dict[int, Feasibility]:
        """Per prompt index, whether the cell's hand can hold the part with one of the episode's grasp candidates
        (`seggrasp.grasp.feasibility`) or, where none of them does, with one of those drawn on the part itself
        (`part_grasps`' first draw, which the plan then tops up with): the true part when there is ground truth
        (judged once per prompt), else the part `plan` selects grasps on."""
        o = self.observation
        plane = table_plane_in_object_frame(o.mesh, o.T_world_obj)
        config = self.generator.config if isinstance(self.generator, AntipodalSampler) else \
            AntipodalConfig.for_hand(self.hand)

        com, mass = self._weight()

        def judge_on(requests: list[int], labels: np.ndarray, grasps: GraspSet) -> dict[int, Feasibility]:
            return judge_requests(requests, self.context.prompts, self.hand, config, o.mesh, labels, grasps,
                                  self.footprint, plane, com, mass)

        def judge(requests: list[int], labels: np.ndarray) -> dict[int, Feasibility]:
            judged = judge_on(requests, labels, self.grasps()) if requests else {}
            if isinstance(self.generator, AntipodalSampler):
                for k in [k for k in requests if not judged[k].feasible and (labels == k).any()]:
                    drawn = GraspSet.concatenate([self.grasps(), self.part_grasps(labels == k, fill=False)])
                    judged[k] = judge_on([k], labels, drawn)[k]
            return judged

        if self.truth_on_mesh is None:
            return judge(list(indices), np.asarray(plan.selection_labels))
        missing = [k for k in dict.fromkeys(indices) if k not in self._true_feasibility]
        self._true_feasibility.update(judge(missing, self.truth_on_mesh))
        return {k: self._true_feasibility[k] for k in indices}

    def clears_others(self, T_world_grasp: np.ndarray, width: float) -> bool:
        """Whether the grasp keeps the hand clear of the other objects the cameras saw on the table (True when the
        object was not searched for among others, or nothing was observed: a grasp given from outside;
        `seggrasp.grasp.clearance.clear_of`)."""
        o = self._observation
        if o is None or o.search is None or not o.found:
            return True
        if self._others is None:
            others = [instance.points for index, instance in enumerate(o.instances) if index != o.search.index]
            self._others = np.concatenate(others) if others else np.zeros((0, 3))
        key = grasp_key(T_world_grasp, width)
        if key not in self._clears:
            self._clears[key] = clear_of(self.hand, T_world_grasp, width, self._others)
        return self._clears[key]

    def reaches(self, T_world_grasp: np.ndarray, width: float) -> bool:
        """Whether the grasp keeps clear of the other objects seen (`clears_others`) and the cell would execute it
        (`Cell.check_reach`); remembered per grasp. A cell that models the scene checks it as a slot's execution
        will find it: reset first if a grasp was executed since."""
        key = grasp_key(T_world_grasp, width)
        if key not in self._reach:
            if not self.clears_others(T_world_grasp, width):
                LOG.debug("grasp refused: it would hit another object on the table")
                self._reach[key] = False
                return False
            if self.cell.models_scene and not self._scene_fresh:
                self._reset_scene()
            reason = self.cell.check_reach(T_world_grasp, width)
            if reason:
                LOG.debug("grasp the cell would refuse: %s", reason)
            self._reach[key] = not reason
        return self._reach[key]

    def run(
        self,
        method: str,
        targets: Sequence[str] | None = None,
        skip: Callable[[Slot], bool] | None = None,
        on_record: Callable[[TrialRecord], None] | None = None,
        on_plan: Callable[[PartPlan], None] | None = None,
        before: Callable[[Slot], None] | None = None,
    ) -> list[TrialRecord]:
        """Plan `method` and execute its slots for each target prompt (those `skip` accepts are left out). Hooks:
        `on_plan` sees the plan before any slot, `before` each slot about to be executed, `on_record` its record."""
        if self.observation.found:
            plan = self.plan(method)
            if on_plan is not None:
                on_plan(plan)
            slots = self.slots(plan, targets)
        else:  # the target is not among the instances: nothing to plan on
            detector = ORACLE_DETECTOR if method == ORACLE else self.detector.label
            slots = [Slot(method, detector, k, rank, None, 0) for k in self.target_indices(targets)
                     for rank in range(self.settings.top_k)]
        records = []
        for slot in slots:
            if skip is not None and skip(slot):
                continue
            if before is not None:
                before(slot)
            record = self.execute(slot)
            records.append(record)
            if on_record is not None:
                on_record(record)
        return records

    def moves_cell(self, slot: Slot) -> bool:
        """Whether executing `slot` moves the cell: it has a grasp whose outcome `outcome_cache` does not hold."""
        if slot.grasp is None:
            return False
        key = grasp_key(slot.grasp.poses[0], float(slot.grasp.widths[0]))
        return self.outcome_cache is None or key not in self.outcome_cache

    def execute(self, slot: Slot, reset: bool = True) -> TrialRecord:
        """Execute one slot's grasp and score it. The scene is reset first unless `reset` is False, or the cell does
        not model the scene (`Cell.models_scene`) and nothing was executed since its last reset."""
        context = self.context
        record = TrialRecord(
            object_id=context.object_id, category=context.category, method=slot.method, detector=slot.detector,
            prompt=context.prompts[slot.prompt_index], prompt_index=slot.prompt_index, rank=slot.rank,
            seed=self.settings.seed, scene_seed=context.scene_seed, n_candidates=slot.n_candidates, executed=False,
        )
        o = self._observation  # None for a grasp given from outside (a gym action) before anything was observed
        if o is not None and o.search is not None:
            record.target_found, record.target_iou = o.search.found, self.target_iou
        if o is not None and not o.found:
            record.contacts_on_part = False if self.truth is not None else None
            record.success = False if self.truth is not None else None
            record.message = f"the detector found the {context.object_name} in none of the " \
                             f"{len(o.instances)} objects on the table"
            record.failure = "not_found"
            return record
        if slot.feasibility is not None:
            record.infeasible = not slot.feasibility.feasible
        if record.infeasible:
            record.contacts_on_part = False if self.truth is not None else None
            record.success = False
            record.message = slot.feasibility.reason
            record.failure = "infeasible"
            return record
        if slot.grasp is None:
            record.contacts_on_part = record.success = False if self.truth is not None else None
            record.message = "no grasp on the selected part"
            record.failure = failure_of(None, None, None)
            return record
        T_world_grasp, width = slot.grasp.poses[0], float(slot.grasp.widths[0])
        score = float(slot.grasp.scores[0])
        record.grasp_score = score if np.isfinite(score) else None
        record.width = width
        record.T_world_grasp = np.round(T_world_grasp, 6).tolist()
        record.quaternion_xyzw = Rotation.from_matrix(T_world_grasp[:3, :3]).as_quat().tolist()
        record.contacts_on_part = self.contacts_on_part(slot)
        outcome = self._outcome(T_world_grasp, width, reset, record)
        record.executed = True
        record.reachable = bool(outcome.reachable)
        record.lifted = bool(outcome.lifted)
        record.lift_height = float(outcome.lift_height)
        record.outcome = outcome.to_json()
        record.message = outcome.message
        on_part = None
        if self.truth is not None:
            record.touched_on_part = self.truth.touched_on_part(outcome, slot.prompt_index)
            on_part = record.touched_on_part if record.touched_on_part is not None else record.contacts_on_part
            record.success = bool(outcome.lifted and on_part)
        record.failure = failure_of(outcome, record.success, on_part)
        return record

    def _reset_scene(self) -> None:
        self.cell.reset(seed=self.context.scene_seed, object_id=self.context.object_id)
        self._scene_fresh = True

    def contacts_on_part(self, slot: Slot) -> bool | None:
        """Part Sel. of a slot from its planned contacts, without executing it: False for a slot without a grasp
        or whose grasp's pads touch nothing (non-finite contacts); None without ground truth or for a grasp given
        from outside (no planned contacts)."""
        if self.truth is None or not slot.planned:
            return None
        if slot.grasp is None:
            return False
        o = self.observation
        return self.truth.contacts_on_part(slot.grasp.contacts[0], o.T_world_obj, o.perceived, slot.prompt_index)

    def _outcome(self, T_world_grasp: np.ndarray, width: float, reset: bool, record: TrialRecord) -> GraspOutcome:
        if not self.clears_others(T_world_grasp, width):  # what a real cell's planner does not know of
            return GraspOutcome(reachable=False, lifted=False, lift_height=0.0, contacts_observed=False,
                                message="refused: the hand would hit another object the cameras saw on the table",
                                failure="collision")
        key = grasp_key(T_world_grasp, width)
        if self.outcome_cache is not None and key in self.outcome_cache:
            record.reused_outcome = True
            return self.outcome_cache[key]
        if reset and (self.cell.models_scene or not self._scene_fresh):
            self._reset_scene()
        self._scene_fresh = False
        outcome = self.cell.execute(T_world_grasp, width)
        if self.outcome_cache is not None:
            self.outcome_cache[key] = outcome
        return outcome


def action_slot(prompt_index: int, T_world_grasp: np.ndarray, width: float, method: str = "action") -> Slot:
    """A slot for a grasp given from outside (the gym env's action): no planned contacts, no score."""
    grasp = GraspSet(np.asarray(T_world_grasp, dtype=np.float64)[None], [width], [np.nan], np.full((1, 2, 3), np.nan))
    return Slot(method, "policy", prompt_index, 0, grasp, 1, planned=False)
