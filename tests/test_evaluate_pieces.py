"""A run carried in pieces (`sim.evaluate.pieces`): only whole tasks are packed, each once, and unpacking gives back
every record for `--resume` to continue."""

from __future__ import annotations

from pathlib import Path

import pytest

from sim.evaluate.config import RunConfig
from sim.evaluate.pieces import main, pack, packed_tasks, pieces_of, unpack
from sim.evaluate.records import JsonLines, load_run, prepare_out
from sim.evaluate.runner import is_complete, recorded_index

PROMPTS = {"mug_classic": ["handle", "body"], "knife_chef": ["handle", "blade"]}


def run_folder(out: Path, top_k: int = 2) -> RunConfig:
    """A run of the oracle on two twin objects at seeds 0-1, `top_k` slots per prompt, recorded in `out`."""
    return prepare_out(out, RunConfig(["oracle"], list(PROMPTS), seeds=[0, 1], top_k=top_k), resume=False)


def write_task(out: Path, object_id: str, seed: int, ranks: int = 2) -> None:
    """The records of one (object, seed) task: its oracle segmentation and `ranks` slots of each prompt."""
    JsonLines(out / "segmentations.jsonl").append(
        {"object_id": object_id, "seed": seed, "robot": "ur5", "method": "oracle"})
    JsonLines(out / "trials.jsonl").extend(
        {"object_id": object_id, "seed": seed, "robot": "ur5", "method": "oracle", "prompt": prompt, "rank": rank,
         "success": rank == 0, "lift_height": 0.1 + 0.01 * rank}
        for prompt in PROMPTS[object_id] for rank in range(ranks))


def test_only_finished_tasks_are_packed_each_once_and_unpacked_whole(tmp_path):
    run, folder = tmp_path / "run", tmp_path / "pieces"
    run_folder(run)
    write_task(run, "mug_classic", 0)
    write_task(run, "knife_chef", 0, ranks=1)  # half a task: left for a later piece

    first = pack(run, folder)
    assert first.name == "piece-000.tar.xz"
    assert packed_tasks(folder) == {("mug_classic", 0)}
    assert pack(run, folder) is None  # nothing finished beyond the piece

    JsonLines(run / "trials.jsonl").extend(
        {"object_id": "knife_chef", "seed": 0, "robot": "ur5", "method": "oracle", "prompt": prompt, "rank": 1,
         "success": False, "lift_height": 0.0} for prompt in PROMPTS["knife_chef"])
    assert pack(run, folder).name == "piece-001.tar.xz"
    assert packed_tasks(folder) == {("mug_classic", 0), ("knife_chef", 0)}

    again = tmp_path / "again"
    assert unpack(folder, again) == 2
    trials = JsonLines(again / "trials.jsonl").read()
    assert len(trials) == 8 and sorted(map(str, trials)) == sorted(map(str, JsonLines(run / "trials.jsonl").read()))
    config = load_run(again)
    held = recorded_index(again)
    assert all(is_complete(held(object_id, 0), object_id, config.at_seed(0)) for object_id in PROMPTS)
    assert not held("mug_classic", 1).trials


def test_a_piece_of_another_run_or_an_unpack_over_records_is_refused(tmp_path, capsys):
    run, other, folder = tmp_path / "run", tmp_path / "other", tmp_path / "pieces"
    run_folder(run)
    write_task(run, "mug_classic", 0)
    pack(run, folder)
    run_folder(other, top_k=3)
    write_task(other, "mug_classic", 0, ranks=3)
    with pytest.raises(ValueError, match="records another run"):
        pack(other, folder)
    assert len(pieces_of(folder)) == 1

    assert main(["unpack", str(folder), str(run)]) == 2
    assert "already holds run.json, trials.jsonl" in capsys.readouterr().err
    assert main(["pack", str(tmp_path / "nowhere"), str(folder)]) == 2
    assert "holds no run.json" in capsys.readouterr().err
