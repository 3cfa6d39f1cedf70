"""The twin behind the emulated lab cell (sim/lab/twin.py), driven directly: placement as SimCell places, the RTDE
base frame, moveJ / moveL / stop timing, protective stops, inverse kinematics, the fingers on an object, the
real-time clock. The same models behind the wire are tested in tests/test_lab_episode.py."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from sim.cell import SimCell
from sim.lab.controller import HOME_Q_WIRE
from sim.lab.kinematic import Trapezoid, pose_matrix, pose_vector
from sim.lab.robotiq import CLOSED_REGISTER, OBJ_AT_POSITION, OBJ_MOVING, OBJ_STOPPED_CLOSING, OPEN_REGISTER
from sim.lab.twin import CAMERA_SERIALS, TwinScene
from sim.lab.twin_arm import END_DEVIATION, PATH_DEVIATION
from sim.robot import HOME_Q, T_FLANGE_GRIPPER

#: The gripper pointing down, closing along the world x axis.
DOWN = np.diag([1.0, -1.0, -1.0])


def down_at(x: float, y: float, z: float) -> list[float]:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = DOWN, (x, y, z)
    return pose_vector(T)


def run(scene: TwinScene, limit: float = 10.0) -> float:
    """Step until the arm rests and the fingers stopped; the simulated seconds it took."""
    steps = 0
    while scene.arm.is_moving() or scene.fingers.object_status() == OBJ_MOVING:
        scene.step_once()
        steps += 1
        assert steps * scene.time_step < limit, "the motion did not end"
    return steps * scene.time_step


@pytest.fixture
def mug():
    scene = TwinScene("mug_classic", 3, None)
    scene.arm.set_tcp([0.0, 0.0, 0.15, 0.0, 0.0, 0.0])
    yield scene
    scene.close()


def test_placement_is_simcells_and_the_world_is_the_rtde_base_frame(mug):
    with SimCell(objects=[mug.cell.current_object], embodiment="arm") as cell:
        cell.reset(3, "mug_classic")
        twin_pose = np.array(mug.truth()["T_world_obj"])
        assert np.abs(twin_pose - cell.object_mesh()[1]).max() < 1e-6
        # the arm at the wire's home has its gripper where SimCell's home puts it
        world, robot = cell.world, cell.robot
        T_sim = world.link_pose(robot.body, robot.gripper.base_link)
    assert np.allclose(mug.arm.actual_q(), HOME_Q_WIRE, atol=1e-6) and HOME_Q_WIRE[0] == pytest.approx(np.pi)
    T_wire = pose_matrix(mug.arm.actual_tcp_pose()) @ np.linalg.inv(pose_matrix([0, 0, 0.15, 0, 0, 0]))
    assert np.abs(T_wire @ T_FLANGE_GRIPPER - T_sim).max() < 1e-6
    assert not np.allclose(HOME_Q, HOME_Q_WIRE)


def test_placement_refuses_bad_requests(mug):
    with pytest.raises(ValueError, match="unknown object id 'teapot'"):
        mug.place("teapot", 0)
    with pytest.raises(ValueError, match="seed must be a non-negative integer"):
        mug.place("mug_classic", -1)


def test_movel_and_movej_end_on_target_in_their_profiles_time(mug):
    arm = mug.arm
    start = pose_matrix(arm.actual_tcp_pose())
    target = down_at(start[0, 3] + 0.12, start[1, 3] - 0.05, start[2, 3] - 0.10)
    arm.move_linear(target, 0.1, 0.5)
    took = run(mug)
    length = float(np.linalg.norm(pose_matrix(target)[:3, 3] - start[:3, 3]))
    assert took == pytest.approx(Trapezoid(length, 0.1, 0.5).duration, abs=0.1)
    assert np.linalg.norm(np.subtract(arm.actual_tcp_pose()[:3], target[:3])) < 1e-3
    q = np.array(arm.actual_q()) + np.array([0.3, 0.1, -0.1, 0.0, 0.0, 0.4])
    arm.move_joints(q, 1.0, 1.4)
    took = run(mug)
    assert took == pytest.approx(Trapezoid(0.4, 1.0, 1.4).duration, abs=0.1)
    assert np.abs(np.array(arm.actual_q()) - q).max() < 2e-3


def test_stop_decelerates_along_the_line(mug):
    arm = mug.arm
    start = np.array(arm.actual_tcp_pose()[:3])
    arm.move_linear(down_at(start[0] + 0.3, start[1], start[2]), 0.1, 0.5)
    mug.advance(0.8)
    arm.stop(1.0)
    run(mug)
    # 0.01 m accelerating, 0.06 m at 0.1 m/s, then 0.005 m braking at 1 m/s^2
    assert np.linalg.norm(np.array(arm.actual_tcp_pose()[:3]) - start) == pytest.approx(0.075, abs=0.003)


def test_pressing_into_the_table_is_a_protective_stop(mug):
    arm = mug.arm
    arm.move_linear(down_at(0.3, 0.2, -0.05), 0.1, 0.5)
    run(mug)
    assert arm.safety_status == "protective_stop" and "N on the table, above the" in arm.stop_reason
    assert arm.actual_tcp_pose()[2] > 0.0  # halted on the table, not at the target below it
    arm.move_joints(HOME_Q_WIRE, 1.0, 1.0)
    assert not arm.is_moving()  # a stopped arm starts nothing


def posts_beside_the_wrist(scene: TwinScene, clearance: float) -> float:
    """Two fixed posts `clearance` (m) from wrist 2's bounding box, on either side of the way a turn of the base moves
    it (whichever way it turns, the wrist meets one); the wrist's distance from the base axis."""
    client, robot = scene.cell.world.client, scene.cell.robot
    low, high = (np.array(corner) for corner in client.getAABB(robot.body, robot.arm_joints[4]))
    wrist, half_post = (low + high) / 2, 0.03
    radius = float(np.linalg.norm(wrist[:2]))
    sideways = np.array([-wrist[1], wrist[0], 0.0]) / radius
    post = client.createCollisionShape(client.GEOM_BOX, halfExtents=[half_post, half_post, 0.1])
    offset = clearance + 0.5 * float(max(high - low)) + half_post
    for side in (1.0, -1.0):
        client.createMultiBody(0.0, post, basePosition=(wrist + side * offset * sideways).tolist())
    scene.advance(0.1)
    assert scene.arm.safety_status == "normal"
    return radius


