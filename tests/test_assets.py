"""The SegGraspSet twin: set composition, mesh and label validity, collision models, PyBullet behaviour,
graspable widths and regeneration (same files, numbers compared with a tolerance: CPUs and BLAS builds differ)."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from assets.__main__ import main as assets_main
from assets.catalog import CATEGORY_PARTS, OBJECT_SPECS, spec_by_id
from assets.generate import (
    ASSETS_DIR,
    GENERATOR_VERSION,
    TWIN_COLLISION,
    build_mesh,
    generate_object,
    label_hash,
    round_to_scale,
)
from seggrasp.mesh import mesh_hash
from seggrasp.object_physics import read_obj_arrays
from seggrasp.objects import ObjectModel, asset_ids, load_asset_set

MANIFEST = json.loads((ASSETS_DIR / "manifest.json").read_text())
RECORDS = {r["id"]: r for r in MANIFEST["objects"]}
ALL_IDS = [s.object_id for s in OBJECT_SPECS]
#: A 2F-85 opens to 85 mm; a part is graspable if some antipodal pair on it is closer than this.
MAX_GRASP_WIDTH = 0.080


@pytest.fixture(scope="module")
def models() -> dict[str, ObjectModel]:
    return {m.object_id: m for m in load_asset_set()}


def test_set_has_36_objects_in_12_categories_with_2_to_4_variants() -> None:
    assert asset_ids() == ALL_IDS
    assert MANIFEST["generator_version"] == GENERATOR_VERSION and MANIFEST["seed"] == 0
    per_category = Counter(r["category"] for r in MANIFEST["objects"])
    assert len(ALL_IDS) == 36
    assert set(per_category) == set(CATEGORY_PARTS)
    assert all(2 <= n <= 4 for n in per_category.values()), per_category
    for record in MANIFEST["objects"]:
        assert record["prompts"] == record["parts"] == list(CATEGORY_PARTS[record["category"]])
        for rel in record["files"].values():
            assert (ASSETS_DIR / rel).is_file(), rel


@pytest.mark.parametrize("object_id", ALL_IDS)
def test_mesh_is_closed_manifold_with_exact_connected_part_labels(models: dict[str, ObjectModel], object_id: str) -> None:
    model = models[object_id]
    mesh = model.mesh
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert mesh.body_count == 1, "parts must form ONE closed surface"
    assert 1000 <= len(mesh.faces) <= 20000
    labels = model.labels.face_labels
    assert labels.shape == (len(mesh.faces),)
    assert (labels >= 0).all(), "every face has a part"
    assert set(labels.tolist()) == set(range(len(model.prompts)))
    adjacency = mesh.face_adjacency
    for k, part in enumerate(model.prompts):
        faces = np.flatnonzero(labels == k)
        inside = (labels[adjacency[:, 0]] == k) & (labels[adjacency[:, 1]] == k)
        components = trimesh.graph.connected_components(adjacency[inside], nodes=faces, min_len=1)
        assert len(components) == 1, f"{object_id}: part {part!r} has {len(components)} regions"
    # sizes are those of real household objects
    assert 0.05 <= mesh.extents.max() <= 0.45
    assert np.allclose(mesh.extents, RECORDS[object_id]["dimensions"], atol=1e-6)
    assert abs(mesh.bounds[0, 2]) < 1e-9 and np.allclose(mesh.bounds[:, :2].sum(axis=0), 0.0, atol=1e-7)


@pytest.mark.parametrize("object_id", ALL_IDS)
def test_physical_properties_are_plausible(models: dict[str, ObjectModel], object_id: str) -> None:
    model = models[object_id]
    assert 0.01 <= model.mass <= 1.0
    density = model.mass / model.mesh.volume
    assert 250.0 <= density <= 8000.0
    assert 0.3 <= model.friction <= 1.0
    assert np.allclose(model.inertia, model.inertia.T)
    moments = np.linalg.eigvalsh(model.inertia)
    assert (moments > 0).all()
    assert moments[0] + moments[1] >= moments[2] * (1 - 1e-6)  # triangle inequality of a real body
    assert np.all(model.center_of_mass >= model.mesh.bounds[0]) and np.all(model.center_of_mass <= model.mesh.bounds[1])


@pytest.mark.parametrize("object_id", ALL_IDS)
def test_collision_model_is_convex_pieces_that_keep_concavities_open(models: dict[str, ObjectModel], object_id: str) -> None:
    model = models[object_id]
    hulls = model.collision_hulls
    hull_parts = RECORDS[object_id]["hull_parts"]
    assert len(hull_parts) == len(hulls)
    counts = Counter(hull_parts)
    assert sorted(counts) == list(range(len(model.prompts))), "every part has its own hulls"
    assert max(counts.values()) <= TWIN_COLLISION.max_hulls
    # a hull lies on its part: the surface nearest to its centroid carries the part's label
    _, _, nearest = trimesh.proximity.closest_point(model.mesh, np.array([h.center_mass for h in hulls]))
    assert np.mean(model.labels.face_labels[nearest] == np.array(hull_parts)) >= 0.9
    for hull in hulls:
        assert hull.is_watertight
        assert hull.volume == pytest.approx(hull.convex_hull.volume, rel=1e-6)
    lower = np.min([h.bounds[0] for h in hulls], axis=0)
    upper = np.max([h.bounds[1] for h in hulls], axis=0)
    assert np.allclose(lower, model.mesh.bounds[0], atol=0.004) and np.allclose(upper, model.mesh.bounds[1], atol=0.004)
    for point in RECORDS[object_id]["keep_open"]:
        for hull in hulls:
            assert not hull.contains([point])[0], f"{object_id}: collision hull fills {point}"
    # the collision model covers the surface: sampled surface points lie in or within 3 mm of a hull
    samples, _ = trimesh.sample.sample_surface(model.mesh, 300, seed=0)
    distance = np.min([np.abs(trimesh.proximity.signed_distance(h, samples)) * ~h.contains(samples) for h in hulls], axis=0)
    assert np.mean(distance < 0.003) > 0.97


def test_categories_with_openings_keep_them(models: dict[str, ObjectModel]) -> None:
    for object_id, record in RECORDS.items():
        if record["category"] in ("mug", "frying_pan", "wine_glass"):
            assert record["keep_open"], object_id
        if record["category"] == "mug":
            assert len(record["keep_open"]) == 2  # handle hole and cup cavity
            assert len(models[object_id].collision_hulls) >= 4
        if record["category"] in ("scissors", "eyeglasses"):
            assert len(record["keep_open"]) == 2, object_id  # two finger loops, two lens openings
        if record["category"] == "kettle":
            assert len(record["keep_open"]) == 1, object_id  # the space the hand goes through under the handle


#: The categories with three or more parts and the thin part of each (what a detector box covers worst).
THIN_PARTS = {"scissors": "pivot", "kettle": "spout", "eyeglasses": "bridge"}


def _part_faces(model: ObjectModel, part: str) -> np.ndarray:
    return np.flatnonzero(model.labels.face_labels == model.prompts.index(part))


@pytest.mark.parametrize("category", sorted(THIN_PARTS))
def test_multi_part_categories_have_a_thin_part_with_enough_faces(models: dict[str, ObjectModel], category: str) -> None:
    ids = asset_ids(category)
    assert len(ids) >= 2
    for object_id in ids:
        model = models[object_id]
        assert len(model.prompts) >= 3 and THIN_PARTS[category] in model.prompts
        faces = _part_faces(model, THIN_PARTS[category])
        assert len(faces) >= 100, f"{object_id}: {len(faces)} faces on the {THIN_PARTS[category]}"
        share = model.mesh.area_faces[faces].sum() / model.mesh.area
        assert 0.003 < share < 0.2, f"{object_id}: the thin part has {share:.1%} of the surface"
        widths = _antipodal_widths(model.mesh, faces)
        assert len(widths) >= 20 and np.median(widths) < 0.02, f"{object_id}: thin part {np.median(widths):.4f} m"


def _neighbour_labels(model: ObjectModel, faces: np.ndarray) -> np.ndarray:
    """Faces of other parts sharing an edge with `faces`."""
    inside = np.isin(model.mesh.face_adjacency, faces)
    pairs = model.mesh.face_adjacency[inside[:, 0] ^ inside[:, 1]]
    return np.unique(pairs[~np.isin(pairs, faces)])


def test_pivot_sits_on_both_blades_and_the_bridge_joins_both_rims(models: dict[str, ObjectModel]) -> None:
    for object_id in asset_ids("scissors"):
        model = models[object_id]
        labels, vertices = model.labels.face_labels, model.mesh.vertices
        pivot, blade = _part_faces(model, "pivot"), _part_faces(model, "blade")
        assert set(labels[_neighbour_labels(model, pivot)].tolist()) == {model.prompts.index("blade")}
        pivot_top = vertices[model.mesh.faces[pivot]][:, :, 2].max()
        assert pivot_top > vertices[model.mesh.faces[blade]][:, :, 2].max()  # the screw head caps the stack
        # the blades are stacked: blade faces at the table and blade faces above the lower blade's top
        blade_z = model.mesh.triangles_center[blade][:, 2]
        assert blade_z.min() < 0.001 and np.ptp(blade_z) > 0.0025
    for object_id in asset_ids("eyeglasses"):
        model = models[object_id]
        bridge = _part_faces(model, "bridge")
        touching = _neighbour_labels(model, bridge)
        assert set(model.labels.face_labels[touching].tolist()) == {model.prompts.index("rim")}
        x = model.mesh.triangles_center[touching][:, 0]
        assert x.min() < -0.005 and x.max() > 0.005, f"{object_id}: the bridge must join the left and right rim"


def test_finger_loops_and_lens_openings_stay_open_in_pybullet(models: dict[str, ObjectModel]) -> None:
    client = pb.connect(pb.DIRECT)
    try:
        for object_id in asset_ids(["scissors", "eyeglasses"]):
            body = pb.loadURDF(str(models[object_id].urdf_path), useFixedBase=True, physicsClientId=client)
            for point in RECORDS[object_id]["keep_open"]:
                hit = pb.rayTest([point[0], point[1], 0.1], [point[0], point[1], -0.05], physicsClientId=client)[0]
                assert hit[0] == -1, f"{object_id}: a vertical ray through {point} hits the collision model"
            pb.removeBody(body, physicsClientId=client)
    finally:
        pb.disconnect(client)


def _world() -> int:
    client = pb.connect(pb.DIRECT)
    pb.setGravity(0, 0, -9.81, physicsClientId=client)
    table = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[0.5, 0.5, 0.02], physicsClientId=client)
    pb.createMultiBody(0, table, basePosition=[0, 0, -0.02], physicsClientId=client)
    return client


@pytest.mark.slow
def test_every_object_settles_on_a_table_in_pybullet(models: dict[str, ObjectModel]) -> None:
    client = _world()
    try:
        for object_id, model in models.items():
            body = pb.loadURDF(str(model.urdf_path), basePosition=[0, 0, 0.02],
                               flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
            info = pb.getDynamicsInfo(body, -1, physicsClientId=client)
            assert info[0] == pytest.approx(model.mass, rel=1e-6)
            assert np.allclose(info[2], np.diag(model.inertia), rtol=1e-5)
            assert info[1] == pytest.approx(model.friction, rel=1e-3)
            assert np.allclose(info[3], model.center_of_mass, atol=1e-6)  # inertial frame = CoM, object axes
            assert np.allclose(info[4], [0, 0, 0, 1], atol=1e-9)
            for _ in range(480):  # 2 s to settle after the 2 cm drop
                pb.stepSimulation(physicsClientId=client)
            start = np.array(pb.getBasePositionAndOrientation(body, physicsClientId=client)[0])
            for _ in range(240):  # 1 s
                pb.stepSimulation(physicsClientId=client)
            end, orientation = pb.getBasePositionAndOrientation(body, physicsClientId=client)
            assert np.linalg.norm(np.array(end) - start) < 0.005, f"{object_id} moved {np.linalg.norm(end - start):.4f} m"
            # base pose = inertial frame (object axes, origin at the CoM): the mesh rests on the table top
            rotation = Rotation.from_quat(orientation).as_matrix()
            world = model.mesh.vertices @ rotation.T + (np.array(end) - rotation @ model.center_of_mass)
            assert -0.002 < world[:, 2].min() < 0.003, f"{object_id} rests at z = {world[:, 2].min():.4f}"
            pb.removeBody(body, physicsClientId=client)
    finally:
        pb.disconnect(client)


def test_pybullet_loads_collision_obj_as_compound_with_mug_handle_hole_open(models: dict[str, ObjectModel]) -> None:
    client = pb.connect(pb.DIRECT)
    try:
        for object_id in asset_ids("mug"):
            body = pb.loadURDF(str(models[object_id].urdf_path), useFixedBase=True, physicsClientId=client)
            hole, cavity = (np.array(p) for p in RECORDS[object_id]["keep_open"])
            through_hole = pb.rayTest((hole - [0, 0.1, 0]).tolist(), (hole + [0, 0.1, 0]).tolist(), physicsClientId=client)
            assert through_hole[0][0] == -1, f"{object_id}: a ray through the handle hole hits the collision model"
            down = pb.rayTest((cavity + [0, 0, 0.2]).tolist(), [cavity[0], cavity[1], -0.1], physicsClientId=client)
            assert down[0][0] == body and down[0][3][2] < 0.012, f"{object_id}: cavity filled (hit {down[0][3]})"
            pb.removeBody(body, physicsClientId=client)
    finally:
        pb.disconnect(client)


def _antipodal_widths(mesh: trimesh.Trimesh, faces: np.ndarray, n: int = 200, seed: int = 0) -> np.ndarray:
    """Distances from points on `faces` straight through the solid (along -normal) to an opposing surface."""
    rng = np.random.default_rng(seed)
    chosen = rng.choice(faces, size=n, p=mesh.area_faces[faces] / mesh.area_faces[faces].sum())
    bary = rng.dirichlet([1, 1, 1], size=n)
    points = np.einsum("ij,ijk->ik", bary, mesh.triangles[chosen])
    normals = mesh.face_normals[chosen]
    origins = points - normals * 1e-5
    locations, rays, hit_faces = mesh.ray.intersects_location(origins, -normals, multiple_hits=False)
    opposing = np.einsum("ij,ij->i", mesh.face_normals[hit_faces], normals[rays]) < -0.8  # inside a friction cone
    return np.linalg.norm(locations - origins[rays], axis=1)[opposing]


#: Parts wider than the gripper's stroke all round, as the real ones are: a kettle is lifted by its handle.
TOO_WIDE_PARTS = {("kettle", "body")}


@pytest.mark.parametrize("object_id", ALL_IDS)
def test_every_part_has_a_graspable_width(models: dict[str, ObjectModel], object_id: str) -> None:
    model = models[object_id]
    for k, part in enumerate(model.prompts):
        widths = _antipodal_widths(model.mesh, np.flatnonzero(model.labels.face_labels == k))
        graspable = (widths > 0.001) & (widths < MAX_GRASP_WIDTH)
        if (model.category, part) in TOO_WIDE_PARTS:
            assert graspable.sum() < 10, f"{object_id}: part {part!r} is listed as too wide but fits the gripper"
        else:
            assert graspable.sum() >= 10, f"{object_id}: part {part!r} has no antipodal width under 80 mm"


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


#: Byte-derived fields of a manifest record: equal bytes on one machine, compared through the files themselves.
BYTE_HASHES = ("sha256", "mesh_hash")
NUMBER = re.compile(r"-?\d+(?:\.\d*)?(?:e[-+]?\d+)?")


def _assert_close(actual: object, expected: object, where: str = "record") -> None:
    """Equal structure, strings and integers; floats within 1e-6 relative or 1e-12 absolute."""
    if isinstance(expected, dict):
        assert isinstance(actual, dict) and actual.keys() == expected.keys(), where
        for key in expected:
            if key not in BYTE_HASHES:
                _assert_close(actual[key], expected[key], f"{where}.{key}")
    elif isinstance(expected, list):
        assert isinstance(actual, list) and len(actual) == len(expected), where
        for k, (a, e) in enumerate(zip(actual, expected)):
            _assert_close(a, e, f"{where}[{k}]")
    elif isinstance(expected, float):
        assert actual == pytest.approx(expected, rel=1e-6, abs=1e-12), where
    else:
        assert actual == expected, where


def _assert_same_text_and_numbers(actual: str, expected: str, where: str) -> None:
    """Same text once numbers are masked, numbers within 1e-6 relative (a URDF)."""
    assert NUMBER.sub("#", actual) == NUMBER.sub("#", expected), where
    _assert_close([float(x) for x in NUMBER.findall(actual)], [float(x) for x in NUMBER.findall(expected)], where)


def _assert_same_obj_geometry(actual: Path, expected: Path, atol: float = 1.5e-8) -> None:
    """Same groups and faces; vertices equal up to the last written decimal (1e-8 m) of another machine's sums."""
    groups, reference = read_obj_arrays(actual), read_obj_arrays(expected)
    assert len(groups) == len(reference), actual
    for (vertices, faces), (ref_vertices, ref_faces) in zip(groups, reference):
        assert np.array_equal(faces, ref_faces), actual
        assert np.allclose(vertices, ref_vertices, rtol=0.0, atol=atol), actual


