"""sim.evaluate.stats: the cluster-bootstrap intervals of a multi-seed run, on synthetic records with known answers."""

import numpy as np
import pytest

from sim.evaluate.report import markdown_report, summarise
from sim.evaluate.stats import describe, grouped_mean, method_intervals, paired_differences, MetricUnits, GRASP_METRICS


def _trials(method: str, successes: dict[tuple[str, int], list[bool]], category: str = "thing") -> list[dict]:
    """Trial records of `method`: for each (object, seed) one slot per entry of its list (executed, on the part
    exactly when it succeeded)."""
    rows = []
    for (object_id, seed), outcomes in successes.items():
        for rank, ok in enumerate(outcomes):
            rows.append({"method": method, "object_id": object_id, "category": category, "seed": seed,
                         "prompt": "handle", "rank": rank, "executed": True, "success": ok,
                         "contacts_on_part": ok, "reachable": True, "detector": "simulated:typical",
                         "T_world_grasp": np.eye(4).tolist()})
    return rows


def _draw(rng: np.random.Generator, n_objects: int, seeds: int, slots: int) -> tuple[dict, float]:
    """Objects drawn from a population whose success probability is Beta(2, 2)-distributed (true mean 0.5)."""
    p = rng.beta(2.0, 2.0, size=n_objects)
    return {(f"obj{o}", s): list(rng.random(slots) < p[o]) for o in range(n_objects) for s in range(seeds)}, 0.5


def test_the_interval_covers_the_population_mean_at_about_the_nominal_rate() -> None:
    rng = np.random.default_rng(7)
    covered, widths = 0, []
    for _ in range(60):
        successes, truth = _draw(rng, n_objects=30, seeds=3, slots=4)
        d = describe(MetricUnits(_trials("m", successes), GRASP_METRICS["success_all_slots"], by_category=False))
        covered += d["ci_low"] <= truth <= d["ci_high"]
        widths.append(d["ci_high"] - d["ci_low"])
    assert covered >= 51, covered  # nominal 95 %: 57 of 60; binomial 1st percentile ~ 53
    # between-object spread dominates: sd of an object's rate over 12 slots is about sqrt(0.05 + 0.2/12); an
    # interval from slots as independent units would be about half as wide
    expected = 2 * 1.96 * np.sqrt(0.05 + 0.2 / 12) / np.sqrt(30)
    assert 0.75 * expected < np.mean(widths) < 1.25 * expected, (np.mean(widths), expected)


def test_a_paired_difference_of_identical_methods_is_zero_with_a_zero_width_interval() -> None:
    successes, _ = _draw(np.random.default_rng(1), n_objects=10, seeds=2, slots=3)
    trials = _trials("seggrasp", successes) + _trials("coarse", successes)
    diff = paired_differences(trials, [], [("seggrasp", "coarse")])["seggrasp - coarse"]["success_all_slots"]
    assert diff["mean"] == diff["ci_low"] == diff["ci_high"] == 0.0
    assert diff["per_seed"] == {"0": 0.0, "1": 0.0}


def test_a_method_better_on_every_object_has_a_difference_interval_above_zero() -> None:
    rng = np.random.default_rng(2)
    worse, _ = _draw(rng, n_objects=12, seeds=2, slots=4)
    better = {unit: [True] + outcomes[1:] for unit, outcomes in worse.items()}  # one more success where it failed
    trials = _trials("seggrasp", better) + _trials("coarse", worse)
    diff = paired_differences(trials, [], [("seggrasp", "coarse")])["seggrasp - coarse"]["success_all_slots"]
    gained = np.mean([not outcomes[0] for outcomes in worse.values()]) / 4
    assert diff["mean"] == pytest.approx(gained)
    assert 0 < diff["ci_low"] <= diff["mean"] <= diff["ci_high"]


def test_means_and_per_seed_values_follow_the_summary_s_formulas() -> None:
    # two seeds: seed 0 all succeed, seed 1 one of four
    successes = {("a", 0): [True, True], ("b", 0): [True, True], ("a", 1): [True, False], ("b", 1): [False, False]}
    segs = [{"method": "m", "object_id": o, "category": c, "seed": 0, "miou": v, "miou_faces": v}
            for o, c, v in (("a", "mug", 1.0), ("b", "mug", 1.0), ("c", "knife", 0.0))]
    intervals = method_intervals(_trials("m", successes), segs, ["m"])["m"]
    assert intervals["success_all_slots"]["mean"] == pytest.approx(5 / 8)
    assert intervals["success_all_slots"]["per_seed"] == {"0": 1.0, "1": 0.25}
    assert intervals["miou"]["mean"] == pytest.approx(0.5)  # mean over categories (mug 1.0, knife 0.0), not 2/3
    weights = np.array([[2.0, 0.0, 1.0]])  # a resample: a twice, b never, c once
    assert grouped_mean(np.array([1.0, 1.0, 0.0]), np.ones(3), np.array([0, 0, 1]), weights)[0] == pytest.approx(0.5)


