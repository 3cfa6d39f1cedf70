"""Camera rig and offscreen rendering: face-id buffers must be exact (checked against trimesh ray casting)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from seggrasp.mesh import unit_normalisation
from seggrasp.render import (
    CAMERA_DISTANCE,
    ViewRenderer,
    camera_rig,
    check_rig,
    decode_face_ids,
    encode_face_colours,
    intrinsics,
    look_at,
    render_views,
)

IMAGE_SIZE = 128


@pytest.fixture(scope="module")
def ring() -> trimesh.Trimesh:
    """A tilted, off-centre thick ring (self-occluding, with a hole), about a thousand faces, in metres."""
    mesh = trimesh.creation.annulus(r_min=0.03, r_max=0.06, height=0.04, sections=48)
    mesh = trimesh.util.concatenate([mesh, trimesh.creation.box([0.02, 0.02, 0.08])])  # a post through the hole
    mesh.apply_transform(trimesh.transformations.rotation_matrix(0.6, [1, 0.3, 0]))
    mesh.apply_translation([0.4, -0.1, 0.2])
    return mesh


@pytest.fixture(scope="module")
def ring_views(ring: trimesh.Trimesh):
    return render_views(ring, camera_rig(4, seed=3), image_size=IMAGE_SIZE)


def _ray_cast_face_ids(mesh: trimesh.Trimesh, view) -> np.ndarray:
    """Face hit by the ray through each pixel centre of `view` (in the unit-normalised frame), -1 for a miss."""
    normalised = mesh.copy()
    normalised.apply_transform(unit_normalisation(mesh))
    height, width = view.size
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    pixels = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], axis=1)
    directions = pixels @ np.linalg.inv(view.K).T @ view.T_world_cam[:3, :3].T
    origins = np.broadcast_to(view.T_world_cam[:3, 3], directions.shape)
    hit_faces, hit_rays = normalised.ray.intersects_id(origins, directions, multiple_hits=False)
    face_ids = np.full(u.size, -1, dtype=np.int64)
    face_ids[hit_rays] = hit_faces
    return face_ids.reshape(height, width)


def _interior(face_ids: np.ndarray) -> np.ndarray:
    """Pixels whose four neighbours show the same face (or background) as they do: not on an edge or silhouette."""
    padded = np.pad(face_ids, 1, mode="edge")
    centre = padded[1:-1, 1:-1]
    return (
        (padded[:-2, 1:-1] == centre) & (padded[2:, 1:-1] == centre)
        & (padded[1:-1, :-2] == centre) & (padded[1:-1, 2:] == centre)
    )


@pytest.mark.slow
def test_face_ids_agree_with_ray_casting(ring: trimesh.Trimesh, ring_views) -> None:
    for view in ring_views:
        reference = _ray_cast_face_ids(ring, view)
        interior = _interior(reference)
        assert interior.mean() > 0.6  # enough pixels away from edges for the comparison to mean something
        agreement = (view.face_ids == reference)[interior].mean()
        assert agreement >= 0.99, f"face ids agree with ray casting on only {agreement:.4f} of interior pixels"
        # Over all pixels (edges included) the buffer still matches nearly everywhere.
        assert (view.face_ids == reference).mean() >= 0.99
        # Where no ray hits, the buffer is background.
        assert (view.face_ids[reference == -1] == -1).mean() >= 0.995


def test_face_ids_decode_to_real_faces(ring: trimesh.Trimesh, ring_views) -> None:
    seen = set()
    for view in ring_views:
        assert view.face_ids.dtype == np.int64 and view.face_ids.shape == (IMAGE_SIZE, IMAGE_SIZE)
        ids = view.face_ids
        assert ids.min() >= -1 and ids.max() < len(ring.faces)
        assert (ids == -1).any() and (ids >= 0).any()
        # Borders of the image are background: the rig frames the whole object.
        border = np.concatenate([ids[0], ids[-1], ids[:, 0], ids[:, -1]])
        assert (border == -1).all()
        seen.update(np.unique(ids[ids >= 0]).tolist())
    assert len(seen) > 0.3 * len(ring.faces)


def test_rgb_is_shaded_object_on_white(ring_views) -> None:
    for view in ring_views:
        assert view.rgb.shape == (IMAGE_SIZE, IMAGE_SIZE, 3) and view.rgb.dtype == np.uint8
        background = view.face_ids == -1
        assert (view.rgb[background] == 255).all()
        object_pixels = view.rgb[_interior(view.face_ids) & ~background].astype(float)
        assert object_pixels.max() < 250  # the surface is grey, not background white
        assert object_pixels.std() > 5  # shading varies with the surface normal


def test_rendering_happens_in_the_unit_normalised_frame(ring: trimesh.Trimesh, ring_views) -> None:
    moved = ring.copy()
    moved.apply_scale(3.0)
    moved.apply_translation([-2.0, 1.0, 0.5])
    views = render_views(moved, camera_rig(4, seed=3), image_size=IMAGE_SIZE)
    for view, reference in zip(views, ring_views):
        interior = _interior(reference.face_ids)
        assert (view.face_ids == reference.face_ids)[interior].mean() > 0.999


def test_image_size_and_intrinsics(ring: trimesh.Trimesh) -> None:
    (view,) = render_views(ring, camera_rig(1), image_size=96)
    assert view.size == (96, 96) and view.rgb.shape == (96, 96, 3)
    np.testing.assert_allclose(view.K, intrinsics(96))
    np.testing.assert_allclose(view.K[:2, 2], [48.0, 48.0])


def test_face_colour_code_round_trip() -> None:
    n_faces = 300_000
    colours = encode_face_colours(n_faces)
    np.testing.assert_array_equal(decode_face_ids(colours[None, :, :3])[0], np.arange(n_faces))
    assert decode_face_ids(np.zeros((2, 2, 3), dtype=np.uint8)).tolist() == [[-1, -1], [-1, -1]]


def test_camera_rig_layout() -> None:
    poses = camera_rig(10, seed=0)
    assert len(poses) == 10
    positions = np.array([pose[:3, 3] for pose in poses])
    np.testing.assert_allclose(np.linalg.norm(positions, axis=1), CAMERA_DISTANCE)
    for pose in poses:
        rotation = pose[:3, :3]
        np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)
        # OpenCV camera: z looks at the origin, image-down (y) points down in the world.
        np.testing.assert_allclose(rotation[:, 2], -pose[:3, 3] / np.linalg.norm(pose[:3, 3]), atol=1e-12)
        assert rotation[2, 1] < 0
    # Mostly from above the equator, never from straight above or below.
    elevations = np.degrees(np.arcsin(positions[:, 2] / CAMERA_DISTANCE))
    assert (elevations > 0).sum() >= 7 and elevations.max() < 80 and elevations.min() > -25
    # Around the object: no side is left without a view.
    azimuths = np.sort(np.degrees(np.arctan2(positions[:, 1], positions[:, 0])))
    gaps = np.diff(np.concatenate([azimuths, azimuths[:1] + 360.0]))
    assert gaps.max() < 90.0


def test_camera_rig_is_deterministic_per_seed() -> None:
    np.testing.assert_array_equal(np.array(camera_rig(5, seed=7)), np.array(camera_rig(5, seed=7)))
    assert not np.allclose(np.array(camera_rig(5, seed=7)), np.array(camera_rig(5, seed=8)))


def test_bad_rig_and_pose_arguments() -> None:
    with pytest.raises(ValueError, match="n_views"):
        camera_rig(0)
    with pytest.raises(ValueError, match="outside the unit sphere"):
        camera_rig(3, distance=0.5)
    with pytest.raises(ValueError, match="up vector"):
        look_at(np.array([0.0, 0.0, 3.0]))
    box = trimesh.creation.box([0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match="outside the unit sphere"):
        render_views(box, [look_at(np.array([0.5, 0.0, 0.2]))], image_size=32)
    with pytest.raises(ValueError, match="4x4"):
        render_views(box, [np.eye(3)], image_size=32)


def test_renderer_reuses_its_shader_program() -> None:
    """Regression: pyrender under OSMesa compiled (and kept) a new shader program on every render pass."""
    renderer = ViewRenderer(32)
    try:
        box = trimesh.creation.box([0.1, 0.1, 0.1])
        for _ in range(3):
            renderer.render(box, camera_rig(4))
        assert len(renderer._renderer._renderer._program_cache._program_cache) == 1
    finally:
        renderer.close()


@pytest.mark.slow
def test_face_ids_exact_on_a_real_scan(ycb_dir) -> None:
    """A YCB scan (16k faces, most smaller than a pixel here) renders to face ids that ray casting confirms."""
    from seggrasp.mesh import load_mesh

    prepared = load_mesh(ycb_dir / "035_power_drill" / "textured.obj")
    (view,) = render_views(prepared.mesh, camera_rig(1, seed=1), image_size=64)
    reference = _ray_cast_face_ids(prepared.mesh, view)
    on_object = (reference >= 0) | (view.face_ids >= 0)
    assert on_object.mean() > 0.05
    # Faces are too small for "interior" pixels, so compare every object pixel.
    assert (view.face_ids == reference)[on_object].mean() >= 0.98
    assert ((view.face_ids >= 0) == (reference >= 0)).mean() >= 0.995


@pytest.mark.parametrize("n_views, image_size, message", [
    (1000, 64, "between 1 and 64"), (1, 10000, "between 8 and 2048"), (64, 2048, "the limit is 32 Mpx")])
def test_absurd_rigs_are_refused_before_rendering(n_views: int, image_size: int, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        check_rig(n_views, image_size)
    box = trimesh.creation.box([0.1, 0.1, 0.1])
    with pytest.raises(ValueError, match=message):
        render_views(box, camera_rig(1) * n_views, image_size=image_size)  # refused before any GL work
    check_rig(10, 512)
    check_rig(32, 1024)
