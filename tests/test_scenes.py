"""Multi-object scenes (`sim.scenes`): seeded plans, packed footprints apart, settled scenes on the table."""

import json

import numpy as np
import pytest
from scipy.spatial import ConvexHull, cKDTree

from sim import scenes
from sim.scenes import ScenePlan, penetrations, place_scene, plan_scene
from sim.world import TABLE_CENTER_XY, TABLE_SIZE, TABLE_TOP_Z, World

IDS = (
    "mug_classic", "mug_tall", "knife_chef", "hammer_claw", "bottle_water", "screwdriver_flat", "spatula_turner",
    "toothbrush_classic", "wine_glass_red",
)


@pytest.fixture(scope="module")
def objects():
    from seggrasp.objects import load_asset

    try:
        return [load_asset(i) for i in IDS]
    except (FileNotFoundError, ValueError) as exc:
        pytest.skip(f"twin not available: {exc}")


@pytest.fixture(scope="module")
def world():
    w = World()
    yield w
    w.close()


def _world_vertices(model, T):
    return model.mesh.vertices @ T[:3, :3].T + T[:3, 3]


def _boundary(model, T, step=0.0005):
    """Points every `step` m along the xy outline of the object's convex hull at pose T, and the outline's hull."""
    xy = np.vstack([model.mesh.vertices] + [h.vertices for h in model.collision_hulls]) @ T[:3, :3].T
    xy = xy[:, :2] + T[:2, 3]
    hull = ConvexHull(xy)
    corners = xy[hull.vertices]
    points = [
        a + np.outer(np.linspace(0, 1, max(2, int(np.linalg.norm(b - a) / step) + 1)), b - a)
        for a, b in zip(corners, np.roll(corners, -1, axis=0))
    ]
    return np.vstack(points), hull


@pytest.mark.parametrize("kind", scenes.KINDS)
def test_plans_are_deterministic_by_seed_and_differ_between_seeds(objects, kind):
    plan = plan_scene(objects, target_id="knife_chef", n_objects=4, kind=kind, seed=3)
    assert plan_scene(objects, target_id="knife_chef", n_objects=4, kind=kind, seed=3) == plan
    other = plan_scene(objects, target_id="knife_chef", n_objects=4, kind=kind, seed=4)
    assert other.poses != plan.poses
    assert (plan.kind, plan.seed, plan.target_id) == (kind, 3, "knife_chef")


def test_target_first_distractors_distinct_and_of_other_categories_first(objects):
    by_id = {o.object_id: o for o in objects}
    for seed in range(5):
        plan = plan_scene(objects, target_id="mug_classic", n_objects=6, kind="pile", seed=seed)
        assert plan.object_ids[0] == "mug_classic" and len(set(plan.object_ids)) == 6 == len(plan.poses)
        assert all(by_id[i].category != "mug" for i in plan.object_ids[1:])
        assert len({by_id[i].category for i in plan.object_ids}) == 6
    # with no other category left, a same-category distractor is taken
    few = [by_id["mug_classic"], by_id["mug_tall"], by_id["knife_chef"]]
    plan = plan_scene(few, target_id="knife_chef", n_objects=3, kind="packed", seed=0)
    assert plan.object_ids[0] == "knife_chef" and set(plan.object_ids) == {"knife_chef", "mug_classic", "mug_tall"}


@pytest.mark.parametrize("seed", range(4))
def test_packed_footprints_are_apart_and_close_together(objects, seed):
    by_id = {o.object_id: o for o in objects}
    plan = plan_scene(objects, target_id="hammer_claw", n_objects=5, kind="packed", seed=seed)
    outlines = [_boundary(by_id[i], plan.pose(k)) for k, i in enumerate(plan.object_ids)]
    nearest = np.full(len(outlines), np.inf)
    for a, (points_a, hull_a) in enumerate(outlines):
        for b, (points_b, hull_b) in enumerate(outlines[a + 1:], start=a + 1):
            # neither contains the other's points, and their outlines are a few mm apart
            assert (hull_a.equations[:, :2] @ points_b.T + hull_a.equations[:, 2:]).max(axis=0).min() > 0
            assert (hull_b.equations[:, :2] @ points_a.T + hull_b.equations[:, 2:]).max(axis=0).min() > 0
            gap = cKDTree(points_a).query(points_b)[0].min()
            assert gap > scenes.PACK_GAP[0] - 0.001
            nearest[[a, b]] = np.minimum(nearest[[a, b]], gap)
    assert nearest.max() < scenes.PACK_GAP[1] + 0.001  # every object has a neighbour within the gap
    for k, i in enumerate(plan.object_ids):  # upright, 1 mm above the table
        T = plan.pose(k)
        assert T[2, 2] == pytest.approx(1.0)
        assert _world_vertices(by_id[i], T)[:, 2].min() >= TABLE_TOP_Z


