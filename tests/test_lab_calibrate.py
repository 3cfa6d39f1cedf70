"""Calibration rehearsed on the emulated lab cell: `python -m hardware calibrate` (unchanged) drives the twin's arm
through the wire while the twin's gripper carries a checkerboard (`python -m sim.lab run --calibration-board
7x6:0.03`, sim/lab/board.py) and the cameras' recordings are rendered again after every motion; the extrinsics it
recovers are compared with the twin's camera poses, which hardware/cell.emulated.yaml states in the RTDE base frame."""

from __future__ import annotations

import re
import sys
import time

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from lab_harness import ROOT, namespace_prefix, run_command
from tests.test_lab_episode import emulated_config

SERIAL = "941000000001"  # cam0
POSES = ROOT / "hardware" / "calibration_poses.cam0.emulated.yaml"
#: What the emulated calibration must recover (docs/robot.md "Rehearse on the emulated cell" has the measurement).
MAX_POSITION_ERROR = 0.005  # m
MAX_ROTATION_ERROR = 1.0  # degrees
MAX_RESIDUAL = 0.002  # m


def truth(serial: str) -> np.ndarray:
    config = yaml.safe_load((ROOT / "hardware" / "cell.emulated.yaml").read_text())
    return np.array(config["calibration"]["T_world_cam"][serial], dtype=float)


