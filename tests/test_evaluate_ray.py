"""`python -m sim.evaluate --engine ray` on a local Ray instance of 2 CPUs: the same records as the local engine, the
tasks run on the objects the driver shipped, and a Ray worker killed mid-task loses and duplicates no trial."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("ray")

from seggrasp.objects import asset_ids  # noqa: E402
from sim.evaluate import JsonLines  # noqa: E402
from sim.evaluate.config import QUICK_CATEGORIES  # noqa: E402
from sim.evaluate.ray_engine import KILL_ONCE_ENV  # noqa: E402
from sim.evaluate.records import curve_key, segmentation_key, trial_key  # noqa: E402
from sim.evaluate.twin import TWIN_DIR_ENV  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
#: A subset of the quick profile that fits the suite: its first two objects, SegGrasp and its coarse votes, top-2.
OBJECTS = [asset_ids([c])[0] for c in QUICK_CATEGORIES[:2]]
SUBSET = ["--objects", ",".join(OBJECTS), "--methods", "seggrasp,coarse",
          "--embodiment", "floating", "--top-k", "2", "--seed", "0"]
FILES = {"trials.jsonl": trial_key, "segmentations.jsonl": segmentation_key, "curves.jsonl": curve_key}


def _evaluate(out: Path, *args: str, env: dict | None = None) -> None:
    environment = dict(os.environ, PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1", PYTHONPATH=str(REPO), **(env or {}))
    result = subprocess.run([sys.executable, "-m", "sim.evaluate", *SUBSET, "--out", str(out), *args], cwd=REPO,
                            env=environment, capture_output=True, text=True, timeout=1800)
    assert result.returncode == 0, result.stderr[-3000:]


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> tuple[Path, Path, Path]:
    """(local run, Ray run whose first task's worker killed itself before returning, the kill marker); the Ray
    workers unpack the shipped objects under <root>/twin."""
    root = tmp_path_factory.mktemp("engines")
    local, ray_run, marker = root / "local", root / "ray", root / "killed-worker.pid"
    _evaluate(local, "--engine", "local", "--workers", "1")
    # RAY_ADDRESS names a cluster that is not there: without --address the engine starts its own instance anyway
    _evaluate(ray_run, "--engine", "ray", "--workers", "2",
              env={KILL_ONCE_ENV: str(marker), TWIN_DIR_ENV: str(root / "twin"), "RAY_ADDRESS": "127.0.0.1:9"})
    return local, ray_run, marker


def _assert_same(a, b, where: str) -> None:
    """Equal, floats (and lists of them) within 1e-9."""
    if isinstance(a, dict):
        assert set(a) == set(b), where
        for key in a:
            _assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, float) or (isinstance(a, list) and a and not isinstance(a[0], (str, dict))):
        np.testing.assert_allclose(np.asarray(b, dtype=float), np.asarray(a, dtype=float), atol=1e-9, err_msg=where)
    else:
        assert a == b, where


@pytest.mark.slow
def test_ray_engine_records_equal_the_local_engine_s(runs) -> None:
    local, ray_run, _ = runs
    for name, key in FILES.items():
        expected = {key(r): r for r in JsonLines(local / name).read()}
        got = {key(r): r for r in JsonLines(ray_run / name).read()}
        assert expected and set(got) == set(expected), name
        for k, record in expected.items():
            _assert_same(record, got[k], f"{name}{k}")
    summaries = [json.loads((run / "summary.json").read_text())["methods"] for run in (local, ray_run)]
    for method in ("seggrasp", "coarse"):
        assert summaries[1][method]["intervals"] == summaries[0][method]["intervals"]


@pytest.mark.slow
def test_ray_tasks_run_on_the_objects_the_driver_shipped(runs) -> None:
    twin_dir = runs[1].parent / "twin"
    assert sorted(p.name.rsplit("-", 1)[0] for p in twin_dir.iterdir()) == sorted(OBJECTS)
    assert all((p / "manifest.json").is_file() and any((p / "decompositions").iterdir()) for p in twin_dir.iterdir())


@pytest.mark.slow
def test_a_killed_ray_worker_loses_and_duplicates_no_trial(runs) -> None:
    local, ray_run, marker = runs
    killed = int(marker.read_text())  # a task's worker process killed itself after evaluating, before returning
    with pytest.raises(ProcessLookupError):
        os.kill(killed, 0)
    lines = [line for line in (ray_run / "trials.jsonl").read_text().splitlines() if line.strip()]
    keys = [trial_key(json.loads(line)) for line in lines]
    assert len(keys) == len(set(keys)) == len(JsonLines(local / "trials.jsonl").read())
    summary = json.loads((ray_run / "summary.json").read_text())["run"]
    assert summary["recorded_trials"] == summary["expected_trials"] and not summary["crashed_tasks"]


def test_a_cluster_that_cannot_be_joined_is_a_clear_error(tmp_path, monkeypatch, capsys) -> None:
    import ray

    from sim.evaluate.cli import main

    def refuse(*args, **kwargs):
        raise ConnectionError("Failed to connect to Ray cluster at 10.0.0.9:6379")

    monkeypatch.setattr(ray, "init", refuse)
    monkeypatch.setattr("sim.evaluate.ray_engine._probe", lambda address: None)  # a head answers; ray.init refuses
    code = main(["--objects", "mug_classic", "--methods", "coarse", "--engine", "ray",
                 "--address", "10.0.0.9:6379", "--out", str(tmp_path / "out")])
    assert code == 2
    message = capsys.readouterr().err
    assert "cannot join the Ray cluster at 10.0.0.9:6379" in message and "RAY_AUTH_MODE=token" in message
