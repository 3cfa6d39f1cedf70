"""bench/bench_selection.py: per-request figures over seeds, paired differences and the done-when checks."""

import json
from pathlib import Path

import pytest

from bench import bench_selection  # noqa: E402

#: per method the (on part, success) of each of a request's two slots, the same for every request; None = no grasp
SLOTS = {"seggrasp": [(True, True), (True, False)], "coarse": [(True, False), None],
         "shapegrasp": [(True, False), (True, False)], "oracle": [(True, True), (True, True)]}


def write_run(folder: Path, seeds: list[int], requests: list[tuple[str, str]]) -> None:
    folder.mkdir(parents=True)
    (folder / "run.json").write_text(json.dumps({"seeds": seeds, "detector": "typical"}))
    lines = []
    for seed in seeds:
        for method, slots in SLOTS.items():
            for object_id, prompt in requests:
                for rank, slot in enumerate(slots):
                    on_part, success = slot if slot is not None else (False, False)
                    lines.append(json.dumps({"method": method, "object_id": object_id, "prompt": prompt,
                                             "rank": rank, "seed": seed, "contacts_on_part": on_part,
                                             "success": success, "executed": slot is not None}))
    (folder / "trials.jsonl").write_text("\n".join(lines) + "\n{\"torn")


@pytest.mark.parametrize("layout", ["a folder per seed", "one folder of two seeds"])
def test_tables_differences_and_checks(tmp_path, layout) -> None:
    requests = [("mug", "handle"), ("mug", "body"), ("knife", "blade")]
    if layout == "a folder per seed":
        write_run(tmp_path / "s0", [0], requests)
        write_run(tmp_path / "s1", [1], requests)
        runs = f"typical={tmp_path / 's0'},{tmp_path / 's1'}"
    else:
        write_run(tmp_path / "s01", [0, 1], requests)
        runs = f"typical={tmp_path / 's01'}"
    out = tmp_path / "doc" / "selection.md"
    assert bench_selection.main(["--runs", runs, "--out", str(out)]) == 0
    text = out.read_text()
    assert "## Detector `typical`: seeds 0, 1" in text
    assert "| seggrasp | 1.000 (1.000 / 1.000) | 0.500 (0.500 / 0.500) | 1.000 (1.000 / 1.000) | 6 / 6 (mean 6)" in text
    assert "| seggrasp − coarse | +0.500 ± 0.000 [+0.500, +0.500], n=6 | +0.500 ± 0.000 [+0.500, +0.500], n=6 |" in text
    assert "| seggrasp − shapegrasp | +0.000 ± 0.000 [+0.000, +0.000], n=6 | +0.500 ± 0.000 [+0.500, +0.500], n=6 | +0.000" in text
    assert "Suc. all slots beats shapegrasp: difference +0.500" in text and "-> met" in text
    assert "Part Sel. all slots beats shapegrasp: difference +0.000" in text and "-> MISSED" in text
    assert "executed slots >= 95 % of oracle's: 6 / 6 = 100.0% -> met" in text


def test_bad_run_folder_is_a_clear_error(tmp_path, capsys) -> None:
    assert bench_selection.main(["--runs", f"typical={tmp_path}", "--out", str(tmp_path / "x.md")]) == 2
    assert "not a sim.evaluate output folder" in capsys.readouterr().err
    assert bench_selection.main(["--runs", "typical", "--out", str(tmp_path / "x.md")]) == 2


def test_seeds_option_keeps_only_those_seeds(tmp_path) -> None:
    write_run(tmp_path / "s01", [0, 1], [("mug", "handle")])
    out = tmp_path / "selection.md"
    assert bench_selection.main(["--runs", f"typical={tmp_path / 's01'}", "--seeds", "1", "--out", str(out)]) == 0
    assert "## Detector `typical`: seeds 1\n" in out.read_text()


def test_category_rows_compare_the_slots_both_record_per_category() -> None:
    def trial(object_id, category, rank, on_part, success=None):
        return {"method": "shapegrasp", "object_id": object_id, "category": category, "prompt": "p", "rank": rank,
                "seed": 0, "contacts_on_part": on_part, "success": success}

    before = [trial("knife_a", "knife", 0, True, False), trial("knife_a", "knife", 1, True, True),
              trial("mug_a", "mug", 0, True, False), trial("mug_b", "mug", 0, False, False)]
    after = [trial("knife_a", "knife", 0, False, True), trial("knife_a", "knife", 1, None, True),
             trial("mug_a", "mug", 0, True, False)]  # mug_b was not planned again: left out of both columns
    rows = bench_selection.category_rows(before, after, "shapegrasp", [("contacts_on_part", "before"),
                                                                       ("contacts_on_part", "after"),
                                                                       ("success", "after")])
    assert rows == ["| shapegrasp | knife | 2 | 1.000 | 0.000 | 1.000 |",
                    "| shapegrasp | mug | 1 | 1.000 | 1.000 | 0.000 |",
                    "| shapegrasp | all | 3 | 1.000 | 0.333 | 0.667 |"]


def test_replan_rejects_an_unknown_method(tmp_path, capsys) -> None:
    write_run(tmp_path / "s0", [0], [("mug", "handle")])
    assert bench_selection.main(["--runs", f"typical={tmp_path / 's0'}", "--replan", "typical", "--methods", "magic",
                                 "--out", str(tmp_path / "x.md")]) == 2
    assert "unknown method 'magic'" in capsys.readouterr().err
