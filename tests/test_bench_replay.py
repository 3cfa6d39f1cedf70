"""bench/bench_replay.py picks a run's executed grasps of one object and prompt, and reads its settings."""

import argparse
import json

import pytest

from bench import bench_replay  # noqa: E402
from seggrasp.cell import GraspOutcome


def test_settings_are_iterations_and_force():
    assert bench_replay.parse_setting("300:100") == (300, 100.0)
    with pytest.raises(argparse.ArgumentTypeError, match="ITERATIONS:FORCE"):
        bench_replay.parse_setting("300")


def test_the_executed_grasps_of_one_object_prompt_and_seed_are_replayed_in_rank_order(tmp_path):
    def trial(rank, **changes):
        return dict(dict(object_id="mug_classic", prompt="handle", seed=0, executed=True, method="oracle", rank=rank,
                         scene_seed=7, T_world_grasp=[[1, 0, 0, 0]] * 4, width=0.02), **changes)

    rows = [trial(2), trial(0), trial(1, executed=False), trial(3, prompt="body"), trial(4, seed=1),
            trial(5, object_id="mug_tall"), trial(1)]
    (tmp_path / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    picked = bench_replay.recorded_grasps(tmp_path, "mug_classic", "handle", 0, limit=2)
    assert [r["rank"] for r in picked] == [0, 1]
    assert len(bench_replay.recorded_grasps(tmp_path, "mug_classic", "handle", 0, limit=10)) == 3


def test_a_contact_log_is_named_after_its_trial_and_setting():
    row = dict(object_id="knife_chef", prompt="blade", seed=1, rank=3)
    assert bench_replay.contact_log_name(row, 300, 235.0) == "knife_chef-blade-seed1-rank3-300x235.md"


def test_each_trial_is_replayed_on_the_robot_system_it_ran_on(monkeypatch):
    opened, executed = [], []

    class Cell:  # stands in for SimCell: records which system each trial ran on
        def __init__(self, models, robot="ur5", **_):
            opened.append(robot)

        def __enter__(self):
            return self

        def __exit__(self, *_):
            return False

        def reset(self, seed, object_id):
            pass

        def execute(self, pose, width):
            executed.append((opened[-1], width))
            return GraspOutcome(True, True, 0.2, contact_force=10.0)

    monkeypatch.setattr(bench_replay, "SimCell", Cell)
    rows = [dict(robot=robot, scene_seed=0, T_world_grasp=[[1, 0, 0, 0]] * 4, width=width)
            for robot, width in (("panda", 0.01), ("ur5", 0.02), ("panda", 0.03))]
    model = argparse.Namespace(object_id="mug_classic")
    outcomes, _, squeeze = bench_replay.replay(model, rows, 100, 70.0)
    assert opened == ["panda", "ur5"]
    assert sorted(executed) == [("panda", 0.01), ("panda", 0.03), ("ur5", 0.02)]
    assert outcomes == {"lifted": 3} and squeeze == 5.0
