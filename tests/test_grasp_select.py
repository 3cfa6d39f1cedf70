"""Part assignment on a two-part mesh, per-prompt top-k selection and the learned-generator adapter."""

import numpy as np
import pytest
import trimesh

from seggrasp.grasp import AntipodalSampler, GraspSet
from seggrasp.grasp.footprint import PadFootprint
from seggrasp.grasp.learned import GraspPrediction, LearnedGraspGenerator
from seggrasp.grasp.select import assign_parts, contact_faces, select_on_part, select_per_prompt
from seggrasp.hands import FRANKA_HAND, ROBOTIQ_2F85


@pytest.fixture(scope="module")
def hammer() -> tuple[trimesh.Trimesh, np.ndarray]:
    """A handle (label 0, x < 0.06) joined to a head (label 1, a wide block at x > 0.06)."""
    handle = trimesh.creation.box((0.12, 0.025, 0.025))
    head = trimesh.creation.box((0.03, 0.05, 0.07))
    head.apply_translation([0.075, 0.0, 0.0])
    mesh = trimesh.util.concatenate([handle, head])
    labels = np.r_[np.zeros(len(handle.faces), int), np.ones(len(head.faces), int)]
    return mesh, labels


@pytest.mark.slow
def test_both_contacts_decide_the_part(hammer) -> None:
    mesh, labels = hammer
    grasps = AntipodalSampler().generate(mesh, seed=0)
    parts = assign_parts(grasps, mesh, labels)
    assert set(np.unique(parts)) <= {-1, 0, 1}
    assert (parts == 0).sum() > 20 and (parts == 1).sum() > 20
    x = grasps.contacts[..., 0]
    on_handle = (x < 0.06 - 1e-9).all(axis=1)
    on_head = (x > 0.06 - 1e-9).all(axis=1)
    assert np.all(on_handle[parts == 0])
    assert np.all(on_head[parts == 1])
    faces = contact_faces(grasps, mesh)
    assert np.array_equal(parts == -1, labels[faces[:, 0]] != labels[faces[:, 1]])


def test_straddling_grasp_is_unassigned(hammer) -> None:
    mesh, labels = hammer
    pose = np.eye(4)
    # contacts: one on the handle's top face, one on the head's bottom face
    straddle = GraspSet(pose[None], [0.05], [1.0], [[[0.0, 0.0, 0.0125], [0.075, 0.0, -0.035]]])
    assert assign_parts(straddle, mesh, labels).tolist() == [-1]
    unknown = labels.copy()
    unknown[:] = -1
    assert assign_parts(straddle, mesh, unknown).tolist() == [-1]


@pytest.mark.slow
def test_top_k_per_prompt_best_first(hammer) -> None:
    mesh, labels = hammer
    grasps = AntipodalSampler().generate(mesh, seed=1)
    parts = assign_parts(grasps, mesh, labels)
    chosen = select_per_prompt(grasps, mesh, labels, n_prompts=3, top_k=10)
    assert [len(c) for c in chosen] == [10, 10, 0]
    for k in (0, 1):
        assert np.all(parts[chosen[k]] == k)
        assert np.all(np.diff(grasps.scores[chosen[k]]) <= 0)
        best_other = grasps.scores[(parts == k)].max()
        assert grasps.scores[chosen[k][0]] == best_other
    with pytest.raises(ValueError, match="one label per mesh face"):
        assign_parts(grasps, mesh, labels[:-1])
    with pytest.raises(ValueError, match="top_k"):
        select_on_part(grasps, parts, 0, top_k=0)


def test_grasps_whose_pads_press_on_the_part_come_before_those_on_a_wider_neighbour(hammer) -> None:
    mesh, labels = hammer
    # two grasps on the handle coming down from above and closing across it (pads 22 mm along x): one in its
    # middle, one whose contacts are on the handle 6 mm from the head, so its pads' edge reaches the wider head
    xs = [0.0, 0.054]
    contacts = np.array([[[x, -0.0125, 0.0], [x, 0.0125, 0.0]] for x in xs])
    poses = np.repeat(np.eye(4)[None], 2, axis=0)
    poses[:, :3, :3] = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    poses[:, :3, 3] = contacts.mean(axis=1)
    grasps = GraspSet(poses, [0.025, 0.025], [0.5, 0.9], contacts)
    assert assign_parts(grasps, mesh, labels).tolist() == [0, 0]
    assert [c.tolist() for c in select_per_prompt(grasps, mesh, labels, 2)] == [[1, 0], []]
    under_pads = PadFootprint().on(mesh).pad_means(grasps, (labels == 0).astype(float)[:, None])[:, :, 0]
    np.testing.assert_allclose(under_pads[0], 1.0)
    assert (under_pads[1] < 0.1).all()  # the head stands 12.5 mm proud: the pads close on it first
    # the grasp whose pads press on the handle comes first; the other still fills the request
    assert [c.tolist() for c in select_per_prompt(grasps, mesh, labels, 2, footprint=PadFootprint())] == [[0, 1], []]
    assert [c.tolist() for c in select_per_prompt(grasps, mesh, labels, 2, 1, PadFootprint())] == [[0], []]
    # pads a metre away touch nothing: each pad falls back to the face nearest its contact
    far = GraspSet(poses + np.array([[0, 0, 0, 1.0], [0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 0]]), [0.025, 0.025],
                   [0.5, 0.9], contacts)
    surface = PadFootprint().on(mesh)
    assert all(len(pad) == 0 for pads in surface.touched_faces(far) for pad in pads)
    np.testing.assert_allclose(surface.pad_means(far, (labels == 0).astype(float)[:, None])[:, :, 0], 1.0)


