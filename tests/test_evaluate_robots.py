"""`python -m sim.evaluate --robots ur5,panda`: every method on each robot system, records that name their system,
each system's tables and their average with intervals."""

from __future__ import annotations

import json

import pytest

from sim.evaluate import main
from sim.evaluate.cli import build_config, parse_args
from sim.evaluate.records import trial_key
from sim.evaluate.report import markdown_report, summarise
from sim.evaluate.stats import system_averages


@pytest.mark.parametrize(("options", "message"), [
    (["--robots", "panda", "--embodiment", "floating"], "the floating gripper is the 2F-85 alone"),
    (["--robots", "panda", "--quick"], "the floating gripper is the 2F-85 alone"),
    (["--robots", "arx5"], "unknown robot(s) ['arx5']"),
    (["--robots", "ur5,ur5"], "--robots"),
    (["--robots", ","], "unknown robot(s)"),
])
def test_a_robot_the_run_cannot_have_is_refused_in_one_sentence(options, message, capsys, tmp_path) -> None:
    assert main(["--methods", "oracle", "--objects", "mug_classic", "--out", str(tmp_path / "o"), *options]) == 2
    error = capsys.readouterr().err
    assert message in error and error.count("\n") == 1


def test_the_real_cell_is_a_ur5(capsys) -> None:
    real = ["--backend", "real", "--config", "cell.yaml", "--detector", "owlv2", "--weights", "w",
            "--objects", "mug", "--prompts", "handle", "--methods", "coarse"]
    assert main([*real, "--robots", "panda"]) == 2
    assert "the real cell is a UR5 with a 2F-85" in capsys.readouterr().err


def test_the_default_run_and_the_quick_profile_are_on_the_ur5_alone() -> None:
    assert build_config(parse_args(["--objects", "mug_classic"])).robots == ["ur5"]
    assert build_config(parse_args(["--quick"])).robots == ["ur5"]
    assert build_config(parse_args(["--robots", "panda,ur5", "--objects", "mug_classic"])).robots == ["panda", "ur5"]


def _rows(robot: str, successes: dict[str, list[bool]]) -> list[dict]:
    """One top-1 slot per (object, seed) of method m on `robot`, successes per object over seeds 0, 1, ..."""
    return [{"object_id": o, "category": o, "method": "m", "seed": s, "robot": robot, "prompt": "handle", "rank": 0,
             "executed": True, "reachable": True, "contacts_on_part": ok, "success": ok, "infeasible": False,
             "detector": "simulated:typical", "T_world_grasp": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}
            for o, seq in successes.items() for s, ok in enumerate(seq)]


def test_the_average_over_systems_is_the_mean_of_the_systems_with_a_bootstrap_interval() -> None:
    ur5 = _rows("ur5", {"a": [True, True], "b": [True, False], "c": [False, False]})
    panda = _rows("panda", {"a": [True, False], "b": [False, False], "c": [False, False]})
    assert len({trial_key(r) for r in ur5 + panda}) == len(ur5 + panda)  # the robot is part of a trial's key
    average = system_averages({"ur5": ur5, "panda": panda}, {}, ["m"])["m"]["success_all_slots"]
    # per category (= object here) then over categories: ur5 (1 + 0.5 + 0) / 3, panda (0.5 + 0 + 0) / 3
    assert average["mean"] == pytest.approx((0.5 + 1 / 6) / 2)
    assert average["ci_low"] <= average["mean"] <= average["ci_high"] and average["ci_high"] > average["ci_low"]
    assert average["per_seed"] == {"0": pytest.approx((2 / 3 + 1 / 3) / 2), "1": pytest.approx((1 / 3 + 0) / 2)}
    # only the (object, seed) pairs both systems have count: the UR5's extra object changes nothing
    more = ur5 + _rows("ur5", {"d": [True, True]})
    assert system_averages({"ur5": more, "panda": panda}, {}, ["m"])["m"]["success_all_slots"]["mean"] == \
        pytest.approx(average["mean"])


