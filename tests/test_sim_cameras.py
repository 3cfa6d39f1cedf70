"""Virtual D435: OpenCV intrinsics/extrinsics from PyBullet's OpenGL matrices, metric depth, the noise model."""

import numpy as np
import pytest

from seggrasp.views import look_at
from sim.cameras import DepthNoise, VirtualD435, backproject, depth_rms, intrinsics
from sim.cell import SimCell
from sim.primitives import primitive_object

BOX = (0.06, 0.04, 0.10)


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    box = primitive_object("box", BOX, tmp_path_factory.mktemp("objects"))
    with SimCell([box], embodiment="floating", seed=2, image_size=(320, 240)) as sim_cell:
        yield sim_cell


def test_d435_intrinsics():
    K = intrinsics()
    assert K[0, 0] == K[1, 1] == 615.0 and K[0, 2] == 319.5 and K[1, 2] == 239.5
    np.testing.assert_allclose(intrinsics(160, 120)[0, 0], 615.0 / 4)
    with pytest.raises(ValueError, match="4:3"):
        intrinsics(640, 360)


def test_look_at_is_an_opencv_pose():
    T = look_at([1.0, 0.0, 1.0], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(T[:3, 2], np.array([-1.0, 0.0, -1.0]) / np.sqrt(2))  # z forward
    assert T[2, 1] < 0  # image y (down) points down in the world
    np.testing.assert_allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)


def test_backprojected_ideal_depth_lands_on_the_table_and_the_box(cell):
    _, T_world_obj = cell.object_mesh()
    client = cell.world.client
    rolled = look_at([0.95, 0.3, 0.6], T_world_obj[:3, 3], up=np.array([0.0, 1.0, 0.0]))  # image x ~ world up
    for T_world_cam in [camera.T_world_cam for camera in cell.cameras] + [rolled]:
        ideal = VirtualD435("ideal", T_world_cam, 320, 240, DepthNoise(enabled=False))
        frame = ideal.capture(client, np.random.default_rng(0))
        _, _, segmentation = ideal.render(client)
        points = backproject(frame)
        v, u = np.nonzero(frame.depth > 0)
        body = segmentation[v, u] & ((1 << 24) - 1)
        table = points[body == cell.world.table_id]
        assert len(table) > 1000
        assert np.abs(table[:, 2]).max() < 1e-4  # the table top is the plane z = 0
        on_box = points[body == cell.object_body]
        assert len(on_box) > 50
        local = (np.c_[on_box, np.ones(len(on_box))] @ np.linalg.inv(T_world_obj).T)[:, :3]
        half = np.array(BOX) / 2
        assert np.all(np.abs(local[:, :2]) < half[:2] + 0.001)
        assert np.all((local[:, 2] > -0.001) & (local[:, 2] < BOX[2] + 0.001))
        # some pixels see the box top at its height
        assert np.sum(np.abs(local[:, 2] - BOX[2]) < 0.001) > 10


def test_box_corner_projects_through_K_and_pose(cell):
    """The projection of a box corner with K and T_world_cam falls on a box pixel in the rendered mask."""
    _, T_world_obj = cell.object_mesh()
    camera = cell.cameras[0]
    _, depth, segmentation = camera.render(cell.world.client)
    centre_top = T_world_obj @ np.array([0.0, 0.0, BOX[2] * 0.9, 1.0])
    p_cam = np.linalg.inv(camera.T_world_cam) @ centre_top
    u, v = (camera.K @ (p_cam[:3] / p_cam[2]))[:2]
    assert (segmentation[int(round(v)), int(round(u))] & ((1 << 24) - 1)) == cell.object_body
    assert depth[int(round(v)), int(round(u))] == pytest.approx(p_cam[2], abs=0.02)


def test_depth_noise_follows_the_realsense_rms_model(cell):
    camera = cell.cameras[0]
    client = cell.world.client
    _, clean, segmentation = camera.render(client)
    frame = camera.capture(client, np.random.default_rng(1))
    table = ((segmentation & ((1 << 24) - 1)) == cell.world.table_id) & (frame.depth > 0)
    residual = (frame.depth - clean)[table]
    expected = depth_rms(clean[table])
    ratio = np.std(residual) / np.sqrt(np.mean(expected**2))
    assert 0.8 < ratio < 1.2
    assert depth_rms(np.array([1.0]))[0] == pytest.approx(0.0036, abs=0.0002)  # ~3.6 mm at 1 m
    dropped = (frame.depth == 0) & (segmentation >= 0)
    assert 0.001 < dropped.mean() < 0.1  # some holes, mostly on depth edges
    assert frame.depth.dtype == np.float32 and frame.rgb.dtype == np.uint8
