"""The grasp-and-lift primitive of the twin (`GraspPrimitive`, run by `sim.cell.SimCell.execute`) and its numbers.

1. plan: pre-grasp (10 cm back along the approach axis z), grasp, and lift (20 cm up) poses; for the arm every
   waypoint must pass the IK reachability check, no configuration on the way (free-space path to the pre-grasp,
   approach, lift) may bring the robot closer to the table than `table_clearance` (the fingertips closer than
   `fingertip_table_clearance`, which a pinch of a part lying flat needs), and the free-space path may not touch
   the object; otherwise the grasp is `reachable=False` and nothing moves;
2. open the gripper to width + margin, move to the pre-grasp through free space (the arm in joint space at its
   speed limit, simulated; the floating gripper is placed there), approach in a straight line, close until the
   finger stalls, lift, hold 1 s (objects under 100 g at more solver iterations: `PhysicsSettings`);
3. report: lifted (the grasped point raised >= 18 cm, both fingertips still touching the object, and the object
   moved < 10 mm / 15 deg relative to the gripper from the close to the end of the hold), else the failure
   (`unreachable`, `collision`, `pushed`, `empty_close`, `slipped`, `rotated`); the rise of the grasped point, the
   mesh faces the fingertips (pads and the inner-finger rims they sit on) touched (contact points in the object
   frame -> nearest face) weighted by their normal force, and the total normal force while holding.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from seggrasp.cell import LIFT_SUCCESS, MAX_ROTATION_DEG, MAX_SLIP, GraspOutcome
from seggrasp.objects import ObjectModel
from sim.recording import StageRecorder
from sim.world import World

#: The object's drift in the fingers is checked every this many physics steps during lift and hold.
TRACK_EVERY = 4
#: Another object on the table whose origin rose this much (m) by the end of the hold was lifted along.
LIFTED_ALONG = 0.05


class PadContact(NamedTuple):
    """One fingertip-object contact: the side (0 = left, 1 = right), the point and the contact normal (from the
    object towards the fingertip) in the object's frame, and the normal force (N)."""

    side: int
    point: np.ndarray
    normal: np.ndarray
    force: float


@dataclass(frozen=True)
class GraspSettings:
    """The grasp-and-lift primitive's numbers (metres, m/s, seconds). The lift runs at the real cell's tool speed
    (hardware/cell.example.yaml `motion.tool_speed`, 0.10 m/s); at the 0.30 m/s used before, heavy tools held off
    their centre of mass slipped more (oracle Suc. on frying pans, hammers, screwdrivers, spatulas and toothbrushes
    0.591 at 0.30 m/s, 0.659 at 0.10 m/s). An arm's approach and lift start and end at rest, ramping at the real
    cell's tool acceleration (`motion.tool_acceleration`, 0.5 m/s^2) as its linear moves do."""

    pregrasp_distance: float = 0.10
    width_margin: float = 0.02
    approach_speed: float = 0.25
    lift_height: float = 0.20
    lift_speed: float = 0.10
    tool_acceleration: float = 0.5
    hold_time: float = 1.0
    lift_success: float = LIFT_SUCCESS  # the grasped point must rise this much
    max_slip: float = MAX_SLIP  # the grasped point may move this much relative to the gripper from close to hold
    max_rotation_deg: float = MAX_ROTATION_DEG  # and the object turn this much
    table_clearance: float = 0.003
    # the fingertips (inner fingers and pads) may come this close: a fingertip pinch of a part lying flat
    # (seggrasp.hands.Hand.pinch_table_clearance) puts them 1.0-1.5 mm above the table
    fingertip_table_clearance: float = 0.001
    settle_time: float = 1.0  # at most; settling stops once the object rests