def test_an_arm_blocked_on_its_path_is_a_protective_stop(mug):
    """A joint held back by something in the arm's way (here a post beside the wrist; in a run, the forearm on the
    bottle it carried) ends the motion in a protective stop, not at rest short of its target."""
    posts_beside_the_wrist(mug, 0.07)
    target = np.array(mug.arm.actual_q()) + np.array([0.8, 0.0, 0.0, 0.0, 0.0, 0.0])
    mug.arm.move_joints(target, 0.5, 1.0)
    run(mug)
    assert mug.arm.safety_status == "protective_stop", "the arm was held back and its motion ended as if done"
    assert mug.arm.stop_reason.startswith("position deviates from path: shoulder_pan_joint ")
    assert "wrist" in mug.arm.stop_reason and "on another object" in mug.arm.stop_reason
    assert abs(mug.arm.actual_q()[0] - target[0]) > 0.4  # halted at the post, far from the target


def test_an_arm_held_short_of_its_end_is_a_protective_stop(mug):
    """Blocked near the end of a motion (within `PATH_DEVIATION` of its path), the arm is stopped once the settling
    time runs out, instead of the motion ending short of its target as if done."""
    radius = posts_beside_the_wrist(mug, 0.005)
    target = np.array(mug.arm.actual_q()) + np.array([0.02 / radius, 0.0, 0.0, 0.0, 0.0, 0.0])  # 20 mm at the wrist
    mug.arm.move_joints(target, 0.5, 1.0)
    run(mug)
    assert mug.arm.safety_status == "protective_stop", "the arm stopped short and its motion ended as if done"
    reason = mug.arm.stop_reason
    assert reason.startswith("position deviates from path: shoulder_pan_joint ") and "wrist" in reason
    short = float(reason.split("shoulder_pan_joint ")[1].split(" rad")[0])
    assert END_DEVIATION < short < PATH_DEVIATION  # caught at the end, not on the way


def test_pressing_down_on_another_object_of_the_scene_is_a_protective_stop():
    scene = TwinScene("mug_classic", 3, None)
    try:
        scene.place("mug_classic", 3, scene="packed", objects_per_scene=4)
        scene.arm.set_tcp([0.0, 0.0, 0.15, 0.0, 0.0, 0.0])
        client = scene.cell.world.client
        body = scene.cell.neighbours[0][0]
        low, high = (np.array(corner) for corner in client.getAABB(body))
        x, y = (low[:2] + high[:2]) / 2
        start = client.getBasePositionAndOrientation(body)[0]
        scene.arm.move_linear(down_at(x, y, high[2] + 0.2), 0.25, 1.0)
        run(scene)
        assert scene.arm.safety_status == "normal"
        scene.arm.move_linear(down_at(x, y, low[2] - 0.05), 0.1, 0.5)  # through it into the table
        run(scene)
        assert scene.arm.safety_status == "protective_stop", "the arm pressed on another object and went on"
        assert "N on the table and other objects (" in scene.arm.stop_reason
        assert scene.arm.actual_tcp_pose()[2] > low[2]  # halted on the object, not at the target below it
        assert np.linalg.norm(np.subtract(client.getBasePositionAndOrientation(body)[0], start)[:2]) < 0.05
    finally:
        scene.close()