def test_one_object_has_no_interval_and_the_report_says_so() -> None:
    trials = _trials("seggrasp", {("a", 0): [True, False], ("a", 1): [True, True]})
    summary = summarise(trials, [], [], ["seggrasp"])
    d = summary["methods"]["seggrasp"]["intervals"]["success_all_slots"]
    assert d["mean"] == pytest.approx(0.75) and d["ci_low"] is None and d["ci_high"] is None
    text = markdown_report(summary, {"detector": "simulated:typical", "embodiment": "floating", "backend": "sim",
                                     "perceive": False, "seeds": [0, 1], "top_k": 2, "n_objects": 1,
                                     "wall_time_s": 1.0})
    assert "0.750 [—]" in text and "seeds: 0, 1" in text and "| seed 0 | seed 1 |" in text


def test_the_engine_benchmark_table_gives_speedups_and_ray_s_overhead() -> None:
    from sim.evaluate.bench import report

    times = {("local", 1): [100.0, 110.0], ("local", 2): [60.0, 50.0], ("ray", 1): [104.0, 106.0],
             ("ray", 2): [57.0, 53.0]}
    text = report(times, [2.0, 3.0], "python -m sim.evaluate.bench")
    assert "| local | 1 | 105.0 | 100.0, 110.0 |" in text
    assert "| speedup of 2 workers over 1, local | 1.91x |" in text
    assert "| speedup of 2 workers over 1, ray | 1.91x |" in text
    assert "| Ray overhead over local, 1 worker(s) | +0.0 % |" in text
    assert "| Ray overhead over local, 2 worker(s) | +0.0 % |" in text
    assert "load average 2.0-3.0" in text


def test_the_engine_benchmark_reports_a_joined_ray_instance_beside_a_started_one() -> None:
    from sim.evaluate.bench import PHASES, report

    times = {("local", 1): [20.0], ("local", 2): [12.0], ("ray", 1): [24.0], ("ray", 2): [15.0],
             ("ray-cluster", 1): [21.0], ("ray-cluster", 2): [12.6]}
    joined = {"engine": 101.0, "connected": 101.5, "packed": 101.2, "done": 110.0}  # no instance stopped
    tasks = [{"started": 102.0, "finished": 109.0, "received": 109.5}]
    phase = {title: f(joined, tasks, 1_000_000, 100.0) for title, f in PHASES}
    text = report(times, [1.0], "bench", None, {("ray-cluster", 1): [phase]})
    assert "| Ray overhead over local, 1 worker(s) | +20.0 % |" in text
    assert "| Ray joining a running instance overhead over local, 1 worker(s) | +5.0 % |" in text
    assert "| Ray joining a running instance overhead over local, 2 worker(s) | +5.0 % |" in text
    assert "| speedup of 2 workers over 1, ray-cluster | 1.67x |" in text
    stopped_row = next(line for line in text.splitlines() if line.startswith("| last task done to Ray stopped"))
    assert stopped_row.endswith("| — |")


def _mixed_rows() -> list[dict]:
    """Slots of three requests: executed or not, with unknown contacts/success, first and later ranks; request c was
    judged infeasible (not executed), a and b feasible."""
    base = {"method": "m", "category": "thing", "seed": 0, "reachable": True, "detector": "simulated:typical",
            "T_world_grasp": np.eye(4).tolist()}
    slots = [  # (object, rank, executed, contacts_on_part, success)
        ("a", 0, True, True, True), ("a", 1, True, True, False), ("a", 2, False, None, None),
        ("b", 0, True, False, False), ("b", 1, True, None, None), ("b", 2, False, False, False),
        ("c", 0, False, False, False), ("c", 1, False, False, False), ("c", 2, False, False, False),
    ]
    return [dict(base, object_id=o, prompt="handle", rank=k, executed=e, contacts_on_part=c, success=s,
                 infeasible=o == "c") for o, k, e, c, s in slots]