@pytest.mark.parametrize("kind", scenes.KINDS)
@pytest.mark.parametrize("seed", range(3))
def test_scenes_of_four_settle_on_the_table_without_interpenetrating(objects, world, kind, seed):
    by_id = {o.object_id: o for o in objects}
    plan = plan_scene(objects, target_id="screwdriver_flat", n_objects=4, kind=kind, seed=seed)
    world.reset()
    bodies = place_scene(world, by_id, plan, settle_time=3.0)
    assert len(bodies) == 4
    assert world.client.getDynamicsInfo(bodies[0], -1)[0] == pytest.approx(by_id["screwdriver_flat"].mass)
    assert penetrations(world, bodies) < 0.002
    half = np.divide(TABLE_SIZE[:2], 2)
    low, high = np.subtract(TABLE_CENTER_XY, half), np.add(TABLE_CENTER_XY, half)
    touching = 0  # contacts between packed objects
    for k, (body, object_id) in enumerate(zip(bodies, plan.object_ids)):
        T = world.body_pose(body)
        vertices = _world_vertices(by_id[object_id], T)
        assert vertices[:, 2].min() > TABLE_TOP_Z - 0.002, object_id
        assert (vertices[:, :2] > low).all() and (vertices[:, :2] < high).all(), object_id
        if kind == "packed":  # upright objects stay where they were put
            assert np.linalg.norm(T[:2, 3] - plan.pose(k)[:2, 3]) < 0.005, object_id
            touching += sum(bool(world.client.getContactPoints(body, other)) for other in bodies[k + 1:])
    assert touching == 0


def test_penetrations_measures_the_overlap_of_bodies(objects, world):
    by_id = {o.object_id: o for o in objects}
    world.reset()
    T = np.eye(4)
    T[:3, 3] = [0.5, 0.0, 0.1]
    a = world.load_object(by_id["mug_classic"], T)
    T[0, 3] += 0.03
    b = world.load_object(by_id["mug_tall"], T)
    assert penetrations(world, [a, b]) > 0.01  # 3 cm apart: their bodies overlap by centimetres
    assert penetrations(world, [a]) == 0.0


def test_bad_arguments_name_the_problem(objects, monkeypatch):
    for n in (1, 7):
        with pytest.raises(ValueError, match=f"n_objects must be between 2 and 6, got {n}"):
            plan_scene(objects, target_id="mug_classic", n_objects=n, kind="packed", seed=0)
    with pytest.raises(ValueError, match="target_id 'teapot' is not among the objects"):
        plan_scene(objects, target_id="teapot", n_objects=3, kind="packed", seed=0)
    with pytest.raises(ValueError, match="unknown scene kind 'heap'"):
        plan_scene(objects, target_id="mug_classic", n_objects=3, kind="heap", seed=0)
    monkeypatch.setattr(scenes, "PACK_HALF_SIZE", 0.12)
    with pytest.raises(ValueError, match="cannot pack 6 objects around the workspace centre"):
        plan_scene(objects, target_id="mug_classic", n_objects=6, kind="packed", seed=0)


def test_record_round_trips_through_json(objects):
    for kind in scenes.KINDS:
        plan = plan_scene(objects, target_id="bottle_water", n_objects=3, kind=kind, seed=7)
        again = ScenePlan.from_record(json.loads(json.dumps(plan.to_record())))
        assert again == plan
        np.testing.assert_array_equal(again.pose(2), plan.pose(2))
