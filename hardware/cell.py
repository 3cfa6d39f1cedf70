"""`RealCell`: the UR5 + Robotiq 2F-85 + RealSense cell behind the same `seggrasp.cell.Cell` interface as the twin.

A person places the object; the cell cannot know its mesh, so `object_mesh()` raises and the episode reconstructs
it from `capture()` with `seggrasp.perception.perceive_object(frames, workspace)`. `execute()` runs pre-grasp,
approach, close, lift, hold, judges the grasp by what the gripper reports (object detection when closing and
after the hold, the finger gap; `judge_hold`), names the failure, then puts the object back down and backs off. Every pose of the sequence is checked against the safety limits before the first command
is sent; a refused or unreachable grasp is reported as `reachable=False`, never raised. A lost connection or a
protective/emergency stop stops the arm and raises (`ConnectionLostError` / `RobotStoppedError`); raised while
putting the object back, the error's `outcome` is the grasp as judged after the hold.
"""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import numpy as np
import trimesh

from hardware.config import CellConfig, load_config
from hardware.errors import ConnectionLostError, HardwareError, MotionError, RobotStoppedError, SafetyError
from hardware.kinematics import inverse_kinematics
from hardware.realsense import RealSenseCamera
from hardware.robotiq import RobotiqGripper
from hardware.safety import SafetyGuard
from hardware.ur import URArm
from seggrasp.cell import MAX_SLIP, Frame, GraspOutcome
from seggrasp.hands import ROBOTIQ_2F85, Hand

log = logging.getLogger(__name__)

#: The object is put back this far above where it was grasped, so a slipped object is not pushed into the table.
PLACE_CLEARANCE = 0.01
#: A reset retracts straight up first when the gripper is more than this below its home height.
RETRACT_TOLERANCE = 0.02
#: The retract stops short of stretching the elbow straight: every 1 cm of it keeps the elbow bent by this much
#: (rad) on its current side. Up to a stretched elbow a moveL meets the singularity (a protective stop on the
#: robot; on the emulated cell, before sim/lab/kinematic.py refused it, a swing round to the other branch).
RETRACT_ELBOW_MARGIN = 0.3
RETRACT_STEP = 0.01
#: The perception box reaches this far below the table top, so the table plane can be measured.
PERCEPTION_BELOW_TABLE = 0.02


def make_guard(config: CellConfig) -> SafetyGuard:
    """The safety guard for a cell configuration (fingertip, pad and flange geometry from the config)."""
    return SafetyGuard(config.limits, finger_reach=0.5 * config.gripper.stroke,
                       tip_beyond_origin=config.gripper.tip_beyond_origin,
                       flange_in_gripper=np.linalg.inv(config.robot.T_flange_gripper)[:3, 3])


def _translated(T: np.ndarray, offset_world: np.ndarray | None = None, along_z: float = 0.0) -> np.ndarray:
    """`T` moved by `offset_world` (world frame) and by `along_z` along its own z axis."""
    out = np.array(T, dtype=np.float64, copy=True)
    out[:3, 3] += out[:3, 2] * along_z
    if offset_world is not None:
        out[:3, 3] += offset_world
    return out


def judge_hold(closed_on_object: bool, held: bool, width_closed: float, width_held: float) -> str:
    """The failure the real cell can see from its gripper (`seggrasp.cell.FAILURES`; "" = success).

    It knows whether the fingers stopped on an object when closing (`empty_close` if not), whether they still
    hold one after lift and hold (`slipped` if not), and the finger gap: when it changed by more than
    `MAX_SLIP` the object moved in the fingers (`slipped`). A rotation about the grasp axis leaves the gap
    unchanged, so the real cell cannot report `rotated` (the twin can)."""
    if not closed_on_object:
        return "empty_close"
    if not held or abs(width_held - width_closed) > MAX_SLIP:
        return "slipped"
    return ""


