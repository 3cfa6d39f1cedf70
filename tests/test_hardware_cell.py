"""`RealCell` end to end on fakes: fake RTDE pair, fake URCap socket server, fake RealSense pipelines."""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import numpy as np
import pytest

from fakes_hardware import (EXAMPLE_CONFIG, FakeAlign, FakePipeline, FakeRobotiqServer, FakeUR, box_on_table,
                            cell_config_for_fakes, example_config, synthetic_frames, write_config)
from hardware import ConnectionLostError, RealCell, RobotStoppedError
from hardware.cell import judge_hold
from hardware.config import load_config
from hardware.ur import matrix_from_ur_pose
from seggrasp.cell import Cell

BOX_XY, BOX_SIZE = (0.52, 0.1), (0.06, 0.05, 0.10)
K = np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]])


@functools.lru_cache(maxsize=None)
def recorded_frames(serial: str) -> list:
    """Ray-cast frames of the box on the table seen by the example config's camera `serial` (computed once)."""
    camera = next(c for c in load_config(EXAMPLE_CONFIG).cameras if c.serial == serial)
    return synthetic_frames(box_on_table(BOX_XY, BOX_SIZE), [camera.T_world_cam()], K, (120, 160),
                            names=[camera.name])


def top_down(xyz) -> np.ndarray:
    """Gripper pointing down at `xyz`, closing along world x."""
    T = np.diag([1.0, -1.0, -1.0, 1.0])
    T[:3, 3] = xyz
    return T


class Rig:
    """A RealCell wired to fakes, with handles on every fake."""

    def __init__(self, tmp_path, object_register: int | None = 150, dry_run: bool = False) -> None:
        # replies end with a newline here (faster); tests/test_hardware_gripper.py covers bare replies too
        self.server = FakeRobotiqServer(object_register=object_register, newline=True)
        path = cell_config_for_fakes(tmp_path / "cell.yaml", self.server.port)
        self.config = load_config(path)
        self.ur = FakeUR(self.config.robot.model, self.config.robot.home_joints)
        self.frames = {camera.serial: recorded_frames(camera.serial) for camera in self.config.cameras}
        self.pipelines: dict[str, FakePipeline] = {}
        self.cell = RealCell.from_config(path, dry_run=dry_run, control_factory=self.ur.control,
                                         receive_factory=self.ur.receive, pipeline_factory=self.pipeline,
                                         align_factory=FakeAlign, camera_warmup_frames=1)

    def pipeline(self, serial: str) -> FakePipeline:
        self.pipelines[serial] = FakePipeline(self.frames[serial])
        return self.pipelines[serial]

    def heights(self) -> list[float]:
        return [round(float(matrix_from_ur_pose(args[0])[2, 3]), 4) for name, args in self.ur.motions
                if name == "moveL"]

    def close(self) -> None:
        self.cell.close()
        self.server.stop()


@pytest.fixture
def rig(tmp_path):
    rig = Rig(tmp_path)
    yield rig
    rig.close()


def test_from_config_connects_everything(rig):
    assert isinstance(rig.cell, Cell)
    # the episode plans for the cell's hand: the 2F-85 with the stroke measured on this one
    assert rig.cell.hand.name == "robotiq_2f85" and rig.cell.hand.stroke == rig.config.gripper.stroke
    assert rig.ur.commands[0][0] == "setTcp"
    assert rig.server.vars["STA"] == 3  # activated
    assert all(p.started for p in rig.pipelines.values()) and len(rig.pipelines) == 2


def test_reset_opens_goes_home_and_prompts(rig, caplog):
    with caplog.at_level(logging.WARNING, logger="hardware.cell"):
        rig.cell.reset(seed=3, object_id="mug_01")
    name, args = rig.ur.motions[-1]
    assert name == "moveJ"
    np.testing.assert_allclose(args[0], rig.config.robot.home_joints)
    assert any(line.startswith("SET POS 0 ") for line in rig.server.lines)
    assert "Place object 'mug_01' on the table" in caplog.text


def test_capture_returns_one_calibrated_frame_per_camera(rig):
    frames = rig.cell.capture()
    assert [f.name for f in frames] == ["front", "side"]
    for frame, camera in zip(frames, rig.config.cameras):
        np.testing.assert_allclose(frame.T_world_cam, camera.T_world_cam())
        np.testing.assert_allclose(frame.K, K)
        assert frame.depth.shape == (120, 160) and (frame.depth > 0).mean() > 0.5