@pytest.mark.parametrize("object_id", ALL_IDS)
def test_committed_files_match_their_manifest_hashes(object_id: str) -> None:
    record = RECORDS[object_id]
    for key in ("mesh", "labels", "urdf", "collision"):
        assert _sha(ASSETS_DIR / record["files"][key]) == record["sha256"][key], key


@pytest.mark.parametrize("object_id", ALL_IDS)
def test_regeneration_reproduces_committed_files(tmp_path: Path, object_id: str) -> None:
    record = RECORDS[object_id]
    out = tmp_path / "objects" / object_id
    out.mkdir(parents=True)
    shutil.copy(ASSETS_DIR / record["files"]["collision"], out / "collision.obj")  # CoACD is checked separately
    regenerated = generate_object(spec_by_id(object_id), out, seed=MANIFEST["seed"], collision=False)
    _assert_same_obj_geometry(out / "mesh.obj", ASSETS_DIR / record["files"]["mesh"])
    assert (out / "labels.json").read_text() == (ASSETS_DIR / record["files"]["labels"]).read_text()
    _assert_same_text_and_numbers((out / "object.urdf").read_text(), (ASSETS_DIR / record["files"]["urdf"]).read_text(),
                                  object_id)
    _assert_close(regenerated, record, object_id)


def _noisy(mass_properties):
    """`mass_properties` plus the floating-point noise another CPU's summation order gives (relative 1e-15, and
    1e-20-sized products of inertia / 1e-17 m centre offsets where the exact value is 0)."""
    rng = np.random.default_rng(7)

    def noisy(solid: trimesh.Trimesh, density: float):
        props = mass_properties(solid, density)
        noise = rng.uniform(-1.0, 1.0, (3, 3)) * 1e-20
        inertia = props.inertia * (1.0 + rng.uniform(-1e-15, 1e-15, (3, 3))) + noise + noise.T
        com = props.center_of_mass * (1.0 + rng.uniform(-1e-15, 1e-15, 3)) + rng.uniform(-1e-17, 1e-17, 3)
        return type(props)(mass=props.mass * (1.0 + 1e-15), center_of_mass=com, inertia=0.5 * (inertia + inertia.T))

    return noisy


