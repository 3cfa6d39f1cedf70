"""The settings of one evaluation run (`RunConfig`) and the choices the command line offers."""

from __future__ import annotations

import functools
import zlib
from dataclasses import dataclass, field, replace

from seggrasp.grasp.select import TOP_K
from seggrasp.hands import ROBOTIQ_2F85, Hand
from seggrasp.truth import REAL_DETECTORS, DetectorSpec, parse_detector
from sim.evaluate.emulated import twin_objects

DEFAULT_METHODS = ("seggrasp", "coarse", "multi", "opt", "geofusion", "anchored", "oracle", "shapegrasp")
QUICK_METHODS = ("oracle", "seggrasp", "coarse")
QUICK_CATEGORIES = ("mug", "knife", "hammer")  # --quick: the first twin object of each
QUICK_TOP_K = 3
#: The most grasps a run executes per prompt: ten times the paper's top-10. Deeper slots are mostly empty (a part
#: rarely has that many distinct grasps) and every slot is a record: --top-k 100000 wrote 57 MB of them in 150 s.
MAX_TOP_K = 100
#: The most run seeds one run takes (each seed is a full pass over the objects: 1000 seeds of the full twin are
#: weeks on a 2-core machine).
MAX_SEEDS = 1000
#: The robot system (`sim.cell.ROBOTS`) a run evaluates unless told: the quick CI profile's, and the real cell's (a
#: UR5 with a 2F-85).
DEFAULT_ROBOT = "ur5"
#: Settings a resumed run must share with the run it continues (methods, objects, seeds and robots are merged).
RESUME_KEYS = ("detector", "weights", "embodiment", "decomposition_seed", "top_k", "backend", "perceive", "prompts",
               "grip_force", "twin_gripper", "dry_run", "scene", "objects_per_scene")
#: Objects on the table in a scene (`--scene`) unless `--objects-per-scene` says.
DEFAULT_OBJECTS_PER_SCENE = 4
#: The twin's gripper model (`sim.gripper`): "slides", the fingertips on force-limited slides traced from the
#: 2F-85's linkage; runs before it simulated "linkage", the linkage's revolute joints. A run resumes only on the
#: model it started with.
TWIN_GRIPPER = "slides"
#: CoACD's seed in every run: the one the bundled decompositions (assets/decompositions) were computed with. A cold
#: decomposition sweep of the twin takes about a minute per object on a 2-core machine, so redrawing it per run seed
#: would make a multi-seed run cold; the run seeds redraw the detector's errors, the scene poses and the grasps.
DECOMPOSITION_SEED = 0


@dataclass
class RunConfig:
    """Everything that defines one evaluation run."""

    methods: list[str]
    objects: list[str]
    detector: str = "typical"
    weights: str | None = None
    embodiment: str = "floating"
    seeds: list[int] = field(default_factory=lambda: [0])
    decomposition_seed: int = DECOMPOSITION_SEED
    top_k: int = TOP_K
    backend: str = "sim"
    config: str | None = None
    perceive: bool = False
    dry_run: bool = False
    quick: bool = False
    prompts: list[str] = field(default_factory=list)
    record: int = 0  # picture strips of the first `record` executed slots per method and object (twin only)
    # N: the twin gripper's force and the sampler's torsion limit (twin only); None: each hand's default
    grip_force: float | None = None
    twin_gripper: str = TWIN_GRIPPER  # the twin's gripper model ("" on the real cell)
    robots: list[str] = field(default_factory=lambda: [DEFAULT_ROBOT])
    # "packed" or "pile": each object among others (`sim.scenes`), objects_per_scene in all (twin and emulated cell;
    # a real cell's operator lays out its table: None)
    scene: str | None = None
    objects_per_scene: int | None = None

    @property
    def uses_torch(self) -> bool:
        """Whether the run's detector is a torch model (a simulated one is not)."""
        return self.detector in REAL_DETECTORS

    @property
    def detector_label(self) -> str:
        """How the run's records name its detector (e.g. `simulated:typical`)."""
        return replace(self, seeds=[0]).detector_spec().label

    @property
    def seed(self) -> int:
        """The seed of a one-seed config (see `at_seed`)."""
        if len(self.seeds) != 1:
            raise ValueError(f"this run has seeds {self.seeds}; take one with at_seed(seed)")
        return self.seeds[0]

    def at_seed(self, seed: int) -> "RunConfig":
        """The same run with the one seed `seed` (what a task of one (object, seed) pair runs)."""
        return replace(self, seeds=[int(seed)])

    @property
    def robot(self) -> str:
        """The robot of a one-robot config (see `at_robot`)."""
        if len(self.robots) != 1:
            raise ValueError(f"this run has robots {self.robots}; take one with at_robot(robot)")
        return self.robots[0]

    def at_robot(self, robot: str) -> "RunConfig":
        """The same run on the one robot system `robot`."""
        return replace(self, robots=[robot])

    @property
    def hand(self) -> Hand:
        """The hand of a one-robot config: the twin's (`sim.cell.ROBOTS`) or the real cell's 2F-85."""
        if self.backend == "sim":
            from sim.cell import ROBOTS

            return ROBOTS[self.robot]
        return ROBOTIQ_2F85

    @property
    def hand_grip_force(self) -> float:
        """The grip force of a one-robot config: `grip_force`, or its hand's default."""
        return self.hand.default_grip_force if self.grip_force is None else self.grip_force

    def detector_spec(self) -> DetectorSpec:
        """The run's detector (seeded with the run seed)."""
        return parse_detector(self.detector, self.weights, self.seed)

    def object_detector(self, object_id: str) -> DetectorSpec:
        """The detector of one object: seeded with the object's scene seed.

        With one shared seed every object would see the same draws of the detector's error model (e.g. the same
        prompt boxed as the whole object in the same view), so a whole run would be one correlated sample.
        """
        return replace(self.detector_spec(), seed=scene_seed_of(object_id, self.seed))


def prompts_of(config: RunConfig, object_id: str) -> list[str]:
    """The prompts a run asks of an object: the run's `--prompts`, else the twin object's own."""
    if config.prompts or not twin_objects(config):
        return list(config.prompts)
    return list(_twin_prompts(object_id))


@functools.lru_cache(maxsize=None)
def _twin_prompts(object_id: str) -> tuple[str, ...]:
    """The twin object's own prompts (loaded once per process, not once per seed)."""
    from seggrasp.objects import load_asset

    return tuple(load_asset(object_id).prompts)


def scene_seed_of(object_id: str, seed: int) -> int:
    """The scene (object pose) seed of an object: fixed for a run seed, different between objects."""
    return int(seed) * 100_003 + zlib.crc32(object_id.encode("utf-8")) % 100_000