def test_object_mesh_points_to_perception(rig):
    with pytest.raises(NotImplementedError, match="perceive_object"):
        rig.cell.object_mesh()


def test_successful_grasp_lifts_holds_puts_back_and_backs_off(rig):
    rig.cell.reset()
    outcome = rig.cell.execute(top_down([0.52, 0.1, 0.05]), 0.05)
    assert outcome.reachable and outcome.lifted and outcome.failure == ""
    assert outcome.lift_height == pytest.approx(0.2)
    assert outcome.contacts_observed is False and len(outcome.touched_faces) == 0
    assert outcome.contact_force == pytest.approx(rig.config.gripper.force)
    # pre-grasp 10 cm up the approach axis, grasp, lift 20 cm, put back 1 cm above, retreat 10 cm
    assert rig.heights() == [0.15, 0.05, 0.25, 0.06, 0.16]
    for name, args in rig.ur.motions:
        if name == "moveL":
            assert args[1] == rig.config.motion.tool_speed and args[3] is True
    opening = rig.cell.gripper.width_to_register(0.05 + rig.config.motion.opening_margin)
    sets = [line for line in rig.server.lines if line.startswith("SET POS")]
    assert sets[-3].startswith(f"SET POS {opening} ")  # opened to width + margin before the approach
    assert sets[-2].startswith("SET POS 255 ")  # closed with the configured force
    assert f"FOR {rig.cell.gripper.force_to_register(rig.config.gripper.force)}" in sets[-2]
    assert sets[-1].startswith(f"SET POS {opening} ")  # released


def test_reset_after_a_grasp_retracts_straight_up_before_going_home(rig):
    rig.cell.reset()
    rig.cell.execute(top_down([0.52, 0.1, 0.05]), 0.05)
    before = len(rig.ur.motions)
    rig.cell.reset()
    (retract, (pose, *_)), (home, _) = rig.ur.motions[before:]
    assert (retract, home) == ("moveL", "moveJ")
    end_of_grasp = matrix_from_ur_pose(rig.ur.motions[before - 1][1][0])
    up = matrix_from_ur_pose(pose)
    np.testing.assert_allclose(up[:3, :3], end_of_grasp[:3, :3], atol=1e-9)
    np.testing.assert_allclose(up[:2, 3], end_of_grasp[:2, 3], atol=1e-9)
    assert up[2, 3] == pytest.approx(rig.cell.arm.home_pose()[2, 3])
    rig.cell.reset()  # already home: no retract
    assert [name for name, _ in rig.ur.motions[before + 2:]] == ["moveJ"]


def test_reset_retracts_no_higher_than_the_elbow_stays_bent():
    # issue 33, found by the evaluation command on the emulated cell: from a far, low, tilted grasp the retract
    # straight up to the home height (0.265 m) stretched the elbow into its singularity (a protective stop)
    from hardware.cell import RETRACT_ELBOW_MARGIN
    from hardware.kinematics import inverse_kinematics

    config = Path(__file__).resolve().parents[1] / "hardware" / "cell.emulated.yaml"
    cell = RealCell.from_config(config, dry_run=True, with_cameras=False)
    cell.arm.move_joints([2.764, -0.677, 0.721, -0.716, -1.352, 0.869], 1.0, 1.4)
    low, before = cell.arm.tcp_pose(), len(cell.arm.planned_motions)
    cell.reset()
    (retract, home) = cell.arm.planned_motions[before:]
    assert (retract.kind, home.kind) == ("moveL", "moveJ")
    up = matrix_from_ur_pose(retract.target)
    np.testing.assert_allclose(up[:2, 3], low[:2, 3], atol=1e-6)
    assert low[2, 3] + 0.1 < up[2, 3] < cell.arm.home_pose()[2, 3] - 0.01
    elbows = [q[2] for q in inverse_kinematics("ur5", up @ np.linalg.inv(cell.config.robot.T_flange_gripper))]
    assert max(elbows) >= RETRACT_ELBOW_MARGIN


def test_object_slipping_during_the_lift_is_not_lifted(rig):
    rig.cell.reset()
    rig.ur.on_motion = lambda kind, target: rig.server.slip() if target[2] > 0.2 else None
    outcome = rig.cell.execute(top_down([0.52, 0.1, 0.05]), 0.05)
    assert outcome.reachable and not outcome.lifted and outcome.lift_height == 0.0
    assert "not held" in outcome.message and outcome.failure == "slipped"
    assert rig.heights() == [0.15, 0.05, 0.25]  # nothing to put back


