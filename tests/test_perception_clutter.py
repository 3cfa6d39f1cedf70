"""Perception among several objects: instances split from the twin's camera frames, the target picked by detector
boxes on the camera images (`seggrasp.target`), and the twin's object detector on those images."""

from __future__ import annotations

import json

import numpy as np
import pytest

from seggrasp.cell import Frame
from seggrasp.cloud import radius_components
from seggrasp.detect.base import Detections
from seggrasp.detect.simulated import PRESETS, SimulatedObjectDetector
from seggrasp.episode import Episode, EpisodeContext, EpisodeSettings, action_slot
from seggrasp.objects import load_asset, load_asset_set
from seggrasp.perception import OrientedCloud, PerceptionConfig, instance_labels, mesh_of, split_instances
from seggrasp.target import camera_views, find_target, instance_iou, true_bodies, visible_pixels
from seggrasp.truth import DetectorSpec, GroundTruth
from seggrasp.views import View
from sim.cell import SimCell
from sim.evaluate import main
from sim.evaluate.runner import workspace_of

IDS = ("mug_classic", "hammer_claw", "bottle_water")
#: Where the three objects are moved to, well apart (more than `PerceptionConfig.cluster_link`).
SPOTS = ((0.45, -0.12), (0.45, 0.12), (0.6, 0.0))


@pytest.fixture(scope="module")
def scene():
    """A packed scene of the mug, the hammer and the bottle, the objects moved apart; its frames and truth."""
    cell = SimCell(objects=[load_asset(i) for i in IDS], embodiment="floating", scene="packed", objects_per_scene=3,
                   seed=3, image_size=(320, 240))
    try:
        cell.reset(seed=3, object_id="mug_classic")
        truth = cell.scene_truth()
        for body, (x, y) in zip(truth.names, SPOTS):
            position, orientation = cell.world.client.getBasePositionAndOrientation(body)
            cell.world.client.resetBasePositionAndOrientation(body, [x, y, position[2]], orientation)
        frames = cell.capture()
        mug = cell.current_object.mesh.copy().apply_transform(cell.world.body_pose(cell.object_body))
        yield frames, truth, split_instances(frames, cell.workspace), mug
    finally:
        cell.close()


class NoBoxes:
    """A detector that finds nothing."""

    name = "none"

    def detect(self, views, prompts):
        return [Detections.empty() for _ in views]


def test_the_twin_s_frames_say_which_body_each_pixel_shows(scene):
    frames, truth, *_ = scene
    for frame in frames:
        assert frame.instance_ids.shape == frame.depth.shape
        assert set(truth.names) <= set(np.unique(frame.instance_ids).tolist())
        assert np.all(frame.depth[frame.instance_ids < 0] == 0)  # nothing rendered, no reading
    assert sorted(truth.names.values()) == ["bottle", "hammer", "mug"] and truth.names[truth.target] == "mug"


def test_three_objects_apart_are_three_instances_each_one_body(scene):
    frames, truth, instances, *_ = scene
    assert len(instances) == 3
    matched = []
    for index in range(3):
        ious = {body: instance_iou(instances, index, body) for body in truth.names}
        best = max(ious, key=ious.get)
        print(f"instance {index}: {len(instances[index].points)} points, IoU {ious}")
        assert ious[best] > 0.8
        matched.append(best)
    assert sorted(matched) == sorted(truth.names)
    assert all(instance.frames is instances[0].frames for instance in instances)


def test_one_instance_alone_reconstructs_its_object(scene):
    frames, truth, instances, truth_mesh = scene
    mug = max(range(3), key=lambda k: instance_iou(instances, k, truth.target))
    mesh = mesh_of(instances[mug])
    assert mesh.is_watertight
    np.testing.assert_allclose(mesh.bounds[:, 2], truth_mesh.bounds[:, 2], atol=0.01)
    np.testing.assert_allclose(mesh.bounds, truth_mesh.bounds, atol=0.03)  # two cameras on one side: hull-filled


def test_a_perfect_detector_picks_each_named_object(scene):
    frames, truth, instances, *_ = scene
    detector = SimulatedObjectDetector(truth.names, preset="perfect")
    for body, name in truth.names.items():
        search = find_target(instances, detector, name)
        assert search.found and len(search.scores) == 3
        assert max(range(3), key=lambda k: instance_iou(instances, k, body)) == search.index
        others = [s for k, s in enumerate(search.scores) if k != search.index]
        assert search.scores[search.index] > 3 * max(others)


def test_the_typical_detector_picks_the_mug_for_most_seeds(scene):
    frames, truth, instances, *_ = scene
    mug = max(range(3), key=lambda k: instance_iou(instances, k, truth.target))
    picks = [find_target(instances, SimulatedObjectDetector(truth.names, "typical", seed), "mug").index
             for seed in range(10)]
    print("typical picks", picks)
    assert sum(p == mug for p in picks) >= 8


