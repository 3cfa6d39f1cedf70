"""The RealSense path on replayed frames: a fake pipeline serving frames recorded from the simulated cameras (and
ray-cast synthetic ones) as raw z16 depth + rgb8 colour, through `RealSenseCamera`."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from fakes_hardware import EXAMPLE_CONFIG, FakeAlign, FakePipeline, box_on_table, synthetic_frames
from hardware.config import load_config
from hardware.errors import ConnectionLostError
from hardware.realsense import RealSenseCamera, intrinsics_to_K
from seggrasp.cell import Frame


@pytest.fixture(scope="module")
def config():
    return load_config(EXAMPLE_CONFIG)


@pytest.fixture(scope="module")
def sim_frames(tmp_path_factory) -> list[Frame]:
    """Two frames from the PyBullet twin's virtual D435s looking at a box on the table."""
    from seggrasp.objects import load_external_object
    from sim.cell import SimCell

    folder = tmp_path_factory.mktemp("sim_box")
    trimesh.creation.box(extents=[0.05, 0.04, 0.08]).export(folder / "box.obj")
    model = load_external_object(folder / "box.obj", cache_dir=folder / "cache", object_id="box")
    cell = SimCell(objects=[model], seed=0, image_size=(160, 120))
    try:
        return cell.capture()
    finally:
        cell.close()


def replay(camera_config, frames: list[Frame], depth_scale: float = 0.001):
    pipeline = FakePipeline(frames, depth_scale=depth_scale)
    align = FakeAlign()
    camera = RealSenseCamera(replace(camera_config, T_mount_cam=frames[0].T_world_cam), pipeline=pipeline,
                             align=align, warmup_frames=2)
    camera.start()
    return camera, pipeline, align


def test_frames_from_the_simulated_cameras_survive_the_realsense_path(config, sim_frames):
    for camera_config, recorded in zip(config.cameras, sim_frames):
        camera, pipeline, align = replay(camera_config, [recorded])
        frame = camera.capture()
        assert frame.name == camera_config.name
        assert frame.rgb.dtype == np.uint8 and frame.depth.dtype == np.float32
        np.testing.assert_array_equal(frame.rgb, recorded.rgb)
        np.testing.assert_allclose(frame.K, recorded.K)
        np.testing.assert_allclose(frame.T_world_cam, recorded.T_world_cam)
        # z16 at 1 mm per unit: at most half a millimetre lost, holes stay holes
        valid = recorded.depth > 0
        assert valid.mean() > 0.5
        assert np.abs(frame.depth[valid] - recorded.depth[valid]).max() <= 0.0005 + 1e-6
        np.testing.assert_array_equal(frame.depth > 0, np.round(recorded.depth / 0.001) > 0)
        assert pipeline.delivered == 3 and align.processed == 1  # two warm-up frames, then one aligned capture
        camera.stop()
        assert pipeline.stopped


def test_depth_scale_and_intrinsics_come_from_the_device(config):
    K = np.array([[200.0, 0, 79.5], [0, 200.0, 59.5], [0, 0, 1]])
    T_world_cam = config.cameras[0].T_world_cam()
    scene = box_on_table((0.52, 0.1), (0.06, 0.05, 0.1))
    frames = synthetic_frames(scene, [T_world_cam], K, (120, 160))
    camera, _, _ = replay(config.cameras[0], frames, depth_scale=0.0001)
    assert camera.depth_scale == pytest.approx(0.0001)
    np.testing.assert_allclose(camera.K, K)
    frame = camera.capture()
    assert np.abs(frame.depth - frames[0].depth).max() <= 0.00005 + 1e-6
    # the box's top face is 10 cm above the table: back-projected points of the red pixels reach z ~ 0.1
    v, u = np.nonzero((frame.rgb[..., 0] == 200) & (frame.depth > 0))
    rays = np.linalg.inv(K) @ np.stack([u, v, np.ones_like(u)])
    points = (T_world_cam[:3, :3] @ (rays * frame.depth[v, u]) + T_world_cam[:3, 3:4]).T
    assert points[:, 2].max() == pytest.approx(0.1, abs=0.002)
    assert np.abs(points[:, :2].mean(axis=0) - [0.52, 0.1]).max() < 0.03


def test_intrinsics_to_K():
    class Intrinsics:
        fx, fy, ppx, ppy = 610.0, 611.0, 320.5, 240.25

    np.testing.assert_allclose(intrinsics_to_K(Intrinsics), [[610, 0, 320.5], [0, 611, 240.25], [0, 0, 1]])


def test_camera_that_stops_delivering_raises_a_clear_error(config, sim_frames):
    camera, pipeline, _ = replay(config.cameras[0], sim_frames[:1])
    pipeline.fail = True
    with pytest.raises(ConnectionLostError, match="delivered no frames"):
        camera.capture()
    unstarted = RealSenseCamera(config.cameras[0], pipeline=FakePipeline(sim_frames[:1]), align=FakeAlign())
    with pytest.raises(ConnectionLostError, match="not streaming"):
        unstarted.capture()
