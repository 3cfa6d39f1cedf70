"""bench/bench_selection_gap.py: rebuilt objects are scored, lost slots get their cause, bad input is a clear error."""

import pickle
from pathlib import Path

import numpy as np
import trimesh

from bench import bench_selection_gap as gap  # noqa: E402


def write_object(cache: Path, swapped: bool) -> None:
    """Two 4 cm boxes side by side (prompt 0 = the one at x < 0), three grasps across each; the coarse votes name
    the boxes right, or (`swapped`) each box by the other prompt."""
    boxes = [trimesh.creation.box((0.04, 0.04, 0.04)) for _ in range(2)]
    boxes[0].apply_translation((-0.03, 0, 0))
    boxes[1].apply_translation((0.03, 0, 0))
    mesh = trimesh.util.concatenate(boxes)
    truth = np.repeat([0, 1], len(boxes[0].faces))
    coarse = np.zeros((len(truth), 2))
    coarse[np.arange(len(truth)), truth if not swapped else 1 - truth] = 1.0
    contacts = np.array([[[x + dx, -0.02, z], [x + dx, 0.02, z]] for x in (-0.03, 0.03)
                         for dx, z in ((-0.01, 0.0), (0.0, 0.005), (0.01, -0.005))])
    poses = np.repeat(np.eye(4)[None], len(contacts), axis=0)
    poses[:, :3, :3] = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # closing along y, from above
    poses[:, :3, 3] = contacts.mean(axis=1)
    record = dict(seed=0, object_id="two_boxes", prompts=["left", "right"], vertices=mesh.vertices, faces=mesh.faces,
                  coarse=coarse, truth=truth, partitions=[(0.05, truth.copy())],
                  grasps=(poses, np.full(len(contacts), 0.04), np.linspace(1, 0.5, len(contacts)), contacts))
    cache.mkdir(parents=True, exist_ok=True)
    (cache / "0-two_boxes.pkl").write_bytes(pickle.dumps(record))


def test_right_votes_select_on_part_and_lose_nothing(tmp_path) -> None:
    write_object(tmp_path, swapped=False)
    objects = gap.load_objects(tmp_path)
    ours, oracle = gap.score(objects, gap.baseline), gap.score(objects, gap.oracle)
    assert ours == oracle == {(0, "two_boxes", "left"): (0.3, 3), (0, "two_boxes", "right"): (0.3, 3)}
    lost_by, _ = gap.diagnose(objects)
    assert sum(lost_by.values()) == 0


def test_swapped_votes_lose_every_slot_to_labels_that_miss_the_part(tmp_path) -> None:
    write_object(tmp_path, swapped=True)
    objects = gap.load_objects(tmp_path)
    assert all(v == (0.0, 3) for v in gap.score(objects, gap.baseline).values())
    lost_by, per_request = gap.diagnose(objects)
    assert {key: n for key, n in lost_by.items() if n} == {("grasp with no pad on the part", "A"): 6.0}
    assert per_request[("two_boxes", "left")][:2] == [3, 3]
    by_argmax, by_assignment = gap.evidence_bound(objects)
    assert set(by_argmax.values()) == set(by_assignment.values()) == {(0.0, 0)}


def test_bad_input_is_a_clear_error(tmp_path, capsys) -> None:
    assert gap.main(["--run", str(tmp_path), "--cache", str(tmp_path / "c"), "--out", str(tmp_path / "x.md")]) == 2
    assert "not a sim.evaluate output folder" in capsys.readouterr().err
    (tmp_path / "run.json").write_text('{"seeds": [0]}')
    (tmp_path / "trials.jsonl").write_text("")
    assert gap.main(["--run", str(tmp_path), "--cache", str(tmp_path / "c"), "--out", str(tmp_path / "x.md")]) == 2
    assert "nothing collected" in capsys.readouterr().err
    assert not (tmp_path / "x.md").exists()
