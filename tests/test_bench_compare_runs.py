"""bench/bench_compare_runs.py pairs one method's requests across two runs and clusters the error by object."""

import json
from pathlib import Path

import numpy as np

from bench import bench_compare_runs  # noqa: E402


def _run(folder: Path, lifted: dict[tuple[str, str], int], robots: dict[str, dict] | None = None) -> Path:
    """A run folder whose oracle lifts `lifted[(object, prompt)]` of 4 slots (seed 0), the rest `no_grasp`; with
    `robots`, per robot system its own such dict, each record naming its system."""
    rows = []
    for robot, lifts in (robots or {None: lifted}).items():
        for (obj, prompt), n in lifts.items():
            for rank in range(4):
                ok = rank < n
                rows.append(dict(method="oracle", object_id=obj, category=obj.split("_")[0], prompt=prompt,
                                 rank=rank, seed=0, executed=ok, contacts_on_part=ok, success=ok,
                                 failure="" if ok else "no_grasp", **({"robot": robot} if robot else {})))
    folder.mkdir()
    (folder / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return folder


def test_the_paired_difference_counts_each_request_once_and_names_the_failures(tmp_path):
    before = _run(tmp_path / "before", {("mug_a", "handle"): 2, ("mug_a", "body"): 4, ("knife_a", "blade"): 0})
    after = _run(tmp_path / "after", {("mug_a", "handle"): 4, ("mug_a", "body"): 4, ("knife_a", "blade"): 2,
                                      ("knife_b", "blade"): 4})  # a request only one run has is not compared
    page = tmp_path / "page.md"
    assert bench_compare_runs.main(["--before", str(before), "--after", str(after), "--out", str(page)]) == 0
    text = page.read_text()
    assert "Requests compared: 3" in text
    # Suc. per request: 0.5 -> 1, 1 -> 1, 0 -> 0.5: mean +0.333
    row = next(line for line in text.splitlines() if line.startswith("| Suc. (all slots)"))
    assert "| 0.500 | 0.833 | +0.333 ±" in row
    assert "no_grasp 6 → 2" in text


def test_the_clustered_error_grows_when_an_objects_requests_move_together():
    d = np.array([0.5, 0.5, 0.0, 0.0])
    apart = bench_compare_runs.clustered_standard_error(d, ["a", "b", "c", "d"])
    together = bench_compare_runs.clustered_standard_error(d, ["a", "a", "c", "c"])
    assert together > apart > 0


def test_runs_without_a_shared_request_are_an_error(tmp_path, capsys):
    before = _run(tmp_path / "before", {("mug_a", "handle"): 2})
    after = _run(tmp_path / "after", {("mug_b", "handle"): 2})
    assert bench_compare_runs.main(["--before", str(before), "--after", str(after)]) == 2
    assert "share no request" in capsys.readouterr().err


def test_a_run_on_two_robot_systems_is_compared_per_system(tmp_path):
    # the same request on two systems is two requests: pooled, the UR5's gain and the Panda's loss would cancel
    before = _run(tmp_path / "before", {}, robots={"ur5": {("mug_a", "handle"): 0}, "panda": {("mug_a", "handle"): 4}})
    after = _run(tmp_path / "after", {}, robots={"ur5": {("mug_a", "handle"): 4}, "panda": {("mug_a", "handle"): 2}})
    page = tmp_path / "page.md"
    assert bench_compare_runs.main(["--before", str(before), "--after", str(after), "--out", str(page)]) == 0
    sections = page.read_text().split("## ")[1:]
    assert [s.splitlines()[0] for s in sections] == ["`oracle` on panda", "`oracle` on ur5"]
    rows = [next(line for line in s.splitlines() if line.startswith("| Suc. (all slots)")) for s in sections]
    assert "| 1.000 | 0.500 | -0.500 ±" in rows[0]
    assert "| 0.000 | 1.000 | +1.000 ±" in rows[1]


def test_suc_over_feasible_requests_and_the_requests_whose_judgement_changed(tmp_path):
    before = _run(tmp_path / "before", {("kettle_a", "body"): 0, ("kettle_a", "handle"): 4})
    after = _run(tmp_path / "after", {("kettle_a", "body"): 0, ("kettle_a", "handle"): 4})
    rows = [json.loads(line) for line in (after / "trials.jsonl").read_text().splitlines()]
    for r in rows:  # the body is judged infeasible after the change: every slot of it, none executed
        if r["prompt"] == "body":
            r.update(infeasible=True, failure="infeasible")
    (after / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    page = tmp_path / "page.md"
    assert bench_compare_runs.main(["--before", str(before), "--after", str(after), "--out", str(page)]) == 0
    text = page.read_text()
    assert ("Suc. over the slots of the requests each run judged feasible: before 4/8 = 0.500, after 4/4 = 1.000; "
            "requests judged infeasible 0 → 1.") in text
    assert "Newly infeasible: kettle_a body (seeds 0)." in text
    assert "Newly feasible" not in text


def test_each_side_may_be_several_runs_one_per_robot_system(tmp_path):
    ur5 = _run(tmp_path / "ur5", {}, robots={"ur5": {("mug_a", "handle"): 0}})
    panda = _run(tmp_path / "panda", {}, robots={"panda": {("mug_a", "handle"): 4}})
    after = _run(tmp_path / "after", {}, robots={"ur5": {("mug_a", "handle"): 4}, "panda": {("mug_a", "handle"): 2}})
    page = tmp_path / "page.md"
    assert bench_compare_runs.main(["--before", str(ur5), str(panda), "--after", str(after), "--out", str(page)]) == 0
    sections = page.read_text().split("## ")[1:]
    assert [s.splitlines()[0] for s in sections] == ["`oracle` on panda", "`oracle` on ur5"]
    assert f"Before: `{ur5}`, `{panda}`; after: `{after}`." in page.read_text()


def test_a_system_only_one_side_ran_is_left_out_of_the_other_side_too(tmp_path):
    # before on both systems, after on the Panda alone: the UR5's records must not count as the Panda's
    before = _run(tmp_path / "before", {}, robots={"ur5": {("mug_a", "handle"): 0}, "panda": {("mug_a", "handle"): 4}})
    after = _run(tmp_path / "after", {}, robots={"panda": {("mug_a", "handle"): 2}})
    page = tmp_path / "page.md"
    assert bench_compare_runs.main(["--before", str(before), "--after", str(after), "--out", str(page)]) == 0
    sections = page.read_text().split("## ")[1:]
    assert [s.splitlines()[0] for s in sections] == ["`oracle` on panda"]
    row = next(line for line in sections[0].splitlines() if line.startswith("| Suc. (all slots)"))
    assert "| 1.000 | 0.500 | -0.500 ±" in row
    assert "no_grasp 0 → 2" in sections[0]
