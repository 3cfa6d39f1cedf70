"""bench/bench_mujoco_replay.py: a twin grasp replayed in MuJoCo."""

import json
from dataclasses import asdict

import numpy as np
import pytest

from bench.bench_mujoco_replay import main, parse_requests, replay
from seggrasp.hands import FRANKA_HAND, ROBOTIQ_2F85
from sim.evaluate.config import RunConfig
from sim.primitives import primitive_object, top_down_grasp


@pytest.fixture(scope="module")
def box(tmp_path_factory):
    return primitive_object("box", (0.03, 0.05, 0.06), tmp_path_factory.mktemp("box"), mass=0.2, friction=0.8)


@pytest.mark.parametrize("hand", [ROBOTIQ_2F85, FRANKA_HAND], ids=lambda h: h.name)
def test_a_box_squeezed_by_its_sides_is_lifted_by_them(box, hand):
    T_obj = np.eye(4)
    T_obj[:3, 3] = [0.5, 0.0, 0.0]
    result = replay(box, "side", T_obj, top_down_grasp(T_obj, 0.035), 0.03, hand, hand.default_grip_force)
    assert result.rise == pytest.approx(0.20, abs=0.01)  # it rose with the hand, not slipping in the pads
    assert result.on_part is True and result.success and result.failure == ""


def test_a_grasp_beside_the_box_closes_on_nothing(box):
    T_obj = np.eye(4)
    T_obj[:3, 3] = [0.5, 0.0, 0.0]
    T_grasp = top_down_grasp(T_obj, 0.035)
    T_grasp[:3, 3] += T_grasp[:3, 0] * 0.06  # 6 cm along the closing axis: both fingers pass beside the box
    result = replay(box, "side", T_obj, T_grasp, 0.03, ROBOTIQ_2F85, 235.0)
    assert result.rise < 0.01 and not result.success and result.failure == "dropped"


def test_the_wrong_part_is_named(box):
    T_obj = np.eye(4)
    T_obj[:3, 3] = [0.5, 0.0, 0.0]
    result = replay(box, "top", T_obj, top_down_grasp(T_obj, 0.035), 0.03, ROBOTIQ_2F85, 235.0)
    assert result.rise > 0.18 and result.on_part is False and result.failure == "wrong_part"


def test_requests_parse_and_bad_ones_are_one_sentence(tmp_path, capsys):
    assert parse_requests("knife_chef:blade, mug_classic:handle") == [("knife_chef", "blade"), ("mug_classic", "handle")]
    with pytest.raises(ValueError, match="OBJECT:PART"):
        parse_requests("knife_chef")
    run = RunConfig(methods=["oracle"], objects=["knife_chef"], seeds=[0], embodiment="arm")
    (tmp_path / "run.json").write_text(json.dumps(asdict(run)))
    (tmp_path / "trials.jsonl").write_text("")
    for argv, words in ((["--requests", "knife_chef"], "OBJECT:PART"), (["--requests", "knife_chef:lid"], "no part"),
                        (["--requests", "no_such:blade"], "no twin object"),
                        (["--requests", "knife_chef:blade"], "no executed trial")):
        assert main(["--run", str(tmp_path), *argv]) == 2
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and words in err
    assert main(["--run", str(tmp_path / "absent"), "--requests", "knife_chef:blade"]) == 2
    assert "holds no evaluation run" in capsys.readouterr().err
