"""Whole episodes on the emulated lab cell: the unchanged `hardware.RealCell` through the real ur_rtde, pyrealsense2
(the twin's recordings) and the Robotiq URCap socket, against `python -m sim.lab` driven by the PyBullet twin.

Each test starts a fresh emulator in its own network namespace (tests/lab_harness.py) with the cameras' recordings
in its own folder (a copy of hardware/cell.emulated.yaml pointing there), and leaves no process behind."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from seggrasp.cell import FAILURES
from tests.lab_harness import ROOT, run_command, run_in_lab

pytestmark = pytest.mark.slow

EMULATED_CONFIG = ROOT / "hardware" / "cell.emulated.yaml"
#: Where hardware/cell.emulated.yaml has the emulator write its recordings.
DEFAULT_RECORDINGS = "~/.cache/seggrasp/lab"


def emulated_config(tmp_path: Path) -> Path:
    """hardware/cell.emulated.yaml with the recordings in `tmp_path/recordings` (no two runs share a folder)."""
    text = EMULATED_CONFIG.read_text()
    assert DEFAULT_RECORDINGS in text
    path = tmp_path / "cell.yaml"
    path.write_text(text.replace(DEFAULT_RECORDINGS, str(tmp_path / "recordings")))
    return path


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def test_the_evaluation_command_runs_through_the_wire_and_records_like_the_twin(tmp_path):
    """`python -m sim.evaluate --backend real --config <emulated cell>` starts the emulator itself and records
    trials scored against the twin's truth (the oracle needs it: the real backend refused it before)."""
    config, out = emulated_config(tmp_path), tmp_path / "run"
    run = run_command([sys.executable, "-m", "sim.evaluate", "--backend", "real", "--config", str(config),
                       "--objects", "bottle_water", "--methods", "oracle", "--top-k", "1", "--out", str(out)],
                      timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    trials = read_jsonl(out / "trials.jsonl")
    assert sorted(t["prompt"] for t in trials) == ["body", "cap"]
    for trial in trials:
        assert trial["extra"]["backend"] == "real" and trial["extra"]["perceive"]
        assert trial["contacts_on_part"] is not None and trial["success"] is not None  # scored: the truth is known
        if trial["executed"]:
            assert trial["outcome"]["contacts_observed"] is False  # the real cell's gripper reports no contacts
            assert trial["success"] == (trial["lifted"] and trial["contacts_on_part"])
        assert trial["success"] or trial["failure"] in FAILURES, trial["message"]
    assert any(t["executed"] and t["reachable"] for t in trials)
    assert (out / "summary.md").is_file() and json.loads((out / "summary.json").read_text())["run"]["backend"] == "real"


def test_the_emulated_cell_lays_out_a_packed_table_and_the_run_finds_the_object_from_its_cameras(tmp_path):
    """`--scene packed` on the emulated cell: the emulator lays the mug among three of the twin's other objects, the
    unchanged RealCell captures them through pyrealsense2, and the run finds the mug among them by its name (the
    simulated object detector boxes the bodies the emulator's masks name) before planning on its mesh alone."""
    config, out = emulated_config(tmp_path), tmp_path / "run"
    run = run_command([sys.executable, "-m", "sim.evaluate", "--backend", "real", "--config", str(config),
                       "--scene", "packed", "--objects", "mug_classic", "--methods", "oracle", "--detector", "perfect",
                       "--top-k", "1", "--out", str(out)], timeout=420)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "Traceback" not in run.stderr
    trials = read_jsonl(out / "trials.jsonl")
    assert sorted(t["prompt"] for t in trials) == ["body", "handle"]
    for trial in trials:
        scene = trial["extra"]["scene"]
        assert scene["kind"] == "packed" and scene["target_id"] == "mug_classic" and len(scene["object_ids"]) == 4
        assert trial["extra"]["backend"] == "real" and trial["target_found"]
        assert trial["target_iou"] > 0.5  # the chosen instance against the emulator's masks of the mug
        assert trial["success"] or trial["failure"] in FAILURES, trial["message"]
    summary = (out / "summary.md").read_text()
    assert "scene: packed, 4 objects" in summary and "Finding the object among the others" in summary
    masks = sorted(p.name for p in (tmp_path / "recordings").glob("*.instances.npy"))
    assert masks == ["941000000001.instances.npy", "941000000002.instances.npy"]


SCENARIO = """
import json, sys
import numpy as np
from seggrasp.cell import FAILURES
from seggrasp.episode import Episode, EpisodeContext, EpisodeSettings
from seggrasp.objects import load_asset
from seggrasp.truth import DetectorSpec, GroundTruth
from sim.evaluate.emulated import EmulatedCell
from sim.lab.control import request

cell = EmulatedCell.from_config(sys.argv[1])
model = load_asset("bottle_water")
context = EpisodeContext.from_object(model, 5)
truth = GroundTruth.of_object(model, context.prompts, true_pose=cell.true_pose)
episode = Episode(cell, context, DetectorSpec("simulated", preset="perfect", seed=5), truth,
                  EpisodeSettings(seed=5, top_k=1, perceive=True, workspace=cell.workspace))
plan = episode.plan("coarse")  # reset (the emulator places), capture, perceive, segment
labels_found = sorted(set(int(v) for v in plan.labels if v >= 0))
slot = next(s for s in episode.slots(plan) if s.grasp is not None)  # grasps, check_reach
record = episode.execute(slot)
# a grasp pushed down through the bottle's top: the twin's arm stops on the force, the stop is released
grasp = np.eye(4)
grasp[:3, :3] = np.diag([1.0, -1.0, -1.0])
grasp[:3, 3] = cell.true_pose()[:3, 3] + [0.0, 0.0, 0.12]
cell.reset(5, "bottle_water")
pushed = cell.execute(grasp, 0.01)
cell.reset(5, "bottle_water")  # the arm works again after the release: home, and a fresh scene
frames = cell.capture()
state = request("twin_state")
cell.close()
print(json.dumps({"record": record.to_json(), "labels": labels_found, "pushed": pushed.to_json(),
                  "frames": [float((f.depth > 0).mean()) for f in frames], "state": state}))
"""


def test_an_episode_through_the_wire_and_a_protective_stop_it_survives(tmp_path):
    """reset -> capture -> perceive -> segment -> grasps -> check_reach -> execute, then a grasp that presses the
    object into the table: a protective stop, recorded as a `collision` and released, after which the cell goes on."""
    config = emulated_config(tmp_path)
    run = run_in_lab(SCENARIO.replace("sys.argv[1]", repr(str(config))),
                     ("--object", "bottle_water", "--seed", "5", "--controller", "cb3", "--polyscope", "3.15.7",
                      "--recordings", str(tmp_path / "recordings")), timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    result = run.result
    record = result["record"]
    assert result["labels"] == [0, 1]  # the perceived mesh was segmented into cap and body
    assert record["executed"] and record["reachable"]
    assert record["success"] or record["failure"] in FAILURES, record["message"]
    assert record["success"] == (record["lifted"] and record["contacts_on_part"])
    pushed = result["pushed"]
    assert pushed["failure"] == "collision" and "the emulator released the stop" in pushed["message"]
    assert "N on the table, above the" in pushed["message"]
    assert result["state"]["safety_status"] == "normal"
    assert min(result["frames"]) > 0.5  # the cameras play the new scene
    assert result["state"]["real_time_factor"] > 0.8