def test_no_box_means_not_found(scene):
    frames, truth, instances, *_ = scene
    for detector, prompt in [(NoBoxes(), "mug"), (SimulatedObjectDetector(truth.names, "perfect"), "teapot")]:
        search = find_target(instances, detector, prompt)
        assert not search.found and search.index is None and search.scores == (0.0, 0.0, 0.0)


def test_bad_target_searches_name_the_problem(scene):
    frames, truth, instances, *_ = scene
    with pytest.raises(ValueError, match="prompt is empty"):
        find_target(instances, NoBoxes(), " ")
    with pytest.raises(ValueError, match="no instances"):
        find_target([], NoBoxes(), "mug")
    bare = [Frame(f.name, f.rgb, f.depth, f.K, f.T_world_cam) for f in frames]
    with pytest.raises(ValueError, match="no instance ids"):
        true_bodies(instances[0].points, bare)
    with pytest.raises(ValueError, match="named bodies"):
        SimulatedObjectDetector({})
    assert np.all(camera_views(bare)[0].face_ids == -1)  # a real cell's images say nothing about bodies


def test_a_point_behind_the_measured_depth_is_hidden():
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    frame = Frame("flat", np.zeros((100, 100, 3), np.uint8), np.full((100, 100), 1.0, np.float32), K, np.eye(4))
    frame.depth[0, 0] = 0.0  # no reading there
    points = np.array([[0, 0, 1.005], [0, 0, 1.05], [0.1, 0.1, 0.5], [0, 0, -1.0], [5.0, 0, 1.0], [-0.5, -0.5, 1.0]])
    u, v, visible = visible_pixels(points, frame, depth_tolerance=0.01)
    assert visible.tolist() == [True, False, True, False, False, True]
    assert (u[0], v[0], u[2], v[2]) == (50, 50, 70, 70)


class OneBox:
    """A detector that boxes the same pixels in every image."""

    name = "one box"

    def __init__(self, box):
        self.box = box

    def detect(self, views, prompts):
        return [Detections(np.array([self.box], float), np.array([0.9]), np.array([0])) for _ in views]


def test_a_small_object_inside_a_large_one_s_box_does_not_win_its_request():
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    frame = Frame("flat", np.zeros((100, 100, 3), np.uint8), np.full((100, 100), 2.0, np.float32), K, np.eye(4))
    grid = np.stack(np.meshgrid(np.linspace(-0.3, 0.3, 13), np.linspace(-0.3, 0.3, 13)), -1).reshape(-1, 2)
    pan = np.c_[grid, np.ones(len(grid))]  # pixels 20-80 at 1 m
    cup = np.c_[grid[::4] * 0.1 + 0.1, np.ones(len(grid[::4]))]  # a few pixels around (60, 60)
    frames = [frame]
    clouds = [OrientedCloud(points, np.tile([0, 0, -1.0], (len(points), 1)), np.array([0, 0, 1.0]), 0.0, 0.004,
                            frames) for points in (cup, pan)]
    search = find_target(clouds, OneBox([20, 20, 81, 81]), "frying pan")  # the pan's box holds all of the cup
    assert search.index == 1 and search.scores[1] > 0.85 and search.scores[0] < 0.05

def _flat_instance(points: np.ndarray) -> tuple[Frame, OrientedCloud]:
    """One 100 x 100 camera at the origin looking along +z (f = 100 px) and one instance of points at z = 1 m."""
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    frame = Frame("flat", np.zeros((100, 100, 3), np.uint8), np.full((100, 100), 2.0, np.float32), K, np.eye(4))
    normals = np.tile([0, 0, -1.0], (len(points), 1))
    return frame, OrientedCloud(points, normals, np.array([0, 0, 1.0]), 0.0, 0.004, [frame])


def test_touching_objects_seen_as_one_instance_are_cut_by_the_target_s_boxes():
    grid = np.stack(np.meshgrid(np.linspace(-0.3, 0.0, 7), np.linspace(-0.3, 0.3, 13)), -1).reshape(-1, 2)
    target = np.c_[grid, np.ones(len(grid))]  # pixels 20-50
    other = np.c_[grid[:, 0] + 0.4, grid[:, 1], np.ones(len(grid))]  # pixels 60-90, touching it in 3-D
    _, merged = _flat_instance(np.r_[target, other])
    search = find_target([merged], OneBox([20, 20, 51, 81]), "spatula")
    assert search.index == 0 and len(search.instances) == 2
    np.testing.assert_array_equal(search.instances[0].points, target)
    np.testing.assert_array_equal(search.instances[1].points, other)  # an obstacle like the other instances
    assert len(search.instances[0].normals) == len(target)