class RealCell:
    """The real robot cell. Build it with `RealCell.from_config(path, dry_run=False)`."""

    models_scene = False  # `check_reach` checks IK and the safety limits only: it knows nothing of the object
    robot_name = "ur5"  # the robot system, as the twin names it (`sim.cell.ROBOTS`): a UR arm with the 2F-85

    def __init__(self, config: CellConfig, arm: URArm, gripper: RobotiqGripper, cameras: list[RealSenseCamera],
                 *, dry_run: bool = False) -> None:
        self.config = config
        self.arm = arm
        self.gripper = gripper
        self.cameras = cameras
        self.dry_run = dry_run
        self._closed = False

    @property
    def hand(self) -> Hand:
        """The cell's 2F-85 with the stroke measured on it (`gripper.stroke` of the config)."""
        return replace(ROBOTIQ_2F85, stroke=self.config.gripper.stroke)

    @classmethod
    def from_config(cls, path: str | Path, dry_run: bool = False, *,
                    control_factory: Callable[[str], Any] | None = None,
                    receive_factory: Callable[[str], Any] | None = None,
                    pipeline_factory: Callable[[str], Any] | None = None,
                    align_factory: Callable[[], Any] | None = None,
                    camera_warmup_frames: int = 15, require_calibration: bool = True,
                    with_cameras: bool = True) -> RealCell:
        """Load the YAML config, connect the arm, gripper and cameras, and activate the gripper.

        In dry run nothing connects to the robot or gripper (motions are checked and logged only); the cameras,
        which move nothing, are still used. The factories replace the ur_rtde / pyrealsense2 objects (tests).
        `require_calibration=False` accepts uncalibrated cameras (to run the hand-eye calibration itself);
        `with_cameras=False` leaves the cameras out (a grasp at a known point needs none).
        """
        config = load_config(path, require_calibration=require_calibration)
        guard = make_guard(config)
        arm = URArm(config.robot, guard, dry_run=dry_run, control_factory=control_factory,
                    receive_factory=receive_factory)
        gripper = RobotiqGripper(config.gripper, guard, dry_run=dry_run)
        cameras = [RealSenseCamera(camera, pipeline=pipeline_factory(camera.serial) if pipeline_factory else None,
                                   align=align_factory() if align_factory else None,
                                   warmup_frames=camera_warmup_frames)
                   for camera in (config.cameras if with_cameras else ())]
        cell = cls(config, arm, gripper, cameras, dry_run=dry_run)
        try:
            arm.connect()
            gripper.connect()
            if not gripper.is_active():
                gripper.activate()
            for camera in cameras:
                camera.start()
        except BaseException:
            cell.close()
            raise
        log.info("real cell ready%s: %d camera(s)", " (DRY RUN: the robot will not move)" if dry_run else "",
                 len(cameras))
        return cell

    # ----------------------------------------------------------------------------------------------------- queries
    @property
    def workspace_bounds(self) -> np.ndarray:
        """(2, 3) world-frame box [min, max] of the workspace (where perception looks for the object)."""
        return np.stack([self.config.limits.workspace_min, self.config.limits.workspace_max])

    @property
    def current_object(self) -> None:
        """Always None: the real cell does not know which object a person placed (SimCell gives its model)."""
        return None

    @property
    def workspace(self):
        """The workspace as `seggrasp.perception.Workspace` (reaching 2 cm below the table, where perception
        measures the table plane) for `perceive_object(frames, workspace)`."""
        from seggrasp.perception import Workspace  # the perception module is only needed by perceiving episodes

        lower = self.config.limits.workspace_min.copy()
        lower[2] = min(lower[2], self.table_height - PERCEPTION_BELOW_TABLE)
        return Workspace(tuple(lower), tuple(self.config.limits.workspace_max), self.table_height)

    @property
    def table_height(self) -> float:
        """z of the table top in the world frame."""
        return self.config.limits.table_height

    # -------------------------------------------------------------------------------------------------- Cell API
    def reset(self, seed: int | None = None, object_id: str | None = None) -> None:
        """Open the gripper, retract straight up, move home, and ask the operator to place the object.

        The seed is only logged: a person places the object. The straight retract keeps the joint move home away
        from the table when the last grasp ended low.
        """
        self._check_open()
        motion = self.config.motion
        self.gripper.open()
        current = self.arm.tcp_pose()
        home_height = min(float(self.arm.home_pose()[2, 3]), float(self.config.limits.workspace_max[2]))
        if current[2, 3] < home_height - RETRACT_TOLERANCE:
            retract = current.copy()
            retract[2, 3] = self._retract_height(current, home_height)
            if retract[2, 3] > current[2, 3] + RETRACT_STEP / 2:
                self.arm.move_linear(retract, motion.tool_speed, motion.tool_acceleration)
        self.arm.move_joints(self.config.robot.home_joints, motion.joint_speed, motion.joint_acceleration)
        what = f"object {object_id!r}" if object_id else "the object"
        prompt = (f"Place {what} on the table inside the workspace box "
                  f"{np.round(self.workspace_bounds, 3).tolist()} (seed {seed}), clear of the gripper.")
        log.warning(prompt)
        if self.config.interactive and sys.stdin is not None and sys.stdin.isatty():
            input(prompt + " Press Enter when done. ")

    def _retract_height(self, current: np.ndarray, home_height: float) -> float:
        """The highest z up to `home_height` a straight retract from `current` reaches with the elbow bent by
        `RETRACT_ELBOW_MARGIN` on its present side at every step (the model's nominal kinematics)."""
        elbow = float(self.arm.joints()[2])
        flange_in_gripper = np.linalg.inv(self.config.robot.T_flange_gripper)
        reached, T = float(current[2, 3]), current.copy()
        while reached < home_height:
            T[2, 3] = min(reached + RETRACT_STEP, home_height)
            solutions = inverse_kinematics(self.config.robot.model, T @ flange_in_gripper)
            if not any(q[2] * elbow > 0 and abs(q[2]) >= RETRACT_ELBOW_MARGIN for q in solutions):
                break
            reached = float(T[2, 3])
        return reached

    def capture(self) -> list[Frame]:
        """One aligned RGB-D frame from every camera (wrist cameras placed by the gripper's current pose)."""
        self._check_open()
        wrist = any(camera.config.mount == "wrist" for camera in self.cameras)
        T_world_gripper = self.arm.tcp_pose() if wrist else None
        return [camera.capture(T_world_gripper) for camera in self.cameras]

    def object_mesh(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        """Not available on the real robot: the mesh must be reconstructed from the camera frames."""
        raise NotImplementedError(
            "the real cell does not know the object's mesh or pose; reconstruct it from cell.capture() with "
            "seggrasp.perception.perceive_object(frames, workspace) (the mesh is then in the world frame)")

    def execute(self, T_world_grasp: np.ndarray, width: float) -> GraspOutcome:
        """Pre-grasp, approach, close, lift, hold and judge; then put the object back and back off.

        `T_world_grasp` is the gripper frame (pad centres) at the grasp and `width` the opening at which the pads
        meet the object. Returns `reachable=False` without moving when any pose breaks a limit or has no IK.
        """
        poses, refusal = self._planned_poses(T_world_grasp, width)
        if refusal:
            return self._not_reached(refusal)
        cfg, motion = self.config, self.config.motion
        pre, grasp, lift, place, retreat = (pose for _, pose in poses)
        opening = min(cfg.gripper.stroke, width + motion.opening_margin)

        stage = "opening the gripper"
        try:
            self.gripper.move_to_width(opening)
            stage = "moving to the pre-grasp pose"
            self.arm.move_linear(pre, motion.tool_speed, motion.tool_acceleration)
            stage = "approaching"
            self.arm.move_linear(grasp, motion.tool_speed, motion.tool_acceleration)
        except (SafetyError, MotionError) as exc:
            log.warning("grasp not reached while %s: %s", stage, exc)
            return self._not_reached(f"{stage}: {exc}", failure="collision")
        except HardwareError as exc:
            raise self._abort(stage, exc) from exc

        try:
            stage = "closing the gripper"
            grip = self.gripper.close(speed=cfg.gripper.speed, force=cfg.gripper.force)
            stage = "lifting"
            self.arm.move_linear(lift, motion.tool_speed, motion.tool_acceleration)
            stage = "holding"
            if not self.dry_run:
                time.sleep(motion.hold_time)
            held = self.gripper.object_detected()
            width_held = self.gripper.width()
        except HardwareError as exc:
            raise self._abort(stage, exc) from exc
        outcome = self._judged(grip.object_detected, held, grip.width, width_held)

        try:
            if held or self.dry_run:  # a dry run plans the whole sequence
                stage = "putting the object back"
                self.arm.move_linear(place, motion.tool_speed, motion.tool_acceleration)
            stage = "releasing"
            self.gripper.move_to_width(opening)
            if held or self.dry_run:
                stage = "backing off"
                self.arm.move_linear(retreat, motion.tool_speed, motion.tool_acceleration)
        except HardwareError as exc:
            raise self._abort(stage, exc, outcome) from exc
        return outcome

    def _judged(self, closed_on_object: bool, held: bool, width_closed: float, width_held: float) -> GraspOutcome:
        """The grasp's outcome from what the gripper reported when closing and after the hold (`judge_hold`)."""
        cfg = self.config
        failure = "" if self.dry_run else judge_hold(closed_on_object, held, width_closed, width_held)
        message = ("dry run: motions planned and logged, nothing moved" if self.dry_run else
                   f"object {'held' if held else 'not held'} after a {cfg.motion.hold_time:.1f} s hold "
                   f"(closed on an object: {closed_on_object}, finger gap {width_held * 1000:.1f} mm)"
                   + (f": {failure}" if failure else ""))
        log.info("grasp outcome: %s", message)
        lifted = held and not failure
        return GraspOutcome(reachable=True, lifted=lifted, lift_height=cfg.motion.lift_height if lifted else 0.0,
                            contact_force=cfg.gripper.force if held else 0.0, contacts_observed=False,
                            message=message, failure=failure)

    def close(self) -> None:
        """Stop the cameras, close the gripper socket and shut down the RTDE connection. Idempotent."""
        if self._closed:
            return
        self._closed = True
        for camera in self.cameras:
            camera.stop()
        self.gripper.disconnect()
        self.arm.close()
        log.info("real cell closed")

    # --------------------------------------------------------------------------------------------------- helpers
    def _check_open(self) -> None:
        if self._closed:
            raise ConnectionLostError("the real cell was closed")

    def check_reach(self, T_world_grasp: np.ndarray, width: float) -> str:
        """Why `execute` would refuse this grasp without moving (a width beyond the stroke; a pose of the
        pre-grasp, grasp, lift, place and retreat, or a straight path between them, outside the safety limits or
        without inverse kinematics); "" when it would go ahead. Nothing moves."""
        return self._planned_poses(T_world_grasp, width)[1]

    def _planned_poses(self, T_world_grasp: np.ndarray, width: float) -> tuple[list[tuple[str, np.ndarray]], str]:
        """The grasp's named motion poses (`_motion_poses`; none for a width beyond the stroke) and why they would be
        refused ("" when they pass), for `check_reach` and `execute`."""
        self._check_open()
        T_grasp = np.asarray(T_world_grasp, dtype=np.float64)
        if T_grasp.shape != (4, 4) or not np.all(np.isfinite(T_grasp)):
            raise ValueError(f"T_world_grasp must be a finite 4x4 matrix, got shape {T_grasp.shape}")
        if not np.isfinite(width) or width < 0:
            raise ValueError(f"grasp width must be a non-negative number, got {width!r}")
        if width > self.config.gripper.stroke:
            return [], f"grasp width {width:.4f} m exceeds the gripper stroke {self.config.gripper.stroke} m"
        poses = self._motion_poses(T_grasp, width)
        try:
            for (name_a, pose_a), (name_b, pose_b) in zip(poses, poses[1:]):
                self.arm.guard.check_pose(pose_a, name_a)
                self.arm.guard.check_linear_path(pose_a, pose_b, f"{name_a} -> {name_b}")
            for name, pose in poses:
                if not self.arm.has_ik_solution(pose):
                    return poses, f"{name} pose has no inverse-kinematics solution"
        except SafetyError as exc:
            return poses, f"refused by the safety limits: {exc}"
        return poses, ""

    def _motion_poses(self, T_world_grasp: np.ndarray, width: float) -> list[tuple[str, np.ndarray]]:
        """The commanded TCP poses of a grasp, in order: pre-grasp, grasp, lift, place, retreat.

        Command frame: the controller's TCP is the fully-open pad centre; at `width` the pads sit `pad_shift(width)`
        further along +z, so the command goes back by that much."""
        motion = self.config.motion
        grasp = _translated(np.asarray(T_world_grasp, dtype=np.float64), along_z=-self.config.gripper.pad_shift(width))
        pre = _translated(grasp, along_z=-motion.pregrasp_distance)
        lift = _translated(grasp, offset_world=np.array([0.0, 0.0, motion.lift_height]))
        place = _translated(grasp, offset_world=np.array([0.0, 0.0, PLACE_CLEARANCE]))
        retreat = _translated(place, along_z=-motion.pregrasp_distance)
        return [("pre-grasp", pre), ("grasp", grasp), ("lift", lift), ("place", place), ("retreat", retreat)]

    def _not_reached(self, message: str, failure: str = "unreachable") -> GraspOutcome:
        log.warning("grasp not executed: %s", message)
        return GraspOutcome(reachable=False, lifted=False, lift_height=0.0, contacts_observed=False,
                            message=message, failure=failure)

    def _abort(self, stage: str, exc: HardwareError, outcome: GraspOutcome | None = None) -> HardwareError:
        """Stop the arm and turn a hardware failure into an error that says what the cell was doing; after the
        hold it carries the grasp's judged `outcome` (the put-back is no part of the grasp)."""
        self.arm.stop()
        kind = type(exc) if isinstance(exc, (ConnectionLostError, RobotStoppedError)) else HardwareError
        log.error("grasp aborted while %s: %s", stage, exc)
        error = kind(f"grasp aborted while {stage}: {exc}")
        error.outcome = outcome
        return error
