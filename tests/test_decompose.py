"""Decomposition sweep: face -> hull mapping, dedup, threshold selection, cache, determinism, reference mode."""

import json
import os
import time

import numpy as np
import pytest
import trimesh

import seggrasp.decompose as decompose
import seggrasp.decompose.workers as workers
from seggrasp.decompose import (
    COACD_DEFAULTS,
    PAPER_THRESHOLDS,
    DecompositionConfig,
    Partition,
    SweepStats,
    canonical_parts,
    decompose_sweep,
    dedupe_partitions,
    map_faces_to_hulls,
    select_scan_thresholds,
    select_thresholds,
    set_coacd_log_level,
)

#: Coarse CoACD settings that keep a run on a box pair well under a second.
QUICK = dict(resolution=300, preprocess_resolution=20, mcts_nodes=8, mcts_iterations=20, mcts_max_depth=1)


def box(extents, centre) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents)
    mesh.apply_translation(centre)
    return mesh


def two_box_mesh() -> tuple[trimesh.Trimesh, np.ndarray]:
    """A big box and a thin slab 2 cm apart, finely tessellated; returns the mesh and the box id of every face."""
    big = box([0.1, 0.1, 0.1], [0.0, 0.0, 0.0]).subdivide().subdivide()
    thin = box([0.1, 0.1, 0.01], [0.0, 0.0, 0.075]).subdivide().subdivide()
    mesh = trimesh.util.concatenate([big, thin])
    return mesh, np.repeat([0, 1], [len(big.faces), len(thin.faces)])


def l_shape() -> trimesh.Trimesh:
    """A closed L-shaped solid (two boxes united): CoACD splits it into two convex parts."""
    return trimesh.boolean.union(
        [box([0.1, 0.03, 0.03], [0.05, 0.0, 0.0]), box([0.03, 0.03, 0.1], [0.085, 0.0, 0.05])], engine="manifold"
    ).subdivide()


def test_map_faces_respects_containment_and_assigns_every_face():
    mesh, truth = two_box_mesh()
    hulls = [box([0.1, 0.1, 0.1], [0, 0, 0]).vertices, box([0.1, 0.1, 0.01], [0, 0, 0.075]).vertices]
    parts = map_faces_to_hulls(mesh.triangles_center, hulls, scale=float(np.linalg.norm(mesh.extents)))
    assert parts.shape == (len(mesh.faces),)
    np.testing.assert_array_equal(parts, truth)


def test_map_faces_outside_every_hull_takes_the_nearest_and_overlaps_go_to_the_smaller_hull():
    hulls = [box([1.0, 1.0, 1.0], [0, 0, 0]).vertices, box([0.2, 0.2, 0.2], [0.5, 0, 0]).vertices]
    centroids = np.array([
        [-0.2, 0.0, 0.0],   # only in the big hull
        [0.5, 0.0, 0.0],    # in both: the small (thin) part wins
        [0.75, 0.0, 0.0],   # outside both, nearer the small hull (0.15) than the big one (0.25)
        [0.0, 0.0, 0.8],    # outside both, nearer the big hull
    ])
    np.testing.assert_array_equal(map_faces_to_hulls(centroids, hulls, scale=1.0), [0, 1, 1, 0])


def test_canonical_parts_and_dedupe_keep_the_earlier_threshold():
    np.testing.assert_array_equal(canonical_parts(np.array([5, 5, 2, 9, 2])), [0, 0, 1, 2, 1])
    a, b = np.array([0, 0, 1, 1]), np.array([0, 1, 2, 2])
    partitions = [Partition(0.05, a.copy()), Partition(0.01, b.copy()), Partition(0.02, b.copy()),
                  Partition(0.03, a.copy()), Partition(0.2, np.zeros(4, dtype=np.int64))]
    kept = dedupe_partitions(partitions)
    assert [p.threshold for p in kept] == [0.01, 0.03, 0.2]