def extrinsic_error(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    """(position error in m, rotation error in degrees)."""
    return (float(np.linalg.norm(T[:3, 3] - T_true[:3, 3])),
            float(np.degrees(Rotation.from_matrix(T[:3, :3].T @ T_true[:3, :3]).magnitude())))


@pytest.mark.slow
def test_the_board_on_the_flange_is_found_by_opencv_at_every_pose_of_both_tours():
    """The plate's geometry: OpenCV finds its inner corners in the twin's renders at every pose of the shipped
    tours, where the board really is (within 2 mm, 1 degree), and the shipped tours are `tour`'s."""
    from hardware.__main__ import _read_poses
    from hardware.calibration import Checkerboard, detect_checkerboard
    from seggrasp.objects import load_asset
    from sim.cell import SimCell
    from sim.lab.board import TCP_DEPTH, BoardBodies, CalibrationBoard, tour

    board = CalibrationBoard.parse("7x6:0.03")
    T = board.T_flange_board
    grid_centre = T[:3, :3] @ [3 * 0.03, 2.5 * 0.03, 0.0] + T[:3, 3]
    assert np.allclose(grid_centre, [0.0, -0.06, TCP_DEPTH])  # beside the hand, level with the TCP
    cell = SimCell(objects=[load_asset("mug_classic")], embodiment="arm")
    try:
        cell.reset(0, "mug_classic")
        bodies = BoardBodies(cell.world.client, board)
        for index, (serial, name) in enumerate(((SERIAL, "cam0"), ("941000000002", "cam1"))):
            shipped = _read_poses(ROOT / "hardware" / f"calibration_poses.{name}.emulated.yaml")
            expected = tour(truth(serial), board)
            assert len(shipped) == len(expected) == 8
            for T_world_tcp, T_expected in zip(shipped, expected):
                assert np.allclose(T_world_tcp, T_expected, atol=1e-5)
                T_world_flange = T_world_tcp.copy()
                T_world_flange[:3, 3] -= T_world_tcp[:3, :3] @ [0.0, 0.0, TCP_DEPTH]
                T_world_board = bodies.place(T_world_flange)
                frame = cell.capture()[index]
                T_cam_board = detect_checkerboard(frame.rgb, frame.K, Checkerboard(7, 6, 0.03))
                assert T_cam_board is not None
                # the detected corners are the black squares' faces, 1 mm in front of the board frame
                T_expected_cam_board = np.linalg.inv(frame.T_world_cam) @ T_world_board
                T_expected_cam_board[:3, 3] += T_expected_cam_board[:3, 2] * -0.001
                position, rotation = extrinsic_error(T_cam_board, T_expected_cam_board)
                assert position < 0.002 and rotation < 1.0
    finally:
        cell.close()


def test_a_motion_ends_only_once_the_cameras_have_rendered_where_it_left_the_board(tmp_path):
    """With the board on, the arm reports a motion finished only after new recordings (with the board where the
    arm's actual joints put it) have replaced the old ones; without it, a motion renders nothing."""
    from sim.lab.board import CalibrationBoard
    from sim.lab.controller import HOME_Q_WIRE
    from sim.lab.twin import CAMERA_SERIALS, TwinScene
    from sim.robot import dh_forward

    scene = TwinScene("mug_classic", 0, tmp_path, board=CalibrationBoard(7, 6, 0.03))
    try:
        assert scene.render_at_rest
        paths = [tmp_path / f"{serial}.db3" for serial in CAMERA_SERIALS]
        before = [path.stat().st_ino for path in paths]
        target = HOME_Q_WIRE + [0.0, 0.0, 0.0, 0.0, 0.0, 0.3]
        scene.arm.move_joints(target.tolist(), 1.0, 1.4)
        deadline = time.monotonic() + 60
        while scene.arm.is_moving() and time.monotonic() < deadline:
            scene.advance(0.02)
            if scene.renders == 0 and scene.arm._reference is None:
                assert scene.arm.is_moving()  # settled but not yet rendered: still moving to the client
        assert not scene.arm.is_moving() and scene.renders == 1
        assert all(path.stat().st_ino != inode for path, inode in zip(paths, before))
        pose = scene.handlers()["board"]({"cmd": "board"})
        T_world_flange = dh_forward(np.asarray(scene.arm.actual_q()))
        assert np.allclose(pose["T_world_board"], T_world_flange @ np.array(pose["T_flange_board"]), atol=1e-6)
        assert np.abs(np.asarray(scene.arm.actual_q()) - target).max() < 2e-3
    finally:
        scene.close()
    plain = TwinScene("mug_classic", 0, None)
    try:
        assert not plain.render_at_rest
        with pytest.raises(ValueError, match="no calibration board"):
            plain.handlers()["board"]({"cmd": "board"})
    finally:
        plain.close()


@pytest.mark.parametrize("options, message", [
    (["--kinematic", "--calibration-board", "7x6:0.03"], "need the twin's cameras"),
    (["--object", "mug_classic", "--calibration-board", "7x7:0.03"], "one count even and one odd"),
    (["--object", "mug_classic", "--calibration-board", "7x6"], "COLUMNSxROWS:SQUARE_M"),
])
def test_a_board_the_emulator_cannot_carry_is_refused_before_it_serves(options, message):
    run = run_command([sys.executable, "-m", "sim.lab", "serve", *options], timeout=60)
    assert run.returncode == 2, run.stderr
    assert message in run.stderr and "Traceback" not in run.stderr


@pytest.mark.slow
def test_calibrate_through_the_wire_recovers_the_twin_camera_extrinsics(tmp_path):
    """The real command, unchanged, against the emulated cell with the board on the flange: the 8-pose tour through
    ur_rtde, every pose seen in a recording rendered after the motion, T_world_cam within 5 mm and 1 degree of the
    twin's camera, RMS residual under 2 mm."""
    config, out = emulated_config(tmp_path), tmp_path / "calibration.yaml"
    argv = [sys.executable, "-m", "sim.lab", "run", "--object", "mug_classic", "--controller", "cb3",
            "--polyscope", "3.15.7", "--recordings", str(tmp_path / "recordings"), "--calibration-board", "7x6:0.03",
            "--", sys.executable, "-m", "hardware", "calibrate", str(config), "--serial", SERIAL,
            "--poses", str(POSES), "--board", "7x6", "--square", "0.03", "--out", str(out)]
    from sim.lab import netns

    prefix = namespace_prefix()
    started = time.monotonic()
    run = run_command([*prefix, *argv], timeout=240, env={netns.NETNS_ENV: "1"} if prefix else None)
    elapsed = time.monotonic() - started
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    assert run.stderr.count("was replaced; opening the new one") >= 8  # each pose seen in a fresh recording
    printed = re.search(r"\((\d+)/(\d+) poses, residual ([0-9.]+) mm\)", run.stdout)
    assert printed, run.stdout
    seen, visited, residual_mm = int(printed[1]), int(printed[2]), float(printed[3])
    assert (seen, visited) == (8, 8)
    assert residual_mm < MAX_RESIDUAL * 1000
    written = yaml.safe_load(out.read_text())
    assert written["metadata"]["samples"] == 8
    assert written["metadata"]["residual_m"] == pytest.approx(residual_mm / 1000, abs=1e-5)
    position, rotation = extrinsic_error(np.array(written["T_world_cam"][SERIAL]), truth(SERIAL))
    print(f"T_world_cam {SERIAL}: {position * 1000:.2f} mm, {rotation:.3f} deg from the twin's camera; "
          f"residual {residual_mm:.2f} mm; {elapsed:.1f} s")
    assert position < MAX_POSITION_ERROR and rotation < MAX_ROTATION_ERROR
