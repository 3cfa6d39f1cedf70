"""Task-oriented grasping in clutter, in the twin: a `SimCell` scene of several objects (`sim.scenes`), grasps that
keep clear of the other objects, the disturbance each trial records, and `python -m sim.evaluate --scene`."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

from seggrasp.objects import load_asset, load_asset_set
from sim.cell import SimCell
from sim.evaluate import main

IDS = ("mug_classic", "hammer_claw", "bottle_water", "knife_chef", "spatula_turner")


@pytest.fixture(scope="module")
def objects():
    return [load_asset(object_id) for object_id in IDS]


@pytest.fixture(scope="module")
def packed(objects):
    cell = SimCell(objects=objects, scene="packed", objects_per_scene=3, seed=3)
    cell.reset(seed=3, object_id="mug_classic")
    yield cell
    cell.close()


def top_down(position: np.ndarray) -> np.ndarray:
    return np.array([[1.0, 0, 0, position[0]], [0, -1.0, 0, position[1]], [0, 0, -1.0, position[2]], [0, 0, 0, 1.0]])


def test_the_requested_object_is_among_the_scene_s_others_and_its_mesh_is_the_one_given(packed):
    plan = packed.scene_plan
    assert plan.object_ids[0] == "mug_classic" and len(set(plan.object_ids)) == 3
    assert [name for _, name in packed.neighbours] == list(plan.object_ids[1:])
    mesh, T_world_obj = packed.object_mesh()
    assert mesh is packed.current_object.mesh and packed.current_object.object_id == "mug_classic"
    np.testing.assert_allclose(T_world_obj, packed.world.body_pose(packed.object_body))
    for body, _ in packed.neighbours:  # apart from the target, on the table
        assert np.linalg.norm(packed.world.body_pose(body)[:2, 3] - T_world_obj[:2, 3]) > 0.03


def test_a_grasp_whose_approach_would_hit_a_neighbour_is_refused(packed):
    body, name = packed.neighbours[0]
    lowest = packed.world.client.getAABB(body)[0]
    centre = np.mean(packed.world.client.getAABB(body), axis=0)
    refusal = packed.check_reach(top_down(np.array([centre[0], centre[1], lowest[2] + 0.02])), 0.02)
    assert f"robot would hit the {name} beside the object" in refusal
    alone = SimCell(objects=[packed.current_object], seed=3)
    try:  # the same pose with nothing there: only the table and the object count
        assert name not in alone.check_reach(top_down(np.array([centre[0], centre[1], lowest[2] + 0.02])), 0.02)
    finally:
        alone.close()


def test_an_executed_grasp_reports_how_far_each_other_object_moved(packed):
    mesh, T_world_obj = packed.object_mesh()
    world_mesh = mesh.copy().apply_transform(T_world_obj)
    starts = [packed.world.body_pose(body)[:3, 3] for body, _ in packed.neighbours]
    outcome = packed.execute(top_down(world_mesh.bounds.mean(axis=0)), 0.08)  # into the mug's body
    assert len(outcome.disturbance) == 2 and all(d >= 0 for d in outcome.disturbance)
    moved = [np.linalg.norm(packed.world.body_pose(body)[:3, 3] - start)
             for (body, _), start in zip(packed.neighbours, starts)]
    np.testing.assert_allclose(outcome.disturbance, moved, atol=1e-6)
    assert outcome.lifted_along == 0
    record = outcome.to_json()
    assert record["disturbance"] == [float(d) for d in outcome.disturbance] and record["lifted_along"] == 0
    packed.reset(seed=3, object_id="mug_classic")


def test_an_object_alone_records_no_disturbance(objects):
    cell = SimCell(objects=objects[:1], seed=0)
    try:
        outcome = cell.execute(top_down(np.array([0.0, 0.0, 0.5])), 0.02)
    finally:
        cell.close()
    assert outcome.disturbance == () and "disturbance" not in outcome.to_json()


def test_bad_scenes_are_refused(objects):
    with pytest.raises(ValueError, match="unknown scene 'heap'"):
        SimCell(objects=objects, scene="heap")
    with pytest.raises(ValueError, match="a scene holds 2-6 objects, got 7"):
        SimCell(objects=objects, scene="pile", objects_per_scene=7)


def test_the_gym_env_gives_the_scene(objects):
    env = gym.make("SegGrasp-v0", objects=objects, scene="pile", objects_per_scene=3)
    try:
        env.reset(seed=1)
        cell = env.unwrapped.cell
        mesh, T_world_obj = cell.object_mesh()
        centre = mesh.copy().apply_transform(T_world_obj).bounds.mean(axis=0)
        action = np.array([*centre, np.pi, 0.0, 0.0, 0.04], dtype=np.float32)
        _, _, terminated, _, info = env.step(action)
    finally:
        env.close()
    assert terminated and info["scene"]["kind"] == "pile" and len(info["scene"]["object_ids"]) == 3
    assert len(info["outcome"]["disturbance"]) == 2


def test_evaluate_runs_a_packed_scene_and_reports_the_other_objects(tmp_path):
    out = tmp_path / "run"
    argv = ["--scene", "packed", "--objects-per-scene", "3", "--objects", "mug_classic", "--methods", "oracle",
            "--top-k", "1", "--embodiment", "arm", "--out", str(out)]
    assert main(argv) == 0
    trials = [json.loads(line) for line in (out / "trials.jsonl").read_text().splitlines()]
    assert trials and all(t["extra"]["scene"]["object_ids"][0] == "mug_classic" for t in trials)
    assert all(len(t["extra"]["scene"]["object_ids"]) == 3 for t in trials)
    executed = [t for t in trials if t["executed"]]
    assert executed and all(len(t["outcome"]["disturbance"]) == 2 for t in executed)
    summary = (out / "summary.md").read_text()
    assert "scene: packed, 3 objects" in summary and "## The other objects on the table" in summary
    assert json.loads((out / "run.json").read_text())["scene"] == "packed"
    assert main(["--resume", "--scene", "pile", "--out", str(out)]) == 2  # a resumed run keeps its scene


@pytest.mark.parametrize("argv, message", [
    (["--objects-per-scene", "3"], "--objects-per-scene sets a scene's size: it needs --scene packed|pile"),
    (["--scene", "packed", "--objects-per-scene", "7"], "--objects-per-scene must be 2-6"),
    (["--backend", "real", "--config", "hardware/cell.example.yaml", "--detector", "owlv2", "--weights", "w",
      "--prompts", "handle", "--scene", "packed", "--objects-per-scene", "3"],
     "--objects-per-scene lays out the twin's table; a real cell's holds what its operator put there"),
])
def test_bad_scene_arguments_get_one_sentence(argv, message, capsys, tmp_path):
    assert main([*argv, "--objects", "mug_classic", "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1


def test_a_pile_settles_clear_of_the_parked_robot():
    """Without the robot's wrist and gripper out of the way, this pile's ball-peen hammer came to rest leaning on
    the 2F-85's knuckle at home, 25 cm above the table; with the whole robot out of the way, a jar rolled 4 cm into
    the arm's base."""
    cell = SimCell(objects=load_asset_set(), scene="pile", objects_per_scene=4, seed=1)
    try:
        cell.reset(seed=1, object_id="mug_classic")
        assert cell.scene_plan.object_ids == ("mug_classic", "frying_pan_20", "bottle_beer", "hammer_ballpeen")
        bodies = [cell.object_body] + [body for body, _ in cell.neighbours]
        assert not any(cell.world.client.getClosestPoints(body, cell.robot.body, distance=0.0) for body in bodies)
        assert max(cell.world.client.getAABB(body)[1][2] for body in bodies) < 0.2  # nothing props a body up
        cell.reset(seed=4, object_id="hammer_claw")  # its jar rolls off the pile to the arm's base and stops there
        jar = dict((name, body) for body, name in cell.neighbours)["bottle_jar"]
        assert cell.world.client.getClosestPoints(jar, cell.robot.body, 0.001)  # against the base, not inside it
        assert min(p[8] for p in cell.world.client.getClosestPoints(jar, cell.robot.body, 0.001)) > -0.005
        cell.robot.reset_home(cell.hand.stroke)
        for _ in range(240):
            cell.world.step()
        assert all(np.linalg.norm(cell.world.client.getBaseVelocity(body)[0]) < 0.05 for body in bodies)
    finally:
        cell.close()


def test_a_real_cell_among_other_objects_finds_its_object_by_the_name_given() -> None:
    """`--scene` on a real cell: the operator laid out the table; the run searches for the object by its --objects
    name and records only the scene's kind."""
    from seggrasp.episode import TrialRecord
    from sim.evaluate.cli import build_config, parse_args
    from sim.evaluate.runner import record_extra, subject_of

    config = build_config(parse_args([
        "--backend", "real", "--config", "hardware/cell.example.yaml", "--detector", "owlv2", "--weights", "w",
        "--objects", "coffee_mug", "--prompts", "handle,body", "--methods", "seggrasp", "--scene", "pile"]))
    assert (config.scene, config.objects_per_scene, config.perceive) == ("pile", None, True)
    context, truth = subject_of("coffee_mug", config, cell=None)
    assert truth is None and context.object_name == "coffee mug" and context.prompts == ["handle", "body"]
    record = TrialRecord(object_id="coffee_mug", category="real", method="seggrasp", detector="owlv2",
                         prompt="handle", prompt_index=0, rank=0, seed=0, scene_seed=0, n_candidates=0, executed=False)
    record_extra(record, config, cell=None)
    assert record.extra["scene"] == {"kind": "pile"}
