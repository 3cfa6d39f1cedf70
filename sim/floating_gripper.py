"""The floating gripper: a 2F-85 with no arm, carried by a Cartesian gantry of three prismatic slides."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from functools import lru_cache
from pathlib import Path

import numpy as np
import pybullet

from sim.gripper import GripperSettings, Robotiq2F85
from sim.gripper_urdf import GRIPPER_BASE_LINK, GRIPPER_DESCRIPTION, inertial_element, simulated_robot, write_urdf
from sim.world import PATH_RESOLUTION, ROBOT_ASSETS, World, linear_poses, pose_to_pb

#: The floating gripper's slides: force limit (N) and the mass (kg) of each carriage.
SLIDE_FORCE = 1000.0
SLIDE_MASS = 1.0
#: Position and velocity gains of the slides' servo while following a path.
SLIDE_GAINS = (0.05, 1.0)


@lru_cache(maxsize=1)
def gantry_urdf() -> Path:
    """The simulated 2F-85 (`simulated_robot` of assets/robots/robotiq_2f85.urdf) mounted on three prismatic slides
    (x, y, z of a fixed anchor), written once per process."""
    robot = simulated_robot(GRIPPER_DESCRIPTION)
    if not any(link.get("name") == GRIPPER_BASE_LINK for link in robot.iter("link")):
        raise ValueError(f"{ROBOT_ASSETS / GRIPPER_DESCRIPTION} has no link {GRIPPER_BASE_LINK!r}")
    parent = "gantry_anchor"
    ET.SubElement(robot, "link", name=parent).append(inertial_element(0.0))
    for name, axis, child in (("x", "1 0 0", "gantry_x_carriage"), ("y", "0 1 0", "gantry_y_carriage"), ("z", "0 0 1", GRIPPER_BASE_LINK)):
        if child != GRIPPER_BASE_LINK:
            ET.SubElement(robot, "link", name=child).append(inertial_element(SLIDE_MASS, 1e-3))
        joint = ET.SubElement(robot, "joint", name=f"gantry_{name}", type="prismatic")
        ET.SubElement(joint, "parent", link=parent)
        ET.SubElement(joint, "child", link=child)
        ET.SubElement(joint, "origin", xyz="0 0 0", rpy="0 0 0")
        ET.SubElement(joint, "axis", xyz=axis)
        ET.SubElement(joint, "limit", lower="-2", upper="2", effort=f"{SLIDE_FORCE:g}", velocity="1")
        parent = child
    return write_urdf(robot, "robotiq_2f85_gantry.urdf")


class FloatingGripper:
    """A 2F-85 with no arm, for fast sweeps: placed directly at free-space targets (as in VGN), then moved along
    straight lines by three stiff prismatic slides under a fixed anchor (a Cartesian gantry, `gantry_urdf`).

    The slides make the gripper part of a fixed-base chain, as on the arm, so the solver anchors the squeezing
    linkage as firmly. A free base dragged by a fixed constraint (the model before) let the pads' grip fade during
    the lift: a claw hammer held at 100 N fell from every top-3 oracle grasp at 100 solver iterations and needed 300
    (`tests/test_sim_gripper.py` lifts it). `place` re-anchors the gantry at the pose with the slides at zero;
    `follow` servos the slides along the path in the anchor's frame (orientation fixed, as every straight line of
    the grasp primitive keeps it).

    Exposes the same motion interface as the arm (`reset_home`, `configuration`, `plan`,
    `free_space_paths`, `move_free`, `place`, `follow`, `hold`, `table_check_links`, `gripper`).
    """

    name = "floating"

    def __init__(self, world: World, T_world_home: np.ndarray, settings: GripperSettings | None = None) -> None:
        self.world = world
        self.T_world_home = np.asarray(T_world_home, dtype=float)
        position, orientation = pose_to_pb(self.T_world_home)
        self.body = world.client.loadURDF(
            str(gantry_urdf()), position, orientation, useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE,
        )
        c = world.client
        joints = {c.getJointInfo(self.body, j)[1].decode(): j for j in range(c.getNumJoints(self.body))}
        self.slides = [joints[f"gantry_{axis}"] for axis in "xyz"]
        self.gripper = Robotiq2F85(world, self.body, joints["gantry_z"], GRIPPER_DESCRIPTION, settings)  # the slide z carries the gripper
        self._anchor = self.T_world_home.copy()
        self._commanded = self.T_world_home.copy()
        self.max_speed = 0.5  # m/s along straight lines

    def _servo(self, T_world_base: np.ndarray, velocity: np.ndarray | None = None) -> None:
        """Drive the slides towards the base pose `T_world_base` (its position in the anchor frame)."""
        R, origin = self._anchor[:3, :3], self._anchor[:3, 3]
        target = R.T @ (np.asarray(T_world_base)[:3, 3] - origin)
        velocity = np.zeros(3) if velocity is None else R.T @ velocity
        kp, kd = SLIDE_GAINS
        self.world.client.setJointMotorControlArray(
            self.body, self.slides, pybullet.POSITION_CONTROL, targetPositions=target.tolist(),
            targetVelocities=velocity.tolist(), forces=[SLIDE_FORCE] * 3, positionGains=[kp] * 3,
            velocityGains=[kd] * 3,
        )

    def _teleport(self, T_world_base: np.ndarray) -> None:
        """Re-anchor the gantry at `T_world_base` with the slides at zero and at rest."""
        c = self.world.client
        self._anchor = np.asarray(T_world_base, dtype=float).copy()
        self._commanded = self._anchor.copy()
        position, orientation = pose_to_pb(self._anchor)
        c.resetBasePositionAndOrientation(self.body, position, orientation)
        for joint in self.slides:
            c.resetJointState(self.body, joint, 0.0, 0.0)
        self._servo(self._anchor)

    def reset_home(self, width: float | None = None) -> None:
        self._teleport(self.T_world_home)
        self.gripper.set_width(self.gripper.max_width if width is None else width)

    def plan(self, poses: list[np.ndarray]) -> tuple[list[list[list[np.ndarray]]], str]:
        """One candidate (a floating gripper reaches every pose): the first pose alone, then straight lines with
        waypoints every `PATH_RESOLUTION` m."""
        paths = [[np.asarray(poses[0], dtype=float)]]
        for index in range(1, len(poses)):
            paths.append(linear_poses(poses[index - 1], poses[index], PATH_RESOLUTION)[1:])
        return [paths], ""

    def configuration(self) -> np.ndarray:
        """The commanded base pose."""
        return self._commanded.copy()

    def free_space_paths(self, T_world_start: np.ndarray, T_world_target: np.ndarray) -> list[list[np.ndarray]]:
        """Poses to check on the way to a free-space target: the floating gripper is placed there directly."""
        return [[T_world_target]]

    def move_free(self, path: list[np.ndarray], on_step=None) -> None:
        """Free-space move of a floating gripper: placed at the end of the (checked) path, as in VGN."""
        self._teleport(path[-1])

    def place(self, T_world_base: np.ndarray) -> None:
        """Put the gripper base at a pose instantly (kinematic; used for checks and free-space moves)."""
        self._teleport(T_world_base)

    def follow(self, path: list[np.ndarray], speed: float, acceleration: float, on_step=None) -> None:
        """Move the base through waypoints at `speed` (m/s), one slide target per physics step; ends at rest on
        the last waypoint. `acceleration` is not used: the floating gripper moves as VGN's does, at full speed."""
        dt = self.world.physics.time_step
        for T_next in path:
            start = self._commanded[:3, 3]
            delta = np.asarray(T_next)[:3, 3] - start
            steps = max(1, int(round(float(np.linalg.norm(delta)) / (min(speed, self.max_speed) * dt))))
            for k in range(1, steps + 1):
                T = self._commanded.copy()
                T[:3, 3] = start + delta * k / steps
                self._servo(T, delta / (steps * dt))
                if on_step is not None:
                    on_step()
                self.world.step()
            self._commanded[:3, 3] = start + delta
        self._servo(self._commanded)

    def hold(self, steps: int, on_step=None) -> None:
        for _ in range(steps):
            if on_step is not None:
                on_step()
            self.world.step()

    def table_check_links(self) -> tuple[int, list[int]]:
        """(body, links) whose geometry must stay clear of the table (the slides have none)."""
        return self.body, list(range(self.gripper.base_link, self.world.client.getNumJoints(self.body)))
