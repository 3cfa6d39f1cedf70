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


def test_unlabelled_scans_are_timed_without_a_miou(tmp_path, capsys):
    import trimesh

    scan = tmp_path / "001_ring"
    scan.mkdir()
    trimesh.creation.annulus(r_min=0.02, r_max=0.05, height=0.03, sections=16).export(scan / "textured.obj")
    (item,) = bench_seg.ycb_meshes(tmp_path)
    assert item.name == "ycb_001_ring" and not item.labelled and item.labels.parts == ["object"]
    assert item.labels.face_labels.shape == (len(item.mesh.faces),)
    modes = {m: 0.5 for m in bench_seg.REFINE_MODES}
    record = {"mesh": item.name, "category": "ycb", "faces": len(item.mesh.faces), "mode": "fast", "labelled": False,
              "times": {"render": 0.1, "vote": 0.1, "decompose": 1.0, "fusion": 0.1, "total_without_detector": 1.3},
              "peak_rss_mb": 100.0, "coacd_seconds": {"0.02": 1.0}, "distinct_partitions": [0.02], "miou": modes,
              "warm": None}
    bench_seg.print_table([record], ["fast"])
    row = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("ycb_001_ring"))
    assert "0.500" not in row and row.split()[-6:-1] == ["-"] * 5
