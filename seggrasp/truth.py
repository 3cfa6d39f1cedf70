"""What a harness (the benchmark, the gym env, a lab script) hands an episode besides the cell: the detector it
chose and, for a labelled object, the ground truth that scores the trials. The method itself never sees either
ground truth or how its detector was made.

The detectors' one registry is here: `SIMULATED_PRESETS`, `REAL_DETECTORS` and `parse_detector`, which every command
line uses to read a detector's name into a `DetectorSpec`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import trimesh

from seggrasp.cell import GraspOutcome
from seggrasp.detect import HF_MODELS, make_detector
from seggrasp.detect.base import Detector
from seggrasp.detect.simulated import PRESETS
from seggrasp.labels import PartLabels
from seggrasp.mesh import PreparedMesh
from seggrasp.method import PartPlan
from seggrasp.objects import ObjectModel

#: The simulated detector's presets (the numbers of its error model: `seggrasp.detect.simulated.PRESETS`).
SIMULATED_PRESETS = tuple(PRESETS)
#: The real (transformers) detectors; they need weights.
REAL_DETECTORS = tuple(HF_MODELS)
#: How the oracle's records name their "detector": its labels are the ground truth's.
ORACLE_DETECTOR = "ground-truth"
#: `transfer_labels`: surface samples of the source mesh, the distance (m) within which a face centre takes its
#: exactly nearest source face, and how many centres one exact query takes.
TRANSFER_SAMPLES = 20000
TRANSFER_EXACT = 0.01
TRANSFER_CHUNK = 256


@dataclass(frozen=True)
class DetectorSpec:
    """Which detector a harness chose: `name` as `make_detector` takes it; `preset` for the simulated detector (which
    boxes parts from ground truth), `weights` for the real ones. `seed`, the detector seed, draws the simulated
    detector's errors and turns the rendered views' camera rig (docs/design.md section 9)."""

    name: str = "simulated"
    preset: str = "typical"
    weights: str | None = None
    seed: int = 0

    @property
    def label(self) -> str:
        """How results name the detector, e.g. `simulated:typical` or `owlv2`."""
        return f"{self.name}:{self.preset}" if self.name == "simulated" else self.name

    @property
    def needs_truth(self) -> bool:
        return self.name == "simulated"

    def build(self, gt_labels: PartLabels | None) -> Detector:
        """The detector; `gt_labels` (one per face of the rendered working mesh) is required for `simulated`."""
        if self.needs_truth and gt_labels is None:
            raise ValueError("the simulated detector needs ground-truth labels; this object has none")
        return make_detector(self.name, weights=self.weights, gt_labels=gt_labels, preset=self.preset, seed=self.seed)

    def for_scene(self, scene: SceneTruth | None) -> Detector:
        """The detector for the cameras' images of a scene; the simulated one boxes the bodies `scene` names
        (`seggrasp.detect.simulated.SimulatedObjectDetector`, this spec's preset and seed)."""
        if not self.needs_truth:
            return make_detector(self.name, weights=self.weights)
        if scene is None:
            raise ValueError("the simulated detector finds objects in camera images from the twin's truth; this "
                             "cell gives none")
        from seggrasp.detect.simulated import SimulatedObjectDetector

        return SimulatedObjectDetector(scene.names, preset=self.preset, seed=self.seed)

    def for_mesh(self, prompts: Sequence[str], rendered: PreparedMesh, truth_on_source: np.ndarray | None) -> Detector:
        """The detector for views of `rendered`, given the true prompt label of each of its source faces."""
        gt = None
        if truth_on_source is not None:
            gt = PartLabels(list(prompts), rendered.from_source(np.asarray(truth_on_source, dtype=np.int64)))
        return self.build(gt)


def parse_detector(text: str, weights: str | None = None, seed: int = 0) -> DetectorSpec:
    """The detector named `text`: `simulated:PRESET` (how records name it, `DetectorSpec.label`), a bare PRESET,
    `simulated` (the default preset) or a real detector, which needs `weights`. ValueError names the problem."""
    name, colon, preset = text.strip().partition(":")
    if name in SIMULATED_PRESETS and not colon:
        name, colon, preset = "simulated", ":", name
    known = [*SIMULATED_PRESETS, *(f"simulated:{p}" for p in SIMULATED_PRESETS), *REAL_DETECTORS]
    if name == "simulated":
        preset = preset if colon else DetectorSpec.preset
        if preset not in SIMULATED_PRESETS:
            raise ValueError(f"unknown simulated-detector preset {preset!r} in {text!r}; use one of {known}")
        if weights:
            raise ValueError(f"the simulated detector {text!r} takes no weights (drop --weights {weights})")
        return DetectorSpec("simulated", preset=preset, seed=seed)
    if name not in REAL_DETECTORS or colon:
        raise ValueError(f"unknown detector {text!r}; use one of {known}")
    if not weights:
        raise ValueError(f"detector {name} needs weights (--weights: a local weights folder or a hub id)")
    return DetectorSpec(name, weights=str(weights), seed=seed)


@dataclass(frozen=True)
class SceneTruth:
    """What the twin knows of the objects on its table: the requested object's body and the name a prompt gives
    each body (`seggrasp.target.object_name`), by the body ids of `Frame.instance_ids`."""

    target: int
    names: dict[int, str]

    def __post_init__(self) -> None:
        if self.target not in self.names:
            raise ValueError(f"the target body {self.target} is not among the named bodies {sorted(self.names)}")


@dataclass
class GroundTruth:
    """The labelled mesh of an object (object frame) with the prompt index of each face (-1 elsewhere).

    `true_pose` returns the labelled object's pose in the world; only a simulator knows it, and it is needed only
    to score a mesh the episode perceived from cameras (which lives in the world frame). `scene`, in a scene of
    several objects in the twin, returns which body is which (`SceneTruth`), for the simulated object detector and
    for scoring the instance chosen as the target.
    """

    mesh: trimesh.Trimesh
    labels: np.ndarray
    true_pose: Callable[[], np.ndarray] | None = None
    scene: Callable[[], SceneTruth] | None = None

    @classmethod
    def of_object(
        cls, model: ObjectModel, prompts: Sequence[str], true_pose: Callable[[], np.ndarray] | None = None,
        scene: Callable[[], SceneTruth] | None = None,
    ) -> "GroundTruth | None":
        """Ground truth of a twin object for `prompts` (None when the object has no labels)."""
        if model.labels is None:
            return None
        return cls(model.mesh, model.labels.remap_to(list(prompts)), true_pose, scene)

    def _T_truth_world(self, T_world_obj: np.ndarray, perceived: bool) -> np.ndarray:
        if not perceived:
            return np.linalg.inv(T_world_obj)
        if self.true_pose is None:
            raise ValueError("scoring a perceived mesh needs the labelled object's true pose (a simulator)")
        return np.linalg.inv(np.asarray(self.true_pose(), dtype=np.float64))

    def on_mesh(self, mesh: trimesh.Trimesh, T_world_obj: np.ndarray, perceived: bool, name: str) -> np.ndarray:
        """Prompt labels per face of the planning mesh (transferred from the labelled mesh when it was perceived)."""
        if not perceived:
            if len(mesh.faces) != len(self.labels):
                raise ValueError(f"{name}: the cell's mesh has {len(mesh.faces)} faces but the labels {len(self.labels)}")
            return self.labels
        # a perceived mesh lives in the world frame (its T_world_obj is the identity)
        return transfer_labels(self.mesh, self.labels, mesh, self._T_truth_world(T_world_obj, perceived))

    def contacts_on_part(self, contacts_world: np.ndarray, T_world_obj: np.ndarray, perceived: bool, k: int) -> bool:
        """Whether both planned finger contacts (world frame, (2, 3)) lie nearest to faces of prompt `k`. A
        non-finite contact is a pad that touches nothing: such a grasp is not on the part."""
        contacts = np.asarray(contacts_world, dtype=np.float64).reshape(2, 3)
        if not np.isfinite(contacts).all():
            return False
        T = self._T_truth_world(T_world_obj, perceived)
        contacts = contacts @ T[:3, :3].T + T[:3, 3]
        _, _, nearest = trimesh.proximity.closest_point(self.mesh, contacts)
        return bool((self.labels[np.asarray(nearest, dtype=np.int64)] == k).all())

    def touched_on_part(self, outcome: GraspOutcome, k: int) -> bool | None:
        """Whether prompt `k`'s true part carries most of what the pads touched (None if contacts are unobserved).

        Each touched face counts with its `touched_weights` entry (contact force or area) when the cell reports
        them, else with weight one.
        """
        if not outcome.contacts_observed:
            return None
        touched = np.asarray(outcome.touched_faces, dtype=np.int64)
        if len(touched) == 0:
            return False
        weights = np.asarray(outcome.touched_weights, dtype=np.float64)
        if len(weights) != len(touched) or weights.sum() <= 0:
            weights = np.ones(len(touched))
        on_part = self.labels[touched] == k
        return bool(weights[on_part].sum() >= 0.5 * weights.sum())

    def oracle_plan(self, labels_on_mesh: np.ndarray) -> PartPlan:
        """The `oracle` method's plan: the true labels of the planning mesh."""
        return PartPlan("oracle", ORACLE_DETECTOR, np.array(labels_on_mesh, dtype=np.int64, copy=True))


def transfer_labels(
    source_mesh: trimesh.Trimesh, source_labels: np.ndarray, target_mesh: trimesh.Trimesh, T_source_target: np.ndarray
) -> np.ndarray:
    """Labels of `target_mesh`'s faces from the nearest face of `source_mesh` (e.g. the twin -> a perceived mesh).

    Face centres within `TRANSFER_EXACT` of the source's surface take its exactly nearest face, queried in chunks of
    `TRANSFER_CHUNK`; those farther (a perceived instance that is another object) take the face of the nearest of
    `TRANSFER_SAMPLES` surface samples: trimesh's exact query weighs every face against a far point, and one such
    mesh of a packed scene asked for 3.4 GiB in one array."""
    from scipy.spatial import cKDTree

    centres = target_mesh.triangles_center @ T_source_target[:3, :3].T + T_source_target[:3, 3]
    samples, sample_faces = trimesh.sample.sample_surface(source_mesh, TRANSFER_SAMPLES, seed=0)
    distance, sample = cKDTree(samples).query(centres)
    nearest = np.asarray(sample_faces, dtype=np.int64)[sample]
    close = np.flatnonzero(distance <= TRANSFER_EXACT)
    for start in range(0, len(close), TRANSFER_CHUNK):
        chunk = close[start : start + TRANSFER_CHUNK]
        nearest[chunk] = trimesh.proximity.closest_point(source_mesh, centres[chunk])[2]
    return np.asarray(source_labels, dtype=np.int64)[nearest]