class GraspPrimitive:
    """One execution of pre-grasp, approach, close, lift and hold on an embodiment (arm or floating gripper).

    Success is judged as on the real cell: the grasped point rises at least `lift_success` and the object moves
    less than `max_slip` / `max_rotation_deg` relative to the gripper from the close to the end of the hold;
    otherwise the outcome names its failure (`seggrasp.cell.FAILURES`)."""

    def __init__(
        self, world: World, robot, object_body: int, model: ObjectModel, settings: GraspSettings,
        recorder: StageRecorder | None = None, neighbours: Sequence[tuple[int, str]] = (),
    ) -> None:
        """`neighbours`: (body, object id) of the other objects on the table, which no configuration of the motion
        may touch and whose displacement the outcome reports."""
        self.world, self.robot, self.object_body, self.model, self.settings = world, robot, object_body, model, settings
        self.gripper = robot.gripper
        self.recorder = recorder
        self.neighbours = tuple(neighbours)
        self._neighbours_start = [world.body_pose(body) for body, _ in self.neighbours]

    def plan(self, T_world_grasp: np.ndarray, width: float) -> tuple[list, str]:
        """The robot's candidate paths (`UR5Arm.plan`) through the grasp's pre-grasp, grasp and lift poses of the
        gripper base, or ([], "unreachable: " and why none)."""
        s = self.settings
        self._T_base_tcp = self.gripper.T_base_tcp(min(width, self.gripper.max_width))
        T_world_base = T_world_grasp @ np.linalg.inv(self._T_base_tcp)
        T_pre = T_world_base.copy()
        T_pre[:3, 3] -= s.pregrasp_distance * T_world_base[:3, 2]
        T_lift = T_world_base.copy()
        T_lift[2, 3] += s.lift_height
        candidates, reason = self.robot.plan([T_pre, T_world_base, T_lift])
        return candidates, "" if candidates else f"unreachable: {reason}"

    def motion(self, T_world_grasp: np.ndarray, width: float) -> tuple[tuple | None, str, str]:
        """The grasp's checked motion from the robot's current configuration: ((free-space transit, candidate
        paths of `plan`), "", "") for the first IK branch (nearest home first) with a free-space path whose whole
        motion passes `collision_on_path`; else (None, failure, message) with the failure `unreachable` (no IK plan)
        or `collision`. The checks pose the robot kinematically and put it back, the fingers as they were."""
        candidates, refusal = self.plan(T_world_grasp, width)
        if not candidates:
            return None, "unreachable", refusal
        opening = self._opening(width)
        start, fingers, reasons = self.robot.configuration(), self.gripper.width(), []
        plan = None
        for candidate in candidates:  # IK branches, nearest home first
            for transit in self.robot.free_space_paths(start, candidate[0][0]):
                # the fingers close at the grasp (the approach's last waypoint) and stay closed on the lift
                reason = self.collision_on_path(transit, candidate[1], opening, candidate[1][-1:] + candidate[2], width)
                if not reason:
                    plan = (transit, candidate)
                    break
                reasons.append(reason)
            if plan is not None:
                break
        self.robot.place(start)  # the checks posed the robot kinematically: put it back
        self.gripper.set_width(fingers)
        if plan is None:
            return None, "collision", reasons[0] + (
                f" (and {len(reasons) - 1} other paths collide)" if len(reasons) > 1 else "")
        return plan, "", ""

    def _opening(self, width: float) -> float:
        """The finger opening for the approach: the grasp's width plus `width_margin`, within the stroke."""
        return min(width + self.settings.width_margin, self.gripper.max_width)

    def run(self, T_world_grasp: np.ndarray, width: float) -> GraspOutcome:
        plan, failure, message = self.motion(T_world_grasp, width)
        if plan is None:
            if failure == "collision":
                self.gripper.set_width(self.gripper.max_width)
            return GraspOutcome(False, False, 0.0, message=message, failure=failure,
                                disturbance=(0.0,) * len(self.neighbours))
        transit, paths = plan
        self.gripper.set_width(self._opening(width))
        self.robot.move_free(transit)
        self._snap("pre-grasp")
        return self._grasp_and_lift(paths)

    def _grasp_and_lift(self, paths: list) -> GraspOutcome:
        """Approach, close, lift and hold along a checked plan; judge the grasp (class docstring)."""
        s = self.settings
        T_obj_start = self.world.body_pose(self.object_body)
        self.robot.follow(paths[1], s.approach_speed, s.tool_acceleration)
        moved, turned = _moved(T_obj_start, self.world.body_pose(self.object_body))
        pushed = moved > s.max_slip or turned > np.deg2rad(s.max_rotation_deg)
        self.gripper.close_until_stall()
        self._snap("closed")
        touched = self.pad_contacts()
        if {c.side for c in touched} != {0, 1}:
            failure = "pushed" if pushed else "empty_close"
            return self._outcome(failure, f"{failure}: the fingers closed on no grasp", touched, 0.0, 0.0)
        T_obj_grasp = np.linalg.inv(self.world.body_pose(self.object_body)) @ self.T_world_tcp()
        point = T_obj_grasp[:, 3]  # the grasped point, object frame
        T_tcp_obj0 = np.linalg.inv(T_obj_grasp)
        drift, steps = [0.0, 0.0], [0]

        def track() -> None:  # every few physics steps: the largest drift of the object in the fingers
            steps[0] += 1
            if steps[0] % TRACK_EVERY:
                return
            T_tcp_obj = np.linalg.inv(self.T_world_tcp()) @ self.world.body_pose(self.object_body)
            moved, turned = _moved(T_tcp_obj0, T_tcp_obj, point)
            drift[0], drift[1] = max(drift[0], moved), max(drift[1], turned)

        self.robot.follow(paths[2], s.lift_speed, s.tool_acceleration, on_step=track)
        self._snap("lifted")
        hold_steps = int(round(s.hold_time / self.world.physics.time_step))
        self.robot.hold(hold_steps - 10, on_step=track)
        forces: list[float] = []
        for _ in range(10):
            self.world.step()
            forces.append(self._pad_normal_force())
        steps[0] = -1
        track()
        self._snap("held")
        final = self.pad_contacts()
        rise = float((self.world.body_pose(self.object_body) @ point)[2] - (T_obj_start @ point)[2])
        held = {c.side for c in final} == {0, 1}
        if not held or rise < s.lift_success:
            failure = "pushed" if pushed and not held else "slipped"
            message = f"{failure}: " + ("dropped" if not held else f"grasped point rose only {rise * 100:.1f} cm")
        elif drift[1] > np.deg2rad(s.max_rotation_deg):
            failure, message = "rotated", f"rotated: held but turned {np.rad2deg(drift[1]):.0f} deg in the fingers"
        elif drift[0] > s.max_slip:
            failure, message = "slipped", f"slipped: held but moved {drift[0] * 1000:.0f} mm in the fingers"
        else:
            failure, message = "", "lifted"
        return self._outcome(failure, message, touched + final, rise, float(np.mean(forces)))

    def _outcome(self, failure: str, message: str, contacts: list[PadContact], rise: float, force: float
                 ) -> GraspOutcome:
        """The outcome with the touched faces weighted by the normal force of their contacts; closes a recording."""
        faces, weights = touched_faces(self.model.mesh, [c.point for c in contacts], [c.force for c in contacts])
        if self.recorder is not None:
            self.recorder.write(f"{self.model.object_id}: {message}")
        ends = [self.world.body_pose(body) for body, _ in self.neighbours]
        return GraspOutcome(
            reachable=True, lifted=not failure, lift_height=max(rise, 0.0), touched_faces=faces,
            contact_force=force, message=message, failure=failure, touched_weights=weights,
            disturbance=tuple(_moved(start, end)[0] for start, end in zip(self._neighbours_start, ends)),
            lifted_along=sum(end[2, 3] - start[2, 3] > LIFTED_ALONG for start, end in zip(self._neighbours_start, ends)),
        )

    def T_world_tcp(self) -> np.ndarray:
        """The gripper's TCP now (its x axis is the closing axis)."""
        return self.world.link_pose(self.gripper.body, self.gripper.base_link) @ self._T_base_tcp

    def _snap(self, stage: str) -> None:
        if self.recorder is not None:
            self.recorder.snap(self, stage)

    def collision_on_path(self, transit: list, approach: list, opening: float, closed: list = (),
                          width: float = 0.0) -> str:
        """'' if the robot keeps `table_clearance` from the table (its fingertips `fingertip_table_clearance`) on
        every configuration - the free-space `transit` and the `approach` with the gripper opened to `opening`, the
        `closed` ones (grasp and lift) with it closed to `width`, where the fingertips reach furthest along the
        approach - and does not touch the object on the `transit` (the rest may touch it) nor another object on
        the table anywhere; else the reason."""
        client = self.world.client
        body, links = self.robot.table_check_links()
        links = set(links)
        fingertips = {link for side in self.gripper.fingertip_links for link in side}
        s = self.settings
        configs, n_open = [*transit, *approach, *closed], len(transit) + len(approach)
        for index, config in enumerate(configs):
            if index in (0, n_open):  # open from the start, closed from the grasp on
                self.gripper.set_width(opening if index < n_open else width)
            self.robot.place(config)
            for point in client.getClosestPoints(body, self.world.table_id,
                                                 max(s.table_clearance, s.fingertip_table_clearance)):
                limit = s.fingertip_table_clearance if point[3] in fingertips else s.table_clearance
                if point[3] in links and point[8] < limit:
                    name = client.getJointInfo(body, point[3])[12].decode() if point[3] >= 0 else "base"
                    return f"robot would touch the table ({name} at waypoint {index + 1} of {len(configs)})"
            if index < len(transit) and client.getClosestPoints(body, self.object_body, 0.0):
                where = "at the pre-grasp" if index == len(transit) - 1 else f"at transit waypoint {index + 1}"
                return f"robot would hit the object {where}"
            for neighbour, name in self.neighbours:
                if client.getClosestPoints(body, neighbour, 0.0):
                    return f"robot would hit the {name} beside the object (waypoint {index + 1} of {len(configs)})"
        return ""

    def pad_contacts(self) -> list[PadContact]:
        """Every fingertip-object contact now (a fingertip is the inner finger with its pad: the finger mesh's rim
        touches as well as the pad box)."""
        T_obj_world = np.linalg.inv(self.world.body_pose(self.object_body))
        contacts = []
        for side, links in enumerate(self.gripper.fingertip_links):
            for link in links:
                for point in self.world.client.getContactPoints(self.robot.body, self.object_body, linkIndexA=link):
                    contacts.append(PadContact(side, (T_obj_world @ np.append(point[6], 1.0))[:3],
                                               T_obj_world[:3, :3] @ np.asarray(point[7]), float(point[9])))
        return contacts

    def _pad_normal_force(self) -> float:
        """Total normal force (N) between the fingertips and the object."""
        return float(sum(c.force for c in self.pad_contacts()))


