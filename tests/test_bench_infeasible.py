"""bench/bench_infeasible.py: requests judged infeasible, executed anyway with a relaxed sampler's grasp."""

from __future__ import annotations

import re

import pytest

from bench import bench_infeasible as bench
from seggrasp.grasp.antipodal import AntipodalConfig
from seggrasp.hands import FRANKA_HAND, ROBOTIQ_2F85
from tests.test_feasibility import box_part, judge


def infeasible(part: str, robot: str = "ur5", **outcome) -> bench.Request:
    return bench.Request("thing", "things", part, robot, 0, False, f"{part}: stands at most 1.0 mm above the table",
                         **outcome)


def check_row(lines: list[str], robot: str) -> list[str]:
    """The cells of the check table's row of `robot`."""
    row = next(line for line in lines if line.startswith(f"| {robot} | "))
    return [cell.strip() for cell in row.strip("|").split("|")]


@pytest.mark.slow
def test_the_reason_kinds_follow_the_judgement_s_own_sentences() -> None:
    assert bench.reason_kind(judge(*box_part((0.06, 0.02, 0.0015)), ROBOTIQ_2F85).reason) == "too low"
    assert bench.reason_kind(judge(*box_part((0.078, 0.078, 0.078)), FRANKA_HAND).reason) == "too wide"


def test_the_reason_kinds_of_sentences() -> None:
    assert bench.reason_kind("blade: lies flat, at most 2.4 mm of it above a pinch's fingertips") == "lies flat"
    assert bench.reason_kind("rim: no collision-free pose of the franka_hand closes on it") == "no pose"
    assert bench.reason_kind("temple: the pads press on it for at most 0 % of their footprint") == "pads' share"
    assert bench.reason_kind("rim: where the pads press on it, they first land on it at most 1.0 mm into the pad from "
                             "its end; the robotiq_2f85's pads hold from 2.0 mm") == "pads' ends"
    assert bench.reason_kind("body: wherever the pads hold it, the 0.83 kg object's weight turns it about the "
                             "closing axis with at least 0.55 N m") == "weight turns it"
    assert bench.reason_kind("lies flat: something new") == "other"  # the part's name is not the reason


def test_the_relaxed_sampler_loosens_the_judgement_s_margins_down_to_the_cell_s_table_clearances() -> None:
    strict = AntipodalConfig.for_hand(FRANKA_HAND, grip_force=70.0)
    relaxed = bench.relaxed_config(FRANKA_HAND, 70.0)
    assert relaxed.pad_half_width == strict.pad_half_width and relaxed.grip_force == 70.0
    assert relaxed.pinch_min_band == 0.0 < strict.pinch_min_band
    assert relaxed.width_margin == 0.001 < strict.width_margin
    assert (relaxed.pinch_table_clearance, relaxed.table_clearance) == (0.001, 0.003)  # sim.grasp_primitive's
    kept = bench.relaxed_config(FRANKA_HAND, 70.0, clearance="sampler")
    assert (kept.pinch_table_clearance, kept.table_clearance) == (strict.pinch_table_clearance,
                                                                  strict.table_clearance)
    with pytest.raises(ValueError, match="clearance"):
        bench.relaxed_config(FRANKA_HAND, 70.0, clearance="floor")


def test_the_strict_limits_a_lifted_grasp_breaks_are_named() -> None:
    low = infeasible("blade", share=1.0, band=0.0003, tip_clearance=0.0011, width=0.0504, tilt_deg=0.0)
    assert low.strict_limits_broken(ROBOTIQ_2F85, 0.5) == ["fingertips 1.1 mm < 1.5 mm above the table",
                                                           "pad band 0.3 mm < 0.5 mm"]
    # the Franka hand pinches from 1.0 mm (its own pinch_table_clearance)
    assert low.strict_limits_broken(FRANKA_HAND, 0.5) == ["pad band 0.3 mm < 0.5 mm"]
    high = infeasible("temple", share=0.0, band=0.0009, tip_clearance=0.01, width=0.078, tilt_deg=30.0)
    # an ordinary grasp high above the table: the pinch's limits do not hold for it
    assert high.strict_limits_broken(FRANKA_HAND, 0.5) == ["pads' share 0 % < 50 %", "width 78.0 mm > 76 mm"]


