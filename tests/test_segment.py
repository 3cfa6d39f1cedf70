"""seggrasp.segment: progress messages before the stages that take seconds on huge meshes."""

import numpy as np
import trimesh

import seggrasp.decompose.workers as workers
from seggrasp.decompose import DecompositionConfig
from seggrasp.detect.simulated import SimulatedDetector
from seggrasp.labels import PartLabels
from seggrasp.mesh import prepare_mesh
from seggrasp.segment import SegmentationConfig, segment


def test_segment_announces_render_decomposition_and_fusion_before_running_them(monkeypatch, tmp_path, caplog):
    box = trimesh.creation.box([0.1, 0.04, 0.03]).subdivide()
    labels = PartLabels(["handle", "head"], (box.triangles_center[:, 0] > 0).astype(np.int64))
    monkeypatch.setattr(workers, "run_coacd_hulls", lambda v, f, t, p: [trimesh.Trimesh(v, f).bounding_box.vertices])
    config = SegmentationConfig(n_views=2, image_size=64, cache_dir=tmp_path, workers=1,
                                decomposition=DecompositionConfig(thresholds=(0.05,)))
    with caplog.at_level("INFO"):
        segment(prepare_mesh(box.vertices, box.faces), ["handle", "head"], SimulatedDetector(labels), config)
    messages = [record.getMessage() for record in caplog.records]
    order = [next(i for i, m in enumerate(messages) if m.startswith(prefix)) for prefix in
             ("rendering 2 views of", "rendered 2 views", "decomposing", "decomposition sweep:", "fusing the votes",
              "segmented")]
    assert order == sorted(order)
