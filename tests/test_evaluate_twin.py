"""sim.evaluate.twin: a twin object shipped as data (what the Ray driver puts in the object store once per object)
unpacks into the same object, and a task given it reads nothing of the installed twin."""

import json
from pathlib import Path

import numpy as np
import pytest

import seggrasp.decompose.sweep as sweep
import seggrasp.objects as objects
from sim.evaluate import JsonLines, RunConfig
from sim.evaluate import ray_engine, runner
from sim.evaluate.records import trial_key
from sim.evaluate.twin import pack, unpack

OBJECT = "knife_chef"


@pytest.fixture(scope="module")
def twin():
    return pack(OBJECT, decomposition_seed=0)


def test_a_packed_object_unpacks_into_the_installed_one_with_its_bundled_decompositions(twin, tmp_path) -> None:
    model, decompositions = unpack(twin, tmp_path)
    installed = objects.load_asset(OBJECT)
    np.testing.assert_array_equal(model.mesh.faces, installed.mesh.faces)
    np.testing.assert_allclose(model.mesh.vertices, installed.mesh.vertices)
    np.testing.assert_array_equal(model.labels.face_labels, installed.labels.face_labels)
    assert model.prompts == installed.prompts and model.mass == installed.mass
    assert model.urdf_path.is_file() and tmp_path in model.urdf_path.parents
    names = {p.name for p in decompositions.iterdir()}
    assert names == set(twin.decompositions) and len(names) == 5  # the sweep's bundled runs of this mesh
    assert all((sweep.ASSET_CACHE_DIR / name).read_bytes() == twin.decompositions[name] for name in names)
    manifest = decompositions.parent / "manifest.json"
    written = manifest.stat().st_mtime_ns
    unpack(twin, tmp_path)  # a second task on the node reuses the folder
    assert manifest.stat().st_mtime_ns == written


def _task(out: Path, twin=None) -> runner.ObjectTask:
    config = RunConfig(methods=["seggrasp"], objects=[OBJECT], embodiment="floating", top_k=1)
    return runner.ObjectTask(OBJECT, 0, config, str(out), runner.Recorded(), parallel=True, collect=True, twin=twin)


@pytest.mark.slow
def test_a_task_given_the_shipped_object_reads_nothing_of_the_installed_twin(twin, tmp_path, monkeypatch) -> None:
    expected = runner.evaluate_object(_task(tmp_path / "installed"))  # reads the package's assets
    runner.close_cell()
    read_manifest = objects._read_manifest

    def only_shipped(assets_dir=objects.ASSETS_DIR):
        assert Path(assets_dir) != objects.ASSETS_DIR, "the task read the installed twin's manifest"
        return read_manifest(assets_dir)

    def no_coacd(*args, **kwargs):
        raise AssertionError("a bundled decomposition was not shipped: CoACD ran")

    monkeypatch.setattr(objects, "_read_manifest", only_shipped)
    monkeypatch.setattr(sweep, "ASSET_CACHE_DIR", tmp_path / "no-bundled-decompositions")
    monkeypatch.setattr(sweep.runner, "run_jobs", no_coacd)
    monkeypatch.setenv("SEGGRASP_TWIN_DIR", str(tmp_path / "node"))
    try:
        status = runner.evaluate_object(_task(tmp_path / "shipped", twin))
    finally:
        runner.close_cell()
    assert status["ok"], status.get("traceback")
    assert (tmp_path / "node" / f"{OBJECT}-{twin.digest}" / "manifest.json").is_file()
    trials = [{trial_key(r): r for r in s["records"]["trials.jsonl"]} for s in (expected, status)]
    assert trials[0] and trials[0].keys() == trials[1].keys()
    for key, record in trials[0].items():
        assert record["success"] == trials[1][key]["success"]
        if record["T_world_grasp"] is None:  # a request judged infeasible: no grasp planned
            assert record["infeasible"] and trials[1][key]["T_world_grasp"] is None
        else:
            np.testing.assert_allclose(trials[1][key]["T_world_grasp"], record["T_world_grasp"], atol=1e-9)
    segmentations = [json.dumps(s["records"]["segmentations.jsonl"]) for s in (expected, status)]
    assert segmentations[0] == segmentations[1]


def test_the_ray_driver_packs_each_object_once_whatever_its_seeds(monkeypatch) -> None:
    packed = []
    monkeypatch.setattr(ray_engine, "pack", lambda object_id, seed: packed.append(object_id) or f"twin of {object_id}")
    config = RunConfig(methods=["seggrasp"], objects=["a", "b"], seeds=[0, 1, 2])
    tasks = [runner.ObjectTask(o, s, config, "out") for s in config.seeds for o in config.objects]
    assert ray_engine.pack_objects(tasks, 0) == {"a": "twin of a", "b": "twin of b"}
    assert packed == ["a", "b"]
