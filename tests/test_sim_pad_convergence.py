"""With `CONVERGED_FINGERS` the twin's 2F-85 keeps its pads parallel while it squeezes and lifts, as the real one
does (sim.cell GraspPrimitive raises the solver iterations when the finger linkage has not converged)."""

import numpy as np
import pytest

from seggrasp.objects import load_asset_set
from sim.cell import SimCell
from sim.primitives import primitive_object, top_down_grasp
from sim.world import CONVERGED_FINGERS

IMAGE = (160, 120)
#: A real 2F-85's pads stay parallel; the twin's may tilt this much (deg) before it counts as unconverged.
MAX_PAD_TILT_DEG = 0.5


def pad_tilt_deg(cell: SimCell) -> float:
    """Angle (deg) between the two pads' approach axes."""
    gripper = cell.robot.gripper
    left, right = (cell.world.link_pose(gripper.body, link)[:3, 2] for link in gripper.pad_links)
    return float(np.rad2deg(np.arccos(np.clip(left @ right, -1.0, 1.0))))


def test_the_pads_stay_parallel_while_holding_a_box(tmp_path):
    # at 100 solver iterations the 100 N squeeze splayed the pads 3.5-5 deg apart at the fingertips on every grasp
    box = primitive_object("box", (0.04, 0.04, 0.08), tmp_path, mass=0.2)
    with SimCell([box], embodiment="arm", seed=0, image_size=IMAGE, physics=CONVERGED_FINGERS) as cell:
        _, T_world_obj = cell.object_mesh()
        outcome = cell.execute(top_down_grasp(T_world_obj, 0.06), 0.04)
        assert outcome.lifted, outcome.message
        assert pad_tilt_deg(cell) < MAX_PAD_TILT_DEG


@pytest.fixture(scope="module")
def stubby():
    return [o for o in load_asset_set() if o.object_id == "screwdriver_stubby"]


def shaft_grasp(T_world_obj: np.ndarray) -> np.ndarray:
    """A level top-down grasp across the stubby screwdriver's 6 mm shaft (its axis is the object's x, 15.8 mm
    above its base; the pads' centres 8.5 mm above it, as the sampler's level grasps place them)."""
    T_obj_grasp = np.eye(4)
    T_obj_grasp[:3, 0] = [0.0, 1.0, 0.0]
    T_obj_grasp[:3, 2] = [0.0, 0.0, -1.0]
    T_obj_grasp[:3, 1] = np.cross(T_obj_grasp[:3, 2], T_obj_grasp[:3, 0])
    T_obj_grasp[:3, 3] = [0.031, 0.0, 0.0243]
    return T_world_obj @ T_obj_grasp


@pytest.mark.parametrize("scene_seed", [51294, 7])
def test_a_screwdriver_shaft_squeezed_level_is_lifted_without_rolling(stubby, scene_seed):
    # a 57 g screwdriver has no torque about its own axis; with splayed pads its shaft was squeezed towards the
    # fingertips and rolled 24-83 deg in the fingers
    with SimCell(stubby, embodiment="arm", seed=0, image_size=IMAGE, physics=CONVERGED_FINGERS) as cell:
        cell.reset(seed=scene_seed, object_id="screwdriver_stubby")
        _, T_world_obj = cell.object_mesh()
        outcome = cell.execute(shaft_grasp(T_world_obj), 0.006)
        assert outcome.lifted, outcome.message
        assert pad_tilt_deg(cell) < MAX_PAD_TILT_DEG



def test_the_converged_fingers_option_reaches_the_twin_and_is_a_resume_key(tmp_path, capsys):
    import json

    from seggrasp.objects import load_asset
    from sim.evaluate import main
    from sim.evaluate.cli import build_config, parse_args
    from sim.evaluate.config import RunConfig
    from sim.evaluate.records import prepare_out
    from sim.evaluate.runner import _get_cell, close_cell

    config = build_config(parse_args(["--methods", "oracle", "--objects", "mug_classic", "--embodiment", "floating",
                                      "--converged-fingers"]))
    assert config.converged_fingers
    prepare_out(tmp_path, config, resume=False)
    assert json.loads((tmp_path / "run.json").read_text())["converged_fingers"] is True
    with pytest.raises(ValueError, match="converged_fingers"):  # a resumed run keeps its solver settings
        prepare_out(tmp_path, RunConfig(**dict(vars(config), converged_fingers=False)), resume=True)
    try:
        cell = _get_cell(config.at_seed(0), load_asset("mug_classic"))
        assert cell.world.physics.pad_tilt_tolerance_deg == CONVERGED_FINGERS.pad_tilt_tolerance_deg
    finally:
        close_cell()
    real = ["--backend", "real", "--config", "cell.yaml", "--detector", "owlv2", "--weights", "w",
            "--objects", "mug", "--prompts", "handle", "--methods", "coarse"]
    assert main([*real, "--converged-fingers"]) == 2
    assert "real cell has no solver" in capsys.readouterr().err
