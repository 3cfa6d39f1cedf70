"""bench/bench_seg.py: a cold benchmark sweep runs CoACD (never served from the bundled twin caches)."""

import sys
from pathlib import Path

import numpy as np
import pytest

import seggrasp.decompose as decompose
import seggrasp.decompose.workers as workers
from seggrasp.decompose import DecompositionConfig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
bench_seg = pytest.importorskip("bench_seg")


def test_cold_sweep_of_a_twin_object_runs_coacd_despite_the_bundled_cache(monkeypatch, tmp_path, twin_knife):
    model = twin_knife
    bundled = decompose.ASSET_CACHE_DIR
    keys = {DecompositionConfig().run_key(decompose.mesh_hash(model.mesh), t) for t in (0.02, 0.25)}
    if not all((bundled / f"{key}.npz").is_file() for key in keys):
        pytest.skip("assets/decompositions/ lacks knife_chef's fast sweep")
    monkeypatch.setattr(workers, "run_coacd_hulls",
                        lambda vertices, faces, threshold, params: [np.asarray(model.mesh.bounding_box.vertices)])
    partitions, stats, seconds, peak_mb = bench_seg.sweep_in_child(model.mesh, DecompositionConfig(), tmp_path, 1)
    assert stats.cached == [] and {0.02, 0.25} <= set(stats.run_seconds)
    assert len(partitions) == 1 and partitions[0].part_of_face.shape == (len(model.mesh.faces),)
    assert seconds > 0 and peak_mb > 0
