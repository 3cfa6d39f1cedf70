"""`SimCell`: the PyBullet twin of the robot cell, implementing `seggrasp.cell.Cell`.

One episode: `reset(seed, object_id)` builds the scene (table, the robot system - a UR5 + 2F-85, a Franka Panda +
Franka Hand (`robot="panda"`, `sim.panda`) or a floating 2F-85 - one object at a seeded pose, settled; with
`scene="packed" | "pile"`, that object among distractors, `sim.scenes`), `capture()` renders the virtual D435s,
`object_mesh()` gives the twin's mesh and pose (of the object the request names), and `execute(T_world_grasp,
width)` runs the grasp-and-lift primitive (`sim.grasp_primitive`), which keeps clear of the other objects.

`record_next(path)` makes the next `execute()` write a picture strip of its stages, `log_contacts_next(path)` a table
of what the fingertips press on at each stage (`sim.recording`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from seggrasp.cell import Frame, GraspOutcome
from seggrasp.hands import FRANKA_HAND, ROBOTIQ_2F85
from seggrasp.objects import ObjectModel
from seggrasp.perception import Workspace
from seggrasp.target import object_name
from seggrasp.truth import SceneTruth
from seggrasp.views import look_at
from sim.cameras import DepthNoise, VirtualD435
from sim.floating_gripper import FloatingGripper
from sim.grasp_primitive import GraspPrimitive, GraspSettings
from sim.gripper import GripperSettings
from sim.recording import ContactLog, StageRecorder, TrialRecorder
from sim.robot import ArmSettings, UR5Arm
from sim.world import (
    TABLE_TOP_Z,
    WORKSPACE_CENTER,
    WORKSPACE_HALF_SIZE,
    WORKSPACE_JITTER,
    PhysicsSettings,
    World,
)

log = logging.getLogger(__name__)

EMBODIMENTS = ("arm", "floating")
#: The robot systems: the arm and its hand (`seggrasp.hands`).
ROBOTS = {"ur5": ROBOTIQ_2F85, "panda": FRANKA_HAND}
#: The most a scene of several objects settles (s): objects of a pile rock longer than one alone.
SCENE_SETTLE_TIME = 3.0
#: Floating gripper's home: above the workspace, pointing down.
FLOATING_HOME = np.array([[1, 0, 0, 0.5], [0, -1, 0, 0.0], [0, 0, -1, 0.45], [0, 0, 0, 1.0]])


@dataclass(frozen=True)
class CameraRig:
    """Virtual D435s on an arc around the workspace, looking at its centre."""

    n_cameras: int = 2
    width: int = 640
    height: int = 480
    radius: float = 0.65
    height_above_table: float = 0.55
    azimuths_deg: tuple[float, float] = (-50.0, 50.0)  # spread of the arc, 0 = facing the robot from +x
    noise: DepthNoise = field(default_factory=DepthNoise)

    def cameras(self) -> list[VirtualD435]:
        if self.n_cameras < 1:
            raise ValueError(f"n_cameras must be at least 1, got {self.n_cameras}")
        target = np.array([WORKSPACE_CENTER[0], WORKSPACE_CENTER[1], TABLE_TOP_Z + 0.05])
        azimuths = (
            np.deg2rad(np.linspace(*self.azimuths_deg, self.n_cameras)) if self.n_cameras > 1 else np.zeros(1)
        )
        cams = []
        for index, azimuth in enumerate(azimuths):
            eye = np.array([
                WORKSPACE_CENTER[0] + self.radius * np.cos(azimuth),
                WORKSPACE_CENTER[1] + self.radius * np.sin(azimuth),
                TABLE_TOP_Z + self.height_above_table,
            ])
            cams.append(VirtualD435(f"cam{index}", look_at(eye, target), self.width, self.height, self.noise))
        return cams


class SimCell:
    """The simulated cell. `objects` defaults to the twin (`seggrasp.objects.load_asset_set()`); `seed` is the scene
    seed of the first scene (`reset`); `robot` the system (`ROBOTS`: "ur5", the UR5 with the 2F-85, or "panda", the
    Franka Panda with the Franka Hand; the floating gripper is the 2F-85's), whose hand is `hand`. Everything else -
    the table, the object's placement, the cameras, the lift, the hold and the success test - is the same for both.
    `scene` ("packed" or "pile"; None: the object alone) puts `objects_per_scene` objects on the table: the chosen
    one and distractors drawn from `objects` (`sim.scenes`)."""

    models_scene = True  # `check_reach` poses the simulated robot among the table and the object

    def __init__(
        self,
        objects: list[ObjectModel] | None = None,
        embodiment: str = "arm",
        seed: int = 0,
        robot: str = "ur5",
        gui: bool = False,
        n_cameras: int = 2,
        image_size: tuple[int, int] = (640, 480),
        camera_noise: DepthNoise | None = None,
        physics: PhysicsSettings | None = None,
        grasp: GraspSettings | None = None,
        arm: ArmSettings | None = None,
        gripper: GripperSettings | None = None,
        scene: str | None = None,
        objects_per_scene: int = 4,
    ) -> None:
        if embodiment not in EMBODIMENTS:
            raise ValueError(f"unknown embodiment {embodiment!r}; use one of {EMBODIMENTS}")
        if robot not in ROBOTS:
            raise ValueError(f"unknown robot {robot!r}; use one of {tuple(ROBOTS)}")
        if robot != "ur5" and embodiment != "arm":
            raise ValueError(f"the floating gripper is the 2F-85's; robot={robot!r} needs embodiment='arm'")
        if scene is not None:
            from sim.scenes import KINDS, N_OBJECTS

            if scene not in KINDS:
                raise ValueError(f"unknown scene {scene!r}; use one of {KINDS} (or None: the object alone)")
            if not N_OBJECTS[0] <= objects_per_scene <= N_OBJECTS[1]:
                raise ValueError(f"a scene holds {N_OBJECTS[0]}-{N_OBJECTS[1]} objects, got {objects_per_scene}")
        if objects is None:
            from seggrasp.objects import load_asset_set

            objects = load_asset_set()
        if not objects:
            raise ValueError("SimCell needs at least one object")
        self.objects = list(objects)
        self._by_id = {o.object_id: o for o in self.objects}
        self.embodiment_name = embodiment
        self.robot_name = robot
        self.hand = ROBOTS[robot]
        self.grasp_settings = grasp or GraspSettings()
        self._arm_settings, self._gripper_settings = arm, gripper
        self.rig = CameraRig(n_cameras, image_size[0], image_size[1], noise=camera_noise or DepthNoise())
        self.cameras = self.rig.cameras()
        self.world = World(gui=gui, physics=physics)
        self.scene, self.objects_per_scene = scene, objects_per_scene
        self.current_object: ObjectModel | None = None
        self.object_body = -1
        self.neighbours: list[tuple[int, str]] = []  # (body, object id) of the other objects on the table
        self.scene_plan = None  # the scene's `sim.scenes.ScenePlan` (None: the object alone)
        self._scene_seed = -1  # reset(None) takes the next scene seed
        self._recorder: StageRecorder | None = None
        self.reset(seed)

    # --- Cell interface ---------------------------------------------------------------------------------------

    def reset(self, seed: int | None = None, object_id: str | None = None) -> None:
        """Rebuild the scene: robot at home, the chosen (or a seeded random) object at a seeded pose, settled.
        `seed` is the scene seed (docs/design.md section 9): it draws the object (when `object_id` is None), its pose
        and the cameras' noise; `seed=None` takes the previous one + 1."""
        self._scene_seed = int(seed) if seed is not None else self._scene_seed + 1
        rng = np.random.default_rng(self._scene_seed)
        if object_id is not None:
            if object_id not in self._by_id:
                raise ValueError(f"unknown object_id {object_id!r}; known: {sorted(self._by_id)[:20]}")
            model = self._by_id[object_id]
        else:
            model = self.objects[int(rng.integers(len(self.objects)))]
        self.world.reset()
        if self.robot_name == "panda":
            from sim.panda import PandaArm

            self.robot = PandaArm(self.world, self._arm_settings, self._gripper_settings)
        elif self.embodiment_name == "arm":
            self.robot = UR5Arm(self.world, self._arm_settings, self._gripper_settings)
        else:
            self.robot = FloatingGripper(self.world, FLOATING_HOME, self._gripper_settings)
        self.robot.reset_home(self.hand.stroke)
        self.current_object = model
        if self.scene is None:
            self.object_body = self.world.load_object(model, self._drop_pose(model, rng))
            self._settle()
        else:
            from sim.scenes import place_scene, plan_scene

            self.scene_plan = plan_scene(self.objects, target_id=model.object_id, n_objects=self.objects_per_scene,
                                         kind=self.scene, seed=self._scene_seed)
            bodies = place_scene(self.world, self._by_id, self.scene_plan, settle_time=SCENE_SETTLE_TIME,
                                 parked=self.robot.body)
            self.object_body = bodies[0]
            self.neighbours = list(zip(bodies[1:], self.scene_plan.object_ids[1:]))
        self._camera_noise_rng = np.random.default_rng([self._scene_seed, 1])

    def _drop_pose(self, model: ObjectModel, rng: np.random.Generator) -> np.ndarray:
        """Seeded pose: yaw uniform, xy jittered around the workspace centre, lowest point 1 mm above the table."""
        yaw = rng.uniform(-np.pi, np.pi)
        xy = WORKSPACE_CENTER + rng.uniform(-WORKSPACE_JITTER, WORKSPACE_JITTER, 2)
        T = np.eye(4)
        T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
        lowest = float((model.mesh.vertices @ T[:3, :3].T)[:, 2].min())
        T[:3, 3] = [xy[0], xy[1], TABLE_TOP_Z - lowest + 0.001]
        return T

    def _settle(self) -> None:
        """Step until the object rests (speed < 5 mm/s and 0.05 rad/s for 0.1 s) or `settle_time` runs out."""
        dt = self.world.physics.time_step
        quiet, needed = 0, int(round(0.1 / dt))
        for _ in range(int(round(self.grasp_settings.settle_time / dt))):
            self.world.step()
            linear, angular = self.world.client.getBaseVelocity(self.object_body)
            quiet = quiet + 1 if np.linalg.norm(linear) < 0.005 and np.linalg.norm(angular) < 0.05 else 0
            if quiet >= needed:
                return
        log.debug("object %s still moving after %.2f s", self.current_object.object_id, self.grasp_settings.settle_time)

    def capture(self) -> list[Frame]:
        return [camera.capture(self.world.client, self._camera_noise_rng) for camera in self.cameras]

    def object_mesh(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        self._require_scene()
        return self.current_object.mesh, self.world.body_pose(self.object_body)

    def scene_truth(self) -> SceneTruth:
        """The bodies on the table (the values of the frames' `instance_ids`) with their objects' names, the
        requested one the target."""
        self._require_scene()
        names = {self.object_body: object_name(self.current_object.category)}
        names.update({body: object_name(self._by_id[object_id].category) for body, object_id in self.neighbours})
        return SceneTruth(self.object_body, names)

    def check_reach(self, T_world_grasp: np.ndarray, width: float) -> str:
        """Why `execute` would refuse this grasp in the scene as it is now - step 1 of `sim.grasp_primitive`: no IK
        plan (`unreachable: ...`), or every free-space path, approach or lift hits the table, the object or another
        object on the table - with nothing moved (the robot is posed kinematically and put back); "" when it would
        go ahead."""
        self._require_scene()
        T_world_grasp, width = _check_grasp(T_world_grasp, width)
        return GraspPrimitive(
            self.world, self.robot, self.object_body, self.current_object, self.grasp_settings,
            neighbours=self.neighbours,
        ).motion(T_world_grasp, width)[2]

    def execute(self, T_world_grasp: np.ndarray, width: float) -> GraspOutcome:
        """Grasp-and-lift (`sim.grasp_primitive`). Unreachable or colliding poses give `reachable=False`."""
        self._require_scene()
        T_world_grasp, width = _check_grasp(T_world_grasp, width)
        recorder, self._recorder = self._recorder, None
        outcome = GraspPrimitive(
            self.world, self.robot, self.object_body, self.current_object, self.grasp_settings, recorder,
            neighbours=self.neighbours,
        ).run(T_world_grasp, width)
        if recorder is not None and not outcome.reachable:
            recorder.write(f"{self.current_object.object_id}: {outcome.message}")
        return outcome

    def record_next(self, path: str | Path) -> None:
        """Record the next `execute()` as a picture strip (pre-grasp, closed, lifted, held) written to `path`."""
        self._recorder = TrialRecorder(path)

    def log_contacts_next(self, path: str | Path) -> None:
        """Log what the fingertips press on at each stage of the next `execute()` to `path`
        (`sim.recording.ContactLog`); replaces a recording armed before."""
        self._recorder = ContactLog(path)

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
            self.world = None

    # --- helpers -----------------------------------------------------------------------------------------------

    @property
    def workspace(self) -> Workspace:
        """The box where the object is (for perception): the table area around the drop zone, 45 cm high."""
        x, y = (float(v) for v in WORKSPACE_CENTER)
        half = WORKSPACE_HALF_SIZE
        return Workspace((x - half, y - half, TABLE_TOP_Z - 0.02), (x + half, y + half, TABLE_TOP_Z + 0.45), TABLE_TOP_Z)

    def _require_scene(self) -> None:
        if self.world is None:
            raise RuntimeError("this SimCell is closed")
        if self.current_object is None:
            raise RuntimeError("no scene: call reset() first")

    def render(self, camera: VirtualD435 | None = None) -> np.ndarray:
        """Noise-free RGB image of the scene (default: the first camera)."""
        rgb, _, _ = (camera or self.cameras[0]).render(self.world.client)
        return rgb

    def __enter__(self) -> "SimCell":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _check_grasp(T: np.ndarray, width: float) -> tuple[np.ndarray, float]:
    """A grasp's pose (`_check_pose`) and width (a non-negative number of metres), or ValueError."""
    if not np.isfinite(width) or width < 0:
        raise ValueError(f"grasp width must be a non-negative number of metres, got {width}")
    return _check_pose(T), float(width)


def _check_pose(T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"grasp pose must be a finite 4x4 matrix, got shape {T.shape}")
    R = T[:3, :3]
    if np.abs(R.T @ R - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        raise ValueError("grasp pose rotation is not a proper rotation matrix")
    T = T.copy()
    T[:3, :3] = Rotation.from_matrix(R).as_matrix()  # re-orthonormalise small numerical error
    return T