def test_threshold_selection_returns_every_distinct_partition_of_the_grid_with_fewer_runs():
    grid = PAPER_THRESHOLDS
    # Known hull counts per threshold: piecewise constant, coarsening with the threshold.
    changes = {0.01: 6, 0.02: 5, 0.05: 4, 0.06: 3, 0.13: 2, 0.21: 1}
    count_at = {}
    current = None
    for t in grid:
        current = changes.get(t, current)
        count_at[t] = current

    def partition(t):
        return canonical_parts(np.arange(12) * count_at[t] // 12)

    runs = []

    def evaluate(thresholds):
        runs.extend(thresholds)
        return {t: partition(t) for t in thresholds}

    found = select_thresholds(grid, evaluate)
    distinct = dedupe_partitions([Partition(t, p) for t, p in found.items()])
    full = dedupe_partitions([Partition(t, partition(t)) for t in grid])
    assert [p.threshold for p in distinct] == [p.threshold for p in full] == sorted(changes)
    assert all(a.same_as(b) for a, b in zip(distinct, full))
    assert len(runs) == len(set(runs)) < len(grid)

    runs.clear()
    capped = select_thresholds(grid, evaluate, max_runs=5)
    assert len(runs) == len(capped) == 5 and min(capped) == 0.01 and max(capped) == 0.25


def four_boxes() -> tuple[trimesh.Trimesh, np.ndarray]:
    """Four separate 2 cm cubes in a row along x (5 cm apart); returns the mesh and the cube of every face."""
    cubes = [box([0.02, 0.02, 0.02], [0.05 * k, 0.0, 0.0]).subdivide() for k in range(4)]
    return trimesh.util.concatenate(cubes), np.repeat(np.arange(4), [len(c.faces) for c in cubes])


#: Known hulls of `four_boxes` per threshold: (lowest threshold, groups of cubes merged into one hull).
KNOWN_GROUPS = ((0.0, ((0,), (1,), (2,), (3,))), (0.05, ((0, 1), (2,), (3,))), (0.10, ((0, 1), (2, 3))),
                (0.20, ((0, 1, 2, 3),)))


def groups_at(threshold: float) -> tuple[tuple[int, ...], ...]:
    return [groups for low, groups in KNOWN_GROUPS if threshold >= low - 1e-9][-1]


def known_hulls(vertices, faces, threshold, params):
    """Stand-in for CoACD on `four_boxes`: one hull (the bounding box of its cubes) per group of `groups_at`."""
    hulls = []
    for group in groups_at(threshold):
        low = np.array([0.05 * min(group) - 0.01, -0.01, -0.01])
        high = np.array([0.05 * max(group) + 0.01, 0.01, 0.01])
        hulls.append(trimesh.bounds.corners(np.stack([low, high])))
    return hulls


def test_sweep_selection_returns_the_distinct_partitions_of_a_mesh_with_known_hulls(monkeypatch, tmp_path):
    mesh, cube_of_face = four_boxes()
    log = tmp_path / "calls.jsonl"
    monkeypatch.setattr(workers, "run_coacd_hulls", recording_coacd(log, None, real=known_hulls))

    def expected(threshold):
        group_of_cube = {cube: g for g, group in enumerate(groups_at(threshold)) for cube in group}
        return canonical_parts(np.array([group_of_cube[c] for c in cube_of_face]))

    grid = DecompositionConfig().thresholds
    truth = dedupe_partitions([Partition(t, expected(t)) for t in grid])
    assert [p.threshold for p in truth] == [0.02, 0.05, 0.1, 0.2] and [p.n_parts for p in truth] == [4, 3, 2, 1]

    # Unlimited bisection: exactly the full grid's distinct partitions, at their first thresholds, in fewer runs.
    found = decompose_sweep(mesh, DecompositionConfig(max_runs=len(grid)), cache_dir=tmp_path / "a", workers=2)
    assert [p.threshold for p in found] == [p.threshold for p in truth]
    assert all(a.same_as(b) for a, b in zip(found, truth))
    runs = [c[0] for c in logged_calls(log)]
    assert len(runs) == len(set(runs)) < len(grid)

    # The default fast sweep (at most FAST_MAX_RUNS runs) still finds every distinct partition, each the true
    # partition at the threshold it reports.
    log.unlink()
    fast = decompose_sweep(mesh, DecompositionConfig(), cache_dir=tmp_path / "b", workers=2)
    assert len(logged_calls(log)) <= decompose.FAST_MAX_RUNS
    assert [p.n_parts for p in fast] == [4, 3, 2, 1]
    assert all(p.same_as(Partition(p.threshold, expected(p.threshold))) for p in fast)


def test_log_level_is_validated_before_coacd_sees_it():
    with pytest.raises(ValueError, match="log level"):
        DecompositionConfig(log_level="trace")
    with pytest.raises(ValueError, match="log level"):
        set_coacd_log_level("verbose")
    with pytest.raises(ValueError, match="unknown CoACD parameters"):
        DecompositionConfig(coacd={"resolutoin": 10})
    with pytest.raises(ValueError, match="mode"):
        DecompositionConfig(mode="quick")


def recording_coacd(log, result, real=None):
    """A stand-in for `run_coacd_hulls` that logs its calls to a file (runs happen in child processes)."""

    def fake(vertices, faces, threshold, params):
        with open(log, "a") as handle:
            handle.write(json.dumps([threshold, params, len(faces), os.getpid()]) + "\n")
        return real(vertices, faces, threshold, params) if real else result

    return fake


def logged_calls(log):
    return [json.loads(line) for line in open(log)] if os.path.exists(log) else []


@pytest.mark.slow
def test_reference_mode_runs_the_literal_paper_sweep(monkeypatch, tmp_path):
    mesh = l_shape()
    log = tmp_path / "calls.jsonl"
    monkeypatch.setattr(workers, "run_coacd_hulls", recording_coacd(log, [np.asarray(mesh.bounding_box.vertices)]))
    partitions = decompose_sweep(mesh, DecompositionConfig(mode="reference", seed=3), cache_dir=tmp_path)
    calls = logged_calls(log)
    assert [c[0] for c in calls] == [pytest.approx(0.01 * k) for k in range(1, 26)]  # all 25, serial, in order
    assert all(c[1] == dict(COACD_DEFAULTS, seed=3) for c in calls)
    assert all(c[2] == len(mesh.faces) for c in calls)  # no simplification
    assert len(partitions) == 1 and partitions[0].threshold == pytest.approx(0.01)


def test_a_crashing_coacd_run_raises_instead_of_killing_the_interpreter(monkeypatch, tmp_path):
    mesh = l_shape().subdivide().subdivide()

    def abort_on_simplified(vertices, faces, threshold, params):
        if len(faces) < len(mesh.faces):
            os.abort()
        return [np.asarray(mesh.bounding_box.vertices)]

    monkeypatch.setattr(workers, "run_coacd_hulls", abort_on_simplified)
    (partition,) = decompose_sweep(mesh, DecompositionConfig(thresholds=(0.05,)), cache_dir=tmp_path / "a")
    assert partition.part_of_face.shape == (len(mesh.faces),)  # retried on the full mesh
    monkeypatch.setattr(workers, "run_coacd_hulls", lambda *args: os.abort())
    with pytest.raises(RuntimeError, match="crashed"):
        decompose_sweep(mesh, DecompositionConfig(thresholds=(0.05,)), cache_dir=tmp_path / "b")


def test_cache_hit_on_second_call_and_miss_on_changed_parameter(monkeypatch, tmp_path):
    mesh = l_shape()
    config = DecompositionConfig(thresholds=(0.05, 0.2), coacd=QUICK, adaptive=False)
    first = decompose_sweep(mesh, config, cache_dir=tmp_path, workers=1)
    assert all(p.part_of_face.shape == (len(mesh.faces),) for p in first)

    log = tmp_path / "calls.jsonl"
    monkeypatch.setattr(workers, "run_coacd_hulls", recording_coacd(log, None, real=decompose.run_coacd_hulls))
    stats = SweepStats()
    second = decompose_sweep(mesh, config, cache_dir=tmp_path, workers=1, stats=stats)
    assert logged_calls(log) == [] and sorted(stats.cached) == [0.05, 0.2]
    assert len(second) == len(first) and all(a.same_as(b) for a, b in zip(first, second))

    changed = DecompositionConfig(thresholds=(0.05, 0.2), coacd=dict(QUICK, resolution=301), adaptive=False)
    decompose_sweep(mesh, changed, cache_dir=tmp_path, workers=1)
    assert sorted(c[0] for c in logged_calls(log)) == [0.05, 0.2]
    os.remove(log)
    decompose_sweep(mesh, DecompositionConfig(thresholds=(0.05, 0.2), coacd=QUICK, adaptive=False, seed=1),
                    cache_dir=tmp_path, workers=1)
    assert sorted(c[0] for c in logged_calls(log)) == [0.05, 0.2]


def test_sweep_is_deterministic_and_splits_the_l_shape(tmp_path):
    mesh = l_shape()
    config = DecompositionConfig(thresholds=(0.05,), coacd=QUICK)
    first = decompose_sweep(mesh, config, cache_dir=tmp_path / "a", workers=1)
    second = decompose_sweep(mesh, config, cache_dir=tmp_path / "b", workers=1)
    assert len(first) == len(second) == 1 and first[0].same_as(second[0])
    assert first[0].n_parts >= 2


def test_decimated_decomposition_maps_every_full_resolution_face(tmp_path):
    mesh = l_shape().subdivide().subdivide()  # ~2.4k faces
    config = DecompositionConfig(thresholds=(0.05,), coacd=QUICK, simplify_tolerance=0.002)
    coarse_vertices, coarse_faces, closed = decompose.simplify(mesh, 0.002)
    assert closed
    assert len(coarse_faces) < len(mesh.faces) / 10
    assert trimesh.Trimesh(coarse_vertices, coarse_faces, process=False).is_watertight
    (partition,) = decompose_sweep(mesh, config, cache_dir=tmp_path, workers=1)
    assert partition.part_of_face.shape == (len(mesh.faces),)
    assert partition.part_of_face.min() == 0
    assert np.array_equal(np.unique(partition.part_of_face), np.arange(partition.n_parts))
    # The arm tips lie in different convex parts.
    tip_x = np.argmin(mesh.triangles_center[:, 0])
    tip_z = np.argmax(mesh.triangles_center[:, 2])
    assert partition.part_of_face[tip_x] != partition.part_of_face[tip_z]


def test_parallel_workers_give_the_serial_result(tmp_path):
    mesh = l_shape()
    config = DecompositionConfig(thresholds=(0.05, 0.1), coacd=QUICK, adaptive=False)
    serial = decompose_sweep(mesh, config, cache_dir=tmp_path / "s", workers=1)
    parallel = decompose_sweep(mesh, config, cache_dir=tmp_path / "p", workers=2)
    assert [p.threshold for p in serial] == [p.threshold for p in parallel]
    assert all(a.same_as(b) for a, b in zip(serial, parallel))


def test_fast_mode_simplifies_caps_the_runs_and_uses_its_coacd_settings(monkeypatch, tmp_path):
    mesh = l_shape().subdivide().subdivide()
    log = tmp_path / "calls.jsonl"
    monkeypatch.setattr(workers, "run_coacd_hulls", recording_coacd(log, [np.asarray(mesh.bounding_box.vertices)]))
    decompose_sweep(mesh, DecompositionConfig(seed=2), cache_dir=tmp_path, workers=2)
    calls = logged_calls(log)
    assert len(calls) <= decompose.FAST_MAX_RUNS
    assert {c[0] for c in calls} >= {0.02, 0.25}
    assert all(c[1] == dict(decompose.FAST_COACD, seed=2) for c in calls)
    assert all(c[2] < len(mesh.faces) for c in calls)
    assert len({c[3] for c in calls}) == len(calls)  # every run in its own process


def test_fast_mode_decomposes_an_open_mesh_through_a_closed_shell_without_coacd_preprocessing(monkeypatch, tmp_path):
    closed = l_shape().subdivide()
    opened = trimesh.Trimesh(closed.vertices, closed.faces[1:], process=False)  # one face missing: not closed
    log = tmp_path / "calls.jsonl"
    monkeypatch.setattr(workers, "run_coacd_hulls", _bounding_box_coacd(log))
    config = DecompositionConfig(thresholds=(0.05,))
    assert config.coacd_params()["preprocess_mode"] == "off"
    decompose_sweep(closed, config, cache_dir=tmp_path / "closed", workers=1)
    (partition,) = decompose_sweep(opened, config, cache_dir=tmp_path / "open", workers=1)
    decompose_sweep(opened, DecompositionConfig(mode="reference", thresholds=(0.05,)), cache_dir=tmp_path / "ref",
                    workers=1)
    (on_closed, on_open, on_open_reference) = logged_calls(log)
    assert on_closed[1]["preprocess_mode"] == "off" and on_closed[2] < len(closed.faces)
    # The closed (twin-like) mesh keeps the fast settings of the bundled caches; the scan searches one cut deep.
    assert on_closed[1] == config.coacd_params() == dict(decompose.FAST_COACD, seed=0)
    assert on_closed[1]["mcts_max_depth"] == 2 and on_open[1]["mcts_max_depth"] == 1
    # Fast mode: CoACD gets a closed shell around the open mesh, so it needs no preprocessing of its own.
    assert on_open[1] == config.coacd_params(scan=True) and on_open[2] != len(opened.faces)
    assert partition.part_of_face.shape == (len(opened.faces),)
    # The reference mode stays literal: the open mesh itself, CoACD's preprocessing on.
    assert on_open_reference[1]["preprocess_mode"] == "auto" and on_open_reference[2] == len(opened.faces)
    # The open mesh's runs are keyed as a scan's; the closed mesh keeps the key of the bundled twin caches.
    assert (tmp_path / "closed" / f"{config.run_key(decompose.mesh_hash(closed), 0.05)}.npz").is_file()
    assert (tmp_path / "open" / f"{config.run_key(decompose.mesh_hash(opened), 0.05, scan=True)}.npz").is_file()


def test_closed_shell_encloses_every_face_of_an_open_mesh():
    from seggrasp.decompose.remesh import closed_shell

    tube = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=32).subdivide()
    tube = trimesh.Trimesh(tube.vertices, tube.faces[np.abs(tube.face_normals[:, 2]) < 0.5])  # caps removed: open
    assert not workers.is_closed_manifold(tube.vertices, tube.faces)
    vertices, faces = closed_shell(tube.vertices, tube.faces, resolution=32)
    shell = trimesh.Trimesh(vertices, faces)
    assert workers.is_closed_manifold(vertices, faces) and shell.volume > 0
    assert shell.contains(tube.triangles_center).all()
    assert shell.volume < 0.5 * trimesh.creation.cylinder(radius=0.04, height=0.1).volume  # a shell, not filled


