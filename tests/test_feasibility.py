"""Requests no gripper can hold are named before the robot moves (seggrasp.grasp.feasibility, Episode)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from seggrasp.cell import FAILURES, GraspOutcome
from seggrasp.episode import Episode, EpisodeContext, table_plane_in_object_frame
from seggrasp.grasp import AntipodalSampler, GraspSet
from seggrasp.grasp.antipodal import AntipodalConfig
from seggrasp.grasp.feasibility import Feasibility, judge_requests, whole_pad_torsion_limit
from seggrasp.grasp.footprint import PadFootprint
from seggrasp.hands import FRANKA_HAND, ROBOTIQ_2F85, Hand
from seggrasp.truth import GroundTruth
from tests.cells import FixedMeshCell


def body_with(part: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A 60 x 50 x 40 mm box body on the table (z = 0) with `part` beside it: the mesh and its labels (body 0,
    part 1)."""
    body = trimesh.creation.box([0.06, 0.05, 0.04])
    body.apply_translation([0.0, 0.0, 0.02])
    mesh = trimesh.util.concatenate([body, part])
    return mesh, np.r_[np.zeros(len(body.faces), dtype=np.int64), np.ones(len(part.faces), dtype=np.int64)]


def box_part(size: tuple[float, float, float]) -> tuple[trimesh.Trimesh, np.ndarray]:
    """A box part of `size` (m) lying on the table against the body's +x side."""
    part = trimesh.creation.box(size)
    part.apply_translation([0.03 + size[0] / 2, 0.0, size[2] / 2])
    return body_with(part)


def judge(mesh: trimesh.Trimesh, labels: np.ndarray, hand: Hand, mass: float | None = None) -> Feasibility:
    """The part's (label 1) judgement for `hand` from the hand's own sampler's candidates (the object weighing
    `mass`, its centre of mass the mesh's)."""
    config = AntipodalConfig.for_hand(hand)
    plane = table_plane_in_object_frame(mesh, np.eye(4))
    grasps = AntipodalSampler(config, hand).generate(mesh, seed=0, table_plane=plane, mass=mass)
    return judge_requests([1], ["body", "part"], hand, config, mesh, labels, grasps, PadFootprint(gripper=hand),
                          plane, mass=mass)[1]


@pytest.fixture(scope="module")
def plate() -> tuple[trimesh.Trimesh, np.ndarray]:
    return box_part((0.06, 0.02, 0.0015))


def test_a_thin_plate_lying_flat_is_infeasible_and_the_reason_names_its_height_and_the_pinch(plate) -> None:
    verdict = judge(*plate, ROBOTIQ_2F85)
    config = AntipodalConfig.for_hand(ROBOTIQ_2F85)
    pinch = 1000 * (config.pinch_table_clearance + config.pinch_min_band)
    assert not verdict.feasible
    assert verdict.reason.startswith("part: stands at most 1.5 mm above the table")
    assert f"a fingertip pinch needs {pinch:.1f} mm" in verdict.reason


def test_a_part_wider_than_the_franka_hand_s_stroke_is_infeasible_for_it_and_feasible_for_the_2f85() -> None:
    cube = box_part((0.078, 0.078, 0.078))  # within the 2F-85's 80 mm, beyond the Franka Hand's 76 mm
    assert judge(*cube, ROBOTIQ_2F85) == Feasibility(True)
    franka = judge(*cube, FRANKA_HAND)
    assert not franka.feasible
    assert franka.reason == ("part: narrowest section 78 mm, wider than the 76 mm the franka_hand closes on "
                             "(80 mm stroke less 4 mm)")


def test_an_ordinary_handle_is_feasible() -> None:
    assert judge(*box_part((0.10, 0.02, 0.02)), ROBOTIQ_2F85).feasible


def test_a_collar_narrower_than_the_pads_is_infeasible_and_the_reason_names_the_share_they_press_on() -> None:
    handle = trimesh.creation.box([0.10, 0.02, 0.02])
    handle.apply_translation([0.08, 0.0, 0.02])
    mesh, _ = body_with(handle.subdivide_to_size(0.002))
    collar = (np.abs(mesh.triangles_center[:, 0] - 0.08) < 0.003).astype(np.int64)  # 6 mm of the 100 mm handle
    verdict = judge(mesh, collar, ROBOTIQ_2F85)
    assert not verdict.feasible
    prefix, suffix = "part: the pads press on it for at most ", " % of their footprint; they need 50 %"
    assert verdict.reason.startswith(prefix) and verdict.reason.endswith(suffix)
    assert 0 < int(verdict.reason[len(prefix):-len(suffix)]) < 50


