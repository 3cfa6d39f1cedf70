"""The PyBullet world: one physics client, the table, object bodies, pose conversions and stepping.

World frame (docs/design.md section 3): the robot base at the origin, z up. The robot stands on the table, so the table top is
the plane z = `TABLE_TOP_Z` = 0. Objects are placed in a workspace in front of the robot (+x).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet
from pybullet_utils import bullet_client
from scipy.spatial.transform import Rotation, Slerp

from seggrasp.objects import ObjectModel

ROBOT_ASSETS = Path(__file__).resolve().parents[1] / "assets" / "robots"
TABLE_TOP_Z = 0.0
#: Table extents (x, y) and thickness in metres; the robot base sits near its -x edge.
TABLE_SIZE = (1.2, 1.2, 0.05)
TABLE_CENTER_XY = (0.35, 0.0)
#: The table top's friction coefficient (PyBullet multiplies it by the object's).
TABLE_FRICTION = 0.6
#: Where objects are dropped: centre (x, y) on the table, +-jitter in x and y, full yaw.
WORKSPACE_CENTER = np.array([0.5, 0.0])
WORKSPACE_JITTER = 0.05
#: Half side (m) of the square workspace box around the drop zone that perception crops to.
WORKSPACE_HALF_SIZE = 0.25
#: PyBullet keeps contacts on convex mesh shapes this far outside the surface (its collision margin), so closed
#: fingers rest this much off each side of an object (measured: tests/test_sim_gripper.py).
COLLISION_SKIN = 0.001
#: Spacing of waypoints along Cartesian straight lines (m).
PATH_RESOLUTION = 0.01


@dataclass(frozen=True)
class PhysicsSettings:
    """Time step and solver settings (240 Hz is PyBullet's tuned default).

    The solver must converge on the gripper's fingers squeezed by its motor: with 50 iterations and PyBullet's
    default contact ERP the pads sank millimetres into what they held. 100 iterations with a contact ERP of 0.8
    (penetration corrected within a few steps) keep them on the surface and deliver the grip force
    (`tests/test_sim_gripper.py`, with the fingertips on slides: `sim.gripper`). `contact_erp=None` keeps PyBullet's
    default.
    """

    time_step: float = 1.0 / 240.0
    solver_iterations: int = 100
    contact_erp: float | None = 0.8
    # an object lighter than this is squeezed by contact impulses far above its momentum: it creeps out of the
    # fingers at 100 iterations (a 20 g toothbrush falls during the lift) and needs `light_object_iterations`; since
    # the pads squeeze with the full grip force (`sim.gripper.Robotiq2F85.squeeze`) a 57 g screwdriver held by its
    # 6 mm shaft also drops at 100 (tests/test_sim_parallel_pads.py)
    light_object_mass: float = 0.1
    light_object_iterations: int | None = 300
    gravity: float = -9.81


def pose_to_pb(T: np.ndarray) -> tuple[list[float], list[float]]:
    """4x4 pose -> PyBullet (position, quaternion xyzw)."""
    T = np.asarray(T, dtype=float)
    return T[:3, 3].tolist(), Rotation.from_matrix(T[:3, :3]).as_quat().tolist()


def pb_to_pose(position, quaternion) -> np.ndarray:
    """PyBullet (position, quaternion xyzw) -> 4x4 pose."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(np.asarray(quaternion, dtype=float)).as_matrix()
    T[:3, 3] = position
    return T


@contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence the process's stdout file descriptor (C-level prints included) for the duration."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), 1)
            yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


def linear_poses(T_start: np.ndarray, T_end: np.ndarray, resolution: float) -> list[np.ndarray]:
    """Poses on the straight line from `T_start` to `T_end` (both included), at most `resolution` m apart;
    the orientation is interpolated by slerp."""
    distance = float(np.linalg.norm(T_end[:3, 3] - T_start[:3, 3]))
    n = max(1, int(np.ceil(distance / resolution)))
    rotations = Rotation.from_matrix(np.stack([T_start[:3, :3], T_end[:3, :3]]))
    slerp = Slerp([0.0, 1.0], rotations)
    poses = []
    for t in np.linspace(0.0, 1.0, n + 1):
        T = np.eye(4)
        T[:3, :3] = slerp([t]).as_matrix()[0]
        T[:3, 3] = (1 - t) * T_start[:3, 3] + t * T_end[:3, 3]
        poses.append(T)
    return poses


class World:
    """One PyBullet client with gravity, a table and helpers to add, pose and step bodies."""

    def __init__(self, gui: bool = False, physics: PhysicsSettings | None = None) -> None:
        self.physics = physics or PhysicsSettings()
        self.gui = gui
        with _quiet_stdout():  # PyBullet's connect prints "argv[0]=" on the C-level stdout
            self.client = bullet_client.BulletClient(connection_mode=pybullet.GUI if gui else pybullet.DIRECT)
        self.table_id = -1
        self.pre_step_hooks: list[Callable[[], None]] = []
        self.step_count = 0
        self.reset()

    @property
    def client_id(self) -> int:
        return int(self.client._client)

    def reset(self) -> None:
        """Empty the world and rebuild the table (every body id becomes invalid)."""
        c = self.client
        self.pre_step_hooks = []
        c.resetSimulation()
        c.setGravity(0.0, 0.0, self.physics.gravity)
        c.setPhysicsEngineParameter(
            fixedTimeStep=self.physics.time_step,
            numSolverIterations=self.physics.solver_iterations,
            deterministicOverlappingPairs=1,
        )
        if self.physics.contact_erp is not None:
            c.setPhysicsEngineParameter(contactERP=self.physics.contact_erp)
        if self.gui:
            c.configureDebugVisualizer(pybullet.COV_ENABLE_GUI, 0)
            c.resetDebugVisualizerCamera(
                cameraDistance=1.4, cameraYaw=50.0, cameraPitch=-35.0,
                cameraTargetPosition=[WORKSPACE_CENTER[0] - 0.15, WORKSPACE_CENTER[1], TABLE_TOP_Z + 0.15],
            )
        half = [TABLE_SIZE[0] / 2, TABLE_SIZE[1] / 2, TABLE_SIZE[2] / 2]
        shape = c.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half)
        visual = c.createVisualShape(pybullet.GEOM_BOX, halfExtents=half, rgbaColor=[0.62, 0.5, 0.38, 1.0])
        self.table_id = c.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=shape,
            baseVisualShapeIndex=visual,
            basePosition=[TABLE_CENTER_XY[0], TABLE_CENTER_XY[1], TABLE_TOP_Z - half[2]],
        )
        c.changeDynamics(self.table_id, -1, lateralFriction=TABLE_FRICTION)

    def load_robot(self, path: Path, T_world_base: np.ndarray | None = None, fixed: bool = True) -> int:
        """Load a robot's URDF file and return its body id."""
        if not Path(path).is_file():
            raise FileNotFoundError(f"robot description not found: {path}")
        position, orientation = pose_to_pb(np.eye(4) if T_world_base is None else T_world_base)
        return self.client.loadURDF(
            str(path), position, orientation, useFixedBase=fixed,
            flags=pybullet.URDF_USE_INERTIA_FROM_FILE | pybullet.URDF_ENABLE_CACHED_GRAPHICS_SHAPES,
        )

    def load_object(self, model: ObjectModel, T_world_obj: np.ndarray) -> int:
        """Load an object's one-link URDF so that its mesh frame sits at `T_world_obj`; set its friction (and the
        solver iterations a light object needs, `PhysicsSettings`)."""
        if model.urdf_path is None or not Path(model.urdf_path).is_file():
            raise ValueError(f"object {model.object_id!r} has no URDF file (urdf_path={model.urdf_path})")
        position, orientation = pose_to_pb(T_world_obj)
        body = self.client.loadURDF(
            str(model.urdf_path), position, orientation, flags=pybullet.URDF_USE_INERTIA_FROM_FILE
        )
        self.client.changeDynamics(
            body, -1, lateralFriction=float(model.friction), spinningFriction=0.001, rollingFriction=0.0001,
        )
        light = self.physics.light_object_iterations is not None and model.mass < self.physics.light_object_mass
        iterations = self.physics.light_object_iterations if light else self.physics.solver_iterations
        self.client.setPhysicsEngineParameter(numSolverIterations=int(iterations))
        return body

    def body_pose(self, body: int) -> np.ndarray:
        """`T_world_link` of a body's base link frame (the URDF frame, not PyBullet's centre-of-mass frame)."""
        c = self.client
        T_world_com = pb_to_pose(*c.getBasePositionAndOrientation(body))
        dynamics = c.getDynamicsInfo(body, -1)
        T_link_com = pb_to_pose(dynamics[3], dynamics[4])
        return T_world_com @ np.linalg.inv(T_link_com)

    def link_pose(self, body: int, link: int) -> np.ndarray:
        """`T_world_link` of a link's URDF frame (-1 = base)."""
        if link == -1:
            return self.body_pose(body)
        state = self.client.getLinkState(body, link, computeForwardKinematics=True)
        return pb_to_pose(state[4], state[5])

    def step(self, n: int = 1) -> None:
        """Advance the physics by `n` time steps, running the pre-step hooks (e.g. the gripper's mimic servo)
        before each."""
        for _ in range(n):
            for hook in self.pre_step_hooks:
                hook()
            self.client.stepSimulation()
        self.step_count += n

    def close(self) -> None:
        """Disconnect the client (idempotent)."""
        if getattr(self, "client", None) is not None:
            try:
                self.client.disconnect()
            except pybullet.error:  # already disconnected
                pass
            self.client = None