def test_inverse_kinematics(mug):
    arm = mug.arm
    here = arm.actual_tcp_pose()
    q = arm.inverse_kinematics(here)
    assert np.abs(np.array(q) - HOME_Q_WIRE).max() < 1e-6
    assert arm.ik_has_solution(down_at(0.5, 0.0, 0.1))
    assert not arm.ik_has_solution(down_at(3.0, 0.0, 0.3))
    assert not arm.pose_within_limits(down_at(0.5, 0.0, -0.01))  # below the table plane
    assert arm.joints_within_limits(HOME_Q_WIRE) and not arm.joints_within_limits([0, 0, 4.0, 0, 0, 0])


@pytest.mark.slow
def test_fingers_stop_on_the_object_hold_it_through_the_lift_and_lose_it():
    scene = TwinScene("bottle_water", 0, None)
    try:
        arm, fingers = scene.arm, scene.fingers
        arm.set_tcp(pose_vector(T_FLANGE_GRIPPER @ scene.gripper.T_base_tcp(scene.gripper.max_width)))
        T = np.array(scene.truth()["T_world_obj"])
        vertices = scene.cell.current_object.mesh.vertices @ T[:3, :3].T + T[:3, 3]
        top = vertices[:, 2].max()
        neck = vertices[vertices[:, 2] > top - 0.02]
        x, y = neck[:, :2].mean(axis=0)
        diameter = 2 * np.linalg.norm(neck[:, :2] - (x, y), axis=1).max()
        fingers.request(0, 255, 255)
        arm.move_linear(down_at(x, y, top + 0.1), 0.25, 1.0)
        run(scene)
        assert fingers.position_register() == OPEN_REGISTER and fingers.object_status() == OBJ_AT_POSITION
        arm.move_linear(down_at(x, y, top - 0.012), 0.1, 0.5)
        run(scene)
        fingers.request(255, 108, 255)
        assert fingers.object_status() == OBJ_MOVING
        run(scene)
        assert fingers.object_status() == OBJ_STOPPED_CLOSING
        assert scene.gripper.width() == pytest.approx(diameter, abs=0.004)
        z0 = scene.truth()["T_world_obj"][2][3]
        arm.move_linear(down_at(x, y, top + 0.19), 0.1, 0.5)
        run(scene)
        scene.advance(1.0)
        assert scene.truth()["T_world_obj"][2][3] - z0 > 0.18 and arm.safety_status == "normal"
        assert fingers.object_status() == OBJ_STOPPED_CLOSING
        scene.lose_object()
        scene.advance(0.5)
        assert fingers.object_status() == OBJ_AT_POSITION and fingers.position_register() > CLOSED_REGISTER - 6
    finally:
        scene.close()


def test_the_clock_keeps_simulated_time_with_the_wall_clock(mug):
    mug.start()
    began = mug.sim_time
    time.sleep(1.0)
    stats = mug.stats()
    assert mug.sim_time - began == pytest.approx(1.0, abs=0.15)
    assert stats["real_time_factor"] > 0.9 and stats["headroom"] > 1.0


def inodes(paths: dict) -> dict:
    """Each file's identity as the client's camera sees a replaced recording (inode, size, modification time)."""
    return {serial: (s.st_ino, s.st_size, s.st_mtime_ns) for serial, s in
            ((serial, Path(path).stat()) for serial, path in paths.items())}


@pytest.mark.slow
def test_each_placement_rewrites_the_cameras_recordings(tmp_path):
    scene = TwinScene("hammer_claw", 1, tmp_path)
    try:
        first = scene.place("hammer_claw", 2)
        assert sorted(first["recordings"]) == sorted(CAMERA_SERIALS)
        assert all(Path(path).parent == tmp_path for path in first["recordings"].values())
        placed = inodes(first["recordings"])
        stopped = inodes(scene.handlers()["camera_stop"]({"cmd": "camera_stop"})["recordings"])
        assert stopped != placed
        again = scene.handlers()["place"]({"cmd": "place", "object": "hammer_claw", "seed": 2})
        assert inodes(again["recordings"]) != stopped
        assert again["T_world_obj"] == first["T_world_obj"] == scene.truth()["T_world_obj_placed"]
    finally:
        scene.close()