def test_an_infeasible_request_is_recorded_without_moving_the_cell_and_a_feasible_one_executes(plate) -> None:
    mesh, labels = plate
    cell = FixedMeshCell(mesh, GraspOutcome(True, True, 0.1, contacts_observed=False))  # every grasp lifts
    episode = Episode(cell, EpisodeContext("plate", "test", ["body", "plate"], scene_seed=0), None,
                      GroundTruth(mesh, labels))
    before = []
    records = episode.run("oracle", ["plate"], before=before.append)
    assert cell.executed == 0 and len(records) == episode.settings.top_k
    assert all(slot.grasp is None and not episode.moves_cell(slot) for slot in before)
    assert "infeasible" in FAILURES
    for record in records:
        assert record.failure == "infeasible" and record.infeasible is True
        assert not record.executed and record.success is False and record.contacts_on_part is False
        assert record.message.startswith("plate: stands at most 1.5 mm above the table")
    body = episode.run("oracle", ["body"])
    assert cell.executed == sum(r.executed for r in body) > 0
    assert all(r.infeasible is False and r.failure != "infeasible" for r in body)


def test_a_collar_over_half_the_pads_is_feasible_though_the_ranking_margin_would_leave_it_under_half() -> None:
    handle = trimesh.creation.box([0.10, 0.02, 0.02])
    handle.apply_translation([0.08, 0.0, 0.02])
    mesh, _ = body_with(handle.subdivide_to_size(0.002))
    collar = (np.abs(mesh.triangles_center[:, 0] - 0.08) < 0.0065).astype(np.int64)  # 13 mm; the pads are 22 mm wide
    assert judge(mesh, collar, ROBOTIQ_2F85).feasible
    # the candidates' best share under the pads widened by the footprint's ranking margin (3 mm a side) is < 50 %
    config = AntipodalConfig.for_hand(ROBOTIQ_2F85)
    plane = table_plane_in_object_frame(mesh, np.eye(4))
    grasps = AntipodalSampler(config, ROBOTIQ_2F85).generate(mesh, seed=0, table_plane=plane)
    widened = PadFootprint(gripper=ROBOTIQ_2F85)
    assert widened.margin > 0
    shares = widened.on(mesh).pad_means(grasps, collar.astype(np.float64)[:, None])[:, :, 0].min(axis=1)
    assert shares.max() < widened.min_share


def test_a_part_only_the_fingertips_ends_land_on_is_infeasible_and_the_reason_says_where_the_pads_land() -> None:
    # a block (label 1) 30 mm wide with upright sides up to 5 mm, then sloping in to 20 mm at its top (10 mm), under a
    # 16 mm wide one (label 0): pads ending over the slope have it under them, but the fingertips land on it first
    corners = [(x, y, z) for x in (-0.02, 0.02) for y, z in ((-0.015, 0.0), (0.015, 0.0), (-0.015, 0.005),
                                                             (0.015, 0.005), (-0.01, 0.01), (0.01, 0.01))]
    low = trimesh.convex.convex_hull(np.array(corners))
    high = trimesh.creation.box((0.040, 0.016, 0.030))
    high.apply_translation([0.0, 0.0, 0.025])
    mesh = trimesh.util.concatenate([low, high])
    labels = np.r_[np.ones(len(low.faces), dtype=np.int64), np.zeros(len(high.faces), dtype=np.int64)]
    hand, config = ROBOTIQ_2F85, AntipodalConfig.for_hand(ROBOTIQ_2F85)
    poses = np.repeat(np.eye(4)[None], 2, axis=0)
    poses[:, :3, :3] = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # down, closing along y
    # the pads end over the slope (9.5 mm up) or 2 mm up the upright sides
    poses[:, 2, 3] = [hand.pad_half_length + 0.0095, hand.pad_half_length + 0.002]
    contacts = np.array([[[0.0, -0.0102, 0.0098], [0.0, 0.0102, 0.0098]],
                         [[0.0, -0.015, 0.0035], [0.0, 0.015, 0.0035]]])
    grasps = GraspSet(poses, [0.0205, 0.030], [0.9, 0.5], contacts)
    plane = table_plane_in_object_frame(mesh, np.eye(4))

    def judged(index: list[int]) -> Feasibility:
        return judge_requests([1], ["top", "block"], hand, config, mesh, labels, grasps.subset(np.array(index)),
                              PadFootprint(gripper=hand), plane)[1]

    tips = judged([0])
    assert not tips.feasible
    assert tips.reason.startswith("block: where the pads' footprint is mostly on it, their faces first land on it "
                                  "for at most 0 %"), tips.reason
    assert "fingertips' ends" in tips.reason and "they need 50 %" in tips.reason
    assert judged([0, 1]).feasible