def test_empty_grasp_is_not_lifted(tmp_path):
    rig = Rig(tmp_path, object_register=None)
    try:
        rig.cell.reset()
        outcome = rig.cell.execute(top_down([0.52, 0.1, 0.05]), 0.05)
        assert outcome.reachable and not outcome.lifted and "closed on an object: False" in outcome.message
        assert outcome.failure == "empty_close"
    finally:
        rig.close()


@pytest.mark.parametrize("grasp, width, reason", [
    (top_down([0.9, 0.1, 0.05]), 0.05, "outside the workspace"),
    (top_down([0.52, 0.1, 0.25]), 0.05, "lift"),  # lifting 20 cm would take the flange out of the box
    (top_down([0.52, 0.1, 0.01]), 0.05, "below the table"),
    (top_down([0.52, 0.1, 0.05]), 0.09, "exceeds the gripper stroke"),
])
def test_refused_grasps_send_no_motion(rig, grasp, width, reason):
    rig.cell.reset()
    motions, lines = len(rig.ur.motions), len(rig.server.lines)
    refusal = rig.cell.check_reach(grasp, width)
    outcome = rig.cell.execute(grasp, width)
    assert not outcome.reachable and not outcome.lifted and outcome.failure == "unreachable"
    assert reason in outcome.message and refusal == outcome.message
    assert len(rig.ur.motions) == motions and len(rig.server.lines) == lines


def test_grasp_without_inverse_kinematics_is_unreachable(rig):
    rig.cell.reset()
    rig.ur.reach = 0.3
    motions = len(rig.ur.motions)
    assert "inverse-kinematics" in rig.cell.check_reach(top_down([0.52, 0.1, 0.05]), 0.05)
    outcome = rig.cell.execute(top_down([0.52, 0.1, 0.05]), 0.05)
    assert not outcome.reachable and "inverse-kinematics" in outcome.message
    assert len(rig.ur.motions) == motions
    rig.ur.reach = 2.0
    assert rig.cell.check_reach(top_down([0.52, 0.1, 0.05]), 0.05) == ""


def test_connection_lost_while_lifting_stops_with_a_clear_error(rig):
    rig.cell.reset()
    rig.ur.motion_polls = 20

    def drop_on_lift(kind, target):
        if target[2] > 0.2:
            rig.ur.disconnect_after_polls = 3

    rig.ur.on_motion = drop_on_lift
    with pytest.raises(ConnectionLostError, match="grasp aborted while lifting"):
        rig.cell.execute(top_down([0.52, 0.1, 0.05]), 0.05)
    assert rig.heights()[-1] == 0.25


def test_a_stop_while_putting_the_object_back_keeps_the_judged_grasp(rig):
    """The put-back is no part of the grasp: a protective stop there (a slipped object pressed into the table) is
    raised, as every stop is, with the grasp's judgement as it stood after the hold."""
    rig.cell.reset()
    rig.ur.motion_polls = 20

    def stop_on_put_back(kind, target):
        if kind == "moveL" and abs(target[2] - 0.06) < 1e-6:  # the put-back pose, 1 cm above the grasp
            rig.ur.protective_stop_after_polls = 3

    rig.ur.on_motion = stop_on_put_back
    with pytest.raises(RobotStoppedError, match="grasp aborted while putting the object back") as stopped:
        rig.cell.execute(top_down([0.52, 0.1, 0.05]), 0.05)
    outcome = stopped.value.outcome
    assert outcome.reachable and outcome.lifted and outcome.failure == "" and "object held" in outcome.message
    assert rig.heights() == [0.15, 0.05, 0.25, 0.06]


def test_gripper_connection_lost_while_closing(rig):
    rig.cell.reset()
    rig.server.drop_on = "SET POS 255"
    with pytest.raises(ConnectionLostError, match="grasp aborted while closing the gripper"):
        rig.cell.execute(top_down([0.52, 0.1, 0.05]), 0.05)
    assert rig.heights() == [0.15, 0.05]  # never lifted