def _across(xs: list[float], z: float, width: float) -> GraspSet:
    """Grasps coming straight down to height `z`, closing along y across a bar on the x axis, centred at `xs`."""
    poses = np.repeat(np.eye(4)[None], len(xs), axis=0)
    poses[:, :3, :3] = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
    poses[:, :3, 3] = [[x, 0.0, z] for x in xs]
    contacts = np.array([[[x, -width / 2, z], [x, width / 2, z]] for x in xs])
    return GraspSet(poses, [width] * len(xs), np.linspace(0.9, 0.5, len(xs)), contacts)


def test_a_neighbour_a_millimetre_prouder_takes_what_the_pads_first_land_on() -> None:
    # a 10 mm bar (label 0) ending in a 12 mm collar (label 1): the collar stands 1 mm proud on each side, within
    # the footprint's 2 mm tolerance but beyond the 0.5 mm of a first touch
    bar = trimesh.creation.box((0.10, 0.010, 0.010))
    collar = trimesh.creation.box((0.010, 0.012, 0.012))
    collar.apply_translation([0.055, 0.0, 0.0])
    mesh = trimesh.util.concatenate([bar, collar])
    labels = np.r_[np.zeros(len(bar.faces), int), np.ones(len(collar.faces), int)]
    grasps = _across([0.042, 0.0], z=0.0, width=0.012)  # the first one's pads (x 31-53 mm) reach 3 mm of collar
    surface = PadFootprint().on(mesh)
    on_bar = labels == 0
    footprint = surface.pad_means(grasps, on_bar.astype(float)[:, None])[:, :, 0]
    assert (footprint[0] > 0.5).all()  # mostly bar under the pads
    np.testing.assert_allclose(surface.first_touch(grasps, on_bar)[0][0], 0.0)  # but they land on the collar
    np.testing.assert_allclose(surface.part_shares(grasps, on_bar), [[0.0, 0.0], [1.0, 1.0]])
    # so the grasp in the bar's middle comes first though the sampler scored the other higher
    assert select_per_prompt(grasps, mesh, labels, 2, footprint=PadFootprint())[0].tolist() == [1, 0]


def test_a_part_only_the_fingertips_ends_reach_is_not_pressed_by_the_pads(two_tier) -> None:
    # the lower block is the part; the 2F-85's fingertips reach 1.25 mm past its pads' ends
    mesh, on_low = two_tier
    hand = PadFootprint().gripper
    tips_only = hand.pad_half_length + 0.010 + 0.0005  # the pads end 0.5 mm above the block, the tips 0.75 mm into it
    pads_on = hand.pad_half_length + 0.005  # the pads' last 5 mm reach down its sides
    grasps = _across([0.0, 0.0], z=0.0, width=0.030)
    grasps.poses[:, 2, 3] = [tips_only, pads_on]
    surface = PadFootprint().on(mesh)
    footprint = surface.pad_means(grasps, on_low.astype(float)[:, None])[:, :, 0]
    np.testing.assert_allclose(footprint, 1.0)  # the footprint, 3 mm wider than the pads, sees only the block
    landed, reach = surface.first_touch(grasps, on_low)
    np.testing.assert_allclose(landed[0], 0.0)
    np.testing.assert_allclose(reach[0], 0.0)  # nothing the pads' faces land on
    # the pads' faces press on 5 mm of its sides, the fingertips' ends on the 1.25 mm below: about 80 % pressed
    assert (landed[1] > 0.7).all() and (landed[1] < 0.9).all()
    assert ((reach[1] > 0.0035) & (reach[1] <= 0.005)).all()