@pytest.mark.parametrize(("object_id", "zero_product"), [("hammer_ballpeen", (0, 2)), ("frying_pan_24", (0, 1))])
def test_floating_point_noise_does_not_change_the_generated_files(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, object_id: str, zero_product: tuple[int, int]
) -> None:
    """Regression: on another CPU, products of inertia of -4.37e-22 instead of -1.02e-21 (exactly 0 for these
    symmetric objects) changed the manifest, and a 1e-17 m centre of mass off the symmetry plane the URDF."""
    import assets.generate as generate

    outputs = {}
    for run in ("exact", "noisy"):
        if run == "noisy":
            monkeypatch.setattr(generate, "mass_properties", _noisy(generate.mass_properties))
        out = tmp_path / run
        out.mkdir()
        shutil.copy(ASSETS_DIR / RECORDS[object_id]["files"]["collision"], out / "collision.obj")
        record = generate_object(spec_by_id(object_id), out, seed=MANIFEST["seed"], collision=False)
        outputs[run] = (record, (out / "object.urdf").read_text())
    assert outputs["noisy"] == outputs["exact"]
    row, column = zero_product
    assert outputs["exact"][0]["inertia"][row][column] == 0.0  # the noise is gone, not just made equal


def test_rounding_to_a_scale_keeps_significant_digits_and_zeroes_noise() -> None:
    values = np.array([0.0045670435, -1.0162e-21, 4.37e-22, -0.000557168349, 7.2e-10, 0.0])
    rounded = round_to_scale(values, scale=0.0056500682, digits=7)
    assert rounded.tolist() == [0.004567044, 0.0, 0.0, -0.000557168, 1e-09, 0.0]
    assert not np.signbit(rounded[1])  # no -0.0 in the files
    assert round_to_scale(0.48098808123, 0.48098808123, 8) == 0.48098808
    with pytest.raises(ValueError, match="positive"):
        round_to_scale(values, scale=0.0, digits=7)


