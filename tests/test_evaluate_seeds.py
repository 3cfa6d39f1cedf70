"""`python -m sim.evaluate --seeds`: parsing, records keyed by seed, resume per (object, seed, method), intervals in
the summary."""

import json
from pathlib import Path

import pytest

from sim.evaluate import JsonLines, main
from sim.evaluate.cli import parse_seeds
from sim.evaluate.config import DECOMPOSITION_SEED

ONE = ["--objects", "mug_classic", "--methods", "oracle", "--embodiment", "floating", "--top-k", "1"]


@pytest.mark.parametrize("text, seeds", [("0-4", [0, 1, 2, 3, 4]), ("0,3,7", [0, 3, 7]), ("2", [2]),
                                         ("0-1, 5", [0, 1, 5])])
def test_seed_lists_parse(text, seeds) -> None:
    assert parse_seeds(text) == seeds


@pytest.mark.parametrize("args, message", [
    (["--seeds", "3-1"], "goes down; write 1-3"),
    (["--seeds", "x"], "'x' is not a seed or a range"),
    (["--seeds", "0,,1"], "'' is not a seed"),
    (["--seeds", "-1"], "is not a seed or a range"),
    (["--seeds", "0-2,1"], "seed(s) [1] given twice"),
    (["--seed", "1", "--seeds", "0-2"], "either --seed S or --seeds LIST"),
    (["--seed", "-3"], "--seed must be a non-negative integer"),
    (["--address", "auto"], "--address joins a Ray cluster: it needs --engine ray"),
])
def test_bad_seeds_exit_2_with_a_message(args, message, capsys, tmp_path) -> None:
    assert main([*ONE, *args, "--out", str(tmp_path / "out")]) == 2
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def _trials(out: Path) -> list[dict]:
    return JsonLines(out / "trials.jsonl").read()


@pytest.mark.slow
def test_each_seed_redraws_the_scene_and_resume_completes_per_object_seed_and_method(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    assert main([*ONE, "--seeds", "0,1", "--out", str(out)]) == 0
    first = _trials(out)
    assert sorted({r["seed"] for r in first}) == [0, 1] and len(first) == 2 * 2  # 2 prompts x top-1 x 2 seeds
    scene = {r["seed"]: r["scene_seed"] for r in first}
    assert scene[0] != scene[1]
    assert {r["extra"]["decomposition_seed"] for r in first} == {DECOMPOSITION_SEED}
    segs = JsonLines(out / "segmentations.jsonl").read()
    assert sorted((r["seed"], r["method"]) for r in segs) == [(0, "oracle"), (1, "oracle")]

    # lose seed 1's trials (as a run stopped early), then resume with one more seed: seed 0 is left alone
    kept = [line for line in (out / "trials.jsonl").read_text().splitlines(keepends=True) if '"seed":0,' in line]
    (out / "trials.jsonl").write_text("".join(kept))
    capsys.readouterr()
    assert main([*ONE, "--seeds", "0-2", "--out", str(out), "--resume"]) == 0
    assert "6/6 trials recorded" in capsys.readouterr().out
    final = _trials(out)
    assert final[:2] == [json.loads(line) for line in kept]
    assert sorted((r["seed"], r["prompt"]) for r in final) == sorted((s, p) for s in (0, 1, 2)
                                                                      for p in {r["prompt"] for r in first})
    redone = {(r["seed"], r["prompt"]): r["success"] for r in final}
    assert all(redone[(1, r["prompt"])] == r["success"] for r in first if r["seed"] == 1)  # same draw again

    summary = json.loads((out / "summary.json").read_text())
    assert json.loads((out / "run.json").read_text())["seeds"] == [0, 1, 2]
    interval = summary["methods"]["oracle"]["intervals"]["part_selection_all_slots"]
    assert set(interval) >= {"mean", "ci_low", "ci_high", "per_seed"}
    assert set(interval["per_seed"]) == {"0", "1", "2"} and interval["mean"] == 1.0
    assert "seeds: 0-2" in (out / "summary.md").read_text()


def test_a_folder_written_before_seeds_resumes_as_its_one_seed(tmp_path) -> None:
    """run.json with one `seed` and records without a `seed` field (CoACD then took the run seed)."""
    from sim.evaluate.config import RunConfig
    from sim.evaluate.records import prepare_out, trial_key

    out = tmp_path / "old"
    out.mkdir()
    old = {"methods": ["oracle"], "objects": ["mug_classic"], "detector": "typical", "weights": None,
           "embodiment": "floating", "seed": 0, "top_k": 1, "backend": "sim", "config": None, "perceive": False,
           "dry_run": False, "quick": False, "prompts": [], "record": 0}
    (out / "run.json").write_text(json.dumps(old))
    record = {"object_id": "mug_classic", "method": "oracle", "prompt": "handle", "rank": 0}
    assert trial_key(record) == ("mug_classic", 0, "ur5", "oracle", "handle", 0)  # and on the UR5
    # it simulated the twin as it then was: the 2F-85's linkage at 100 N
    then = dict(grip_force=100.0, twin_gripper="linkage")
    config = prepare_out(out, RunConfig(["oracle"], ["mug_classic"], seeds=[0], top_k=1, **then), resume=True)
    assert config.seeds == [0]
    with pytest.raises(ValueError, match="twin_gripper"):  # today's twin does not continue it
        prepare_out(out, RunConfig(["oracle"], ["mug_classic"], seeds=[0], top_k=1), resume=True)
    (out / "run.json").write_text(json.dumps(dict(old, seed=1)))  # decomposed with CoACD seed 1: not the same run
    with pytest.raises(ValueError, match="decomposition_seed"):
        prepare_out(out, RunConfig(["oracle"], ["mug_classic"], seeds=[1], top_k=1, **then), resume=True)


def test_resume_skips_the_object_seed_pairs_the_folder_holds_completely(tmp_path) -> None:
    from sim.evaluate.config import RunConfig
    from sim.evaluate.runner import make_tasks

    out = tmp_path / "run"
    config = RunConfig(["oracle"], ["mug_classic"], seeds=[0, 1], top_k=2)
    trials = JsonLines(out / "trials.jsonl")
    trials.extend({"object_id": "mug_classic", "seed": seed, "method": "oracle", "prompt": prompt, "rank": rank}
                  for seed in (0, 1) for prompt in ("handle", "body") for rank in (0, 1))
    JsonLines(out / "segmentations.jsonl").extend({"object_id": "mug_classic", "seed": s, "method": "oracle"}
                                                 for s in (0, 1))
    lines = trials.path.read_text().splitlines(keepends=True)
    trials.path.write_text("".join(lines[:-1]))  # seed 1 lacks its last slot
    tasks, complete = make_tasks(config, out, parallel=False)
    assert [(t.object_id, t.seed) for t in tasks] == [("mug_classic", 1)] and len(tasks[0].recorded.trials) == 3
    assert [(c["object_id"], c["seed"], c["new_trials"]) for c in complete] == [("mug_classic", 0, 0)]
    (out / "segmentations.jsonl").write_text("")  # a missing segmentation makes a pair incomplete too
    trials.path.write_text("".join(lines))
    tasks, complete = make_tasks(config, out, parallel=False)
    assert len(tasks) == 2 and not complete
