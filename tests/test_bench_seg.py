"""bench/bench_seg.py: a cold benchmark sweep runs CoACD (never served from the bundled twin caches)."""

import re
import types

import numpy as np
import pytest

import seggrasp.decompose as decompose
import seggrasp.decompose.workers as workers
from seggrasp.decompose import DecompositionConfig

from bench import bench_seg  # noqa: E402


def test_cold_sweep_of_a_twin_object_runs_coacd_despite_the_bundled_cache(monkeypatch, tmp_path, twin_knife):
    model = twin_knife
    bundled = decompose.ASSET_CACHE_DIR
    keys = {DecompositionConfig().run_key(decompose.mesh_hash(model.mesh), t) for t in (0.02, 0.25)}
    if not all((bundled / f"{key}.npz").is_file() for key in keys):
        pytest.skip("assets/decompositions/ lacks knife_chef's fast sweep")
    monkeypatch.setattr(workers, "run_coacd_hulls",
                        lambda vertices, faces, threshold, params: [np.asarray(model.mesh.bounding_box.vertices)])
    partitions, stats, seconds, peak_mb, cpu = bench_seg.sweep_in_child(model.mesh, DecompositionConfig(), tmp_path,
                                                                        1)
    assert stats.cached == [] and {0.02, 0.25} <= set(stats.run_seconds)
    assert len(partitions) == 1 and partitions[0].part_of_face.shape == (len(model.mesh.faces),)
    assert seconds > 0 and peak_mb > 0 and cpu > 0


def test_quality_report_pairs_seeds_and_flags_categories_and_meshes_below_geofusion():
    def record(mesh, category, seed, coarse, full, default):
        return {"mesh": mesh, "category": category, "seed": seed,
                "miou": {"none": coarse, "full": full, "default": default}}

    records = [record("a1", "a", 0, 0.3, 0.4, 0.6), record("a1", "a", 1, 0.5, 0.6, 0.6),
               record("b1", "b", 0, 0.3, 0.5, 0.4), record("b1", "b", 1, 0.3, 0.5, 0.5)]
    mean, se = bench_seg.paired_over_seeds(records, "default", "none")
    # per-seed category-mean differences: seed 0 (0.3 + 0.1) / 2 = 0.2, seed 1 (0.1 + 0.2) / 2 = 0.15
    assert mean == pytest.approx(0.175) and se == pytest.approx(0.025)
    report = bench_seg.quality_report(records, "test")
    assert "not above GeoFusion: b." in report and "Worst mesh, default - GeoFusion: b1 -0.050" in report
    assert "more than 0.05 below GeoFusion: none." in report  # b1 is exactly 0.05 below
    records[2]["miou"]["default"] = 0.3
    assert "more than 0.05 below GeoFusion: b1 -0.100." in bench_seg.quality_report(records, "test")
    assert "| a1 | a | 0.400 | 0.500 | 0.600 | +0.100 +- 0.100 |" in report
    # category b: default - GeoFusion per seed -0.1 and 0.0, default - coarse 0.1 and 0.2
    assert "| b | 0.300 | 0.500 | 0.450 | -0.050 +- 0.050 | +0.150 +- 0.050 |" in report


def test_quality_needs_a_known_mesh_set_and_results_need_quality(capsys):
    with pytest.raises(SystemExit):
        bench_seg.main(["--meshes", "twin", "--results", "x.md"])
    assert "--results needs --quality" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        bench_seg.main(["--meshes", "twin", "--quality", "--seeds", "0"])