def test_another_seed_gives_other_valid_shapes() -> None:
    spec = spec_by_id("mug_classic")
    default, other = build_mesh(spec, 0), build_mesh(spec, 1)
    committed = read_obj_arrays(ASSETS_DIR / RECORDS["mug_classic"]["files"]["mesh"])[0]
    assert np.array_equal(default.mesh.faces, committed[1])
    assert np.allclose(default.mesh.vertices, committed[0], rtol=0.0, atol=1.5e-8)
    assert label_hash(default.labels.face_labels) == RECORDS["mug_classic"]["label_hash"]
    assert mesh_hash(other.mesh) != mesh_hash(default.mesh)
    assert other.mesh.is_watertight and set(other.labels.face_labels.tolist()) == {0, 1}


def test_collision_arrays_read_back_as_separate_hulls() -> None:
    groups = read_obj_arrays(ASSETS_DIR / RECORDS["mug_classic"]["files"]["collision"])
    assert len(groups) == RECORDS["mug_classic"]["n_hulls"] >= 4
    assert all(trimesh.Trimesh(v, f).is_convex for v, f in groups)


@pytest.mark.slow
def test_coacd_collision_model_is_reproduced(tmp_path: Path) -> None:
    record = RECORDS["mug_classic"]
    regenerated = generate_object(spec_by_id("mug_classic"), tmp_path, seed=MANIFEST["seed"], collision=True)
    _assert_same_obj_geometry(tmp_path / "collision.obj", ASSETS_DIR / record["files"]["collision"])
    _assert_close(regenerated, record)


