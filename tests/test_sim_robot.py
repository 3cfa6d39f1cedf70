"""UR5 + 2F-85 description: DH kinematics, IK reachability, gripper geometry."""

import numpy as np
import pytest

from sim.gripper import MAX_WIDTH
from sim.robot import HOME_Q, JOINT_LOWER, JOINT_UPPER, T_BASELINK_DHBASE, UR5Arm, dh_forward, pose_error, ur_analytic_ik
from sim.world import World


@pytest.fixture(scope="module")
def arm():
    world = World()
    robot = UR5Arm(world)
    yield robot
    world.close()


def test_urdf_forward_kinematics_is_the_ur5_dh_chain(arm):
    c = arm.world.client
    tool0 = [j for j in range(c.getNumJoints(arm.body)) if c.getJointInfo(arm.body, j)[12] == b"tool0"][0]
    rng = np.random.default_rng(0)
    for _ in range(5):
        q = rng.uniform(-3.0, 3.0, 6)
        arm.place(q)
        T_pybullet = arm.world.link_pose(arm.body, tool0)
        np.testing.assert_allclose(T_BASELINK_DHBASE @ dh_forward(q), T_pybullet, atol=1e-6)
        np.testing.assert_allclose(arm.fk(q), arm.world.link_pose(arm.body, arm.gripper_base_link), atol=1e-6)
    # UR5 reach at zero joints: the arm lies stretched along +x of base_link (a2 + a3 + wrist offsets).
    T0 = T_BASELINK_DHBASE @ dh_forward(np.zeros(6))
    assert T0[0, 3] == pytest.approx(0.425 + 0.39225, abs=1e-9)
    assert T0[2, 3] == pytest.approx(0.089159 - 0.09465, abs=1e-9)


def test_ik_round_trip_and_reachability_check(arm):
    target = arm.fk(HOME_Q + np.array([0.3, 0.2, -0.3, 0.1, 0.2, 0.5]))
    q, reason = arm.ik(target)
    assert q is not None, reason
    position_error, angle_error = pose_error(arm.fk(q), target)
    assert position_error < 0.005 and angle_error < np.deg2rad(3)

    far = target.copy()
    far[:3, 3] = [1.4, 0.0, 0.3]  # beyond the UR5's 0.85 m reach
    q, reason = arm.ik(far)
    assert q is None and "workspace" in reason
    assert arm.ik_solutions(far) == []
    # every branch the analytic IK returns reaches the target exactly
    solutions = arm.ik_solutions(target)
    assert len(solutions) >= 2
    for q in solutions:
        position_error, angle_error = pose_error(arm.fk(q), target)
        assert position_error < 1e-9 and angle_error < 1e-9


def test_gripper_stroke_matches_the_datasheet(arm):
    gripper = arm.gripper
    assert gripper.max_width == pytest.approx(MAX_WIDTH, abs=0.003)  # 85 mm stroke
    assert gripper.width_for_travel(gripper.max_travel) < 0.005
    widths = [gripper.width_for_travel(t) for t in np.linspace(0, gripper.max_travel, 20)]
    assert np.all(np.diff(widths) < 0)
    for width in (0.01, 0.04, 0.08):
        assert gripper.width_for_travel(gripper.travel_for_width(width)) == pytest.approx(width, abs=1e-4)
    gripper.set_width(0.06)
    assert gripper.width() == pytest.approx(0.06, abs=1e-4)
    assert gripper.finger_asymmetry() < 1e-4
    # TCP is between the pads: ~14 cm in front of the gripper base.
    assert 0.12 < gripper.T_base_tcp(0.05)[2, 3] < 0.16


def test_closed_form_ik_recovers_random_configurations(arm):
    rng = np.random.default_rng(1)
    for _ in range(30):
        q = rng.uniform(JOINT_LOWER / 2, JOINT_UPPER / 2 - 1e-3)
        solutions = ur_analytic_ik(dh_forward(q))
        assert 1 <= len(solutions) <= 8
        for solution in solutions:
            np.testing.assert_allclose(dh_forward(solution), dh_forward(q), atol=1e-9)
        wrapped = [np.abs((s - q + np.pi) % (2 * np.pi) - np.pi).max() for s in solutions]
        assert min(wrapped) < 1e-6  # the configuration we started from is one of the branches


def test_a_straight_move_ends_at_rest_on_its_target(arm):
    """Issue 12: after the approach the arm stays on the planned pose while the gripper closes (it used to keep
    commanding the approach velocity and sank 3 mm past it, pushing the fingertips towards the table)."""
    arm.reset_home(MAX_WIDTH)
    T_target = arm.fk(HOME_Q)
    T_target[:3, 3] = [0.5, 0.0, 0.15]
    T_target[:3, :3] = np.diag([1.0, -1.0, -1.0])  # pointing down
    T_pre = T_target.copy()
    T_pre[2, 3] += 0.10
    candidates, reason = arm.plan([T_pre, T_target])
    assert candidates, reason
    paths = candidates[0]
    arm.place(paths[0][0])
    arm.follow(paths[1], 0.25, 0.5)  # the cell's approach speed and tool acceleration
    arm.world.step(120)  # as long as closing the gripper takes
    position_error, _ = pose_error(arm.world.link_pose(arm.body, arm.gripper_base_link), T_target)
    assert position_error < 0.001


def test_a_straight_move_with_an_acceleration_starts_and_ends_at_rest(arm):
    """The approach and lift ramp at the cell's tool acceleration, as a real linear move does: from rest, the
    gripper covers about a t^2 / 2 at first (at full speed from the first step, 25 mm in 0.1 s), and a move too
    short to reach its speed takes 2 sqrt(length / a)."""
    arm.reset_home(MAX_WIDTH)
    T_pre = arm.fk(HOME_Q)
    T_pre[:3, 3] = [0.5, 0.0, 0.25]
    T_pre[:3, :3] = np.diag([1.0, -1.0, -1.0])
    T_target = T_pre.copy()
    T_target[2, 3] -= 0.10
    candidates, reason = arm.plan([T_pre, T_target])
    assert candidates, reason
    paths = candidates[0]
    arm.place(paths[0][0])
    dt, acceleration = arm.world.physics.time_step, 0.5
    heights = []
    arm.follow(paths[1], 0.25, acceleration,
               on_step=lambda: heights.append(arm.world.link_pose(arm.body, arm.gripper_base_link)[2, 3]))
    start = heights[0]
    after = start - heights[int(round(0.1 / dt))]  # the base comes down
    assert 0.5 * acceleration * 0.1**2 * 0.5 < after < 0.5 * acceleration * 0.1**2 * 2.0
    assert len(heights) * dt == pytest.approx(2.0 * np.sqrt(0.10 / acceleration), rel=0.05)
    arm.world.step(120)
    assert pose_error(arm.world.link_pose(arm.body, arm.gripper_base_link), T_target)[0] < 0.001
