"""The robot-cell interface that both backends implement (`sim.SimCell`, `hardware.RealCell`).

Frames follow docs/design.md section 3: `world` has the robot base at the origin and z up; cameras use the OpenCV convention
(x right, y down, z forward); `T_a_b` maps coordinates in frame b to frame a. The gripper frame has z along the
approach direction, x along the closing direction (finger to finger) and its origin between the fingertips.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np
import trimesh

from seggrasp.hands import ROBOTIQ_2F85, Hand


@dataclass
class Frame:
    """One RGB-D capture of one camera."""

    name: str
    rgb: np.ndarray  # (H, W, 3) uint8
    depth: np.ndarray  # (H, W) float32 metres; 0 where the camera has no reading
    K: np.ndarray  # (3, 3) pinhole intrinsics
    T_world_cam: np.ndarray  # (4, 4) camera (OpenCV) -> world
    # the twin only: the body each pixel shows (H, W) int, -1 none (PyBullet's segmentation mask); None on a real
    # cell. The simulated object detector (`seggrasp.detect.simulated.SimulatedObjectDetector`) and the scoring of
    # perceived instances read it; perception never does.
    instance_ids: np.ndarray | None = None


#: The Robotiq 2F-85's grip force range (datasheet, N) and the cell's default setting (`seggrasp.hands.ROBOTIQ_2F85`,
#: where a hand's numbers live), shared by the twin (`sim.gripper.GripperSettings`; a twin run sets another with
#: `python -m sim.evaluate --grip-force N`), the grasp sampler's torque limit and the real cell
#: (hardware/cell.example.yaml `gripper.force`, at the example's `limits.max_grip_force`; hardware/config.py's
#: default). The default is the 2F-85's full force: pans, kettles and hammers held by their handles turn in the
#: fingers under their own weight at 100 N (docs/results/archive/twin-physics-rounds.md, fifth round); lower it in
#: cell.yaml for fragile objects.
GRIP_FORCE_RANGE = ROBOTIQ_2F85.grip_force_range
DEFAULT_GRIP_FORCE = ROBOTIQ_2F85.default_grip_force
#: The 2F-85's finger speed range (m/s, datasheet), spanned linearly by the URCap's SPE register 0-255; shared by
#: the real cell (hardware/robotiq.py, hardware/config.py) and the emulated lab cell's gripper (sim/lab/robotiq.py),
#: which may not import hardware/.
FINGER_SPEED_RANGE = ROBOTIQ_2F85.finger_speed_range

# Success as a lab judges it, the same on both backends: the grasped point rises at least LIFT_SUCCESS (m; the
# lift is 20 cm) and the object moves less than MAX_SLIP (m) and MAX_ROTATION_DEG in the fingers from the close to
# the end of the hold.
LIFT_SUCCESS = 0.18
MAX_SLIP = 0.010
MAX_ROTATION_DEG = 15.0

# Why a trial failed. The cell names the physical failures; the harness adds `no_grasp` (the method planned no
# grasp for the slot), `wrong_part` (held, but on another part than the prompted one) and `infeasible` (no grasp
# candidate of the cell's hand holds the part, judged before the robot moves: seggrasp.grasp.feasibility; the
# trial's message says why) and `not_found` (among several objects on the table, the detector's boxes for the
# object's name cover none of the perceived instances: seggrasp.target; nothing is planned for the request). ""
# means success.
FAILURES = ("unreachable", "collision", "pushed", "empty_close", "slipped", "rotated", "wrong_part", "no_grasp",
            "infeasible", "not_found")


@dataclass
class GraspOutcome:
    """What happened when a grasp was executed.

    `touched_faces` are faces of the object mesh (in its file order) that the finger pads touched and
    `touched_weights` (same length, optional) how much of the contact each carried (normal force or area); a backend
    that cannot observe contacts (the real robot) leaves both empty and sets `contacts_observed=False`.
    `failure` is one of `FAILURES`, or "" when the cell saw nothing go wrong.
    """

    reachable: bool
    lifted: bool
    lift_height: float  # metres the object rose (0 if not reached or not lifted)
    touched_faces: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    contact_force: float = 0.0  # newtons, total normal force between pads and object while holding
    contacts_observed: bool = True
    message: str = ""
    failure: str = ""
    touched_weights: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.float64))
    # in a scene of several objects: how far (m) each other object moved, in the scene's order, and how many of
    # them rose with the grasped one (both empty / 0 for an object alone on the table)
    disturbance: tuple[float, ...] = ()
    lifted_along: int = 0

    def __post_init__(self) -> None:
        if self.failure and self.failure not in FAILURES:
            raise ValueError(f"unknown failure {self.failure!r}; expected one of {FAILURES}")
        if len(self.touched_weights) not in (0, len(self.touched_faces)):
            raise ValueError("touched_weights must be empty or have one weight per touched face")

    def to_json(self) -> dict:
        return {
            "reachable": bool(self.reachable),
            "lifted": bool(self.lifted),
            "lift_height": float(self.lift_height),
            "touched_faces": [int(f) for f in self.touched_faces],
            "contact_force": float(self.contact_force),
            "contacts_observed": bool(self.contacts_observed),
            "message": self.message,
            "failure": self.failure,
            "touched_weights": [float(w) for w in self.touched_weights],
            **({"disturbance": [float(d) for d in self.disturbance], "lifted_along": int(self.lifted_along)}
               if self.disturbance else {}),
        }


@runtime_checkable
class Cell(Protocol):
    """A robot cell: cameras, an arm with a parallel gripper, and one object on a table."""

    #: Whether the cell's `check_reach` looks at a model of the scene (the twin: it poses the simulated robot among
    #: the table and the object). Such a cell checks in a freshly reset scene and executes every grasp from a reset,
    #: so no outcome depends on the checks made before it. A cell that checks only its arm (the real cell) is reset
    #: only when a grasp has been executed since the last reset: one reset ("place the object") per grasp.
    models_scene: bool
    #: The cell's gripper (`seggrasp.hands`): the episode samples, ranks and plans its grasps for this hand.
    hand: Hand

    def reset(self, seed: int | None = None, object_id: str | None = None) -> None:
        """Put the scene in its start state (the same seed gives the same scene)."""

    def capture(self) -> list[Frame]:
        """One RGB-D frame from every camera."""

    def object_mesh(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        """The object's mesh (object frame, metres) and `T_world_obj`, when the backend knows them.

        The simulator knows the twin's mesh and pose; the real cell raises `NotImplementedError` and the mesh is
        reconstructed from `capture()` instead.
        """

    def check_reach(self, T_world_grasp: np.ndarray, width: float) -> str:
        """Why the cell would refuse to execute this grasp now (a pose on its way has no inverse kinematics or breaks
        the cell's limits; a cell that models its surroundings, the twin, also refuses a motion that would hit the
        table or the object), checked without moving anything; "" when it would go ahead. `execute` refuses the
        same grasps."""

    def execute(self, T_world_grasp: np.ndarray, width: float) -> GraspOutcome:
        """Pre-grasp, approach, close, lift 20 cm and hold; report the outcome. Never raises for a failed grasp."""

    def close(self) -> None:
        """Release the backend's resources (physics client, robot connection, cameras)."""
