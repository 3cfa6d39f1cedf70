"""The simulated 2F-85 closes on boxes and cylinders at the true width, without sinking in, symmetrically."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from sim.cell import SimCell
from seggrasp.cell import DEFAULT_GRIP_FORCE, GRIP_FORCE_RANGE
from sim.gripper import PAD_THICKNESS, GripperSettings
from sim.primitives import primitive_object, top_down_grasp
from sim.world import COLLISION_SKIN

SIZES_MM = (10, 30, 60)
#: The real cell's former (and the issue's) reference setting.
FORCE_40N = 40.0


def _close_on(kind: str, size_mm: int, force: float, directory) -> tuple[float, float, float]:
    """(pad gap - true width, deepest penetration, asymmetry) in metres after closing on a resting object."""
    s = size_mm / 1000
    if kind == "box":
        obj = primitive_object("box", (s, 0.05, 0.06), directory, mass=0.2)
    else:
        obj = primitive_object("cylinder", (s / 2, 0.06), directory, mass=0.2)
    with SimCell([obj], embodiment="floating", seed=0, image_size=(64, 48), gripper=GripperSettings(force)) as cell:
        cell.reset(seed=1)
        _, T_world_obj = cell.object_mesh()
        gripper = cell.robot.gripper
        cell.robot.place(top_down_grasp(T_world_obj, 0.04) @ np.linalg.inv(gripper.T_base_tcp(s)))
        gripper.set_width(min(s + 0.02, gripper.max_width))
        gripper.close_until_stall()
        cell.world.step(60)
        T_base_world = np.linalg.inv(cell.world.link_pose(gripper.body, gripper.base_link))
        left, right = (T_base_world @ cell.world.link_pose(gripper.body, link) for link in gripper.pad_links)
        gap = abs(left[0, 3] - right[0, 3]) - PAD_THICKNESS
        depths = [
            point[8]
            for side in gripper.fingertip_links
            for link in side
            for point in cell.world.client.getContactPoints(gripper.body, cell.object_body, linkIndexA=link)
        ]
        return gap - s - 2 * COLLISION_SKIN, -min(depths, default=0.0), gripper.finger_asymmetry()


@pytest.mark.parametrize("kind", ["box", "cylinder"])
@pytest.mark.parametrize("size_mm", SIZES_MM)
def test_closing_at_40n_stops_on_the_surface(kind, size_mm, tmp_path):
    width_error, penetration, asymmetry = _close_on(kind, size_mm, FORCE_40N, tmp_path)
    assert abs(width_error) < 0.001
    assert penetration < 0.0005
    assert asymmetry < 0.001


@pytest.mark.parametrize("kind", ["box", "cylinder"])
@pytest.mark.parametrize("size_mm", SIZES_MM)
def test_closing_at_the_maximum_force_keeps_the_width(kind, size_mm, tmp_path):
    width_error, penetration, asymmetry = _close_on(kind, size_mm, GRIP_FORCE_RANGE[1], tmp_path)
    assert abs(width_error) < 0.001
    assert asymmetry < 0.0015
    assert penetration < 0.0015


def test_closing_at_the_maximum_force_stays_on_the_surface(tmp_path):
    # with the floating gripper's base on a fixed constraint the light linkage sank 1.2-1.4 mm into 10 mm objects at
    # 235 N; on its gantry (a fixed-base chain, as the arm) it stays within 0.5 mm
    assert max(_close_on(kind, 10, GRIP_FORCE_RANGE[1], tmp_path)[1] for kind in ("box", "cylinder")) < 0.0005


def test_grip_force_is_a_setting_within_the_2f85_range_shared_with_the_real_cell():
    with open(Path(__file__).resolve().parents[1] / "hardware" / "cell.example.yaml") as handle:
        assert yaml.safe_load(handle)["gripper"]["force"] == DEFAULT_GRIP_FORCE
    assert GripperSettings().grip_force == DEFAULT_GRIP_FORCE
    with pytest.raises(ValueError, match="grip_force"):
        GripperSettings(grip_force=300.0)


def test_a_light_object_gets_the_solver_iterations_it_needs(tmp_path):
    """Issue 12: at 100 iterations a 20 g toothbrush squeezed at 100 N creeps out of the fingers during the lift
    (oracle 1/10 on its head, 10/10 at 300 iterations); heavier objects keep the faster setting."""
    from sim.world import PhysicsSettings, World

    settings = PhysicsSettings()
    light = primitive_object("box", (0.10, 0.012, 0.012), tmp_path, mass=0.02, object_id="light")
    heavy = primitive_object("box", (0.10, 0.03, 0.03), tmp_path, mass=0.3, object_id="heavy")
    for physics, model, expected in (
        (settings, light, settings.light_object_iterations), (settings, heavy, settings.solver_iterations),
        (PhysicsSettings(light_object_iterations=None), light, settings.solver_iterations),
    ):
        world = World(physics=physics)
        try:
            world.load_object(model, np.eye(4))
            assert world.client.getPhysicsEngineParameters()["numSolverIterations"] == expected
        finally:
            world.close()
    assert settings.light_object_iterations > settings.solver_iterations


@pytest.mark.slow
def test_the_floating_gripper_lifts_a_claw_hammer_by_its_handle():
    """Issue 12: with its base dragged by a fixed constraint the floating gripper dropped the twin's claw hammer
    from every top-3 grasp at 100 solver iterations (the pads' grip faded during the lift); the arm held them."""
    from seggrasp.episode import table_plane_in_object_frame
    from seggrasp.grasp.antipodal import AntipodalSampler
    from seggrasp.objects import load_asset_set

    try:
        objects = [o for o in load_asset_set("hammer") if o.object_id == "hammer_claw"]
    except (FileNotFoundError, ValueError) as exc:  # absent, or being regenerated (its own tests check it)
        pytest.skip(f"twin assets unavailable: {exc}")
    with SimCell(objects, embodiment="floating", seed=0, image_size=(64, 48)) as cell:
        cell.reset(seed=10884, object_id="hammer_claw")  # the quick CI profile's scene
        mesh, T_world_obj = cell.object_mesh()
        model = cell.current_object
        grasps = AntipodalSampler().generate(
            mesh, seed=0, table_plane=table_plane_in_object_frame(mesh, T_world_obj),
            center_of_mass=model.center_of_mass, mass=model.mass,
        ).transformed(T_world_obj)
        outcomes = []
        for index in range(2):
            cell.reset(seed=10884, object_id="hammer_claw")
            outcomes.append(cell.execute(grasps.poses[index], grasps.widths[index]))
        assert all(outcome.lifted for outcome in outcomes), [outcome.message for outcome in outcomes]


def test_the_pads_on_slides_trace_the_linkage_of_the_description():
    """The simulated fingertips hang on slides (`sim.gripper_urdf.slide_fingertips`); at every opening their pads sit
    where the description's six-bar linkage puts them, parallel, as on the real 2F-85."""
    from sim.gripper import Robotiq2F85
    from sim.gripper_urdf import ARC_ANGLES, GRIPPER_DESCRIPTION, PAD_LINKS, SIDES, simulated_urdf
    from sim.world import ROBOT_ASSETS, World

    world = World()
    try:
        c = world.client
        linkage = c.loadURDF(str(ROBOT_ASSETS / GRIPPER_DESCRIPTION), useFixedBase=True)  # relative mesh paths
        slid = world.load_robot(simulated_urdf(GRIPPER_DESCRIPTION))
        gripper = Robotiq2F85(world, slid, -1, GRIPPER_DESCRIPTION)
        joints = {c.getJointInfo(linkage, j)[1].decode(): j for j in range(c.getNumJoints(linkage))}
        links = {c.getJointInfo(linkage, j)[12].decode(): j for j in range(c.getNumJoints(linkage))}
        travels = gripper.arcs[0][0]
        assert np.all(np.diff(travels) > 0)
        for angle, travel in zip(ARC_ANGLES[::4], travels[::4]):
            for side in SIDES:
                c.resetJointState(linkage, joints[side[0]], angle)
                c.resetJointState(linkage, joints[side[2]], -angle)
            gripper.set_travel(travel)
            for name, pad in zip(PAD_LINKS, gripper.pad_links):
                expected, simulated = world.link_pose(linkage, links[name]), world.link_pose(slid, pad)
                assert np.abs(simulated[:3, 3] - expected[:3, 3]).max() < 1e-5
                assert np.abs(simulated[:3, :3] - expected[:3, :3]).max() < 1e-6  # parallel to the open pose's
    finally:
        world.close()