def test_the_check_passes_under_five_percent_lifted_by_the_part_and_fails_at_it() -> None:
    lifted = {"candidates": 3, "checked": 1, "executed": True, "lifted": True, "by_part": True, "width": 0.01,
              "tilt_deg": 0.0, "contact_height": 0.002, "share": 1.0, "band": 0.0003, "tip_clearance": 0.0011,
              "in_strict": False}
    ur5 = [infeasible("blade", lifted=False, candidates=2, executed=True, failure="slipped") for _ in range(19)]
    ur5 += [infeasible("pivot", **lifted)]  # 1 of 20 = 5 %: not under it
    panda = [infeasible("pivot", "panda") for _ in range(20)]  # no relaxed candidate at all
    feasible = bench.Request("thing", "things", "handle", "panda", 0, True)
    lines = bench.report(ur5 + panda + [feasible], ["ur5", "panda"], "python bench/bench_infeasible.py", 1.0, "")
    # robot | judged | infeasible | no candidate | candidate | reachable | lifted | by the part | share | check
    assert check_row(lines, "ur5") == ["ur5", "20", "20", "0", "20", "20", "1", "1", "1/20 = 5.0 %", "FAIL"]
    assert check_row(lines, "panda") == ["panda", "21", "20", "20", "0", "0", "0", "0", "0/20 = 0.0 %", "pass"]
    text = "\n".join(lines)
    assert "| thing | blade | ur5 | 19/19 | stands at most 1.0 mm above the table | 2 | 19 | slipped x19 |" in text
    assert re.search(r"\| thing: pivot \| ur5 \| 0 \| too low \| 10\.0 \| 0\.0 \| 2\.0 \| 100 % \| 0\.3 \| 1\.1 \| no \|"
                     r" fingertips 1\.1 mm < 1\.5 mm above the table; pad band 0\.3 mm < 0\.5 mm \|", text)


@pytest.mark.parametrize("argv, message", [
    (["--robots", "arx5"], "--robots 'arx5'"),
    (["--seeds", "3-1"], "the range 3-1 goes down"),
    (["--objects", "knife_chef,mug"], "mug not in the twin"),
    (["--objects", "knife_chef,knife_chef"], "--objects lists an entry more than once"),
])
def test_bad_arguments_get_one_sentence_and_exit_2(argv, message, capsys, tmp_path) -> None:
    assert bench.main([*argv, "--out", str(tmp_path / "out.md")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out.md").exists()


@pytest.mark.slow
def test_the_kids_scissors_blade_is_judged_infeasible_on_the_ur5_and_executed_anyway(tmp_path) -> None:
    requests = bench.run(["scissors_kids"], ["ur5"], [0])
    by_part = {r.part: r for r in requests}
    assert set(by_part) == {"handle", "blade", "pivot"} and by_part["handle"].feasible
    blade, pivot = by_part["blade"], by_part["pivot"]
    assert not blade.feasible and blade.kind == "no pose" and not pivot.feasible and pivot.candidates == 0
    assert blade.candidates > 0 and blade.executed  # the relaxed sampler closes on the blade; the UR5 reaches it
    counts = bench.counts_by(requests, lambda r: r.robot)["ur5"]
    assert (counts.judged, counts.infeasible) == (3, 2)
    assert isinstance(counts.by_part, int) and 0 <= counts.by_part <= counts.lifted <= counts.infeasible
    lines = bench.report(requests, ["ur5"], "python bench/bench_infeasible.py", 1.0, "")
    row = check_row(lines, "ur5")
    assert row[:6] == ["ur5", "3", "2", "1", "1", "1"]  # judged, infeasible, without and with a candidate, reached
    assert row[-1] == ("pass" if counts.by_part == 0 else "FAIL")