def test_bundled_twin_caches_make_the_sweep_warm(monkeypatch, tmp_path, twin_knife):
    model = twin_knife
    monkeypatch.setattr(workers, "run_coacd_hulls", lambda *args: os.abort())
    stats = SweepStats()
    try:
        partitions = decompose_sweep(model.mesh, DecompositionConfig(), cache_dir=tmp_path, stats=stats)
    except RuntimeError:
        pytest.fail("assets/decompositions/ lacks knife_chef: run `python -m assets decompose`")
    assert stats.run_seconds == {} and len(stats.cached) >= 2
    assert partitions[0].part_of_face.shape == (len(model.mesh.faces),)
    with pytest.raises(RuntimeError, match="crashed"):  # bundled=False: a cold run (benchmarks) must run CoACD
        decompose_sweep(model.mesh, DecompositionConfig(), cache_dir=tmp_path / "cold", bundled=False)


def test_assets_command_precomputes_the_bundled_sweeps(monkeypatch, capsys, twin_knife):
    """`python -m assets decompose` fills assets/decompositions/; with the committed caches it runs no CoACD."""
    from assets.__main__ import main as assets_main

    monkeypatch.setattr(workers, "run_coacd_hulls", lambda *args: os.abort())
    assert assets_main(["decompose", "--only", "knife_chef"]) == 0
    assert "knife_chef:" in capsys.readouterr().out


