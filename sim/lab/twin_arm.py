"""The twin's UR5 behind the emulated controller (`TwinArm`, the controller's `ArmModel`), in the RTDE base frame.

A moveJ, moveL or stop is planned by the controller's kinematic model (`sim.lab.kinematic.KinematicArm`, started at
the arm's actual joints: trapezoidal profiles, inverse kinematics, joint limits, a safety plane at the table top)
and tracked every physics step by the UR5's joint servos (`UR5Arm._command`, as the twin's own motions); a motion
ends when the arm has settled on its end (and, when the scene renders its cameras after every motion, once they
have been rendered). The arm halts where it is on a safety stop: one the controller sets, or a
protective stop of its own when, during a motion, a link of the arm (upper arm to wrist) touches the table, the
robot presses on the table (directly or through the object) and on the other objects of a scene with more than
`PROTECTIVE_FORCE` in all for `PROTECTIVE_STEPS` physics steps, or a joint falls more than `PATH_DEVIATION` behind
its path for as many steps or stays `END_DEVIATION` short of its end (something blocks the arm: e.g. the forearm
on the object it carries). Brushing another object aside stops nothing: a real arm feels the force it takes, not
the touch. Assumption, not checked against a UR: its collision detection (joint torques against the model;
"position deviates from path") stops a blocked arm at about those deviations. The scene (sim/lab/twin.py) steps it
and holds its lock around every call.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from sim.lab.controller import HOME_Q_WIRE
from sim.lab.kinematic import KinematicArm, pose_matrix, pose_vector
from sim.robot import T_BASELINK_DHBASE, UR5Arm, dh_forward
from sim.world import TABLE_TOP_Z, pose_to_pb

if TYPE_CHECKING:
    from sim.lab.twin import TwinScene

log = logging.getLogger(__name__)


#: Where the twin's URDF `base_link` sits in its world, the RTDE base frame (module docstring).
T_WORLD_BASELINK = np.linalg.inv(T_BASELINK_DHBASE)
#: Force (N) the robot may press on the table, directly or through the object, before the emulated controller
#: stops the arm: the tool force limit of the emulated safety configuration.
PROTECTIVE_FORCE = 150.0
#: Physics steps in a row the force (or the deviation) must stay above its limit (one step's solver spike does not
#: stop the arm).
PROTECTIVE_STEPS = 3
#: How far (rad) a joint may trail its path before the controller calls the arm blocked: its servos track within
#: 0.004 rad through the emulated cell's grasps (twin UR5, 125 Hz references); an arm whose forearm pressed on the
#: bottle it carried trailed by 0.26 rad and its motion ended 60 mm short.
PATH_DEVIATION = 0.05
#: How far (rad) a joint may still be from the motion's end when `SETTLE_TIME` runs out: an arm held this far short
#: (a block met near the end, under `PATH_DEVIATION`) is stopped too; a free one settles within `SETTLED_ERROR`.
END_DEVIATION = 0.01
#: A motion has ended once every joint is this close (rad) to its end and slower than `SETTLED_SPEED` (rad/s), or
#: `SETTLE_TIME` (s) after its reference came to rest.
SETTLED_ERROR = 1e-3
SETTLED_SPEED = 0.01
SETTLE_TIME = 1.0


class TwinArm:
    """The twin's UR5 behind the emulated controller (an `ArmModel`): poses in the RTDE base frame with the active
    TCP, joints in rad. A command starts a `KinematicArm` at the arm's actual joints (the controller's motion
    planner: its profiles, inverse kinematics, joint limits and the table's safety plane); every physics step the
    joint servos track that reference. Getters return the state after the last physics step without touching
    PyBullet."""

    def __init__(self, scene: TwinScene) -> None:
        self.scene = scene
        self.safety_status = "normal"
        self.stop_reason = ""
        self._tcp = np.eye(4)
        self._q = HOME_Q_WIRE.copy()
        self._qd = np.zeros(6)
        self._reference: KinematicArm | None = None
        self._moving = False
        self._over_force = 0
        self._deviating = 0
        self._arm_links: set[int] = set()  # the robot's links from the upper arm to wrist 3

    # --- state (cached) ---
    def step(self, dt: float) -> None:
        """Advance the physics by `dt` when no clock thread runs (tests); the clock steps it otherwise."""
        if not self.scene.clock_running:
            self.scene.advance(dt)

    def actual_q(self) -> list[float]:
        return [float(v) for v in self._q]

    def actual_qd(self) -> list[float]:
        return [float(v) for v in self._qd]

    def actual_tcp_pose(self) -> list[float]:
        return pose_vector(dh_forward(self._q) @ self._tcp)

    def is_moving(self) -> bool:
        return self._moving

    def set_tcp(self, pose: list[float]) -> None:
        self._tcp = pose_matrix(pose)

    # --- queries and commands, on the controller's kinematic model at the actual joints ---
    def _planner(self) -> KinematicArm:
        lower, upper = self.scene.joint_limits
        planner = KinematicArm(self._q, lower, upper, planes=(((0.0, 0.0, 1.0), TABLE_TOP_Z),))
        planner.set_tcp(pose_vector(self._tcp))
        return planner

    def joints_within_limits(self, q: list[float]) -> bool:
        return self._planner().joints_within_limits(q)

    def pose_within_limits(self, pose: list[float]) -> bool:
        """Reachable within the joint limits, with the TCP above the table plane (the emulated safety plane)."""
        return self._planner().pose_within_limits(pose)

    def ik_has_solution(self, pose: list[float], qnear: list[float] | None = None) -> bool:
        return self._planner().ik_has_solution(pose, qnear)

    def inverse_kinematics(self, pose: list[float], qnear: list[float] | None = None) -> list[float] | None:
        return self._planner().inverse_kinematics(pose, qnear)

    def move_joints(self, q: list[float], speed: float, acceleration: float) -> None:
        self._start(lambda planner: planner.move_joints(q, speed, acceleration))

    def move_linear(self, pose: list[float], speed: float, acceleration: float) -> None:
        self._start(lambda planner: planner.move_linear(pose, speed, acceleration))

    def _start(self, command) -> None:
        if self.safety_status != "normal":  # a stopped arm starts nothing (the controller has stopped the program)
            return
        with self.scene.lock:
            planner = self._planner()
            command(planner)
            if planner.is_moving():
                self._reference, self._moving = planner, True

    def stop(self, deceleration: float) -> None:
        """Decelerate the running motion to rest along its path (stopL / stopJ)."""
        with self.scene.lock:
            if self._reference is not None:
                self._reference.stop(deceleration)

    # --- per physics step (the scene's lock is held) ---
    def reload(self, robot: UR5Arm) -> None:
        """After a placement rebuilt the robot: turn its base into the RTDE frame and put the arm back where it
        was, at rest."""
        position, orientation = pose_to_pb(T_WORLD_BASELINK)
        robot.world.client.resetBasePositionAndOrientation(robot.body, position, orientation)
        robot.place(self._q)
        self._reference, self._moving, self._qd = None, False, np.zeros(6)
        self._arm_links = set(range(robot.arm_joints[1], robot.gripper.base_link))

    def before_step(self, robot: UR5Arm, dt: float) -> None:
        """Command the joint servos for the next physics step."""
        reference = self._reference
        if reference is None:
            return
        if self.safety_status != "normal":
            self._halt(robot)
            return
        reference.step(dt)
        if reference.safety_status != "normal":  # the planner found no inverse kinematics on the line
            self._protective_stop(robot, "moveL: no inverse kinematics on the way (a singularity or out of reach)")
            return
        robot._command(np.asarray(reference.q), np.asarray(reference.qd))  # the UR5's servos, as the twin's moves

    def after_step(self, robot: UR5Arm, table: int, obj: int, weight: float, others: Sequence[int] = ()) -> None:
        """Read the joints, end a motion once the arm has settled on its end, and watch for a protective stop."""
        states = robot.world.client.getJointStates(robot.body, robot.arm_joints)
        self._q = np.array([s[0] for s in states])
        self._qd = np.array([s[1] for s in states])
        reference = self._reference
        if reference is None:
            self._settling = 0.0
            return
        error = np.abs(self._q - np.asarray(reference.q))  # each joint's distance from its path
        timed_out = False  # the motion ends this step without having settled
        if not reference.is_moving():
            self._settling += self.scene.time_step
            settled = error.max() < SETTLED_ERROR and np.abs(self._qd).max() < SETTLED_SPEED
            timed_out = not settled and self._settling > SETTLE_TIME
            if settled or timed_out:
                self._reference = None
                if self.scene.render_at_rest:  # finished once the cameras have seen where it ended
                    self.scene.render_soon(self._rendered)
                else:
                    self._moving = False
        else:
            self._settling = 0.0
        if self.safety_status == "normal":  # the controller watches its own motions
            reason = (self._deviation(robot, error, timed_out, table, obj)
                      or self._collision(robot, table, obj, weight, others))
            if reason:
                self._protective_stop(robot, reason)

    def _rendered(self) -> None:
        """The cameras were rendered after the last motion: it has finished, unless another one started since."""
        with self.scene.lock:
            if self._reference is None:
                self._moving = False

    def _protective_stop(self, robot: UR5Arm, reason: str) -> None:
        self.safety_status, self.stop_reason = "protective_stop", reason
        log.warning("protective stop: %s", reason)
        self._halt(robot)

    def _collision(self, robot: UR5Arm, table: int, obj: int, weight: float, others: Sequence[int] = ()) -> str:
        """Why the controller would stop the arm: a link of the arm on the table, or the robot pressing on the
        table (directly, or through the object: the table's push on it beyond its `weight`) and on the `others`
        (bodies of the other objects on the table) with more than `PROTECTIVE_FORCE` for `PROTECTIVE_STEPS` steps;
        "" otherwise. (The contact forces between the fingers and the object do not sum to what the arm feels in
        PyBullet: the squeeze leaves tens of newtons of residue.)"""
        c = robot.world.client
        press = 0.0
        for point in c.getContactPoints(bodyA=robot.body, bodyB=table):
            if point[3] in self._arm_links:
                return f"arm-table collision ({c.getJointInfo(robot.body, point[3])[12].decode()} touches the table)"
            press += point[9]
        press += max(0.0, sum(point[9] for point in c.getContactPoints(bodyA=obj, bodyB=table)) - weight)
        on_others = sum(point[9] for body in others for point in c.getContactPoints(bodyA=robot.body, bodyB=body))
        self._over_force = self._over_force + 1 if press + on_others > PROTECTIVE_FORCE else 0
        if self._over_force >= PROTECTIVE_STEPS:
            self._over_force = 0
            where = "on the table" if on_others == 0 else f"on the table and other objects ({on_others:.0f} N on them)"
            return f"the tool presses {press + on_others:.0f} N {where}, above the {PROTECTIVE_FORCE:.0f} N limit"
        return ""

    def _deviation(self, robot: UR5Arm, error: np.ndarray, timed_out: bool, table: int, obj: int) -> str:
        """Why the controller would call the arm blocked: a joint `error` (rad, from its path) above
        `PATH_DEVIATION` for `PROTECTIVE_STEPS` steps, or above `END_DEVIATION` when the motion `timed_out` unsettled
        this step, named with what the arm's links touch; "" otherwise."""
        ended_short = timed_out and error.max() > END_DEVIATION
        self._deviating = self._deviating + 1 if error.max() > PATH_DEVIATION else 0
        if self._deviating < PROTECTIVE_STEPS and not ended_short:
            return ""
        self._deviating = 0
        c = robot.world.client
        names = {table: "the table", obj: "the object"}
        touched = sorted({f"{c.getJointInfo(robot.body, p[3])[12].decode()} on {names.get(p[2], 'another object')}"
                          for p in c.getContactPoints(bodyA=robot.body) if p[3] in self._arm_links})
        joint = int(np.argmax(error))
        return (f"position deviates from path: {c.getJointInfo(robot.body, robot.arm_joints[joint])[1].decode()} "
                f"{error[joint]:.3f} rad off its path (blocked: {', '.join(touched) or 'no link of the arm touches'})")

    def _halt(self, robot: UR5Arm) -> None:
        """Brake where the arm is and end its motion."""
        robot._command(self._q, np.zeros(6))
        self._reference, self._moving = None, False
