"""ShapeGrasp's planned contacts are where its pads first touch the surface (the sampler's pad sweep), and a planned
grasp whose pads touch nothing is a Part Sel. failure of its slot."""

import numpy as np
import pytest
import trimesh

from seggrasp.baselines import shapegrasp_grasps
from seggrasp.cell import GraspOutcome
from seggrasp.episode import Episode, EpisodeContext, Slot, action_slot
from seggrasp.grasp import GraspSet
from seggrasp.grasp.pads import pad_contacts
from seggrasp.hands import ROBOTIQ_2F85
from seggrasp.truth import GroundTruth
from tests.cells import FixedMeshCell


def two_parts(first: trimesh.Trimesh, second: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray]:
    """One mesh of two parts and the part (also the prompt) of each face."""
    part_of_face = np.r_[np.zeros(len(first.faces), int), np.ones(len(second.faces), int)]
    return trimesh.util.concatenate([first, second]), part_of_face


def votes_for_parts(n_parts: int) -> np.ndarray:
    """Part-by-prompt votes that give prompt k part k."""
    return np.eye(n_parts) + 0.1


def box(extents, centre) -> trimesh.Trimesh:
    mesh = trimesh.creation.box(extents)
    mesh.apply_translation(centre)
    return mesh


def test_a_top_down_grasp_above_a_low_flat_part_touches_nothing_and_is_not_on_the_part() -> None:
    """A 3 mm plate on the table: the grasp is raised so the fingertips clear the table, the pads pass above the
    plate and close on air (the block beside it lies off the pads' 22 mm width)."""
    plate = box((0.06, 0.03, 0.003), (0.0, 0.0, 0.0015))
    block = box((0.03, 0.03, 0.08), (0.0, 0.05, 0.04))
    mesh, part_of_face = two_parts(plate, block)
    T_world_obj = np.eye(4)
    T_world_obj[:3, 3] = [0.5, 0.0, 0.0]
    plate_grasp = shapegrasp_grasps(mesh, votes_for_parts(2), part_of_face, T_world_obj)[0]
    assert len(plate_grasp) == 1
    assert np.isnan(plate_grasp.contacts).all()
    assert plate_grasp.widths[0] == pytest.approx(0.085)  # it closes from the full opening, on nothing
    truth = GroundTruth(mesh, part_of_face)
    world = plate_grasp.transformed(T_world_obj)
    assert truth.contacts_on_part(world.contacts[0], T_world_obj, False, 0) is False


def test_a_grasp_over_a_box_touches_where_the_pads_first_meet_its_faces() -> None:
    """A 30 mm box on a 50 mm one: at the upper box's centroid the pads reach down past its bottom and first meet
    the lower box's sides (a ray along the closing line would stop at the upper box's sides, 30 mm apart)."""
    lower = box((0.05, 0.05, 0.06), (0.0, 0.0, 0.03))
    upper = box((0.03, 0.03, 0.03), (0.0, 0.0, 0.075))
    mesh, part_of_face = two_parts(upper, lower)
    grasp = shapegrasp_grasps(mesh, votes_for_parts(2), part_of_face, np.eye(4))[0]
    origin = grasp.poses[0, :3, 3]
    assert origin == pytest.approx([0.0, 0.0, 0.075], abs=1e-9)
    contacts = grasp.contacts[0]
    assert contacts[:, 0] == pytest.approx([-0.025, 0.025], abs=1e-9)  # on the lower box's -x and +x faces
    assert np.all(contacts[:, 2] <= 0.06 + 1e-9) and np.all(contacts[:, 2] >= 0.075 - 0.01875 - 1e-9)
    assert np.all(np.abs(contacts[:, 1]) <= 0.011 + 1e-9)  # within the pads' width
    assert grasp.widths[0] == pytest.approx(0.05, abs=1e-9)
    truth = GroundTruth(mesh, part_of_face)
    assert truth.contacts_on_part(contacts, np.eye(4), False, 1) and not truth.contacts_on_part(contacts, np.eye(4),
                                                                                                   False, 0)


def test_pad_contacts_of_a_box_and_of_an_empty_sweep() -> None:
    mesh = box((0.04, 0.02, 0.02), (0.0, 0.0, 0.0))
    cloud, _ = trimesh.sample.sample_surface(mesh, 4000, seed=1)
    poses = np.repeat(np.eye(4)[None], 2, axis=0)
    poses[1, :3, 3] = [0.0, 0.0, 0.05]  # the pads 50 mm above the box: they sweep nothing
    hand = ROBOTIQ_2F85
    contacts, widths = pad_contacts(poses, hand.stroke, cloud, hand.pad_half_width, hand.pad_half_length)
    assert contacts[0, :, 0] == pytest.approx([-0.02, 0.02], abs=1e-9) and widths[0] == pytest.approx(0.04)
    assert np.isnan(contacts[1]).all() and np.isnan(widths[1])


def test_a_planned_grasp_that_touches_nothing_is_a_part_selection_failure() -> None:
    mesh = box((0.04, 0.04, 0.04), (0.0, 0.0, 0.02))
    labels = np.zeros(len(mesh.faces), int)  # the whole box is the prompted part
    cell = FixedMeshCell(mesh, GraspOutcome(True, False, 0.0), models_scene=False)  # reaches, never lifts
    episode = Episode(cell, EpisodeContext("box", "box", ["body"], scene_seed=0), None, GroundTruth(mesh, labels))
    above = np.eye(4)
    above[:3, 3] = [0.0, 0.0, 0.2]
    contactless = GraspSet(above[None], [0.085], [1.0], np.full((1, 2, 3), np.nan))
    record = episode.execute(Slot("shapegrasp", "simulated:typical", 0, 0, contactless, 1))
    assert record.executed and cell.executed == 1
    assert record.contacts_on_part is False and record.success is False
    # a grasp given from outside (the gym env's action) has no planned contacts: there is nothing to score
    assert episode.execute(action_slot(0, above, 0.085)).contacts_on_part is None