def _bounding_box_coacd(log):
    return recording_coacd(log, None, real=lambda v, f, t, p: [trimesh.Trimesh(v, f).bounding_box.vertices])


@pytest.mark.parametrize("damage", ["empty", "truncated"])
def test_a_damaged_cache_entry_is_reported_discarded_and_recomputed(monkeypatch, tmp_path, caplog, damage):
    mesh = l_shape()
    config = DecompositionConfig(thresholds=(0.05,), adaptive=False)
    log = tmp_path / "calls.jsonl"
    monkeypatch.setattr(workers, "run_coacd_hulls", _bounding_box_coacd(log))
    cache = tmp_path / "cache"
    (first,) = decompose_sweep(mesh, config, cache_dir=cache, workers=1)
    (entry,) = cache.glob("*.npz")
    data = entry.read_bytes()
    entry.write_bytes(b"" if damage == "empty" else data[: len(data) // 2])
    with caplog.at_level("WARNING", logger="seggrasp.decompose"):
        (again,) = decompose_sweep(mesh, config, cache_dir=cache, workers=1)
    assert again.same_as(first)
    assert len(logged_calls(log)) == 2  # recomputed
    assert str(entry) in caplog.text and "discarded" in caplog.text
    assert decompose_sweep(mesh, config, cache_dir=cache, workers=1)[0].same_as(first)  # the entry is whole again
    assert len(logged_calls(log)) == 2


def test_a_damaged_read_only_bundled_entry_is_skipped_and_left_alone(monkeypatch, tmp_path, caplog):
    mesh = l_shape()
    config = DecompositionConfig(thresholds=(0.05,), adaptive=False)
    bundled = tmp_path / "bundled"
    bundled.mkdir()
    entry = bundled / f"{config.run_key(decompose.mesh_hash(mesh), 0.05)}.npz"
    entry.write_bytes(b"PK\x03\x04 truncated")
    monkeypatch.setattr(decompose.sweep, "ASSET_CACHE_DIR", bundled)
    monkeypatch.setattr(workers, "run_coacd_hulls", _bounding_box_coacd(tmp_path / "calls.jsonl"))
    with caplog.at_level("WARNING", logger="seggrasp.decompose"):
        (partition,) = decompose_sweep(mesh, config, cache_dir=tmp_path / "cache", workers=1)
    assert partition.part_of_face.shape == (len(mesh.faces),)
    assert str(entry) in caplog.text and "skipped" in caplog.text
    assert entry.read_bytes() == b"PK\x03\x04 truncated"


def _slow_at_fine_thresholds(vertices, faces, threshold, params):
    started = time.process_time()
    while threshold < 0.1 and time.process_time() - started < 30:  # burns CPU: the budget counts CPU seconds
        pass
    return [trimesh.Trimesh(vertices, faces).bounding_box.vertices]


@pytest.mark.slow
def test_a_run_over_its_time_budget_is_killed_and_the_sweep_goes_on(monkeypatch, tmp_path, caplog):
    mesh = l_shape()
    monkeypatch.setattr(workers, "run_coacd_hulls", _slow_at_fine_thresholds)
    config = DecompositionConfig(thresholds=(0.05, 0.2), adaptive=False, run_timeout=1.0)
    stats = SweepStats()
    started = time.monotonic()
    with caplog.at_level("INFO", logger="seggrasp.decompose"):
        partitions = decompose_sweep(mesh, config, cache_dir=tmp_path, workers=2, stats=stats)
    assert time.monotonic() - started < 25
    assert [p.threshold for p in partitions] == [0.2] and stats.timed_out == [0.05]
    assert "threshold 0.05 exceeded its time budget of 1 CPU s" in caplog.text
    assert "CoACD at threshold 0.20: 1 parts in" in caplog.text
    assert len(list(tmp_path.glob("*.npz"))) == 1  # the killed run is not cached
    with pytest.raises(decompose.SweepTimeout, match="--coacd-timeout"):
        decompose_sweep(mesh, DecompositionConfig(thresholds=(0.05,), run_timeout=0.5), cache_dir=tmp_path)
    with pytest.raises(ValueError, match="run_timeout"):
        DecompositionConfig(run_timeout=0)


def test_a_long_run_logs_a_heartbeat(monkeypatch, caplog):
    mesh = l_shape()
    monkeypatch.setattr(workers, "run_coacd_hulls", lambda v, f, t, p: time.sleep(1.2) or [mesh.bounding_box.vertices])
    job = workers.Job(mesh.vertices, mesh.faces, mesh.triangles_center, 1.0, 0.05, {}, "error")
    with caplog.at_level("INFO", logger="seggrasp.decompose"):
        (outcome,) = workers.run_jobs([job], 1, timeout=None, heartbeat=0.3)
    assert outcome.status == "ok"
    assert "CoACD still running: threshold 0.05 for" in caplog.text


def test_adaptive_selection_skips_thresholds_that_failed():
    grid = PAPER_THRESHOLDS
    tried = []

    fine, coarse = canonical_parts(np.arange(8) // 2), np.zeros(8, dtype=np.int64)

    def evaluate(thresholds):  # the partition changes between 0.12 and 0.14; the run at 0.13 fails
        tried.extend(thresholds)
        return {t: fine if t < 0.125 else coarse for t in thresholds if abs(t - 0.13) > 1e-9}

    found = select_thresholds(grid, evaluate)
    assert len(tried) == len(set(tried))  # nothing is tried twice
    assert 0.13 not in found and 0.14 in found and 0.12 in found


@pytest.mark.parametrize("closed", [True, False])
def test_coacd_never_sees_more_than_the_face_limit_and_every_face_is_mapped(monkeypatch, tmp_path, closed):
    mesh = l_shape().subdivide().subdivide()  # ~2.4k faces; the limit is lowered to 500 for the test
    if not closed:  # the top cap of the upright arm removed: an open mesh
        mesh = trimesh.Trimesh(mesh.vertices, mesh.faces[mesh.triangles_center[:, 2] < mesh.bounds[1, 2] - 1e-6],
                               process=False)
    monkeypatch.setattr(decompose.sweep, "MAX_COACD_FACES", 500)
    log = tmp_path / "calls.jsonl"
    monkeypatch.setattr(workers, "run_coacd_hulls", _bounding_box_coacd(log))
    config = DecompositionConfig(thresholds=(0.05,), simplify_tolerance=0.0)  # no manifold3d simplification
    (partition,) = decompose_sweep(mesh, config, cache_dir=tmp_path, workers=1)
    ((threshold, params, n_faces, _),) = logged_calls(log)
    assert 250 <= n_faces <= 500 < len(mesh.faces)
    # The open mesh is replaced by a closed shell first: manifold3d verifies both decimated meshes as closed, so CoACD
    # skips its preprocessing on both.
    assert params["preprocess_mode"] == "off"
    assert partition.part_of_face.shape == (len(mesh.faces),)


def test_face_mapping_in_chunks_equals_one_block(monkeypatch):
    mesh, truth = two_box_mesh()
    hulls = [box([0.1, 0.1, 0.1], [0, 0, 0]).vertices, box([0.1, 0.1, 0.01], [0, 0, 0.075]).vertices,
             np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0], [0.1, 0.1, 0.0]])]  # a flat one too
    scale = float(np.linalg.norm(mesh.extents))
    whole = map_faces_to_hulls(mesh.triangles_center, hulls, scale)
    monkeypatch.setattr(decompose.mapping, "MAP_CHUNK", 7)
    np.testing.assert_array_equal(map_faces_to_hulls(mesh.triangles_center, hulls, scale), whole)