def test_pads_landing_only_on_their_last_millimetres_hold_for_the_franka_and_not_for_the_2f85(two_tier) -> None:
    # the pads' last 1 mm or last 5 mm reach down the lower block's sides; the 2F-85's finger curves away past its
    # pad (`pad_end_margin` 2 mm), the Franka Hand's pad runs to the finger's end (none)
    mesh, on_low = two_tier
    for hand, held in ((ROBOTIQ_2F85, [False, True]), (FRANKA_HAND, [True, True])):
        grasps = _across([0.0, 0.0], z=0.0, width=0.030)
        grasps.poses[:, 2, 3] = [0.010 + hand.pad_half_length - 0.001, 0.010 + hand.pad_half_length - 0.005]
        surface = PadFootprint(gripper=hand).on(mesh)
        reach = surface.first_touch(grasps, on_low)[1]
        assert (reach[0] < 0.0015).all() and (reach[1] > 0.0035).all(), (hand.name, reach)
        assert surface.holds(grasps, on_low).tolist() == held, hand.name
        assert surface.lands_on_pads(grasps).tolist() == held, hand.name
        # the grasp whose pads hold comes first, though the sampler scored the other higher
        labels = (~on_low).astype(np.int64)
        chosen = select_per_prompt(grasps, mesh, labels, 2, footprint=PadFootprint(gripper=hand))[0].tolist()
        assert chosen == ([0, 1] if held[0] else [1, 0]), hand.name


def test_a_fingertip_shorter_than_the_first_touch_tolerance_is_pad(two_tier) -> None:
    # the Franka Hand's finger reaches 0.1 mm past its pad (the 2F-85's 1.25 mm): a block's top edge landed on
    # 0.05 mm past the pad's end is pressed by the Franka's pad face, and not by the 2F-85's fingertip
    mesh, on_low = two_tier
    for hand, expected in ((FRANKA_HAND, 1.0), (ROBOTIQ_2F85, 0.0)):
        grasps = _across([0.0], z=0.010 + hand.pad_half_length + 0.00005, width=0.030)
        if hand is ROBOTIQ_2F85:  # its tip reaches 1.25 mm: land 0.65 mm past the pad's end, as far inside the tip
            grasps.poses[:, 2, 3] = 0.010 + hand.pad_half_length + 0.00065
        shares = PadFootprint(gripper=hand).on(mesh).first_touch(grasps, on_low)[0]
        np.testing.assert_allclose(shares, expected, err_msg=hand.name)


@pytest.mark.slow
def test_sampled_grasps_keep_their_pads_on_their_own_part(hammer) -> None:
    mesh, labels = hammer
    grasps = AntipodalSampler().generate(mesh, seed=1)
    plain = select_per_prompt(grasps, mesh, labels, n_prompts=2, top_k=10)
    kept = select_per_prompt(grasps, mesh, labels, n_prompts=2, top_k=10, footprint=PadFootprint())
    assert [len(c) for c in kept] == [10, 10]
    surface = PadFootprint(margin=0.0, tolerance=0.0005).on(mesh)
    for k, chosen in enumerate(kept):
        assert np.all(np.diff(grasps.scores[chosen]) <= 0)
        # even measured with the bare pads, what each chosen grasp presses on is mostly its own part
        shares = surface.pad_means(grasps.subset(chosen), (labels == k).astype(float)[:, None])[:, :, 0]
        assert (shares >= 0.5).all()
    assert any(set(a) != set(b) for a, b in zip(plain, kept))  # the check changed some choice


class _FixedGraspModel:
    """Test double standing in for a network: two grasps with a base-origin convention, one contact each."""

    def __init__(self, base_offset: float) -> None:
        self.base_offset = base_offset
        self.seen_points = 0

    def predict(self, points: np.ndarray, seed: int) -> GraspPrediction:
        self.seen_points = len(points)
        poses = np.repeat(np.eye(4)[None], 2, axis=0)
        poses[:, 2, 3] = [-self.base_offset, -self.base_offset + 0.01]  # base sits behind the pads along z
        return GraspPrediction(poses, [0.04, 0.2], [0.3, 0.9], [[-0.02, 0, 0], [-0.1, 0, 0.01]])


def test_learned_adapter_converts_frames_and_filters() -> None:
    model = _FixedGraspModel(base_offset=0.1)
    T_model_grasp = np.eye(4)
    T_model_grasp[2, 3] = 0.1
    generator = LearnedGraspGenerator(model, n_points=500, T_model_grasp=T_model_grasp)
    grasps = generator.generate(trimesh.creation.box((0.04, 0.04, 0.04)), seed=0)
    assert model.seen_points == 500
    assert len(grasps) == 1  # the 0.2 m wide proposal exceeds the 85 mm stroke
    assert np.allclose(grasps.poses[0, :3, 3], 0.0)
    assert np.allclose(grasps.contacts[0], [[-0.02, 0, 0], [0.02, 0, 0]])
    with pytest.raises(ValueError, match="predict"):
        LearnedGraspGenerator(object())


def test_a_meshs_pad_surface_is_sampled_once_and_anew_once_the_mesh_moves() -> None:
    mesh = trimesh.creation.box((0.10, 0.010, 0.010))
    first, again = PadFootprint().on(mesh), PadFootprint(margin=0.0).on(mesh)  # margin does not change the sample
    assert again.points is first.points and not first.points.flags.writeable
    mesh.apply_translation([0.0, 0.0, 0.05])
    moved = PadFootprint().on(mesh)
    assert moved.points is not first.points
    np.testing.assert_allclose(moved.points[:, 2].mean(), first.points[:, 2].mean() + 0.05, atol=1e-3)
