"""bench/bench_pad_reach.py rebuilds executed oracle trials and bins them by how far into the pads they landed."""

import json
from pathlib import Path

import numpy as np
import pytest

from bench import bench_pad_reach
from bench.bench_infeasible import episode_of
from seggrasp.objects import load_asset


def test_trials_are_binned_by_reach_with_their_success_and_most_frequent_requests() -> None:
    measured = [(0.0005, False, "knife blade slipped")] * 3 + [(0.0005, True, "knife blade lifted"),
                                                              (0.0025, True, "mug handle lifted"), (0.02, True, "x y lifted"),
                                                              (0.0, True, "glasses temple lifted")]
    rows = bench_pad_reach.table(measured)
    assert rows[2] == "| 0: only the fingertip beyond the pad lands | 1 | 1/1 = 1.00 | glasses temple lifted: 1 |"
    assert rows[3] == "| 0-1 | 4 | 1/4 = 0.25 | knife blade slipped: 3, knife blade lifted: 1 |"
    assert rows[4] == "| 2-3 | 1 | 1/1 = 1.00 | mug handle lifted: 1 |"
    assert rows[5].startswith("| 8- | 1 | 1/1 = 1.00 |")
    assert len(rows) == 6  # empty bins are left out


def test_only_executed_oracle_trials_of_feasible_requests_of_the_asked_robots_count(tmp_path: Path) -> None:
    base = dict(object_id="mug_classic", prompt="handle", seed=0, executed=True, success=True, failure="")
    rows = [dict(base, method="oracle", robot="ur5"), dict(base, method="coarse", robot="ur5"),
            dict(base, method="oracle", robot="ur5", executed=False), dict(base, method="oracle", robot="panda"),
            dict(base, method="oracle", robot="ur5", infeasible=True)]
    rows = [dict(row, rank=rank) for rank, row in enumerate(rows)]  # distinct slots
    (tmp_path / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    trials = bench_pad_reach.executed_trials(tmp_path, ["ur5"])
    assert list(trials) == [("ur5", "mug_classic")] and len(trials[("ur5", "mug_classic")]) == 1


def test_a_missing_run_or_a_broken_record_is_one_sentence_and_a_non_zero_exit(tmp_path: Path, capsys) -> None:
    assert bench_pad_reach.main(["--run", str(tmp_path)]) == 2
    assert "trials.jsonl does not exist" in capsys.readouterr().err
    (tmp_path / "trials.jsonl").write_text('{"method": "oracle"}\n{not json\n')
    assert bench_pad_reach.main(["--run", str(tmp_path)]) == 2
    assert "trials.jsonl:2: corrupt record" in capsys.readouterr().err  # the runs' own reader names file and line


@pytest.mark.slow
def test_a_grasp_rebuilt_from_its_world_pose_reads_the_reach_of_its_own_object_frame_grasp() -> None:
    # the oracle's best mug-handle grasp of seed 0, recorded as a trial is (world pose), measures as it does in the
    # object frame
    model = load_asset("mug_classic")
    from sim.cell import SimCell

    with SimCell([model], embodiment="arm", seed=0, robot="ur5") as cell:
        episode = episode_of(cell, "mug_classic", "ur5", 0, model)
        slot = next(s for s in episode.slots(episode.plan("oracle")) if s.grasp is not None)
    trial = dict(seed=0, prompt="handle", success=True, failure="", T_world_grasp=slot.grasp.poses[0].tolist(),
                 width=float(slot.grasp.widths[0]))
    [(reach, success, what)] = bench_pad_reach.measure("ur5", "mug_classic", [trial])
    T_obj_world = np.linalg.inv(episode.observation.T_world_obj)
    in_object = slot.grasp.transformed(T_obj_world)
    surface = episode.footprint.on(episode.observation.mesh)
    expected = surface.first_touch(in_object, np.zeros(len(episode.observation.mesh.faces), dtype=bool))[1].min()
    assert reach == pytest.approx(expected, abs=1e-6)
    assert 0.0 < reach <= 2 * episode.hand.pad_half_length
    assert success and what == "mug_classic handle lifted"