def test_the_face_limit_is_in_the_cache_key_only_of_meshes_above_it(monkeypatch, tmp_path):
    mesh = l_shape().subdivide()
    config = DecompositionConfig(thresholds=(0.05,))
    monkeypatch.setattr(workers, "run_coacd_hulls", _bounding_box_coacd(tmp_path / "calls.jsonl"))
    decompose_sweep(mesh, config, cache_dir=tmp_path / "small", workers=1)
    assert (tmp_path / "small" / f"{config.run_key(decompose.mesh_hash(mesh), 0.05)}.npz").is_file()
    monkeypatch.setattr(decompose.sweep, "MAX_COACD_FACES", len(mesh.faces) - 1)
    decompose_sweep(mesh, config, cache_dir=tmp_path / "big", workers=1)
    key = config.run_key(decompose.mesh_hash(mesh), 0.05, face_limit=len(mesh.faces) - 1, scan=True)
    assert [p.name for p in (tmp_path / "big").glob("*.npz")] == [f"{key}.npz"]


def test_scan_thresholds_run_coarse_first_and_nothing_finer_than_a_crowded_partition():
    grid = decompose.FAST_THRESHOLDS
    batches = []

    def evaluate(thresholds):  # finer thresholds give more parts: 0.06 -> 33, 0.04 -> 50, 0.02 -> 100
        batches.append(list(thresholds))
        return {t: canonical_parts(np.arange(400) % int(round(2 / t))) for t in thresholds}

    capped = select_scan_thresholds(grid, evaluate, max_parts=40)
    assert batches == [[0.06, 0.11, 0.25], [0.04]]  # one parallel round, then finer one at a time until crowded
    assert sorted(capped) == [0.04, 0.06, 0.11, 0.25]
    batches.clear()
    assert sorted(select_scan_thresholds(grid, evaluate, max_parts=30)) == [0.06, 0.11, 0.25]
    batches.clear()
    uncapped = select_scan_thresholds(grid, evaluate, max_parts=1000)
    # 33 parts at 0.06: two more doublings stay under the cap, so 0.04 and the finest grid value run together
    assert batches == [[0.06, 0.11, 0.25], [0.04, 0.02]] and min(uncapped) == 0.02
    batches.clear()
    assert min(select_scan_thresholds(grid, evaluate, max_parts=60)) == 0.02  # 66 expected at 0.04: one at a time
    assert batches == [[0.06, 0.11, 0.25], [0.04], [0.02]]
    batches.clear()
    assert sorted(select_scan_thresholds(grid, evaluate, max_parts=1000, max_runs=4)) == [0.04, 0.06, 0.11, 0.25]
    batches.clear()
    custom = select_scan_thresholds((0.01, 0.05, 0.1, 0.3), evaluate, max_parts=1000)
    assert batches == [[0.05, 0.1, 0.3], [0.01]]  # nearest grid values; the finest always tried last
    assert sorted(custom) == [0.01, 0.05, 0.1, 0.3]