@pytest.mark.slow
def test_cli_lists_and_renders_a_gallery(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert assets_main(["list"]) == 0
    out = capsys.readouterr().out
    assert "36 objects in 12 categories" in out and "wine_glass_coupe" in out and "eyeglasses_aviator" in out
    png = tmp_path / "mugs.png"
    assert assets_main(["gallery", "--category", "mug", "--out", str(png), "--columns", "2"]) == 0
    from PIL import Image

    image = np.asarray(Image.open(png).convert("RGB"))
    assert image.shape[0] > 300 and image.shape[1] > 300
    assert (np.abs(image.astype(int) - [230, 85, 60]).sum(axis=2) < 60).sum() > 100  # handle colour is visible
    assert assets_main(["list", "--category", "teapot"]) == 2
    assert "unknown categories" in capsys.readouterr().err
    assert (ASSETS_DIR / "gallery.png").is_file()


def test_cli_generates_one_object_into_another_folder(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert assets_main(["generate", "--only", "knife_paring", "--root", str(tmp_path), "--no-collision"]) == 2
    assert "no collision model" in capsys.readouterr().err
    assert assets_main(["generate", "--only", "knife_paring", "--root", str(tmp_path)]) == 0  # CoACD on 2 parts
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert [r["id"] for r in manifest["objects"]] == ["knife_paring"]
    _assert_close(manifest["objects"][0], RECORDS["knife_paring"])
    _assert_same_obj_geometry(tmp_path / "objects" / "knife_paring" / "collision.obj",
                              ASSETS_DIR / RECORDS["knife_paring"]["files"]["collision"])
