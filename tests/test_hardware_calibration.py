"""Hand-eye calibration: synthetic poses with a known answer, checkerboard pose detection on rendered images, and
the whole eye-to-hand routine (dry-run arm carrying a board in front of a rendered camera)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fakes_hardware import EXAMPLE_CONFIG
from hardware.calibration import (Checkerboard, calibrate_eye_in_hand, calibrate_eye_to_hand, collect_samples,
                                  detect_checkerboard, eye_in_hand_residual, eye_to_hand_residual, load_extrinsics,
                                  save_extrinsics)
from hardware.cell import make_guard
from hardware.config import ConfigError, load_config
from hardware.ur import URArm
from seggrasp.cell import Frame

BOARD = Checkerboard(columns=7, rows=6, square=0.03)
K = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])


def transform(rotation: Rotation, translation) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = rotation.as_matrix()
    T[:3, 3] = translation
    return T


def look_at(eye, target) -> np.ndarray:
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = eye
    return T


def render_board(T_cam_target: np.ndarray, size=(480, 640), supersample: int = 2) -> np.ndarray:
    """RGB image of the checkerboard (plus a white margin) on a grey background, by ray casting."""
    h, w = size
    # sub-pixel j of pixel k (which spans [k - 0.5, k + 0.5]) sits at k - 0.5 + (j + 0.5) / supersample
    first = 0.5 / supersample - 0.5
    u, v = np.meshgrid(np.arange(w * supersample) / supersample + first,
                       np.arange(h * supersample) / supersample + first)
    rays = np.stack([u.ravel(), v.ravel(), np.ones(u.size)]).T @ np.linalg.inv(K).T
    T_target_cam = np.linalg.inv(T_cam_target)
    directions = rays @ T_target_cam[:3, :3].T
    origin = T_target_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -origin[2] / directions[:, 2]
    points = origin + t[:, None] * directions
    image = np.full(len(rays), 110.0)
    sq = BOARD.square
    margin = (points[:, 0] >= -2 * sq) & (points[:, 0] < (BOARD.columns + 1) * sq) & \
             (points[:, 1] >= -2 * sq) & (points[:, 1] < (BOARD.rows + 1) * sq) & (t > 0)
    image[margin] = 255.0
    squares = (points[:, 0] >= -sq) & (points[:, 0] < BOARD.columns * sq) & \
              (points[:, 1] >= -sq) & (points[:, 1] < BOARD.rows * sq) & (t > 0)
    parity = (np.floor(points[:, 0] / sq) + np.floor(points[:, 1] / sq)) % 2 == 0
    image[squares & parity] = 0.0
    image = image.reshape(h, supersample, w, supersample).mean(axis=(1, 3))
    return np.repeat(image[..., None], 3, axis=2).round().astype(np.uint8)


def board_pose_facing(camera_eye, board_center, rotation=None) -> np.ndarray:
    """T_cam_target of a board centred at `board_center` whose z axis points away from the camera."""
    T_world_target = look_at(np.asarray(board_center, float), 2 * np.asarray(board_center) - camera_eye)
    if rotation is not None:
        T_world_target[:3, :3] = T_world_target[:3, :3] @ rotation.as_matrix()
    shift = np.eye(4)
    shift[:2, 3] = [-(BOARD.columns - 1) * BOARD.square / 2, -(BOARD.rows - 1) * BOARD.square / 2]
    return T_world_target @ shift


def test_checkerboard_pose_is_recovered_from_a_rendered_image():
    eye = np.array([0.0, 0.0, 0.0])
    for angles in ([0, 0, 0], [20, -15, 30], [-25, 10, -60]):
        T_world_target = board_pose_facing(eye, [0.05, -0.03, 0.7], Rotation.from_euler("xyz", angles, degrees=True))
        T_cam_target = T_world_target  # the camera sits at the origin looking down its own z
        found = detect_checkerboard(render_board(T_cam_target), K, BOARD)
        assert found is not None
        assert np.linalg.norm(found[:3, 3] - T_cam_target[:3, 3]) < 0.003
        angle = Rotation.from_matrix(found[:3, :3].T @ T_cam_target[:3, :3]).magnitude()
        assert np.degrees(angle) < 1.0
    blank = np.full((480, 640, 3), 128, dtype=np.uint8)
    assert detect_checkerboard(blank, K, BOARD) is None
    with pytest.raises(ValueError, match="ambiguous"):
        Checkerboard(columns=7, rows=5, square=0.03)


def synthetic_samples(n: int, noise: float, rng: np.random.Generator):
    T_base_cam = look_at(np.array([0.5, 0.9, 0.7]), [0.5, 0.1, 0.1])
    T_gripper_target = transform(Rotation.from_euler("xyz", [0.1, -0.2, 0.3]), [0.02, -0.01, 0.05])
    T_gripper_cam = transform(Rotation.from_euler("xyz", [0.05, 0.1, 1.6]), [0.06, 0.0, -0.08])
    T_base_table_target = transform(Rotation.from_euler("z", 0.4), [0.5, 0.1, 0.0])
    grippers, to_hand, in_hand = [], [], []
    for _ in range(n):
        rotation = Rotation.from_euler("x", np.pi) * Rotation.from_rotvec(rng.normal(size=3) * 0.35)
        T_bg = transform(rotation, [0.5, 0.1, 0.3] + rng.uniform(-0.12, 0.12, 3))
        noisy = transform(Rotation.from_rotvec(rng.normal(size=3) * noise), rng.normal(size=3) * noise)
        grippers.append(T_bg)
        to_hand.append(np.linalg.inv(T_base_cam) @ T_bg @ T_gripper_target @ noisy)
        in_hand.append(np.linalg.inv(T_bg @ T_gripper_cam) @ T_base_table_target @ noisy)
    return grippers, to_hand, in_hand, T_base_cam, T_gripper_target, T_gripper_cam


@pytest.mark.parametrize("method", ["shah", "li"])
def test_eye_to_hand_recovers_the_camera_pose(method):
    rng = np.random.default_rng(0)
    grippers, observed, _, T_base_cam, T_gripper_target, _ = synthetic_samples(15, 0.0, rng)
    found_cam, found_target = calibrate_eye_to_hand(grippers, observed, method)
    np.testing.assert_allclose(found_cam, T_base_cam, atol=1e-6)
    np.testing.assert_allclose(found_target, T_gripper_target, atol=1e-6)
    assert eye_to_hand_residual(found_cam, found_target, grippers, observed) < 1e-9
    # with 1 mm / 1 mrad measurement noise the answer stays within a few millimetres
    grippers, observed, _, T_base_cam, _, _ = synthetic_samples(20, 0.001, np.random.default_rng(1))
    found_cam, found_target = calibrate_eye_to_hand(grippers, observed, method)
    assert np.linalg.norm(found_cam[:3, 3] - T_base_cam[:3, 3]) < 0.005
    assert 0.0005 < eye_to_hand_residual(found_cam, found_target, grippers, observed) < 0.005


@pytest.mark.parametrize("method", ["tsai", "park", "daniilidis"])
def test_eye_in_hand_recovers_the_wrist_camera(method):
    grippers, _, observed, _, _, T_gripper_cam = synthetic_samples(15, 0.0, np.random.default_rng(2))
    found = calibrate_eye_in_hand(grippers, observed, method)
    np.testing.assert_allclose(found, T_gripper_cam, atol=1e-6)
    assert eye_in_hand_residual(found, grippers, observed) < 1e-9
    grippers, _, observed, _, _, T_gripper_cam = synthetic_samples(20, 0.001, np.random.default_rng(5))
    found = calibrate_eye_in_hand(grippers, observed, method)
    assert np.linalg.norm(found[:3, 3] - T_gripper_cam[:3, 3]) < 0.005
    assert 0.0005 < eye_in_hand_residual(found, grippers, observed) < 0.005


def test_bad_calibration_input_is_rejected():
    grippers, observed, _, _, _, _ = synthetic_samples(5, 0.0, np.random.default_rng(3))
    with pytest.raises(ValueError, match="at least 3"):
        calibrate_eye_to_hand(grippers[:2], observed[:2])
    with pytest.raises(ValueError, match="4 target poses"):
        calibrate_eye_to_hand(grippers, observed[:4])
    with pytest.raises(ValueError, match="unknown eye-to-hand method"):
        calibrate_eye_to_hand(grippers, observed, "tsai")
    with pytest.raises(ValueError, match=r"T_base_gripper\[1\]"):
        calibrate_eye_in_hand([grippers[0], np.eye(3), grippers[2]], observed[:3])


def test_extrinsics_file_round_trips_and_feeds_the_config(tmp_path):
    T = look_at(np.array([0.5, 0.9, 0.7]), [0.5, 0.1, 0.1])
    path = tmp_path / "calibration.yaml"
    save_extrinsics(path, {"T_world_cam": {"012345678901": T, "012345678902": np.eye(4)}, "T_gripper_cam": {}},
                    {"method": "shah", "residual_m": 0.001})
    loaded = load_extrinsics(path)
    np.testing.assert_allclose(loaded["T_world_cam"]["012345678901"], T, atol=1e-8)
    assert loaded["T_gripper_cam"] == {}
    # the cell config can point at the file instead of inline matrices
    text = EXAMPLE_CONFIG.read_text()
    start = text.index("  T_world_cam:")
    end = text.index("\nworkspace:")
    (tmp_path / "cell.yaml").write_text(text[:start] + "  file: calibration.yaml\n" + text[end:])
    config = load_config(tmp_path / "cell.yaml")
    np.testing.assert_allclose(config.cameras[0].T_world_cam(), T, atol=1e-8)
    path.write_text("T_world_cam: {'012345678901': [[1, 0], [0, 1]]}\n")
    with pytest.raises(ConfigError, match="calibration.file: .*4x4"):
        load_config(tmp_path / "cell.yaml")


class RenderedCamera:
    """A fixed camera that renders the board carried by the arm (eye-to-hand)."""

    name = "rendered"

    def __init__(self, arm: URArm, T_base_cam: np.ndarray, T_gripper_target: np.ndarray) -> None:
        self.arm, self.T_base_cam, self.T_gripper_target = arm, T_base_cam, T_gripper_target

    def capture(self) -> Frame:
        T_cam_target = np.linalg.inv(self.T_base_cam) @ self.arm.tcp_pose() @ self.T_gripper_target
        return Frame(self.name, render_board(T_cam_target), np.zeros((480, 640), np.float32), K, self.T_base_cam)


def test_eye_to_hand_routine_end_to_end_with_rendered_images():
    config = load_config(EXAMPLE_CONFIG)
    arm = URArm(config.robot, make_guard(config), dry_run=True)
    arm.connect()
    T_base_cam = look_at(np.array([0.45, 0.75, 0.75]), [0.5, 0.1, 0.25])
    # the board hangs below the fingertips, facing up toward the camera
    T_gripper_target = transform(Rotation.from_euler("x", np.pi), [-0.09, 0.06, 0.06])
    rng = np.random.default_rng(4)
    poses = []
    for _ in range(10):
        rotation = Rotation.from_euler("x", np.pi) * Rotation.from_euler("xyz", rng.uniform(-20, 20, 3),
                                                                          degrees=True)
        poses.append(transform(rotation, [0.5, 0.1, 0.3] + rng.uniform([-0.08, -0.08, -0.05],
                                                                          [0.08, 0.08, 0.08])))
    camera = RenderedCamera(arm, T_base_cam, T_gripper_target)
    grippers, boards = collect_samples(arm, camera.capture, poses, BOARD, speed=0.1, acceleration=0.5)
    assert len(boards) >= 8
    found_cam, found_target = calibrate_eye_to_hand(grippers, boards)
    assert np.linalg.norm(found_cam[:3, 3] - T_base_cam[:3, 3]) < 0.005
    assert np.degrees(Rotation.from_matrix(found_cam[:3, :3].T @ T_base_cam[:3, :3]).magnitude()) < 0.5
    assert eye_to_hand_residual(found_cam, found_target, grippers, boards) < 0.003
    assert len(arm.planned_motions) == 10  # every pose went through the (dry-run) arm and its safety guard