def test_a_box_around_a_small_part_of_the_instance_does_not_cut_it():
    grid = np.stack(np.meshgrid(np.linspace(-0.3, 0.3, 13), np.linspace(-0.3, 0.3, 13)), -1).reshape(-1, 2)
    _, instance = _flat_instance(np.c_[grid, np.ones(len(grid))])
    search = find_target([instance], OneBox([20, 20, 31, 31]), "pan")  # would keep 9 of 169 points
    assert search.found and search.instances == [instance]
    assert find_target([instance], OneBox([18, 18, 83, 83]), "pan").instances == [instance]  # nothing outside


def _two_bodies_view() -> View:
    ids = np.full((120, 160), -1, dtype=np.int64)
    ids[20:60, 10:50] = 7  # the named target
    ids[40:100, 90:150] = 9  # another object
    return View(np.zeros((120, 160, 3), np.uint8), ids, np.eye(3), np.eye(4))


def test_perfect_object_boxes_are_tight_and_the_typical_error_model_follows_its_preset():
    view = _two_bodies_view()
    perfect = SimulatedObjectDetector({7: "mug", 9: "bottle"}, "perfect").detect([view], ["Mug", "teapot"])[0]
    np.testing.assert_array_equal(perfect.boxes, [[10, 20, 50, 60]])
    assert perfect.scores.tolist() == [1.0] and perfect.prompt_index.tolist() == [0]
    typical = PRESETS["typical"]
    misses, false_boxes = 0, []
    for seed in range(400):
        found = SimulatedObjectDetector({7: "mug", 9: "bottle"}, "typical", seed).detect([view], ["mug"])[0]
        on_target = (found.boxes[:, 0] + found.boxes[:, 2]) / 2 < 70
        misses += not on_target.any()
        false_boxes += found.scores[~on_target].tolist()
        assert on_target.sum() <= 1
    # the target is 31 % of the objects' pixels: fully prominent, so it is missed at the preset's miss_rate
    assert abs(misses / 400 - typical.miss_rate) < 0.05
    assert abs(len(false_boxes) / 400 - typical.false_boxes) < 0.08  # each around the other object
    assert all(typical.false_confidence[0] <= s <= typical.false_confidence[1] for s in false_boxes)
    once, again = (SimulatedObjectDetector({7: "mug", 9: "bottle"}, "typical", 3).detect([view], ["mug"])[0]
                   for _ in range(2))
    np.testing.assert_array_equal(once.boxes, again.boxes)  # a seed repeats its errors


def _box_surface(low, high, step=0.002) -> np.ndarray:
    """Points on the top and the four sides of an axis-aligned box (m), `step` apart."""
    xs, ys, zs = (np.arange(a, b + 1e-9, step) for a, b in zip(low, high))
    top = np.array([(x, y, high[2]) for x in xs for y in ys])
    sides = [np.array([(x, y, z) for x in xs for z in zs]) for y in (low[1], high[1])]
    sides += [np.array([(x, y, z) for y in ys for z in zs]) for x in (low[0], high[0])]
    return np.concatenate([top, *sides])


def test_objects_a_few_millimetres_apart_are_separate_instances_and_fragments_join_the_nearest():
    config = PerceptionConfig()
    left = _box_surface((0.0, 0.0, 0.0), (0.05, 0.05, 0.06))
    right = _box_surface((0.058, 0.0, 0.0), (0.1, 0.05, 0.04))  # 8 mm beside it, shorter
    bowl = _box_surface((0.0, 0.0, 0.075), (0.05, 0.05, 0.08))  # 15 mm above the left box, not on the table
    speck = np.array([[0.3, 0.3, 0.1]] * 5) + np.arange(5)[:, None] * 0.001
    points = np.concatenate([left, right, bowl, speck])
    parts = np.repeat([0, 1, 2, 3], [len(left), len(right), len(bowl), len(speck)])
    assert len(np.unique(radius_components(points[parts < 2], config.cluster_link))) == 1  # one object's links
    labels = instance_labels(points, points[:, 2], config)
    assert labels.max() == 1
    assert len(set(labels[parts == 0])) == 1 and len(set(labels[parts == 1])) == 1
    assert labels[parts == 0][0] == 0 != labels[parts == 1][0]  # the larger one first
    assert np.all(labels[parts == 2] == 0) and np.all(labels[parts == 3] == -1)
    assert np.all(instance_labels(points[parts >= 2], points[parts >= 2][:, 2], config) == -1)  # nothing rests