def test_dry_run_moves_nothing(tmp_path, caplog):
    rig = Rig(tmp_path, dry_run=True)
    try:
        with caplog.at_level(logging.INFO):
            rig.cell.reset()
            outcome = rig.cell.execute(top_down([0.52, 0.1, 0.05]), 0.05)
        assert outcome.reachable and not outcome.lifted and "dry run" in outcome.message
        assert rig.ur.control_created == 0 and rig.ur.receive_created == 0 and rig.ur.commands == []
        assert rig.server.connections == 0 and rig.server.lines == []
        planned = [(m.kind, round(float(matrix_from_ur_pose(m.target)[2, 3]), 4)) if m.kind == "moveL" else m.kind
                   for m in rig.cell.arm.planned_motions]
        assert planned == ["moveJ", ("moveL", 0.15), ("moveL", 0.05), ("moveL", 0.25), ("moveL", 0.06),
                           ("moveL", 0.16)]
        assert caplog.text.count("[dry run] moveL") == 5
        assert len(rig.cell.capture()) == 2  # cameras move nothing and still work
        refused = rig.cell.execute(top_down([0.9, 0.1, 0.05]), 0.05)
        assert not refused.reachable
    finally:
        rig.close()


def test_close_shuts_everything_down_once(rig):
    rig.cell.close()
    names = [name for name, _ in rig.ur.commands]
    assert "stopScript" in names and names[-1] == "receive.disconnect"
    assert all(p.stopped for p in rig.pipelines.values())
    rig.cell.close()
    assert [name for name, _ in rig.ur.commands] == names
    with pytest.raises(ConnectionLostError, match="closed"):
        rig.cell.capture()


def test_gym_env_drives_the_real_cell(tmp_path):
    import gymnasium as gym

    from sim import register_envs

    register_envs()
    server = FakeRobotiqServer(object_register=150, newline=True)
    path = cell_config_for_fakes(tmp_path / "cell.yaml", server.port)
    config = load_config(path)
    ur = FakeUR(config.robot.model, config.robot.home_joints)
    env = gym.make("SegGrasp-v0", backend="real", config=str(path), control_factory=ur.control,
                   receive_factory=ur.receive, align_factory=FakeAlign, camera_warmup_frames=0,
                   pipeline_factory=lambda serial: FakePipeline(recorded_frames(serial)))
    try:
        observation, info = env.reset(seed=0, options={"prompt": "body"})
        assert info == {"object_id": None, "prompt": "body"}
        assert set(observation) == {"prompt", "front", "side"}
        np.testing.assert_allclose(observation["front"]["T_world_cam"], config.cameras[0].T_world_cam())
        action = np.array([0.52, 0.1, 0.05, np.pi, 0.0, 0.0, 0.05], dtype=np.float32)
        _, reward, terminated, _, info = env.step(action)
        assert terminated and reward == 1.0 and info["outcome"]["lifted"] and info["on_part"] is None
        assert len([name for name, _ in ur.motions if name == "moveL"]) == 5
    finally:
        env.close()
        server.stop()
    assert any(name == "stopScript" for name, _ in ur.commands)


def test_wrist_camera_frames_follow_the_gripper(tmp_path):
    server = FakeRobotiqServer(newline=True)
    data = example_config()
    data["gripper"].update(host="127.0.0.1", port=server.port)
    data["cameras"].append({"serial": "wrist1", "name": "wrist", "mount": "wrist"})
    data["calibration"]["T_gripper_cam"] = {"wrist1": {"xyz": [0.0, 0.08, -0.12], "rpy": [0.0, 0.0, 0.0]}}
    path = write_config(tmp_path / "cell.yaml", data)
    config = load_config(path)
    ur = FakeUR(config.robot.model, config.robot.home_joints)
    front = config.cameras[0].serial
    cell = RealCell.from_config(path, control_factory=ur.control, receive_factory=ur.receive,
                                pipeline_factory=lambda serial: FakePipeline(recorded_frames(front)),
                                align_factory=FakeAlign, camera_warmup_frames=0)
    try:
        T_gripper_cam = config.cameras[2].T_mount_cam
        for target in (None, top_down([0.5, 0.0, 0.3])):
            if target is not None:
                cell.arm.move_linear(target, 0.1, 0.5)
            frames = cell.capture()
            np.testing.assert_allclose(frames[0].T_world_cam, config.cameras[0].T_world_cam())
            np.testing.assert_allclose(frames[2].T_world_cam, cell.arm.tcp_pose() @ T_gripper_cam, atol=1e-9)
        assert frames[2].T_world_cam[2, 3] == pytest.approx(0.3 + 0.12)  # 12 cm behind the pads, pointing down
    finally:
        cell.close()
        server.stop()


def test_hold_judged_from_the_gripper():
    assert judge_hold(True, True, 0.030, 0.029) == ""
    assert judge_hold(False, False, 0.0, 0.0) == "empty_close"
    assert judge_hold(True, False, 0.030, 0.0) == "slipped"
    assert judge_hold(True, True, 0.030, 0.012) == "slipped"  # the fingers closed further: it slid out
