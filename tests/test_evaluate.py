"""`python -m sim.evaluate`: results file format, torn lines, resume, the folder lock, the vote cache, a killed run,
the summary and the quick run."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sim.evaluate import JsonLines, OutputLock, main, markdown_report, summarise

REPO = Path(__file__).resolve().parents[1]
SMALL = ["--objects", "mug_classic", "--methods", "oracle", "--embodiment", "floating", "--top-k", "4"]


def _env() -> dict:
    env = dict(os.environ)
    env.update(PYOPENGL_PLATFORM="osmesa", OMP_NUM_THREADS="1", PYTHONPATH=str(REPO))
    return env


def _evaluate(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sim.evaluate", *args], cwd=REPO, env=_env(), capture_output=True,
                          text=True, timeout=timeout)


def _trials(out: Path) -> list[dict]:
    return JsonLines(out / "trials.jsonl").read()


def test_jsonlines_ignores_and_repairs_a_torn_last_line(tmp_path) -> None:
    results = JsonLines(tmp_path / "trials.jsonl")
    results.append({"a": 1})
    results.append({"a": 2})
    with open(results.path, "ab") as handle:
        handle.write(b'{"a": 3, "b"')  # a writer killed mid-line
    assert results.read() == [{"a": 1}, {"a": 2}]
    assert results.repair() == len(b'{"a": 3, "b"')
    results.append({"a": 4})
    assert results.read() == [{"a": 1}, {"a": 2}, {"a": 4}]
    assert results.repair() == 0
    results.path.write_text('{"a": 1}\n{broken\n{"a": 2}\n')
    with pytest.raises(ValueError, match="corrupt record"):
        results.read()


def test_summary_counts_part_selection_success_and_variance() -> None:
    def trial(method, obj, prompt, rank, on_part, success, yaw):
        c, s = np.cos(yaw), np.sin(yaw)
        pose = [[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
        return {"method": method, "object_id": obj, "category": obj.split("_")[0], "prompt": prompt, "rank": rank,
                "detector": "simulated:typical", "executed": True, "reachable": True, "contacts_on_part": on_part,
                "success": success, "T_world_grasp": pose}

    trials = [trial("a", "mug_1", "handle", 0, True, True, 0.0), trial("a", "mug_1", "handle", 1, True, False, 0.0),
              trial("a", "knife_1", "blade", 0, False, False, 0.0), trial("a", "knife_1", "blade", 1, True, True, 0.0),
              trial("b", "mug_1", "handle", 0, True, True, 0.0), trial("b", "mug_1", "handle", 1, True, True, 1.0)]
    empty_slot = dict(trial("a", "knife_1", "blade", 2, False, False, 0.0), executed=False, reachable=False,
                      T_world_grasp=None)
    trials.append(empty_slot)  # the method had no third grasp on the blade
    segmentations = [{"method": "a", "object_id": "mug_1", "category": "mug", "miou": 0.5, "miou_faces": 0.4,
                      "detector": "simulated:typical"},
                     {"method": "a", "object_id": "knife_1", "category": "knife", "miou": 0.7, "miou_faces": 0.6,
                      "detector": "simulated:typical"}]
    summary = summarise(trials, segmentations, [], ["a", "b"])
    a, b = summary["methods"]["a"], summary["methods"]["b"]
    assert a["part_selection"] == pytest.approx(0.75) and a["success"] == pytest.approx(0.5)
    assert a["success_top1"] == pytest.approx(0.5)  # the first slot of (mug_1, handle) and of (knife_1, blade)
    assert a["failures"] == {"no_grasp": 1, "other": 2}
    assert a["executed"] == 4 and a["trials"] == 5 and a["success_all_slots"] == pytest.approx(0.4)
    assert a["part_selection_all_slots"] == pytest.approx(0.6)
    assert a["miou"]["overall"] == pytest.approx(0.6) and a["miou"]["categories"] == {"knife": 0.7, "mug": 0.5}
    assert a["sigma2"] == pytest.approx(0.0) and b["sigma2"] > 0.01
    assert b["success"] == 1.0 and "miou" not in b
    text = markdown_report(summary, {"detector": "simulated:typical", "embodiment": "floating", "backend": "sim",
                                     "perceive": False, "seed": 0, "top_k": 2, "n_objects": 2, "wall_time_s": 1.0})
    assert "| a | 0.600 | 0.600 | 0.400 | 0.500 | 0.750 | 0.500 | — | 0.0000 | 4 / 5 | 4 |" in text
    assert "cannot hold" not in text  # no request was judged
    assert "| knife | 3 | 1 | 1 |" in text  # failures of a on knives: no_grasp 1, other 1


def test_bad_arguments_exit_with_a_message(capsys) -> None:
    assert main(["--methods", "magic"]) == 2
    assert "unknown method" in capsys.readouterr().err
    assert main(["--detector", "owlv2"]) == 2
    assert "--weights" in capsys.readouterr().err
    assert main(["--objects", "no_such_object"]) == 2
    assert "unknown object" in capsys.readouterr().err


@pytest.mark.slow
def test_resume_skips_recorded_trials_and_refuses_a_different_setup(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert main([*SMALL, "--out", str(out)]) == 0
    records = _trials(out)
    assert len(records) == 2 * 4  # two prompts x top-4
    assert len({(r["prompt"], r["rank"]) for r in records}) == 8

    capsys.readouterr()
    assert main([*SMALL, "--out", str(out)]) == 2
    assert "--resume" in capsys.readouterr().err

    # drop the last three trials: a resumed run records exactly those, with the same outcomes
    lines = (out / "trials.jsonl").read_text().splitlines(keepends=True)
    (out / "trials.jsonl").write_text("".join(lines[:-3]))
    assert main([*SMALL, "--out", str(out), "--resume"]) == 0
    assert "8/8 trials recorded" in capsys.readouterr().out
    redone = _trials(out)
    assert len(redone) == 8
    strip = lambda r: {k: v for k, v in r.items() if k != "reused_outcome"}  # noqa: E731
    assert [strip(r) for r in redone[-3:]] == [strip(json.loads(line)) for line in lines[-3:]]

    assert main([*SMALL[:-2], "--top-k", "2", "--out", str(out), "--resume"]) == 2
    assert "settings differ" in capsys.readouterr().err


IN_PROCESS = ["--objects", "mug_classic", "--methods", "coarse,oracle", "--embodiment", "floating", "--top-k", "1"]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory) -> Path:
    """A finished small run (mug, coarse + oracle, top-1), copied by the tests that change it."""
    out = tmp_path_factory.mktemp("small") / "run"
    assert main([*IN_PROCESS, "--out", str(out)]) == 0
    return out


def _copy(run: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(run, tmp_path / "run"))


def _segmentations(out: Path) -> dict:
    return {r["method"]: r for r in JsonLines(out / "segmentations.jsonl").read()}


@pytest.mark.slow
def test_votes_are_keyed_by_the_prompts_and_resume_refuses_other_prompts(small_run, tmp_path, capsys) -> None:
    """Issue 13 finding 1: votes cached for one prompt order must never be reused for another."""
    out = _copy(small_run, tmp_path)
    assert main([*IN_PROCESS, "--prompts", "body,handle", "--out", str(out), "--resume"]) == 2
    assert "settings differ" in capsys.readouterr().err
    for name in ("run.json", "trials.jsonl", "segmentations.jsonl", "curves.jsonl"):
        (out / name).unlink()  # start over in the folder: only the vote cache is left
    coarse_only = [*IN_PROCESS[:2], "--methods", "coarse", *IN_PROCESS[4:], "--prompts", "body,handle"]
    assert main([*coarse_only, "--out", str(out)]) == 0
    clean = tmp_path / "clean"
    assert main([*coarse_only, "--out", str(clean)]) == 0
    assert _segmentations(out)["coarse"]["miou"] == pytest.approx(_segmentations(clean)["coarse"]["miou"])


@pytest.mark.slow
def test_record_writes_picture_strips_and_leaves_the_records_unchanged(small_run, tmp_path) -> None:
    """Issue 12: `--record 1` saves a strip of the first executed slot per method and object; the trials match a
    run without recording."""
    from PIL import Image

    from sim.recording import FRAME_SIZE

    out = tmp_path / "recorded"
    assert main([*IN_PROCESS, "--record", "1", "--out", str(out)]) == 0
    strips = sorted((out / "strips").glob("*.png"))
    ran_the_cell = [r for r in _trials(out) if r["executed"] and not r["reused_outcome"]]
    first = {}  # the first slot per method that ran the cell (the file is in execution order)
    for record in ran_the_cell:
        first.setdefault(record["method"], f"{record['method']}-mug_classic-{record['prompt']}-{record['rank']}.png")
    expected = set(first.values())
    assert {p.name for p in strips} == expected and strips
    for path in strips:
        width, height = Image.open(path).size
        assert width % FRAME_SIZE[0] == 0 and height > FRAME_SIZE[1]  # stage frames side by side, captioned
    plain = {(r["method"], r["prompt"], r["rank"]): r for r in _trials(small_run)}
    for record in _trials(out):
        reference = plain[(record["method"], record["prompt"], record["rank"])]
        for key in ("executed", "success", "failure", "lifted", "T_world_grasp"):
            assert record[key] == reference[key], key
        assert record["lift_height"] == pytest.approx(reference["lift_height"], abs=1e-6)


def test_record_is_refused_without_the_twin(capsys) -> None:
    real = ["--backend", "real", "--config", "cell.yaml", "--detector", "owlv2", "--weights", "w",
            "--objects", "thing", "--prompts", "handle"]
    assert main([*real, "--record", "1"]) == 2
    assert "--record needs the twin" in capsys.readouterr().err
    assert main([*IN_PROCESS, "--record", "-1"]) == 2
    assert "--record must be at least 0" in capsys.readouterr().err


@pytest.mark.slow
def test_a_second_run_on_the_folder_is_refused_and_duplicates_count_once(small_run, tmp_path, capsys) -> None:
    """Issue 13 finding 2: the folder is locked while a run writes it; duplicated records are ignored."""
    out = _copy(small_run, tmp_path)
    with OutputLock(out):
        assert main([*IN_PROCESS, "--out", str(out), "--resume"]) == 2
        err = capsys.readouterr().err
        assert "in use by another run" in err and f"pid {os.getpid()}" in err
    trials = out / "trials.jsonl"
    trials.write_text(trials.read_text() * 2)  # as left by two runs before the folder had a lock
    assert main([*IN_PROCESS, "--out", str(out), "--resume"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["run"]["recorded_trials"] == summary["run"]["expected_trials"] == 4
    assert summary["methods"]["coarse"]["trials"] == summary["methods"]["oracle"]["trials"] == 2


@pytest.mark.slow
def test_resume_keeps_the_run_s_methods_and_recomputes_a_damaged_vote_cache(small_run, tmp_path, capsys) -> None:
    """Issue 13 findings 3 and 6: a resume with fewer methods keeps the others; a truncated cache is recomputed."""
    out = _copy(small_run, tmp_path)
    cached = sorted((out / "cache" / "mug_classic").glob("*.npz"))
    assert cached
    for path in cached:
        path.write_bytes(path.read_bytes()[:10])
    trials = out / "trials.jsonl"  # drop a trial: a complete (object, seed) is not evaluated again
    trials.write_text("".join(trials.read_text().splitlines(keepends=True)[:-1]))
    assert main([*IN_PROCESS[:2], "--methods", "coarse", *IN_PROCESS[4:], "--out", str(out), "--resume"]) == 0
    assert json.loads((out / "run.json").read_text())["methods"] == ["coarse", "oracle"]
    assert set(json.loads((out / "summary.json").read_text())["methods"]) == {"coarse", "oracle"}
    for path in cached:
        with np.load(path) as data:
            assert data["scores"].shape[1] == 2
    assert main([*IN_PROCESS, "--out", str(tmp_path / "missing"), "--resume"]) == 2
    assert "cannot resume" in capsys.readouterr().err


@pytest.mark.slow
def test_a_killed_run_leaves_a_valid_file_that_resumes(tmp_path) -> None:
    out = tmp_path / "killed"
    args = [sys.executable, "-m", "sim.evaluate", *SMALL[:-1], "6", "--out", str(out)]
    process = subprocess.Popen(args, cwd=REPO, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    trials = out / "trials.jsonl"
    deadline = time.time() + 300
    while time.time() < deadline and (not trials.exists() or trials.read_bytes().count(b"\n") < 3):
        time.sleep(0.05)
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=30)
    recorded = _trials(out)  # parses: at most a torn last line is ignored
    assert 3 <= len(recorded) < 12
    assert main([*SMALL[:-1], "6", "--out", str(out), "--resume"]) == 0  # the lock died with the killed run
    final = _trials(out)
    assert len(final) == 12
    assert len({(r["prompt"], r["rank"]) for r in final}) == 12


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory) -> tuple[Path, dict, float]:
    """One `python -m sim.evaluate --quick` run shared by the quick-profile tests."""
    out = tmp_path_factory.mktemp("quick") / "out"
    started = time.time()
    result = _evaluate("--quick", "--out", str(out), timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    return out, json.loads((out / "summary.json").read_text()), time.time() - started


@pytest.mark.slow
def test_quick_evaluation_is_complete(quick_run) -> None:
    out, summary, seconds = quick_run
    run = summary["run"]
    assert run["recorded_trials"] == run["expected_trials"] > 0
    assert not run["crashed_objects"]
    keys = {(r["object_id"], r["method"], r["prompt"], r["rank"]) for r in _trials(out)}
    assert len(keys) == run["expected_trials"]
    methods = summary["methods"]
    assert methods["oracle"]["part_selection"] == 1.0
    assert methods["oracle"]["part_selection"] >= methods["seggrasp"]["part_selection"]
    assert methods["oracle"]["part_selection"] >= methods["coarse"]["part_selection"]
    for name in ("summary.md", "plots/miou_per_category.png", "plots/threshold_curve.png"):
        assert (out / name).is_file(), name
    assert seconds < 600


@pytest.mark.slow
def test_quick_part_selection_orders_oracle_seggrasp_coarse(quick_run) -> None:
    _, summary, _ = quick_run
    part_sel = {m: summary["methods"][m]["part_selection"] for m in ("oracle", "seggrasp", "coarse")}
    assert part_sel["oracle"] >= part_sel["seggrasp"] >= part_sel["coarse"], part_sel