def test_ycb_set_without_the_scans_is_a_clear_error(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("SEGGRASP_YCB_DIR", str(tmp_path / "absent"))
    with pytest.raises(SystemExit):
        bench_seg.main(["--meshes", "ycb", "--quality"])
    assert "YCB scans not found" in capsys.readouterr().err


def test_a_ycb_scan_is_selected_by_its_name(monkeypatch):
    scan = types.SimpleNamespace(name="048_hammer")
    monkeypatch.setattr(bench_seg, "ycb_meshes", lambda: [scan])
    chosen = []
    monkeypatch.setattr(bench_seg, "quality", lambda items, args: chosen.extend(items))
    assert bench_seg.main(["--meshes", "048_hammer", "--quality"]) == 0
    assert chosen == [scan]


def test_perceived_mesh_is_a_closed_reconstruction_labelled_from_the_source(twin_knife):
    item = bench_seg.LabelledMesh(twin_knife.object_id, twin_knife.category, twin_knife.mesh, twin_knife.labels)
    seen = bench_seg.perceived(item, n_points=8000)
    assert seen.mesh.is_watertight and len(seen.mesh.faces) != len(item.mesh.faces)
    assert seen.labels.face_labels.shape == (len(seen.mesh.faces),)
    assert set(np.unique(seen.labels.face_labels)) == set(range(len(item.labels.parts)))
    handle = item.labels.parts.index("handle")  # labels follow the geometry: the handle stays on its side
    offset = {name: m.triangles_center[lab.face_labels == handle, 0].mean() - m.triangles_center[:, 0].mean()
              for name, m, lab in (("source", item.mesh, item.labels), ("seen", seen.mesh, seen.labels))}
    assert np.sign(offset["source"]) == np.sign(offset["seen"]) != 0


def test_cold_report_lists_every_run_and_the_paired_fast_reference_gap():
    def record(mesh, mode, full):
        return {"mesh": mesh, "faces": 100, "mode": mode, "times": {"render": 0.5, "decompose": 2.0,
                "total_without_detector": 3.0}, "peak_rss_mb": 300.0, "decompose_cpu_s": 3.5,
                "coacd_seconds": {"0.02": 1.0}, "parts_per_partition": [7], "detector_seeds": [0, 1],
                "miou": {"none": 0.4, "full": float(np.mean(full))}, "miou_per_seed": {"full": full}}

    records = [record("a", "fast", [0.5, 0.7]), record("a", "reference", [0.4, 0.4]), record("b", "fast", [0.5, 0.5])]
    report = bench_seg.cold_report(records, "python bench/bench_seg.py --x")
    assert "| a | 100 | fast | 0.5 | 2.0 (3.5) | 3.0 | 300 | 1 | 7 | 2 | 0.400 | 0.600 |" in report
    assert "| b | 100 | fast |" in report
    # differences 0.1 and 0.3: mean +20 points, standard error 10 points; only mesh a has both modes
    assert "on a: +20.00 points (paired standard error 10.00 points over 2 mesh x detector-seed pairs)" in report
    assert report.rstrip().endswith("Measured by `python bench/bench_seg.py --x`.")


def test_method_labels_show_the_default_and_soft_anchoring_without_its_gate():
    # three convex parts, prompts handle / blade / pivot; the pivot's evidence is weak everywhere (tests/test_fusion.py)
    from seggrasp.decompose import Partition

    scores = np.repeat([[0.7, 0.29, 0.01], [0.43, 0.5, 0.07], [0.6, 0.38, 0.02]], 2, axis=0)
    partitions = [Partition(0.02, np.arange(6)), Partition(0.1, np.array([0, 0, 1, 1, 2, 2]))]
    labels = bench_seg.method_labels(scores, partitions, np.ones(6))
    np.testing.assert_array_equal(labels["default"], labels["anchor-soft"])
    assert (labels["anchor-soft-ungated"] == 2).any() and not (labels["default"] == 2).any()
    gated = bench_seg.method_labels(scores, partitions, np.ones(6), min_ratios=[0.1, 0.3])
    np.testing.assert_array_equal(gated["anchor-soft-gate0.1"], labels["anchor-soft-ungated"])  # the pivot passes 0.1
    np.testing.assert_array_equal(gated["anchor-soft-gate0.3"], labels["default"])


def test_quality_seed_and_gate_options_are_checked(capsys):
    for bad in (["--first-seed", "-1"], ["--min-ratios", "0.3,x"], ["--min-ratios", "1.5"]):
        with pytest.raises(SystemExit):
            bench_seg.main(["--meshes", "twin", "--quality", *bad])
    assert "--min-ratios must lie in [0, 1]" in capsys.readouterr().err


def test_paired_difference_gives_mean_standard_error_and_pairs():
    gap, se, pairs = bench_seg.paired_difference([0.5, 0.7, 0.6], [0.4, 0.4, 0.6])
    # differences 0.1, 0.3, 0.0: mean 0.1333, sample sd 0.1528, SE 0.1528 / sqrt(3)
    assert gap == pytest.approx(0.4 / 3) and se == pytest.approx(np.std([0.1, 0.3, 0.0], ddof=1) / np.sqrt(3))
    assert pairs == 3
    assert np.isnan(bench_seg.paired_difference([0.5], [0.4])[1])
    with pytest.raises(ValueError, match="equally long"):
        bench_seg.paired_difference([], [])


def test_rescore_prints_the_paired_gap_of_two_stored_sweeps(monkeypatch, tmp_path, capsys):
    item = bench_seg.primitive_meshes()[1]  # the hammer: handle and head
    n = len(item.mesh.faces)
    folder = tmp_path / "bench_arrays"
    folder.mkdir()
    right = item.labels.face_labels.astype(np.int32)
    np.savez(folder / f"{item.name}_fast.npz", thresholds=np.array([0.1]), partitions=right[None])
    np.savez(folder / f"{item.name}_before.npz", thresholds=np.array([0.1]), partitions=np.zeros((1, n), np.int32))

    def scores(item, preset, seed, n_views, image_size):  # the head voted for everywhere, the handle on its half
        s = np.zeros((n, 2))
        s[:, 1] = 1.0
        s[item.labels.face_labels == 0, 0] = 2.0 if seed == 0 else 0.5
        return s, {}

    monkeypatch.setattr(bench_seg, "coarse_scores", scores)
    bench_seg.main(["--meshes", item.name, "--rescore", "--rescore-modes", "fast,before", "--seeds", "2",
                    "--out", str(tmp_path / "bench.jsonl")])
    out = capsys.readouterr().out
    gap = re.search(r"full mIoU fast - before: ([-+][0-9.]+) points \(paired standard error ([0-9.]+) points over 2 ", out)
    assert gap is not None, out
    # the true partition beats a single part under both seeds' scores
    assert float(gap.group(1)) > 10 and float(gap.group(2)) >= 0