def touched_faces(mesh: trimesh.Trimesh, points: Sequence[np.ndarray], forces: Sequence[float]
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The faces of `mesh` nearest to contact points (its frame) and the summed normal force on each (uniform
    weights when no contact carried force): a `GraspOutcome`'s `touched_faces` and `touched_weights`."""
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    _, _, triangles = trimesh.proximity.closest_point(mesh, np.asarray(points, dtype=np.float64))
    faces, inverse = np.unique(np.asarray(triangles, dtype=np.int64), return_inverse=True)
    weights = np.bincount(inverse.reshape(-1), weights=np.asarray(forces, dtype=np.float64), minlength=len(faces))
    if weights.sum() <= 0:
        weights = np.ones(len(faces))
    return faces, weights


def _moved(T_a: np.ndarray, T_b: np.ndarray, point: np.ndarray | None = None) -> tuple[float, float]:
    """(distance m, angle rad) between two poses of a body: how far `point` (body frame; default its origin)
    moved and how far the body turned."""
    point = np.array([0.0, 0.0, 0.0, 1.0]) if point is None else point
    distance = float(np.linalg.norm((T_a @ point)[:3] - (T_b @ point)[:3]))
    return distance, float(Rotation.from_matrix(T_a[:3, :3].T @ T_b[:3, :3]).magnitude())