def test_scan_coacd_settings_apply_to_fast_mode_scans_only():
    fast, reference = DecompositionConfig(), DecompositionConfig(mode="reference")
    assert fast.coacd_params(scan=True) == dict(decompose.FAST_COACD, **decompose.SCAN_COACD, seed=0)
    assert fast.coacd_params() == dict(decompose.FAST_COACD, seed=0)
    assert reference.coacd_params(scan=True) == reference.coacd_params() == dict(decompose.COACD_DEFAULTS, seed=0)
    assert DecompositionConfig(coacd={"mcts_max_depth": 3}).coacd_params(scan=True)["mcts_max_depth"] == 3
    assert fast.run_key("0" * 64, 0.05) != fast.run_key("0" * 64, 0.05, scan=True)


def test_only_scans_get_the_part_cap(monkeypatch, tmp_path):
    closed = l_shape().subdivide()
    opened = trimesh.Trimesh(closed.vertices, closed.faces[1:], process=False)
    log = tmp_path / "calls.jsonl"

    def many_hulls(vertices, faces, threshold, params):  # one hull per group of faces: 8 parts at 0.02, 1 at 0.25
        with open(log, "a") as handle:
            handle.write(json.dumps([threshold]) + "\n")
        centres = trimesh.Trimesh(vertices, faces).triangles_center
        groups = np.array_split(np.argsort(centres[:, 0]), max(1, int(round(0.16 / threshold))))
        return [trimesh.Trimesh(vertices, faces).bounding_box.vertices] if len(groups) == 1 else [
            trimesh.PointCloud(centres[g]).bounding_box.vertices for g in groups]

    monkeypatch.setattr(workers, "run_coacd_hulls", many_hulls)
    config = DecompositionConfig(scan_max_parts=3)
    decompose_sweep(closed, config, cache_dir=tmp_path / "closed", workers=1)
    assert 0.02 in {c[0] for c in logged_calls(log)}
    log.unlink()
    decompose_sweep(opened, config, cache_dir=tmp_path / "open", workers=1)
    assert 0.02 not in {c[0] for c in logged_calls(log)}
    with pytest.raises(ValueError, match="scan_max_parts"):
        DecompositionConfig(scan_max_parts=0)


def test_more_simplification_passes_leave_fewer_faces_of_a_dense_curved_mesh():
    import manifold3d

    torus = trimesh.creation.torus(0.05, 0.015, major_sections=48, minor_sections=16)
    refined = manifold3d.Manifold(manifold3d.Mesh64(np.array(torus.vertices), np.array(torus.faces, dtype=np.uint64)))
    refined = refined.refine_to_length(0.002).to_mesh64()
    dense = trimesh.Trimesh(np.asarray(refined.vert_properties[:, :3]), np.asarray(refined.tri_verts, np.int64))
    _, once, closed_once = workers.simplify(dense, 0.002)
    vertices, thrice, closed = workers.simplify(dense, 0.002, passes=3)
    assert closed_once and closed and workers.is_closed_manifold(vertices, thrice)
    assert len(thrice) < 0.8 * len(once) < len(dense.faces)
