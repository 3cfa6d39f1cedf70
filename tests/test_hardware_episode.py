"""The same episode code (seggrasp.episode.Episode) end to end on `RealCell` with fakes: the cameras replay
frames recorded from the simulated D435s, the mesh comes from seggrasp.perception, the arm is a fake RTDE pair and
the gripper a fake URCap server holding an object of the cylinder's width."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from fakes_hardware import FakeAlign, FakePipeline, FakeRobotiqServer, FakeUR, example_config, write_config
from hardware import RealCell
from hardware.ur import matrix_from_ur_pose
from seggrasp.detect.base import Detections
from seggrasp.episode import Episode, EpisodeContext, EpisodeSettings
from seggrasp.truth import DetectorSpec

pytest.importorskip("seggrasp.perception")

RADIUS, HEIGHT = 0.03, 0.11
HOME_FACING_PLUS_X = [np.pi, -np.pi / 2, np.pi / 2, -np.pi / 2, -np.pi / 2, 0.0]


class WholeViewDetector:
    """Boxes the whole image for the first prompt (the typical 'part prompt boxed as the whole object' answer)."""

    name = "whole-view"

    def detect(self, views, prompts):
        return [Detections(np.array([[0, 0, v.rgb.shape[1] - 1, v.rgb.shape[0] - 1]]), np.array([0.9]),
                           np.array([0])) for v in views]


@dataclass(frozen=True)
class WholeViewSpec(DetectorSpec):
    """A detector spec that needs no weights and no ground truth (the real cell has none)."""

    name: str = "whole-view"

    def build(self, gt_labels):
        assert gt_labels is None  # the real cell has no ground truth
        return WholeViewDetector()


@pytest.fixture(scope="module")
def sim_frames(tmp_path_factory):
    """Frames of a cylinder on the table from the twin's virtual D435s."""
    from sim.cell import SimCell
    from sim.primitives import primitive_object

    model = primitive_object("cylinder", (RADIUS, HEIGHT), tmp_path_factory.mktemp("objects"), mass=0.2)
    with SimCell([model], embodiment="floating", seed=0, image_size=(320, 240)) as cell:
        frames = cell.capture()
        _, T_world_obj = cell.object_mesh()
    return frames, T_world_obj


def test_episode_runs_end_to_end_on_the_real_cell(tmp_path, sim_frames):
    frames, T_world_obj = sim_frames
    with FakeRobotiqServer(newline=True) as server:
        data = example_config()
        data["robot"]["home_joints"] = HOME_FACING_PLUS_X
        data["gripper"].update(host="127.0.0.1", port=server.port)
        data["workspace"] = {"min": [0.25, -0.25, 0.0], "max": [0.75, 0.25, 0.5]}
        data["motion"]["hold_time"] = 0.05
        data["cameras"] = [{"serial": f"sim{i}", "name": frame.name} for i, frame in enumerate(frames)]
        data["calibration"] = {"T_world_cam": {f"sim{i}": frame.T_world_cam.tolist()
                                               for i, frame in enumerate(frames)}}
        path = write_config(tmp_path / "cell.yaml", data)
        ur = FakeUR("ur5", np.array(HOME_FACING_PLUS_X))
        cell = RealCell.from_config(
            path, control_factory=ur.control, receive_factory=ur.receive,
            pipeline_factory=lambda serial: FakePipeline([frames[int(serial[3:])]]), align_factory=FakeAlign,
            camera_warmup_frames=0)
        server.object_register = cell.gripper.width_to_register(2 * RADIUS)
        try:
            context = EpisodeContext(object_id="cylinder", category="cylinder", prompts=["side"], scene_seed=0)
            settings = EpisodeSettings(seed=0, top_k=2, perceive=True, workspace=cell.workspace)
            records = Episode(cell, context, WholeViewSpec(), settings=settings).run("coarse")
        finally:
            cell.close()

    assert len(records) == 2
    # each trial: reset (retract if low, home), then pre-grasp, grasp, lift, put back, back off
    names = [name for name, _ in ur.motions]
    assert names == ["moveJ"] + ["moveJ"] + ["moveL"] * 5 + ["moveL", "moveJ"] + ["moveL"] * 5
    grasp_poses = [matrix_from_ur_pose(ur.motions[i][1][0]) for i in (3, 10)]
    for record, commanded in zip(records, grasp_poses):
        assert record.executed and record.reachable and record.lifted, record.message
        assert record.lift_height == pytest.approx(0.2) and record.outcome["contacts_observed"] is False
        assert record.success is None  # no ground truth on the real cell
        # the arm went exactly where the episode asked, and that is on the perceived cylinder's side
        np.testing.assert_allclose(commanded, np.array(record.T_world_grasp), atol=1e-6)
        axis_offset = commanded[:2, 3] - T_world_obj[:2, 3]
        assert np.linalg.norm(axis_offset) < 0.015
        assert 0.0 < commanded[2, 3] < HEIGHT  # between the table (z = 0) and the cylinder's top
        assert 0.04 < record.width < 2 * RADIUS + 0.015  # across the perceived cylinder (+ any sampler margin)
