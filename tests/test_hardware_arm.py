"""The UR arm against a fake RTDE control/receive pair (injected), and the pose conversions and safety guard."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fakes_hardware import EXAMPLE_CONFIG, FakeUR
from hardware.cell import make_guard
from hardware.config import load_config
from hardware.errors import ConnectionLostError, MotionError, RobotStoppedError, SafetyError
from hardware.robotiq import RobotiqGripper
from hardware.ur import URArm, forward_kinematics, matrix_from_ur_pose, ur_pose_from_matrix


@pytest.fixture(scope="module")
def config():
    return load_config(EXAMPLE_CONFIG)


@pytest.fixture
def fake(config):
    return FakeUR(config.robot.model, config.robot.home_joints)


@pytest.fixture
def arm(config, fake):
    arm = URArm(config.robot, make_guard(config), control_factory=fake.control, receive_factory=fake.receive)
    arm.connect()
    return arm


def pose(xyz, rotation=None) -> np.ndarray:
    """Gripper pointing down (z = -world z) at `xyz`, optionally rotated further."""
    T = np.eye(4)
    R = Rotation.from_euler("x", np.pi)
    T[:3, :3] = (R * rotation).as_matrix() if rotation is not None else R.as_matrix()
    T[:3, 3] = xyz
    return T


def test_pose_conversion_round_trips_including_half_turns():
    rng = np.random.default_rng(0)
    rotations = list(Rotation.random(50, random_state=1)) + [Rotation.from_rotvec([np.pi, 0, 0]),
                                                             Rotation.from_rotvec([0, 0, np.pi - 1e-9]),
                                                             Rotation.identity()]
    for rotation in rotations:
        T = np.eye(4)
        T[:3, :3] = rotation.as_matrix()
        T[:3, 3] = rng.normal(size=3)
        vector = ur_pose_from_matrix(T)
        assert len(vector) == 6 and np.linalg.norm(vector[3:]) <= np.pi + 1e-9
        np.testing.assert_allclose(matrix_from_ur_pose(vector), T, atol=1e-9)
    # a known value: 90 degrees about z is the rotation vector (0, 0, pi/2)
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    np.testing.assert_allclose(ur_pose_from_matrix(T)[3:], [0, 0, np.pi / 2], atol=1e-12)
    with pytest.raises(ValueError):
        matrix_from_ur_pose([1, 2, 3])


def test_nominal_kinematics_match_the_published_zero_pose():
    # all joints at zero: the UR5 lies stretched along -x, flange at (a2 + a3, -(d4 + d6), d1 - d5)
    T = forward_kinematics("ur5", np.zeros(6))
    np.testing.assert_allclose(T[:3, 3], [-0.81725, -0.19145, 0.089159 - 0.09465], atol=1e-9)


def test_connect_sets_the_tcp_to_the_gripper_frame(arm, fake, config):
    name, args = fake.commands[0]
    assert name == "setTcp"
    np.testing.assert_allclose(matrix_from_ur_pose(args[0]), config.robot.T_flange_gripper, atol=1e-12)
    expected = forward_kinematics("ur5", config.robot.home_joints) @ config.robot.T_flange_gripper
    np.testing.assert_allclose(arm.tcp_pose(), expected, atol=1e-9)
    np.testing.assert_allclose(arm.joints(), config.robot.home_joints)


def test_move_linear_sends_the_ur_pose_asynchronously_and_waits(arm, fake):
    target = pose([0.5, 0.1, 0.2], Rotation.from_euler("z", 0.3))
    arm.move_linear(target, 0.1, 0.5)
    name, (vector, speed, acceleration, asynchronous) = fake.motions[-1]
    assert name == "moveL" and asynchronous is True and (speed, acceleration) == (0.1, 0.5)
    np.testing.assert_allclose(matrix_from_ur_pose(vector), target, atol=1e-9)
    np.testing.assert_allclose(arm.tcp_pose(), target, atol=1e-9)


def test_pose_outside_the_workspace_never_reaches_the_arm(arm, fake):
    with pytest.raises(SafetyError, match="outside the workspace"):
        arm.move_linear(pose([0.9, 0.1, 0.2]), 0.1, 0.5)
    with pytest.raises(SafetyError, match="z = 0.600 m is outside"):
        arm.move_linear(pose([0.5, 0.1, 0.6]), 0.1, 0.5)
    assert fake.motions == []


def test_fingertips_below_the_table_clearance_are_refused(arm, fake, config):
    # the gripper origin is inside the box, but pointing down 1 cm above the table the tips (2 cm beyond) are not
    with pytest.raises(SafetyError, match="fingertip .* below the table clearance"):
        arm.move_linear(pose([0.5, 0.1, 0.01]), 0.1, 0.5)
    # tilted 90 degrees about the approach axis' normal: one finger points at the table
    tilted = pose([0.5, 0.1, 0.03], Rotation.from_euler("y", 90, degrees=True))
    with pytest.raises(SafetyError, match="below the table"):
        arm.move_linear(tilted, 0.1, 0.5)
    assert fake.motions == []


def test_a_path_through_a_forbidden_region_is_refused(arm, fake):
    # both ends keep every fingertip above the table, but halfway through the turn from pointing down to pointing
    # sideways the lower fingertip dips below the clearance limit
    start = pose([0.5, 0.1, 0.044])
    goal = start.copy()
    goal[:3, :3] = Rotation.from_euler("y", 90, degrees=True).as_matrix() @ start[:3, :3]
    arm.guard.check_pose(start)
    arm.guard.check_pose(goal)
    with pytest.raises(SafetyError, match="% of the path"):
        arm.guard.check_linear_path(start, goal)
    assert fake.motions == []


def test_speed_and_acceleration_caps(arm, fake, config):
    target = pose([0.5, 0.1, 0.2])
    with pytest.raises(SafetyError, match="tool speed 0.5 m/s exceeds the limit 0.25"):
        arm.move_linear(target, 0.5, 0.5)
    with pytest.raises(SafetyError, match="tool acceleration"):
        arm.move_linear(target, 0.1, 5.0)
    with pytest.raises(SafetyError, match="joint speed"):
        arm.move_joints(config.robot.home_joints, 2.0, 0.5)
    with pytest.raises(SafetyError, match="positive"):
        arm.move_linear(target, -0.1, 0.5)
    assert fake.motions == []


def test_move_joints_checks_the_tool_path(arm, fake, config):
    home = config.robot.home_joints
    arm.move_joints(home + np.array([0.2, 0, 0, 0, 0, 0]), 0.5, 0.8)
    assert fake.motions[-1][0] == "moveJ"
    np.testing.assert_allclose(arm.joints(), home + np.array([0.2, 0, 0, 0, 0, 0]))
    # lowering the shoulder drives the tool through the table
    with pytest.raises(SafetyError, match="moveJ"):
        arm.move_joints(home + np.array([0, 0.6, 0, 0, 0, 0]), 0.5, 0.8)
    assert len(fake.motions) == 1


@pytest.mark.parametrize("raises", [True, False], ids=["calls-raise", "reports-disconnected"])
def test_connection_dropped_mid_motion_stops_with_a_clear_error(arm, fake, raises):
    fake.motion_polls = 10
    fake.disconnect_after_polls = 3
    fake.disconnect_raises = raises
    with pytest.raises(ConnectionLostError, match="connection"):
        arm.move_linear(pose([0.5, 0.1, 0.2]), 0.1, 0.5)
    assert not arm.is_connected()
    # nothing is sent on a dropped link: ur_rtde would reconnect inside stopL, racing its own reconnect (F2)
    assert not any(name == "stopL" for name, _ in fake.commands)
    with pytest.raises(ConnectionLostError):
        arm.move_linear(pose([0.5, 0.1, 0.25]), 0.1, 0.5)
    assert len(fake.motions) == 1  # nothing was sent on the dead link
    arm.reconnect()
    assert fake.commands[-1][0] == "setTcp"  # the TCP is re-applied after reconnecting
    fake.disconnect_after_polls = None
    arm.move_linear(pose([0.5, 0.1, 0.25]), 0.1, 0.5)
    np.testing.assert_allclose(arm.tcp_pose()[:3, 3], [0.5, 0.1, 0.25], atol=1e-9)


def test_protective_and_emergency_stops_are_detected(arm, fake):
    fake.motion_polls = 10
    fake.protective_stop_after_polls = 2
    with pytest.raises(RobotStoppedError, match="protective stop"):
        arm.move_linear(pose([0.5, 0.1, 0.2]), 0.1, 0.5)
    fake.protective_stopped, fake.protective_stop_after_polls = False, None
    fake.emergency_stopped = True
    with pytest.raises(RobotStoppedError, match="emergency"):
        arm.move_linear(pose([0.5, 0.1, 0.2]), 0.1, 0.5)
    assert len(fake.motions) == 1


def test_motion_that_ends_away_from_its_target_is_an_error(arm, fake):
    fake.motion_polls = 1
    original = fake.progress

    def lose_the_motion() -> int:  # the controller reports the operation over but the arm never moved
        fake._pending = None
        fake._token = -2 if fake._token == -1 else -1
        return original()

    fake.progress = lose_the_motion
    with pytest.raises(MotionError, match="away from its target"):
        arm.move_linear(pose([0.5, 0.1, 0.2]), 0.1, 0.5)


def test_dry_run_never_connects_and_records_the_plan(config, fake):
    arm = URArm(config.robot, make_guard(config), dry_run=True, control_factory=fake.control,
                receive_factory=fake.receive)
    arm.connect()
    target = pose([0.5, 0.1, 0.2])
    arm.move_linear(target, 0.1, 0.5)
    arm.move_joints(config.robot.home_joints, 0.5, 0.8)
    with pytest.raises(SafetyError):
        arm.move_linear(pose([0.9, 0.0, 0.2]), 0.1, 0.5)
    arm.close()
    assert fake.control_created == 0 and fake.receive_created == 0 and fake.commands == []
    assert [m.kind for m in arm.planned_motions] == ["moveL", "moveJ"]
    np.testing.assert_allclose(matrix_from_ur_pose(arm.planned_motions[0].target), target, atol=1e-9)


def test_close_stops_the_script_and_disconnects(arm, fake):
    arm.close()
    names = [name for name, _ in fake.commands]
    assert names[-3:] == ["stopScript", "disconnect", "receive.disconnect"]
    arm.close()  # idempotent
    with pytest.raises(ConnectionLostError, match="not connected"):
        arm.tcp_pose()


def test_motion_that_never_finishes_is_stopped_after_the_timeout(config, fake):
    arm = URArm(replace(config.robot, motion_timeout=0.2), make_guard(config), control_factory=fake.control,
                receive_factory=fake.receive)
    arm.connect()
    fake.motion_polls = 10**9
    with pytest.raises(MotionError, match="did not finish within its time limit; the arm was stopped"):
        arm.move_linear(pose([0.5, 0.1, 0.2]), 0.1, 0.5)
    assert fake.commands[-1][0] == "stopL"


def test_motion_ending_with_the_wrong_orientation_is_an_error(arm, fake):
    fake.motion_polls = 1
    original = fake.progress

    def twist_on_arrival() -> int:
        token = original()
        if token < 0:
            fake.tcp = fake.tcp @ np.diag([-1.0, -1.0, 1.0, 1.0])  # right place, turned half a turn about z
        return token

    fake.progress = twist_on_arrival
    with pytest.raises(MotionError, match="away from its target"):
        arm.move_linear(pose([0.5, 0.1, 0.2]), 0.1, 0.5)


def test_move_joints_asks_the_controllers_safety_limits_first(arm, fake, config):
    target = config.robot.home_joints + np.array([0.2, 0, 0, 0, 0, 0])
    fake.refuse_joints = True
    with pytest.raises(SafetyError, match="controller reports joints .* outside its safety limits"):
        arm.move_joints(target, 0.5, 0.8)
    fake.refuse_joints, fake.refuse_poses = False, True
    with pytest.raises(SafetyError, match="moveJ: the controller reports .* outside its safety limits"):
        arm.move_joints(target, 0.5, 0.8)
    assert fake.motions == []
    fake.refuse_poses = False
    arm.move_joints(target, 0.5, 0.8)
    names = [name for name, _ in fake.commands]
    assert names[-3:] == ["isJointsWithinSafetyLimits", "isPoseWithinSafetyLimits", "moveJ"]
    np.testing.assert_allclose(fake.commands[-3][1][0], target)


def test_the_flange_must_stay_inside_the_workspace(arm, fake):
    # the pad centres are inside the box (z 0.45 < 0.55) but the flange, 15.5 cm above them, is not
    with pytest.raises(SafetyError, match=r"flange z = 0.605 m is outside the workspace \[0.000, 0.550\]"):
        arm.move_linear(pose([0.5, 0.1, 0.45]), 0.1, 0.5)
    assert fake.motions == []


def test_fingertips_are_checked_against_the_box_at_the_commanded_opening(config, fake):
    guard = make_guard(config)
    arm = URArm(config.robot, guard, dry_run=True)
    gripper = RobotiqGripper(config.gripper, guard, dry_run=True)
    arm.connect()
    near_edge = pose([0.74, 0.1, 0.2])  # closing along world x, 1 cm inside the box's x = 0.75 face
    # fully open (or unknown) the +x fingertip sticks out 4.25 cm: refused
    with pytest.raises(SafetyError, match=r"fingertip \+x x = 0.782 m is outside the workspace"):
        arm.move_linear(near_edge, 0.1, 0.5)
    gripper.move_to_width(0.01)
    arm.move_linear(near_edge, 0.1, 0.5)  # 1 cm open: both tips inside
    # opening the fingers there would push the +x tip out of the box: refused before the gripper is told
    commands = list(gripper.commands)
    with pytest.raises(SafetyError, match=r"opening the gripper: fingertip \+x x = 0.782 m is outside"):
        gripper.open()
    assert gripper.commands == commands
    gripper.move_to_width(0.015)  # a little wider still fits
    assert [m.kind for m in arm.planned_motions] == ["moveL"]


def test_dry_run_reports_poses_beyond_the_arms_reach_as_unreachable(config, fake):
    arm = URArm(config.robot, make_guard(config), dry_run=True)
    arm.connect()
    assert arm.has_ik_solution(pose([0.5, 0.1, 0.2]))
    # inside the box, but pointing down at its far top corner the flange is 0.92 m from the shoulder (reach 0.85 m)
    assert not arm.has_ik_solution(pose([0.74, 0.28, 0.4]))
    # a gripper hanging over the robot's own base
    assert not arm.has_ik_solution(pose([0.02, 0.0, 0.3]))