def test_a_packed_scene_as_it_settled_is_split_into_its_objects():
    """The twin's packed scene of seed 0 for the tall mug: mug, eyeglasses, wine glass and toothbrush 5-30 mm
    apart, seen by the two cameras at their full resolution."""
    cell = SimCell(objects=load_asset_set(), scene="packed", objects_per_scene=4, seed=0)
    try:
        cell.reset(seed=0, object_id="mug_tall")
        truth = cell.scene_truth()
        instances = split_instances(cell.capture(), cell.workspace)
    finally:
        cell.close()
    assert sorted(truth.names.values()) == ["eyeglasses", "mug", "toothbrush", "wine glass"]
    assert len(instances) == 4
    best = {body: max(range(4), key=lambda k: instance_iou(instances, k, body)) for body in truth.names}
    ious = {truth.names[body]: instance_iou(instances, k, body) for body, k in best.items()}
    print("IoU per object", ious)
    assert len(set(best.values())) == 4 and min(ious.values()) > 0.8 and ious["mug"] > 0.95


class NoObjectSpec:
    """A detector choice whose detector never boxes anything on the cameras' images."""

    label = "none"

    def for_scene(self, scene):
        return NoBoxes()


def packed_mug_episode(detector, top_k: int) -> tuple[SimCell, Episode]:
    """The mug among the hammer and the bottle as packed (seed 3), and a perceiving episode for it among others."""
    cell = SimCell(objects=[load_asset(i) for i in IDS], embodiment="floating", scene="packed", objects_per_scene=3,
                   seed=3, image_size=(320, 240))
    cell.reset(seed=3, object_id="mug_classic")
    model = cell.current_object
    context = EpisodeContext.from_object(model, 3)
    truth = GroundTruth.of_object(model, context.prompts, lambda: cell.object_mesh()[1], cell.scene_truth)
    settings = EpisodeSettings(top_k=top_k, perceive=True, workspace=workspace_of(cell), among_others=True)
    return cell, Episode(cell, context, detector, truth, settings)


def test_a_target_the_detector_finds_in_no_instance_fails_every_slot_as_not_found():
    cell, episode = packed_mug_episode(NoObjectSpec(), top_k=2)
    context = episode.context
    try:
        records = episode.run("oracle")
    finally:
        cell.close()
    assert len(records) == 2 * len(context.prompts)
    assert all(r.failure == "not_found" and not r.executed and r.success is False for r in records)
    assert all(r.target_found is False and r.target_iou is None for r in records)
    assert records[0].message == "the detector found the mug in none of the 3 objects on the table"


def test_evaluate_finds_the_object_among_others_from_the_cameras(tmp_path):
    out = tmp_path / "run"
    argv = ["--scene", "packed", "--objects-per-scene", "3", "--objects", "mug_classic", "--methods", "oracle",
            "--top-k", "1", "--perceive", "--detector", "perfect", "--out", str(out)]
    assert main(argv) == 0
    trials = [json.loads(line) for line in (out / "trials.jsonl").read_text().splitlines()]
    assert trials and all(t["target_found"] is True and t["target_iou"] > 0.8 for t in trials)
    summary = json.loads((out / "summary.json").read_text())
    search = summary["methods"]["oracle"]["target_search"]["packed"]
    assert search["found"] == 1.0 and search["requests"] == 2 and search["instance_iou"] > 0.8
    assert "## Finding the object among the others" in (out / "summary.md").read_text()


def test_grasps_that_would_hit_another_object_seen_are_refused_before_the_cell_moves():
    """A packed scene (mug, hammer, bottle 5-30 mm apart): of the mug's grasps, those whose open hand along the
    approach or closed fingers would take in another instance's points are refused without reaching the cell, and
    recorded as collisions; the twin's own check, which knows the true bodies, refuses most of them too."""
    cell, episode = packed_mug_episode(DetectorSpec("simulated", preset="perfect", seed=3), top_k=1)
    try:
        grasps = episode.grasps().transformed(episode.observation.T_world_obj)
        assert episode.observation.search.found and len(grasps) > 50
        picked = np.linspace(0, len(grasps) - 1, 60).astype(int)
        clear = np.array([episode.clears_others(grasps.poses[i], float(grasps.widths[i])) for i in picked])
        assert clear.any() and not clear.all()
        refused = picked[~clear]
        twin_refuses = [bool(cell.check_reach(grasps.poses[i], float(grasps.widths[i]))) for i in refused]
        print(f"{len(refused)} of {len(picked)} grasps refused as hitting another object; the twin's check refuses "
              f"{sum(twin_refuses)} of them")
        assert sum(twin_refuses) >= 0.5 * len(refused)
        first = refused[0]
        assert not episode.reaches(grasps.poses[first], float(grasps.widths[first]))
        record = episode.execute(action_slot(0, grasps.poses[first], float(grasps.widths[first])))
    finally:
        cell.close()
    assert record.failure == "collision" and not record.reachable and not record.lifted
    assert record.message == "refused: the hand would hit another object the cameras saw on the table"