def test_the_report_of_two_systems_gives_the_average_then_each_system() -> None:
    ur5 = _rows("ur5", {"a": [True, True], "b": [True, False]})
    panda = _rows("panda", {"a": [True, False], "b": [False, False]})
    systems = {robot: dict(summarise(rows, [], [], ["m"]), hand=hand)
               for robot, rows, hand in (("ur5", ur5, "robotiq_2f85"), ("panda", panda, "franka_hand"))}
    summary = {"systems": systems, "average": system_averages({"ur5": ur5, "panda": panda}, {}, ["m"])}
    header = {"detector": "simulated:typical", "embodiment": "arm", "backend": "sim", "robots": ["ur5", "panda"],
              "perceive": False, "seeds": [0, 1], "top_k": 1, "n_objects": 2, "wall_time_s": 1.0}
    text = markdown_report(summary, header)
    average = text.index("## Average over the robot systems (ur5, panda)")
    assert average < text.index("# ur5: robotiq_2f85") < text.index("# panda: franka_hand")
    assert "· robots: ur5, panda ·" in text
    row = next(line for line in text[average:].splitlines() if line.startswith("| m |"))
    assert row.split(" | ")[2].startswith("0.500 [")  # Suc.: (0.75 + 0.25) / 2


@pytest.mark.slow
def test_a_run_on_both_systems_records_each_and_resumes_with_a_robot_added(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    base = ["--methods", "oracle", "--objects", "mug_classic", "--top-k", "1", "--out", str(out)]
    assert main([*base, "--robots", "ur5"]) == 0
    assert main(["--resume", "--out", str(out), "--robots", "panda"]) == 0
    trials = [json.loads(line) for line in (out / "trials.jsonl").read_text().splitlines()]
    assert sorted((r["robot"], r["extra"]["hand"]) for r in trials) == [
        ("panda", "franka_hand"), ("panda", "franka_hand"), ("ur5", "robotiq_2f85"), ("ur5", "robotiq_2f85")]
    segmentations = [json.loads(line) for line in (out / "segmentations.jsonl").read_text().splitlines()]
    assert sorted(r["robot"] for r in segmentations) == ["panda", "ur5"]
    assert json.loads((out / "run.json").read_text())["robots"] == ["ur5", "panda"]
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["systems"]) == {"ur5", "panda"} and summary["run"]["recorded_trials"] == 4
    assert summary["systems"]["panda"]["hand"] == "franka_hand"
    assert "success_all_slots" in summary["average"]["oracle"]
    capsys.readouterr()
    assert main(["--resume", "--out", str(out)]) == 0  # complete: nothing runs again, nothing is counted twice
    assert "4/4 trials recorded" in capsys.readouterr().out
    assert len((out / "trials.jsonl").read_text().splitlines()) == 4


def test_a_record_of_a_robot_the_run_lacks_is_set_aside_and_an_old_record_is_the_ur5_s() -> None:
    from sim.evaluate.config import RunConfig
    from sim.evaluate.records import foreign, robot_of

    record = {"object_id": "mug_classic", "method": "oracle", "seed": 0, "detector": "ground-truth",
              "prompt": "handle", "rank": 0}
    ur5_run = RunConfig(["oracle"], ["mug_classic"], embodiment="arm")
    assert robot_of(record) == "ur5" and foreign("trials.jsonl", record, ur5_run) == ""
    panda = dict(record, robot="panda")
    assert foreign("trials.jsonl", panda, ur5_run) == "robot 'panda' is not one of the run's (ur5)"
    assert foreign("trials.jsonl", panda, RunConfig(["oracle"], ["mug_classic"], robots=["ur5", "panda"])) == ""


def test_each_robot_s_picture_strip_has_its_own_file() -> None:
    from pathlib import Path

    from sim.evaluate.strips import strip_path

    out = Path("run")
    ur5 = strip_path(out, "oracle", "mug_classic", "handle", 0, seed=2)
    assert ur5 == out / "strips" / "oracle-mug_classic-handle-0-seed2.png"  # as before robots were named
    assert strip_path(out, "oracle", "mug_classic", "handle", 0, seed=2, robot="panda") == \
        out / "strips" / "oracle-mug_classic-handle-0-seed2-panda.png"