def test_a_part_the_pads_land_on_only_at_their_ends_is_infeasible_for_the_2f85_and_the_reason_says_how_far_in(
        two_tier) -> None:
    # the lower block (label 1) 30 mm wide and 10 mm tall under a 20 mm wide one (label 0): pads whose last 1.5 mm
    # reaches down the block's sides (the 2F-85's fingertip 1.25 mm below) land on it only at their ends; the 2F-85's
    # finger curves away there, the Franka's does not
    mesh, on_low = two_tier
    labels = on_low.astype(np.int64)
    plane = table_plane_in_object_frame(mesh, np.eye(4))

    def judged(hand: Hand, reaches: list[float]) -> Feasibility:
        poses = np.repeat(np.eye(4)[None], len(reaches), axis=0)
        poses[:, :3, :3] = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])  # down, closing along y
        poses[:, 2, 3] = [0.010 + hand.pad_half_length - r for r in reaches]  # the pads' last r down the sides
        contacts = np.array([[[0.0, -0.015, 0.010 - r / 2], [0.0, 0.015, 0.010 - r / 2]] for r in reaches])
        grasps = GraspSet(poses, [0.030] * len(reaches), np.linspace(0.9, 0.5, len(reaches)), contacts)
        return judge_requests([1], ["top", "block"], hand, AntipodalConfig.for_hand(hand), mesh, labels, grasps,
                              PadFootprint(gripper=hand), plane)[1]

    ends = judged(ROBOTIQ_2F85, [0.0015])
    assert not ends.feasible
    assert ends.reason.startswith("block: where the pads press on it, they first land on it at most "), ends.reason
    assert ends.reason.endswith("mm into the pad from its end; the robotiq_2f85's pads hold from 2.0 mm"), ends.reason
    assert float(ends.reason.split("at most ")[1].split(" mm")[0]) <= 1.5
    assert judged(ROBOTIQ_2F85, [0.0015, 0.005]).feasible  # a lower-ranked candidate whose pads reach 5 mm holds it
    assert judged(FRANKA_HAND, [0.0015]).feasible


def test_a_part_held_only_far_from_a_heavy_body_is_infeasible_and_the_reason_names_the_torque() -> None:
    # a 90 mm bar beside the body, longer than the stroke: the pads close across it, its length pointing at the body
    bar = box_part((0.09, 0.02, 0.03))
    config = AntipodalConfig.for_hand(FRANKA_HAND)
    assert judge(*bar, FRANKA_HAND, mass=0.1).feasible
    verdict = judge(*bar, FRANKA_HAND, mass=3.0)
    assert not verdict.feasible
    assert verdict.reason.startswith("part: wherever the pads hold it, the 3.00 kg object's weight turns it about the "
                                     "closing axis with at least")
    assert f"hold at most {whole_pad_torsion_limit(FRANKA_HAND, config):.2f} N m at 70 N" in verdict.reason


def test_the_whole_pad_torsion_radius_is_the_pads_mean_distance_from_its_centre() -> None:
    for hand in (ROBOTIQ_2F85, FRANKA_HAND):
        midpoints = (np.arange(800) + 0.5) / 800 * 2 - 1  # cell centres of a grid over [-1, 1]
        y, z = np.meshgrid(hand.pad_half_width * midpoints, hand.pad_half_length * midpoints)
        assert hand.whole_pad_torsion_radius == pytest.approx(np.hypot(y, z).mean(), rel=1e-3)
        assert hand.whole_pad_torsion_radius > hand.torsion_radius
