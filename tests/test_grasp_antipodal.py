"""The antipodal sampler: friction cone, stroke, collision-free poses (checked independently), determinism."""

import numpy as np
import pytest
import trimesh

from seggrasp.grasp import ROBOTIQ_2F85, AntipodalConfig, AntipodalSampler, GraspSet
from seggrasp.grasp.antipodal import gravity_torque, part_draw_weights
from seggrasp.grasp.footprint import contact_faces
from seggrasp.hands import FRANKA_HAND

MU = 0.5
TABLE = np.array([0.0, 0.0, 1.0, 0.0])  # object frame: table top at z = 0, normal up


def _on_table(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh = mesh.copy()
    mesh.apply_translation([0.0, 0.0, -mesh.bounds[0, 2]])
    return mesh


@pytest.fixture(scope="module", params=["box", "cylinder"])
def object_and_grasps(request) -> tuple[trimesh.Trimesh, GraspSet]:
    if request.param == "box":
        mesh = _on_table(trimesh.creation.box((0.05, 0.065, 0.11)))
    else:
        mesh = _on_table(trimesh.creation.cylinder(radius=0.03, height=0.12, sections=48))
    sampler = AntipodalSampler(AntipodalConfig(friction_coefficient=MU))
    return mesh, sampler.generate(mesh, seed=3, table_plane=TABLE)


def _box_grid(lo: np.ndarray, hi: np.ndarray, step: float = 0.004) -> np.ndarray:
    """Points strictly inside an axis-aligned box."""
    axes = [np.arange(a + 0.5 * step, b, step) if b - a > step else np.array([(a + b) / 2]) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


@pytest.mark.slow
def test_enough_grasps_sorted_best_first(object_and_grasps) -> None:
    _, grasps = object_and_grasps
    assert len(grasps) >= 200
    assert np.all(np.diff(grasps.scores) <= 0)


def test_poses_are_rigid_and_centred_between_the_contacts(object_and_grasps) -> None:
    _, g = object_and_grasps
    rotations = g.poses[:, :3, :3]
    assert np.allclose(rotations @ rotations.transpose(0, 2, 1), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(rotations), 1.0)
    # the contacts' midpoint lies on the approach axis, at a depth from the pad centres the sampler may choose
    midpoint_local = np.einsum("nji,nj->ni", rotations, g.contacts.mean(axis=1) - g.poses[:, :3, 3])
    assert np.allclose(midpoint_local[:, :2], 0.0, atol=1e-9)
    depths = AntipodalConfig().all_contact_depths
    assert np.all(np.isclose(midpoint_local[:, 2:3], depths[None, :], atol=1e-9).any(axis=1))
    closing = g.contacts[:, 1] - g.contacts[:, 0]
    assert np.allclose(np.linalg.norm(closing, axis=1), g.widths)
    # x axis of the gripper is the closing direction (finger to finger)
    assert np.allclose(np.abs(np.einsum("ij,ij->i", closing / g.widths[:, None], g.poses[:, :3, 0])), 1.0, atol=1e-9)


def test_contacts_on_surface_within_friction_cone_and_stroke(object_and_grasps) -> None:
    mesh, g = object_and_grasps
    flat = g.contacts.reshape(-1, 3)
    _, distance, triangle = trimesh.proximity.closest_point(mesh, flat)
    assert distance.max() < 1e-6
    normals = mesh.face_normals[triangle].reshape(-1, 2, 3)
    axis = (g.contacts[:, 1] - g.contacts[:, 0]) / g.widths[:, None]
    half_angle = np.arctan(MU)
    # contact 0 pushes along +axis (against its outward normal); contact 1 along -axis
    angle_0 = np.arccos(np.clip(np.einsum("ij,ij->i", axis, -normals[:, 0]), -1, 1))
    angle_1 = np.arccos(np.clip(np.einsum("ij,ij->i", -axis, -normals[:, 1]), -1, 1))
    assert angle_0.max() <= half_angle + 1e-6
    assert angle_1.max() <= half_angle + 1e-6
    assert g.widths.max() <= ROBOTIQ_2F85.stroke
    assert g.widths.min() > 0


def test_fingers_and_palm_do_not_penetrate_object_or_table(object_and_grasps) -> None:
    mesh, g = object_and_grasps
    rng = np.random.default_rng(0)
    for i in rng.choice(len(g), size=25, replace=False):
        boxes = ROBOTIQ_2F85.boxes(float(ROBOTIQ_2F85.pre_grasp_opening(g.widths[i])))
        local = np.vstack([_box_grid(lo, hi) for lo, hi in boxes])
        world = local @ g.poses[i, :3, :3].T + g.poses[i, :3, 3]
        assert not mesh.contains(world).any(), f"grasp {i} penetrates the object"
        assert world[:, 2].min() > 0.0, f"grasp {i} goes below the table"


@pytest.mark.slow
def test_same_seed_same_grasps_other_seed_differs() -> None:
    mesh = _on_table(trimesh.creation.cylinder(radius=0.025, height=0.1, sections=32))
    sampler = AntipodalSampler()
    a = sampler.generate(mesh, seed=7, table_plane=TABLE)
    b = sampler.generate(mesh, seed=7, table_plane=TABLE)
    c = sampler.generate(mesh, seed=8, table_plane=TABLE)
    assert len(a) > 0
    for name in ("poses", "widths", "scores", "contacts"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert len(a) != len(c) or not np.allclose(a.poses, c.poses)


def test_object_wider_than_the_stroke_has_no_grasps() -> None:
    cube = trimesh.creation.box((0.12, 0.12, 0.12))
    assert len(AntipodalSampler().generate(cube, seed=0)) == 0


def test_flat_bar_on_the_table_is_grasped_from_above_near_the_fingertips() -> None:
    bar = _on_table(trimesh.creation.box((0.2, 0.02, 0.016)))
    g = AntipodalSampler().generate(bar, seed=0, table_plane=TABLE)
    assert len(g) > 0
    # too low for the pad centres: every grasp holds the bar between the pad centres and the fingertips
    midpoint_local = np.einsum("nji,nj->ni", g.poses[:, :3, :3], g.contacts.mean(axis=1) - g.poses[:, :3, 3])
    assert midpoint_local[:, 2].min() > 0.0
    assert np.all(g.poses[:, 2, 2] < -0.5)  # from above


@pytest.mark.slow
def test_ring_is_held_by_its_wall_or_around_its_outside_never_from_inside_the_hole() -> None:
    ring = _on_table(trimesh.creation.annulus(r_min=0.03, r_max=0.04, height=0.05, sections=64))
    g = AntipodalSampler().generate(ring, seed=1, table_plane=TABLE)
    assert len(g) > 0
    # a grasp pinches the 10 mm wall (the flat 22 mm pads also span the wall's curvature, which the footprint adds)
    # or closes from outside on the 80 mm outer wall; a pad never stops on the inner wall across the hole
    radius = np.linalg.norm(g.contacts[..., :2], axis=-1)
    across = g.widths >= 0.03
    assert (g.widths[~across] < 0.03).all() and across.any()
    assert radius[across].min() > 0.037


def test_ring_lying_flat_with_a_hole_too_small_for_a_finger_is_held_from_outside() -> None:
    # a scissors handle: a 26 mm ring, 8 mm tall, whose 16 mm hole no 2F-85 finger enters
    ring = _on_table(trimesh.creation.annulus(r_min=0.008, r_max=0.013, height=0.008, sections=64))
    assert len(AntipodalSampler(AntipodalConfig(envelope_centres=0)).generate(ring, seed=0, table_plane=TABLE)) == 0
    g = AntipodalSampler().generate(ring, seed=0, table_plane=TABLE)
    assert len(g) > 0
    assert np.all(g.poses[:, 2, 2] < -0.99)  # straight down
    np.testing.assert_allclose(g.widths, 0.026, atol=0.0015)
    assert np.linalg.norm(g.contacts[..., :2], axis=-1).min() > 0.0115  # on the outer wall
    # the fingertips stay above the table
    tips = g.poses[:, 2, 3] + g.poses[:, 2, 2] * ROBOTIQ_2F85.tip_beyond_origin
    assert tips.min() > 0.0


def _hammer() -> tuple[trimesh.Trimesh, np.ndarray, float]:
    """A hammer lying on the table: a light 25 mm handle (0.1 kg) along x and a heavy steel head (1 kg) at +x."""
    handle = trimesh.creation.box((0.26, 0.025, 0.025))
    handle.apply_translation([0.0, 0.0, 0.0125])
    head = trimesh.creation.box((0.03, 0.10, 0.03))
    head.apply_translation([0.145, 0.0, 0.015])
    com = (0.1 * handle.center_mass + 1.0 * head.center_mass) / 1.1
    return trimesh.util.concatenate([handle, head]), com, 1.1


@pytest.mark.slow
def test_hammer_grasp_holds_against_the_heavy_head() -> None:
    mesh, com, mass = _hammer()
    config = AntipodalConfig(friction_coefficient=MU, grip_force=100.0)
    sampler = AntipodalSampler(config)
    torque = lambda g: gravity_torque(g.poses[:1], com, TABLE[:3], mass)[0]  # noqa: E731
    best = sampler.generate(mesh, seed=2, table_plane=TABLE, center_of_mass=com, mass=mass)
    assert len(best) > 0
    assert torque(best) < config.torsion_limit
    # the uniform-density guess puts the centre of mass in the handle's middle: its first grasp would not hold
    naive = sampler.generate(mesh, seed=2, table_plane=TABLE, mass=mass)
    assert torque(naive) > config.torsion_limit


def _along_pad(g: GraspSet) -> np.ndarray:
    """Where the contacts' midpoint lies along the pads (m from their centres, + towards the fingertips)."""
    return np.einsum("nij,ni->nj", g.poses[:, :3, :3], g.contacts.mean(axis=1) - g.poses[:, :3, 3])[:, 2]


def test_contacts_stay_off_the_pad_ends() -> None:
    mesh = _on_table(trimesh.creation.box((0.03, 0.03, 0.012)))  # a flat part: the fingertips meet the table
    no_pinch = AntipodalConfig(friction_coefficient=MU, pinch_contact_depths=())
    g = AntipodalSampler(no_pinch).generate(mesh, seed=0, table_plane=TABLE)
    assert len(g) > 0
    assert np.abs(_along_pad(g)).max() <= 0.01875 - 0.006 + 1e-6  # >= 6 mm from either end of the 37.5 mm pad


def test_a_low_part_lying_flat_is_pinched_with_the_fingertips() -> None:
    # a 10 mm bar lying flat (a scissors handle, a toothbrush handle): its sides are lower than the pads reach with
    # the contact 6.75 mm from the pad's end and the fingertips 3.5 mm above the table
    bar = _on_table(trimesh.creation.box((0.12, 0.015, 0.010)))
    config = AntipodalConfig(friction_coefficient=MU)
    assert len(AntipodalSampler(AntipodalConfig(friction_coefficient=MU, pinch_contact_depths=())).generate(
        bar, seed=0, table_plane=TABLE)) == 0
    g = AntipodalSampler(config).generate(bar, seed=0, table_plane=TABLE)
    assert len(g) >= 10
    assert np.all(g.poses[:, 2, 2] <= -np.cos(np.deg2rad(config.pinch_max_tilt_deg)) + 1e-9)  # straight down
    fingertips = g.poses[:, 2, 3] + ROBOTIQ_2F85.tip_beyond_origin * g.poses[:, 2, 2]
    assert fingertips.min() >= config.pinch_table_clearance - 1e-6
    assert _along_pad(g).max() <= 0.01875 - 0.00225 + 1e-6  # the contact at least 2.25 mm from the pad's end
    assert np.all(np.abs(g.widths - 0.015) < 0.0015)  # across the bar, not along it


def test_each_hand_pinches_from_its_own_height_above_the_table() -> None:
    # a 3.7 mm bar lying flat: the Franka hand's pinches bring its fingertips down to its 1.0 mm, the 2F-85's to 1.5
    bar = _on_table(trimesh.creation.box((0.12, 0.015, 0.0037)))
    lowest = {}
    for hand in (FRANKA_HAND, ROBOTIQ_2F85):
        g = AntipodalSampler(AntipodalConfig.for_hand(hand, friction_coefficient=MU), hand).generate(
            bar, seed=0, table_plane=TABLE)
        assert len(g) > 0
        lowest[hand.name] = (g.poses[:, 2, 3] + hand.tip_beyond_origin * g.poses[:, 2, 2]).min()
    assert FRANKA_HAND.pinch_table_clearance - 1e-6 <= lowest["franka_hand"] < 0.0012
    assert lowest["robotiq_2f85"] >= ROBOTIQ_2F85.pinch_table_clearance - 1e-6


def test_a_pinch_needs_the_pads_on_the_part_over_the_band() -> None:
    # a knife: a 12 mm handle and a 2 mm blade held 8 mm above the table by it; pinching the blade across its width
    # touches its two 2 mm edges with the last millimetres of the pads: enough for the default 0.5 mm band (both
    # hands lift such blades in the twin), not for a 3 mm one
    handle = trimesh.creation.box((0.10, 0.02, 0.012))
    handle.apply_translation([-0.05, 0.0, 0.006])
    blade = trimesh.creation.box((0.08, 0.02, 0.002))
    blade.apply_translation([0.04, 0.0, 0.009])
    knife = trimesh.util.concatenate([handle, blade])

    def blade_grasps(config: AntipodalConfig) -> int:
        g = AntipodalSampler(config).generate(knife, seed=0, table_plane=TABLE)
        return int((g.contacts[:, :, 0].min(axis=1) > 0.015).sum())  # the 22 mm pads clear of the handle's end

    assert blade_grasps(AntipodalConfig(friction_coefficient=MU)) > 0
    assert blade_grasps(AntipodalConfig(friction_coefficient=MU, pinch_min_band=0.003)) == 0


@pytest.mark.slow
def test_footprint_gives_the_width_the_pads_close_on() -> None:
    # a 20 mm stem under a 60 mm wide, 10 mm thick cap: pads on the stem just below the cap sweep the cap too
    stem = trimesh.creation.box((0.02, 0.02, 0.06))
    stem.apply_translation([0.0, 0.0, 0.03])
    cap = trimesh.creation.box((0.06, 0.02, 0.01))
    cap.apply_translation([0.0, 0.0, 0.065])
    mesh = trimesh.util.concatenate([stem, cap])
    g = AntipodalSampler(AntipodalConfig(friction_coefficient=MU)).generate(mesh, seed=0, table_plane=TABLE)
    assert len(g) > 0
    near_cap = (np.abs(g.poses[:, 2, 3] - 0.06) < 0.01) & (np.abs(g.poses[:, 0, 0]) > 0.95)  # closing along x
    assert near_cap.any()
    assert np.all(g.widths[near_cap] > 0.05)  # the cap, not the 20 mm stem, sets the width


def test_sampling_on_a_part_finds_the_grasps_the_whole_mesh_barely_has(box_with_knob) -> None:
    mesh, labels = box_with_knob
    knob = labels == 1
    sampler = AntipodalSampler(AntipodalConfig(n_surface_samples=300, envelope_centres=0))
    everywhere = sampler.generate(mesh, seed=0, table_plane=TABLE)
    on_knob = sampler.generate(mesh, seed=0, table_plane=TABLE, on_faces=knob)
    touches = lambda g: knob[contact_faces(g, mesh)].all(axis=1)  # noqa: E731
    assert touches(everywhere).sum() < 10  # the knob is 3 % of the surface
    # first contacts drawn on the knob and, for at most half of them, on the box within a pad's length of it
    assert touches(on_knob).sum() >= 100
    with pytest.raises(ValueError, match="on_faces must mark some of the mesh's"):
        sampler.generate(mesh, seed=0, table_plane=TABLE, on_faces=np.zeros(len(mesh.faces), bool))
    with pytest.raises(ValueError, match="on_faces must mark some"):
        sampler.generate(mesh, seed=0, table_plane=TABLE, on_faces=knob[:-1])


def test_a_part_s_draw_takes_in_its_neighbours_within_reach_at_most_as_much_as_the_part(box_with_knob) -> None:
    mesh, labels = box_with_knob
    knob = labels == 1
    # the box's nearest vertices, its top corners, lie 34 mm from the knob's rim
    assert np.array_equal(part_draw_weights(mesh, knob, 0.02), knob.astype(float))
    weights = part_draw_weights(mesh, knob, 0.04)
    ring = (weights > 0) & ~knob
    below = mesh.triangles_center[:, 2] < 1e-6  # the box's bottom: no vertex within reach
    assert np.all(weights[knob] == 1.0) and np.array_equal(ring, ~knob & ~below)
    assert (mesh.area_faces * weights)[ring].sum() == pytest.approx(mesh.area_faces[knob].sum())


def test_bad_table_plane_and_config_are_rejected() -> None:
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    with pytest.raises(ValueError, match="table_plane"):
        AntipodalSampler().generate(box, table_plane=[0, 0, 1])
    with pytest.raises(ValueError, match="pinch_contact_depths"):
        AntipodalConfig(pinch_contact_depths=(0.019,))  # beyond the pad's end
    with pytest.raises(ValueError, match="pinch_table_clearance"):
        AntipodalConfig(pinch_table_clearance=-0.001)
    with pytest.raises(ValueError, match="pinch_max_tilt_deg"):
        AntipodalConfig(pinch_max_tilt_deg=120.0)
    with pytest.raises(ValueError, match="friction_coefficient"):
        AntipodalConfig(friction_coefficient=0.0)


@pytest.mark.slow
def test_graspset_transform_and_subset() -> None:
    box = trimesh.creation.box((0.05, 0.05, 0.05))
    g = AntipodalSampler().generate(box, seed=0)
    T = np.eye(4)
    T[:3, :3] = trimesh.transformations.rotation_matrix(0.7, [0, 0, 1])[:3, :3]
    T[:3, 3] = [0.4, -0.1, 0.2]
    moved = g.transformed(T)
    assert np.allclose(moved.contacts, g.contacts @ T[:3, :3].T + T[:3, 3])
    assert np.allclose(moved.poses, T @ g.poses)
    top = g.subset(np.arange(3))
    assert len(top) == 3 and np.array_equal(top.scores, g.scores[:3])
    with pytest.raises(ValueError, match="disagree"):
        GraspSet(np.zeros((2, 4, 4)), np.zeros(3), np.zeros(2), np.zeros((2, 2, 3)))


def _level_handle_grasps(mesh: trimesh.Trimesh) -> np.ndarray:
    """Top-down grasps on a handle lying along y: closing level (x within 5 deg of the table) across it."""
    g = AntipodalSampler(AntipodalConfig(friction_coefficient=MU)).generate(mesh, seed=0, table_plane=TABLE)
    return g.subset(np.flatnonzero((np.abs(g.poses[:, 2, 0]) < np.sin(np.deg2rad(5.0))) & (g.poses[:, 2, 2] < -0.99)))


def test_a_round_handle_lying_flat_is_grasped_level_across_its_widest_section() -> None:
    # a 30 mm round handle lying on the table: its antipodal pairs run through the axis at every tilt, and only the
    # pads closing level with the table meet it along a line across the pads (the contact that resists twist)
    handle = _on_table(trimesh.creation.cylinder(radius=0.015, height=0.12, sections=24))
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1.0, 0.0, 0.0], [0.0, 0.0, 0.015]))
    level = _level_handle_grasps(handle)
    assert len(level) >= 20
    assert np.all(np.abs(level.widths - 0.03) < 0.0015)
    assert np.all(np.abs(level.contacts[..., 2] - 0.015) < 0.003)  # at the axis height, the widest section



@pytest.mark.slow
def test_level_grasps_do_not_pinch_the_edges_of_a_slanted_wall() -> None:
    # a 3 mm wall leaning 20 deg (a pan's flared side): pads closing level with the table would touch only its
    # edges (a point each), so level poses are kept only where the surface faces the pads
    wall = trimesh.creation.box((0.003, 0.06, 0.04))
    wall.apply_transform(trimesh.transformations.rotation_matrix(np.deg2rad(20.0), [0.0, 1.0, 0.0]))
    wall = _on_table(wall)

    def level(config: AntipodalConfig) -> int:
        g = AntipodalSampler(config).generate(wall, seed=0, table_plane=TABLE)
        across = np.abs(g.poses[:, 0, 0]) > 0.999  # closing level across the wall's thickness (x), not its length
        return int((across & (g.poses[:, 2, 2] < -0.999)).sum())

    assert level(AntipodalConfig(friction_coefficient=MU, level_facing_deg=180.0)) > 0  # without the check
    assert level(AntipodalConfig(friction_coefficient=MU)) == 0