def test_the_report_s_grasp_figures_are_the_interval_means_and_keep_their_values() -> None:
    from sim.evaluate.report import grasp_metrics

    rows = _mixed_rows()
    figures = grasp_metrics(rows)
    # hand-counted: all slots with a known value; top-1 = rank 0; executed-only = executed with a known value;
    # feasible-only = the slots of requests a and b with a known success
    assert figures["part_selection_all_slots"] == pytest.approx(2 / 7)
    assert figures["success_all_slots"] == pytest.approx(1 / 7)
    assert figures["success_top1"] == pytest.approx(1 / 3)
    assert figures["part_selection"] == pytest.approx(2 / 3)
    assert figures["success"] == pytest.approx(1 / 3)
    assert figures["success_feasible"] == pytest.approx(1 / 4)
    assert (figures["requests"], figures["infeasible_requests"], figures["judged_requests"]) == (3, 1, 3)
    intervals = method_intervals(rows, [], ["m"])["m"]
    for name in GRASP_METRICS:
        assert figures[name] == pytest.approx(intervals[name]["mean"]), name


def test_what_grasps_did_to_the_other_objects_is_not_swayed_by_one_knocked_off_the_table() -> None:
    """The farthest-moved neighbour per executed grasp: median and 90th percentile, the shares moved >= 10 mm and
    lifted along; an object knocked off the twin's table falls on (28 m in a pile run) and must not set the figure."""
    from sim.evaluate.report import grasp_metrics

    farthest = [0.0, 0.001, 0.002, 0.003, 0.004, 0.005, 0.006, 0.02, 0.03, 28.0]
    base = _mixed_rows()[0]
    rows = [dict(base, rank=k, executed=True, outcome={"disturbance": [d / 2, d], "lifted_along": int(k == 0)})
            for k, d in enumerate(farthest)]
    figures = grasp_metrics(rows)
    assert figures["disturbance_median_mm"] == pytest.approx(4.5)
    assert figures["disturbance_p90_mm"] == pytest.approx(1000 * (0.03 + 0.1 * (28.0 - 0.03)))
    assert figures["disturbed"] == pytest.approx(0.3) and figures["lifted_along"] == pytest.approx(0.1)
    assert "disturbance_median_mm" not in grasp_metrics([dict(row, outcome={}) for row in rows])  # objects alone


def test_the_report_and_the_intervals_share_one_metric_definition(monkeypatch) -> None:
    from sim.evaluate.report import grasp_metrics

    rows = _mixed_rows()
    monkeypatch.setitem(GRASP_METRICS, "success_top1", lambda r: float(bool(r["success"])) if r["rank"] == 1 else None)
    assert grasp_metrics(rows)["success_top1"] == pytest.approx(0.0)  # rank 1: one failure, one unknown
    assert method_intervals(rows, [], ["m"])["m"]["success_top1"]["mean"] == pytest.approx(0.0)


def test_the_engine_benchmark_reports_ray_s_phases_and_rewrites_only_its_profile_s_section(tmp_path) -> None:
    from sim.evaluate.bench import PHASES, report, write_section

    times = {("local", 1): [10.0], ("local", 2): [6.0], ("ray", 1): [13.0], ("ray", 2): [8.0]}
    stamps = {"engine": 101.0, "connected": 104.0, "packed": 101.5, "done": 112.0, "stopped": 113.5}
    tasks = [{"started": 105.0, "finished": 108.0, "received": 108.25},
             {"started": 108.5, "finished": 111.5, "received": 111.75}]
    phase = {title: f(stamps, tasks, 2_000_000, 100.0) for title, f in PHASES}
    text = report(times, [1.0], "bench", {("local", 1): [9.5]}, {("ray", 1): [phase]})
    assert "| local | 1 | 10.0 | 10.0 | 9.5 |" in text and "| ray | 1 | 13.0 | 13.0 | — |" in text
    rows = {line.split(" | ")[0][2:]: line.rsplit("|", 2)[1].strip() for line in text.splitlines()
            if line.startswith("| ")}
    values = [rows[title] for title, _ in PHASES]
    assert values == ["1.00", "3.00", "0.50", "2.00", "1.00", "6.00", "0.25", "1.50"]
    doc = tmp_path / "engines.md"
    doc.write_text("# Engines\n\nprose\n")
    write_section(doc, "--quick", "old quick\n")
    write_section(doc, "--quick --seeds 0-4", "five seeds\n")
    write_section(doc, "--quick", "new quick\n")
    content = doc.read_text()
    assert content.startswith("# Engines\n\nprose\n") and "old quick" not in content
    assert content.index("new quick") < content.index("five seeds") and content.count("<!-- bench --quick -->") == 1
