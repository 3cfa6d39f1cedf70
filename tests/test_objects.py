"""Object loaders and physical models: the twin's loaders, mass properties, OBJ/URDF writing, external meshes
(synthetic and real YCB scans)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from seggrasp.labels import PartLabels, write_labels
from seggrasp.object_physics import (
    CollisionConfig,
    MassProperties,
    combine_mass_properties,
    mass_properties,
    obj_text,
    read_collision_hulls,
    urdf_text,
    write_collision_obj,
)
from seggrasp.objects import (
    ObjectModel,
    asset_ids,
    estimate_mass_properties,
    load_asset,
    load_asset_set,
    load_external_object,
)

#: Coarse CoACD settings for tests: a few hulls, quickly.
FAST_COLLISION = CollisionConfig(threshold=0.15, max_hulls=6, resolution=400, mcts_iterations=15, preprocess="on",
                                 max_faces=2000)


def test_asset_ids_filter_by_category_and_reject_unknown_names() -> None:
    mugs = asset_ids("mug")
    assert mugs and all(i.startswith("mug_") for i in mugs)
    both = asset_ids(["mug", "knife"])
    assert set(both) == set(mugs) | set(asset_ids("knife"))
    assert both == [i for i in asset_ids() if i in both]  # manifest order
    with pytest.raises(ValueError, match="unknown categories.*teapot"):
        asset_ids(["mug", "teapot"])
    with pytest.raises(ValueError, match="unknown object id 'teapot'"):
        load_asset("teapot")


def test_load_asset_returns_a_complete_object_model() -> None:
    model = load_asset("mug_classic")
    assert isinstance(model, ObjectModel)
    assert model.category == "mug" and model.prompts == ["handle", "body"]
    assert model.labels is not None and model.labels.parts == model.prompts
    assert model.labels.n_faces == len(model.mesh.faces)
    assert model.mesh_path.is_file() and model.collision_path.is_file() and model.urdf_path.is_file()
    assert len(model.collision_hulls) >= 4
    assert model.center_of_mass.shape == (3,) and model.inertia.shape == (3, 3)
    assert [m.object_id for m in load_asset_set("wine_glass")] == asset_ids("wine_glass")


def test_load_asset_detects_a_tampered_mesh(tmp_path: Path) -> None:
    from seggrasp.objects import ASSETS_DIR

    manifest = json.loads((ASSETS_DIR / "manifest.json").read_text())
    record = next(r for r in manifest["objects"] if r["id"] == "knife_chef")
    for rel in record["files"].values():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes((ASSETS_DIR / rel).read_bytes())
    (tmp_path / "manifest.json").write_text(json.dumps({**manifest, "objects": [record]}))
    assert load_asset("knife_chef", assets_dir=tmp_path).object_id == "knife_chef"
    mesh_file = tmp_path / record["files"]["mesh"]
    lines = mesh_file.read_text().splitlines()
    lines[0] = "v 0.5 0.5 0.5"  # one vertex moved
    mesh_file.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match="does not match the manifest"):
        load_asset("knife_chef", assets_dir=tmp_path)


def test_mass_properties_of_a_box_match_the_closed_form() -> None:
    size = np.array([0.1, 0.04, 0.02])
    box = trimesh.creation.box(size)
    box.apply_translation([0.3, 0.0, 0.0])
    props = mass_properties(box, 2000.0)
    mass = 2000.0 * size.prod()
    assert props.mass == pytest.approx(mass)
    assert np.allclose(props.center_of_mass, [0.3, 0, 0])
    expected = mass / 12.0 * np.array([size[1] ** 2 + size[2] ** 2, size[0] ** 2 + size[2] ** 2, size[0] ** 2 + size[1] ** 2])
    assert np.allclose(np.diag(props.inertia), expected, rtol=1e-9)
    with pytest.raises(ValueError, match="density"):
        mass_properties(box, 0.0)


def test_combining_two_halves_gives_the_whole_body() -> None:
    left = trimesh.creation.box([0.05, 0.04, 0.02])
    left.apply_translation([-0.025, 0, 0])
    right = trimesh.creation.box([0.05, 0.04, 0.02])
    right.apply_translation([0.025, 0, 0])
    combined = combine_mass_properties([mass_properties(left, 700.0), mass_properties(right, 700.0)])
    whole = mass_properties(trimesh.creation.box([0.1, 0.04, 0.02]), 700.0)
    assert combined.mass == pytest.approx(whole.mass)
    assert np.allclose(combined.center_of_mass, whole.center_of_mass, atol=1e-12)
    assert np.allclose(combined.inertia, whole.inertia, rtol=1e-9)


def test_urdf_and_compound_collision_obj_load_in_pybullet(tmp_path: Path) -> None:
    # an L-shaped object from two boxes: a compound keeps the inner corner empty, a single hull would fill it
    a = trimesh.creation.box([0.1, 0.02, 0.02])
    a.apply_translation([0.05, 0.01, 0.01])
    b = trimesh.creation.box([0.02, 0.1, 0.02])
    b.apply_translation([0.01, 0.05, 0.01])
    write_collision_obj(tmp_path / "collision.obj", [a, b])
    assert len(read_collision_hulls(tmp_path / "collision.obj")) == 2
    union = trimesh.util.concatenate([a, b])
    (tmp_path / "mesh.obj").write_text(obj_text(union.vertices, union.faces))
    props = MassProperties(0.2, np.array([0.03, 0.03, 0.01]), np.diag([1e-4, 2e-4, 3e-4]))
    (tmp_path / "object.urdf").write_text(urdf_text("ell", "mesh.obj", "collision.obj", props, 0.7))
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(tmp_path / "object.urdf"), flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
        info = pb.getDynamicsInfo(body, -1, physicsClientId=client)
        assert info[0] == pytest.approx(0.2) and info[1] == pytest.approx(0.7)
        assert np.allclose(info[2], [1e-4, 2e-4, 3e-4]) and np.allclose(info[3], [0.03, 0.03, 0.01])
        inner_corner = pb.rayTest([0.07, 0.07, 0.1], [0.07, 0.07, -0.1], physicsClientId=client)
        assert inner_corner[0][0] == -1, "the OBJ's hulls were merged into one convex hull"
        on_arm = pb.rayTest([0.07, 0.01, 0.1], [0.07, 0.01, -0.1], physicsClientId=client)
        assert on_arm[0][0] == body and on_arm[0][3][2] == pytest.approx(0.02, abs=1e-3)
    finally:
        pb.disconnect(client)


def test_estimated_mass_properties_say_how_they_were_obtained() -> None:
    cylinder = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=64)
    exact, how = estimate_mass_properties(cylinder, 1000.0)
    assert how.startswith("exact") and exact.mass == pytest.approx(1000 * cylinder.volume)
    one_hole = cylinder.copy()
    one_hole.update_faces(np.arange(1, len(one_hole.faces)))
    filled, how = estimate_mass_properties(one_hole, 1000.0)
    assert "filling holes" in how and filled.mass == pytest.approx(exact.mass, rel=1e-6)
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.04)
    bowl = sphere.copy()
    bowl.update_faces(sphere.triangles_center[:, 2] < 0.02)  # a big hole: an open thin shell
    voxel, how = estimate_mass_properties(bowl, 1000.0)
    assert "voxelisation" in how
    assert 0 < voxel.mass < 0.1 * 1000.0 * sphere.volume  # an open thin shell weighs far less than the solid ball


def _write_scaled_box(path: Path, scale: float) -> trimesh.Trimesh:
    box = trimesh.creation.box([0.08 * scale, 0.05 * scale, 0.03 * scale])
    box.apply_translation(np.array([0.5, -0.2, 0.7]) * scale)  # arbitrary origin
    path.write_text(obj_text(box.vertices, box.faces))
    return box


def test_external_mesh_becomes_a_physical_object(tmp_path: Path) -> None:
    box = _write_scaled_box(tmp_path / "brick.obj", 1.0)
    labels = np.where(box.triangles_center[:, 0] > 0.5, 0, 1)  # +x half "end", the rest "middle"
    write_labels(tmp_path / "brick.json", PartLabels(["end", "middle"], labels))
    model = load_external_object(tmp_path / "brick.obj", tmp_path / "brick.json", prompts=["middle", "end"],
                                 density=500.0, friction=0.8, cache_dir=tmp_path / "cache", collision=FAST_COLLISION)
    assert model.object_id == "brick" and model.category == "external"
    assert model.prompts == ["middle", "end"]
    assert np.array_equal(model.labels.face_labels, 1 - labels)  # relabelled to prompt order
    assert model.mass == pytest.approx(500.0 * 0.08 * 0.05 * 0.03)
    assert np.allclose(model.mesh.bounds, [[-0.04, -0.025, 0.0], [0.04, 0.025, 0.03]], atol=1e-9)  # twin frame
    assert np.allclose(model.center_of_mass, [0, 0, 0.015], atol=1e-9)
    assert model.notes and "exact" in model.notes[0]
    assert model.urdf_path.parent.parent == tmp_path / "cache" and model.collision_hulls
    fixed = load_external_object(tmp_path / "brick.obj", mass=0.3, cache_dir=tmp_path / "cache", collision=FAST_COLLISION)
    assert fixed.mass == pytest.approx(0.3) and fixed.labels is None and fixed.prompts == []
    assert fixed.collision_path == model.collision_path  # CoACD result reused from the cache


def test_external_loader_rejects_what_cannot_be_made_physical(tmp_path: Path) -> None:
    _write_scaled_box(tmp_path / "millimetres.obj", 1000.0)
    with pytest.raises(ValueError, match="absurd size"):
        load_external_object(tmp_path / "millimetres.obj", cache_dir=tmp_path)
    _write_scaled_box(tmp_path / "crate.obj", 15.0)
    with pytest.raises(ValueError, match="tabletop object"):
        load_external_object(tmp_path / "crate.obj", cache_dir=tmp_path)
    sheet = trimesh.creation.box([0.1, 0.1, 0.0002])
    (tmp_path / "sheet.obj").write_text(obj_text(sheet.vertices, sheet.faces))
    with pytest.raises(ValueError, match="flat: its thinnest side is 0.2 mm"):
        load_external_object(tmp_path / "sheet.obj", cache_dir=tmp_path)
    box = _write_scaled_box(tmp_path / "brick.obj", 1.0)
    write_labels(tmp_path / "short.json", PartLabels(["a"], np.zeros(len(box.faces) - 1, dtype=int)))
    with pytest.raises(ValueError, match="face labels"):
        load_external_object(tmp_path / "brick.obj", tmp_path / "short.json", cache_dir=tmp_path)
    with pytest.raises(ValueError, match="density"):
        load_external_object(tmp_path / "brick.obj", density=-1.0, cache_dir=tmp_path)
    with pytest.raises(FileNotFoundError):
        load_external_object(tmp_path / "missing.obj", cache_dir=tmp_path)


@pytest.mark.slow
def test_ycb_scans_load_through_the_external_loader(ycb_dir: Path, tmp_path: Path) -> None:
    # the mug scan has non-manifold edges (not watertight): its volume still comes from the closed surface
    from seggrasp.mesh import load_mesh

    mug = load_mesh(ycb_dir / "025_mug" / "textured.obj").mesh
    assert not mug.is_watertight
    props, how = estimate_mass_properties(mug, 1000.0)
    assert "closed" in how and 0.05 < props.mass < 0.3

    hammer = load_external_object(ycb_dir / "048_hammer" / "textured.obj", prompts=["handle", "head"], mass=0.665,
                                  cache_dir=tmp_path, collision=FAST_COLLISION)
    assert hammer.object_id == "048_hammer" and hammer.mass == pytest.approx(0.665)
    assert len(hammer.mesh.faces) == 16384 and hammer.mesh.bounds[0, 2] == pytest.approx(0.0)
    assert 1 <= len(hammer.collision_hulls) <= FAST_COLLISION.max_hulls
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0, 0, -9.81, physicsClientId=client)
        pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client), physicsClientId=client)
        body = pb.loadURDF(str(hammer.urdf_path), basePosition=[0, 0, 0.02], flags=pb.URDF_USE_INERTIA_FROM_FILE,
                           physicsClientId=client)
        for _ in range(480):
            pb.stepSimulation(physicsClientId=client)
        start = np.array(pb.getBasePositionAndOrientation(body, physicsClientId=client)[0])
        for _ in range(240):
            pb.stepSimulation(physicsClientId=client)
        end, orientation = pb.getBasePositionAndOrientation(body, physicsClientId=client)
        assert np.linalg.norm(np.array(end) - start) < 0.005
        rotation = Rotation.from_quat(orientation).as_matrix()
        world = hammer.mesh.vertices @ rotation.T + (np.array(end) - rotation @ hammer.center_of_mass)
        assert -0.002 < world[:, 2].min() < 0.003
    finally:
        pb.disconnect(client)


@pytest.mark.slow
def test_non_watertight_ycb_mug_becomes_a_physical_object(ycb_dir: Path, tmp_path: Path) -> None:
    mug = load_external_object(ycb_dir / "025_mug" / "textured.obj", prompts=["handle", "body"], density=1100.0,
                               cache_dir=tmp_path)
    assert "closed (but not 2-manifold)" in mug.notes[0]
    assert 0.08 < mug.mass < 0.25  # YCB mass sheet: 0.118 kg
    assert 2 <= len(mug.collision_hulls) <= 16
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(mug.urdf_path), useFixedBase=True, physicsClientId=client)
        top = mug.mesh.bounds[1, 2]
        # the cup stays hollow: a ray down the middle reaches the inside of the floor, far below the rim
        hit = pb.rayTest([0.0, 0.0, top + 0.1], [0.0, 0.0, -0.1], physicsClientId=client)[0]
        assert hit[0] == body and hit[3][2] < 0.5 * top
    finally:
        pb.disconnect(client)


def test_coacd_runs_isolated_so_an_abort_becomes_a_clear_error(monkeypatch: pytest.MonkeyPatch) -> None:
    import seggrasp.object_physics as objects

    box = trimesh.creation.box([0.05, 0.04, 0.03])
    vertices, faces = np.asarray(box.vertices, dtype=np.float64), np.asarray(box.faces, dtype=np.int32)
    assert objects._run_coacd_isolated(vertices, faces, {"no_such_option": 1}) is None  # the child died
    assert len(objects.convex_decomposition(box, FAST_COLLISION)) == 1
    calls = []
    monkeypatch.setattr(objects, "_run_coacd_isolated", lambda v, f, options: calls.append(options) or None)
    with pytest.raises(ValueError, match="CoACD aborted on this mesh"):
        objects.convex_decomposition(box, FAST_COLLISION)
    assert [c["preprocess_mode"] for c in calls] == ["on", "off"]
