"""`SimCell`: the PyBullet twin of the robot cell, implementing `seggrasp.cell.Cell`, and its grasp-and-lift.

One episode: `reset(seed, object_id)` builds the scene (table, UR5 + 2F-85 or a floating 2F-85, one object at a
seeded pose, settled), `capture()` renders the virtual D435s, `object_mesh()` gives the twin's mesh and pose, and
`execute(T_world_grasp, width)` runs the grasp-and-lift primitive:

1. plan: pre-grasp (10 cm back along the approach axis z), grasp, and lift (20 cm up) poses; for the arm every
   waypoint must pass the IK reachability check, no configuration on the way (free-space path to the pre-grasp,
   approach, lift) may bring the robot closer to the table than `table_clearance`, and the free-space path may
   not touch the object; otherwise the grasp is `reachable=False` and nothing moves;
2. open the gripper to width + margin, move to the pre-grasp through free space (the arm in joint space at its
   speed limit, simulated; the floating gripper is placed there), approach in a straight line, close until the
   finger stalls, lift, hold 1 s;
3. report: lifted (raised >= 18 cm with both fingertips still touching it), lift height, the mesh faces the
   fingertips (pads and the inner-finger rims they sit on) touched (contact points in the object frame -> nearest
   face), and their total normal force while holding.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from seggrasp.cell import Frame, GraspOutcome
from seggrasp.objects import ObjectModel
from seggrasp.perception import Workspace
from seggrasp.views import look_at
from sim.cameras import DepthNoise, VirtualD435
from sim.gripper import MAX_WIDTH, FloatingGripper, GripperSettings
from sim.robot import ArmSettings, UR5Arm
from sim.world import TABLE_TOP_Z, WORKSPACE_CENTER, WORKSPACE_JITTER, PhysicsSettings, World

log = logging.getLogger(__name__)

EMBODIMENTS = ("arm", "floating")
#: Half side (m) of the square workspace box around the drop zone that perception crops to.
WORKSPACE_HALF_SIZE = 0.25
#: Floating gripper's home: above the workspace, pointing down.
FLOATING_HOME = np.array([[1, 0, 0, 0.5], [0, -1, 0, 0.0], [0, 0, -1, 0.45], [0, 0, 0, 1.0]])


@dataclass(frozen=True)
class GraspSettings:
    """The grasp-and-lift primitive's numbers (metres, m/s, seconds). The lift runs at the real cell's tool speed
    (hardware/cell.example.yaml `motion.tool_speed`, 0.10 m/s); at the 0.30 m/s used before, heavy tools held off
    their centre of mass slipped more (oracle Suc. on frying pans, hammers, screwdrivers, spatulas and toothbrushes
    0.591 at 0.30 m/s, 0.659 at 0.10 m/s)."""

    pregrasp_distance: float = 0.10
    width_margin: float = 0.02
    approach_speed: float = 0.25
    lift_height: float = 0.20
    lift_speed: float = 0.10
    hold_time: float = 1.0
    lift_success: float = 0.18
    table_clearance: float = 0.003
    settle_time: float = 1.0  # at most; settling stops once the object rests


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
    """The simulated cell. `objects` defaults to the twin (`seggrasp.objects.load_asset_set()`)."""

    def __init__(
        self,
        objects: list[ObjectModel] | None = None,
        embodiment: str = "arm",
        seed: int = 0,
        gui: bool = False,
        n_cameras: int = 2,
        image_size: tuple[int, int] = (640, 480),
        camera_noise: DepthNoise | None = None,
        physics: PhysicsSettings | None = None,
        grasp: GraspSettings | None = None,
        arm: ArmSettings | None = None,
        gripper: GripperSettings | None = None,
    ) -> None:
        if embodiment not in EMBODIMENTS:
            raise ValueError(f"unknown embodiment {embodiment!r}; use one of {EMBODIMENTS}")
        if objects is None:
            from seggrasp.objects import load_asset_set

            objects = load_asset_set()
        if not objects:
            raise ValueError("SimCell needs at least one object")
        self.objects = list(objects)
        self._by_id = {o.object_id: o for o in self.objects}
        self.embodiment_name = embodiment
        self.grasp_settings = grasp or GraspSettings()
        self._arm_settings, self._gripper_settings = arm, gripper
        self.rig = CameraRig(n_cameras, image_size[0], image_size[1], noise=camera_noise or DepthNoise())
        self.cameras = self.rig.cameras()
        self.world = World(gui=gui, physics=physics)
        self.current_object: ObjectModel | None = None
        self.object_body = -1
        self._seed = -1  # reset(None) takes the next seed
        self.reset(seed)

    # --- Cell interface ---------------------------------------------------------------------------------------

    def reset(self, seed: int | None = None, object_id: str | None = None) -> None:
        """Rebuild the scene: robot at home, the chosen (or a seeded random) object at a seeded pose, settled.
        `seed=None` takes the previous seed + 1."""
        self._seed = int(seed) if seed is not None else self._seed + 1
        rng = np.random.default_rng(self._seed)
        if object_id is not None:
            if object_id not in self._by_id:
                raise ValueError(f"unknown object_id {object_id!r}; known: {sorted(self._by_id)[:20]}")
            model = self._by_id[object_id]
        else:
            model = self.objects[int(rng.integers(len(self.objects)))]
        self.world.reset()
        if self.embodiment_name == "arm":
            self.robot = UR5Arm(self.world, self._arm_settings, self._gripper_settings)
        else:
            self.robot = FloatingGripper(self.world, FLOATING_HOME, self._gripper_settings)
        self.robot.reset_home(MAX_WIDTH)
        self.current_object = model
        self.object_body = self.world.load_object(model, self._drop_pose(model, rng))
        self._settle()
        self._camera_rng = np.random.default_rng([self._seed, 1])

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
        return [camera.capture(self.world.client, self._camera_rng) for camera in self.cameras]

    def object_mesh(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        self._require_scene()
        return self.current_object.mesh, self.world.body_pose(self.object_body)

    def execute(self, T_world_grasp: np.ndarray, width: float) -> GraspOutcome:
        """Grasp-and-lift (module docstring). Unreachable or colliding poses give `reachable=False`."""
        self._require_scene()
        T_world_grasp = _check_pose(T_world_grasp)
        if not np.isfinite(width) or width < 0:
            raise ValueError(f"grasp width must be a non-negative number of metres, got {width}")
        return GraspPrimitive(self.world, self.robot, self.object_body, self.current_object, self.grasp_settings).run(
            T_world_grasp, float(width)
        )

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


class GraspPrimitive:
    """One execution of pre-grasp, approach, close, lift and hold on an embodiment (arm or floating gripper)."""

    def __init__(self, world: World, robot, object_body: int, model: ObjectModel, settings: GraspSettings) -> None:
        self.world, self.robot, self.object_body, self.model, self.settings = world, robot, object_body, model, settings
        self.gripper = robot.gripper

    def run(self, T_world_grasp: np.ndarray, width: float) -> GraspOutcome:
        s = self.settings
        opening = min(width + s.width_margin, self.gripper.max_width)
        T_world_base = T_world_grasp @ np.linalg.inv(self.gripper.T_base_tcp(min(width, self.gripper.max_width)))
        T_pre = T_world_base.copy()
        T_pre[:3, 3] -= s.pregrasp_distance * T_world_base[:3, 2]
        T_lift = T_world_base.copy()
        T_lift[2, 3] += s.lift_height
        candidates, reason = self.robot.plan([T_pre, T_world_base, T_lift])
        if not candidates:
            return GraspOutcome(reachable=False, lifted=False, lift_height=0.0, message=f"unreachable: {reason}")
        plan, start, reasons = None, self.robot.configuration(), []
        for candidate in candidates:  # IK branches, nearest home first
            for transit in self.robot.free_space_paths(start, candidate[0][0]):
                reason = self.collision_on_path(transit, candidate[1] + candidate[2], opening)
                if not reason:
                    plan = (transit, candidate)
                    break
                reasons.append(reason)
            if plan is not None:
                break
        self.robot.place(start)  # the checks posed the robot kinematically: put it back
        if plan is None:
            self.gripper.set_width(self.gripper.max_width)
            message = reasons[0] + (f" (and {len(reasons) - 1} other paths collide)" if len(reasons) > 1 else "")
            return GraspOutcome(reachable=False, lifted=False, lift_height=0.0, message=message)
        transit, paths = plan
        self.gripper.set_width(opening)
        self.robot.move_free(transit)

        z_start = self.world.body_pose(self.object_body)[2, 3]
        self.robot.follow(paths[1], s.approach_speed)
        self.gripper.close_until_stall()
        touched = self._pad_contacts()
        self.robot.follow(paths[2], s.lift_speed)
        hold_steps = int(round(s.hold_time / self.world.physics.time_step))
        forces: list[float] = []
        self.robot.hold(hold_steps - 10)
        for _ in range(10):
            self.world.step()
            forces.append(self._pad_normal_force())
        final_contacts = self._pad_contacts()
        touched = [*touched, *final_contacts]
        lift_height = float(self.world.body_pose(self.object_body)[2, 3] - z_start)
        both_pads = {side for side, _ in final_contacts} == {0, 1}
        lifted = lift_height >= s.lift_success and both_pads
        faces = self._faces_of(np.array([p for _, p in touched])) if touched else np.zeros(0, dtype=np.int64)
        message = "lifted" if lifted else ("not lifted: dropped or never held" if not both_pads else "not lifted: too low")
        return GraspOutcome(
            reachable=True, lifted=bool(lifted), lift_height=max(lift_height, 0.0),
            touched_faces=faces, contact_force=float(np.mean(forces)), message=message,
        )

    def collision_on_path(self, transit: list, near_object: list, opening: float) -> str:
        """'' if the robot (gripper opened to `opening`) keeps `table_clearance` from the table on every
        configuration and does not touch the object on the free-space `transit` (the `near_object` part -
        approach and lift - may touch it); else the reason."""
        client = self.world.client
        body, links = self.robot.table_check_links()
        links = set(links)
        self.gripper.set_width(opening)
        configs = transit + near_object
        for index, config in enumerate(configs):
            self.robot.place(config)
            for point in client.getClosestPoints(body, self.world.table_id, self.settings.table_clearance):
                if point[3] in links:
                    name = client.getJointInfo(body, point[3])[12].decode() if point[3] >= 0 else "base"
                    return f"robot would touch the table ({name} at waypoint {index + 1} of {len(configs)})"
            if index < len(transit) and client.getClosestPoints(body, self.object_body, 0.0):
                where = "at the pre-grasp" if index == len(transit) - 1 else f"at transit waypoint {index + 1}"
                return f"robot would hit the object {where}"
        return ""

    def _pad_contacts(self) -> list[tuple[int, np.ndarray]]:
        """(side 0 = left / 1 = right, contact point in the object frame) for every fingertip-object contact
        (a fingertip is the inner finger with its pad: the finger mesh's rim touches as well as the pad box)."""
        T_obj_world = np.linalg.inv(self.world.body_pose(self.object_body))
        contacts = []
        for side, links in enumerate(self.gripper.fingertip_links):
            for link in links:
                for point in self.world.client.getContactPoints(self.robot.body, self.object_body, linkIndexA=link):
                    contacts.append((side, (T_obj_world @ np.append(point[6], 1.0))[:3]))
        return contacts

    def _pad_normal_force(self) -> float:
        """Total normal force (N) between the fingertips and the object."""
        return float(sum(
            point[9]
            for links in self.gripper.fingertip_links
            for link in links
            for point in self.world.client.getContactPoints(self.robot.body, self.object_body, linkIndexA=link)
        ))

    def _faces_of(self, points: np.ndarray) -> np.ndarray:
        """Mesh faces nearest to contact points (object frame)."""
        _, _, triangles = trimesh.proximity.closest_point(self.model.mesh, points)
        return np.unique(np.asarray(triangles, dtype=np.int64))
