"""The bundled twin decompositions (assets/decompositions/) stay valid: every twin object's fast sweep is served from
them, without a CoACD run (the scan settings of issue 16 must not change a twin object's settings or cache keys)."""

import pytest

import seggrasp.decompose.workers as workers
from seggrasp.decompose import DecompositionConfig, SweepStats, decompose_sweep


def test_every_twin_object_is_served_from_the_bundled_caches(monkeypatch, tmp_path):
    from seggrasp.objects import load_asset_set

    try:
        models = load_asset_set()
    except (FileNotFoundError, ValueError) as exc:
        pytest.skip(f"twin not available: {exc}")

    def no_coacd(*args, **kwargs):
        raise AssertionError("CoACD ran: a bundled decomposition no longer matches its cache key")

    monkeypatch.setattr(workers, "run_coacd_hulls", no_coacd)
    for model in models:
        stats = SweepStats()
        partitions = decompose_sweep(model.mesh, DecompositionConfig(), cache_dir=tmp_path, workers=1, stats=stats)
        assert stats.run_seconds == {} and stats.cached, model.object_id
        assert partitions and all(p.part_of_face.shape == (len(model.mesh.faces),) for p in partitions)
