"""Mesh loading, validation, repair and normalisation (seggrasp.mesh) and label files (seggrasp.labels)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from seggrasp.labels import PartLabels, read_labels, write_labels
from seggrasp.mesh import load_mesh, mesh_hash, prepare_mesh, unit_normalisation

FORMATS = ("obj", "ply", "off", "stl", "glb")


@pytest.fixture
def ring() -> trimesh.Trimesh:
    """A small closed mesh of a few hundred faces, 10 cm across (metres)."""
    return trimesh.creation.annulus(r_min=0.02, r_max=0.05, height=0.03, sections=32)


def _square_with_sliver() -> tuple[np.ndarray, np.ndarray]:
    """Two triangles of a unit square plus, between them in file order, a zero-area face on the diagonal."""
    vertices = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0.1, 0], [0, 0.1, 0], [0.05, 0.05, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 4, 2], [0, 2, 3]])
    return vertices, faces


# --------------------------------------------------------------------------------------------- loading formats


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_keeps_geometry_and_face_order(ring: trimesh.Trimesh, tmp_path: Path, fmt: str) -> None:
    path = tmp_path / f"ring.{fmt}"
    ring.export(path)
    prepared = load_mesh(path)
    assert prepared.source_path == path
    assert prepared.n_faces == prepared.n_source_faces == len(ring.faces)
    # Working face k is the input face source_face[k], with the same corners.
    np.testing.assert_allclose(prepared.mesh.triangles, ring.triangles[prepared.source_face], atol=1e-6)
    # STL stores three fresh vertices per triangle: duplicates must have been merged back.
    assert len(prepared.mesh.vertices) == len(ring.vertices)
    assert prepared.mesh.is_watertight


def test_unsupported_format_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "cloud.xyz"
    path.write_text("0 0 0\n1 1 1\n")
    with pytest.raises(ValueError, match="unsupported mesh format"):
        load_mesh(path)


def test_missing_file_is_reported(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="not found"):
        load_mesh(tmp_path / "nothing.obj")


@pytest.mark.parametrize(
    "name, content",
    [
        ("broken.obj", "v 1 2\nf 1 2 9\n"),
        ("broken.ply", "this is not a ply file"),
        ("broken.glb", "xx"),
        ("broken.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n"),
        ("broken.stl", "solid x\nnot a facet\n"),
        ("empty.obj", ""),
    ],
)
def test_corrupt_or_empty_file_gives_value_error(tmp_path: Path, name: str, content: str) -> None:
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(ValueError, match=str(path.name)):
        load_mesh(path)


@pytest.fixture
def no_charset_detector(monkeypatch) -> None:
    """As on a fresh machine: trimesh's optional charset detector is not installed."""
    monkeypatch.setitem(sys.modules, "charset_normalizer", None)
    monkeypatch.setitem(sys.modules, "chardet", None)


def _with_latin1_comment(data: bytes, fmt: str) -> bytes:
    if fmt == "ply":
        return data.replace(b"end_header", b"comment scanned in Z\xfcrich\nend_header", 1)
    if fmt == "stl":
        return data.replace(b"solid", b"solid caf\xe9", 1)
    return b"# scanned in Z\xfcrich\n" + data if fmt == "obj" else data + b"# caf\xe9\n"


@pytest.mark.parametrize("fmt", ["obj", "ply", "off", "stl"])
def test_text_mesh_with_a_latin1_byte_loads(ring, tmp_path: Path, no_charset_detector, fmt: str) -> None:
    plain = tmp_path / f"plain.{fmt}"
    ring.export(plain, **({"encoding": "ascii"} if fmt == "ply" else {"file_type": "stl_ascii"} if fmt == "stl" else {}))
    path = tmp_path / f"latin1.{fmt}"
    path.write_bytes(_with_latin1_comment(plain.read_bytes(), fmt))
    with pytest.raises(UnicodeDecodeError):
        path.read_bytes().decode("utf-8")
    prepared = load_mesh(path)
    assert prepared.n_source_faces == len(ring.faces)
    np.testing.assert_allclose(prepared.mesh.triangles, load_mesh(plain).mesh.triangles)


@pytest.mark.parametrize("fmt", FORMATS)
def test_binary_garbage_is_not_a_readable_mesh_of_its_format(tmp_path: Path, no_charset_detector, fmt: str) -> None:
    path = tmp_path / f"garbage.{fmt}"
    path.write_bytes(np.random.default_rng(0).bytes(5000))
    with pytest.raises(ValueError, match=rf"garbage.{fmt} is not a readable {fmt.upper()} mesh") as caught:
        load_mesh(path)
    assert "charset" not in str(caught.value)


@pytest.mark.parametrize("fmt", ["ply", "obj"])
def test_point_cloud_names_its_vertices_and_missing_faces(tmp_path: Path, fmt: str) -> None:
    path = tmp_path / f"cloud.{fmt}"
    trimesh.PointCloud(np.random.default_rng(0).random((1498, 3)) * 0.1).export(path)
    with pytest.raises(ValueError, match="1498 vertices and no faces"):
        load_mesh(path)


# --------------------------------------------------------------------------------------------- validation


def test_empty_arrays_are_rejected() -> None:
    with pytest.raises(ValueError, match="empty mesh"):
        prepare_mesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    with pytest.raises(ValueError, match="no faces"):
        prepare_mesh(np.eye(3) * 0.1, np.zeros((0, 3), dtype=int))


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_vertices_are_rejected(bad: float) -> None:
    vertices, faces = _square_with_sliver()
    vertices[3, 1] = bad
    with pytest.raises(ValueError, match="NaN or infinite.*vertex 3"):
        prepare_mesh(vertices, faces)


@pytest.mark.parametrize("index", [5, 100, -1])
def test_out_of_range_indices_are_rejected(index: int) -> None:
    vertices, faces = _square_with_sliver()
    faces[2, 1] = index
    with pytest.raises(ValueError, match="outside 0..4.*face 2"):
        prepare_mesh(vertices, faces)


def test_non_triangle_and_non_integer_faces_are_rejected() -> None:
    vertices, _ = _square_with_sliver()
    with pytest.raises(ValueError, match="triangles"):
        prepare_mesh(vertices, np.array([[0, 1, 2, 3]]))
    with pytest.raises(ValueError, match="integers"):
        prepare_mesh(vertices, np.array([[0.0, 1.0, 2.0]]))


def test_all_zero_area_faces_are_rejected() -> None:
    vertices = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0, 0.1, 0]], dtype=float)
    faces = np.array([[0, 1, 2], [3, 3, 0], [0, 1, 1]])  # collinear, and repeated indices
    with pytest.raises(ValueError, match="all 3 faces have zero area"):
        prepare_mesh(vertices, faces)


@pytest.mark.parametrize("scale", [1e-5, 1000.0])
def test_absurd_size_is_rejected(ring: trimesh.Trimesh, scale: float) -> None:
    with pytest.raises(ValueError, match="absurd size"):
        prepare_mesh(ring.vertices * scale, ring.faces)


def test_absurd_size_from_file_in_millimetres(ring: trimesh.Trimesh, tmp_path: Path) -> None:
    path = tmp_path / "mm.obj"
    trimesh.Trimesh(ring.vertices * 1000.0, ring.faces).export(path)
    with pytest.raises(ValueError, match="millimetres"):
        load_mesh(path)


# --------------------------------------------------------------------------------------------- repairs


def test_duplicate_vertices_are_merged_keeping_face_order(ring: trimesh.Trimesh) -> None:
    soup_vertices = ring.triangles.reshape(-1, 3)  # three private vertices per face
    soup_faces = np.arange(len(soup_vertices)).reshape(-1, 3)
    prepared = prepare_mesh(soup_vertices, soup_faces)
    assert len(prepared.mesh.vertices) == len(ring.vertices)
    np.testing.assert_array_equal(prepared.source_face, np.arange(len(ring.faces)))
    np.testing.assert_allclose(prepared.mesh.triangles, ring.triangles)
    assert prepared.mesh.is_watertight


def test_degenerate_faces_dropped_with_map_back_to_file_order() -> None:
    vertices, faces = _square_with_sliver()
    prepared = prepare_mesh(vertices, faces)
    assert prepared.n_faces == 2 and prepared.n_source_faces == 3
    np.testing.assert_array_equal(prepared.source_face, [0, 2])
    np.testing.assert_array_equal(prepared.dropped_faces, [1])
    # The dropped sliver takes its value from a kept neighbour.
    assert prepared.source_to_work[1] in (0, 1)
    np.testing.assert_array_equal(prepared.source_to_work[[0, 2]], [0, 1])

    working_values = np.array([10, 20])
    lifted = prepared.to_source(working_values)
    assert lifted.shape == (3,)
    np.testing.assert_array_equal(lifted[[0, 2]], [10, 20])
    np.testing.assert_array_equal(prepared.from_source(lifted), working_values)
    # Two-dimensional per-face arrays (faces x prompts) lift row-wise.
    scores = np.array([[1.0, 0.0], [0.0, 2.0]])
    np.testing.assert_array_equal(prepared.to_source(scores)[2], [0.0, 2.0])

    with pytest.raises(ValueError, match="one per working face"):
        prepared.to_source(np.zeros(3))
    with pytest.raises(ValueError, match="one per face of the input mesh"):
        prepared.from_source(np.zeros(2))


def test_degenerate_faces_dropped_from_a_file(ring: trimesh.Trimesh, tmp_path: Path) -> None:
    faces = np.insert(ring.faces, [7, 40], [[0, 0, 1], [2, 3, 3]], axis=0)  # two collapsed faces, file rows 7, 41
    path = tmp_path / "holes.obj"
    trimesh.Trimesh(ring.vertices, faces, process=False).export(path)
    prepared = load_mesh(path)
    assert prepared.n_source_faces == len(ring.faces) + 2
    np.testing.assert_array_equal(prepared.dropped_faces, [7, 41])
    np.testing.assert_allclose(prepared.mesh.triangles, ring.triangles, atol=1e-6)


def test_faces_collapsed_by_vertex_merging_are_dropped() -> None:
    vertices = np.array([[0, 0, 0], [1e-9, 0, 0], [0, 0.1, 0], [0.1, 0.1, 0], [0, 0, 0.1]], dtype=float)
    faces = np.array([[0, 1, 2], [0, 3, 2], [0, 2, 4]])
    prepared = prepare_mesh(vertices, faces)
    working = prepared.mesh.faces
    repeated = (working[:, 0] == working[:, 1]) | (working[:, 1] == working[:, 2]) | (working[:, 0] == working[:, 2])
    assert not repeated.any()


# --------------------------------------------------------------------------------------------- normalisation, hash


def test_unit_normalisation_fits_the_unit_sphere(ring: trimesh.Trimesh) -> None:
    shifted = ring.copy()
    shifted.apply_translation([0.3, -0.2, 0.5])
    transform = unit_normalisation(shifted)
    normalised = shifted.copy()
    normalised.apply_transform(transform)
    np.testing.assert_allclose(normalised.bounds.mean(axis=0), 0.0, atol=1e-9)
    assert np.linalg.norm(normalised.vertices, axis=1).max() == pytest.approx(1.0)


def test_mesh_hash_is_stable_and_sensitive(ring: trimesh.Trimesh) -> None:
    assert mesh_hash(ring) == mesh_hash(ring.copy())
    moved = ring.copy()
    moved.vertices[0] += 1e-6
    assert mesh_hash(moved) != mesh_hash(ring)


# --------------------------------------------------------------------------------------------- label files


@pytest.mark.parametrize("suffix", [".json", ".npz"])
def test_label_file_round_trip(tmp_path: Path, suffix: str) -> None:
    labels = PartLabels(["handle", "body"], np.array([0, 1, 1, -1, 0]))
    path = tmp_path / f"labels{suffix}"
    write_labels(path, labels)
    back = read_labels(path)
    assert back.parts == ["handle", "body"]
    np.testing.assert_array_equal(back.face_labels, [0, 1, 1, -1, 0])
    assert back.face_labels.dtype == np.int64
    assert not list(tmp_path.glob(".*.tmp"))  # the atomic writer left no temporary file


def test_label_file_json_layout(tmp_path: Path) -> None:
    path = tmp_path / "labels.json"
    write_labels(path, PartLabels(["a", "b"], np.array([1, 0])))
    assert json.loads(path.read_text()) == {"parts": ["a", "b"], "face_labels": [1, 0]}


def test_labels_remap_to_prompts_and_lookups() -> None:
    labels = PartLabels(["Handle", "body", "lid"], np.array([0, 1, 2, -1]))
    np.testing.assert_array_equal(labels.remap_to(["body", "handle"]), [1, 0, -1, -1])
    assert labels.part_index(" HANDLE ") == 0
    with pytest.raises(ValueError, match="no part named 'spout'"):
        labels.part_index("spout")
    labels.check_faces(4)
    with pytest.raises(ValueError, match="4 face labels but the mesh has 5 faces"):
        labels.check_faces(5)


@pytest.mark.parametrize(
    "parts, face_labels, message",
    [
        (["a"], [0, 1], "outside -1..0"),
        (["a", "b"], [0, -2], "outside -1..1"),
        (["a"], [0.5, 0], "integers"),
        (["a", "a"], [0, 1], "unique"),
        (["a"], [[0, 0]], "1-D"),
    ],
)
def test_bad_part_labels_are_rejected(parts: list, face_labels: list, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        PartLabels(parts, np.asarray(face_labels))


@pytest.mark.parametrize(
    "name, content",
    [
        ("truncated.json", "[1, 2"),
        ("list.json", "[1, 2]"),
        ("nokey.json", json.dumps({"parts": ["a"]})),
        ("range.json", json.dumps({"parts": ["a"], "face_labels": [0, 3]})),
        ("fraction.json", json.dumps({"parts": ["a"], "face_labels": [0, 0.5]})),
        ("corrupt.npz", "not a zip archive"),
    ],
)
def test_bad_label_files_are_rejected(tmp_path: Path, name: str, content: str) -> None:
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(ValueError, match=f"bad label file .*{name}"):
        read_labels(path)


def test_label_npz_without_face_labels_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "partial.npz"
    np.savez(path, parts=np.array(["a"]))
    with pytest.raises(ValueError, match="bad label file"):
        read_labels(path)


def test_label_file_type_and_presence(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        read_labels(tmp_path / "missing.json")
    (tmp_path / "labels.csv").write_text("0,1\n")
    with pytest.raises(ValueError, match="unsupported label file type"):
        read_labels(tmp_path / "labels.csv")
    with pytest.raises(ValueError, match="unsupported label file type"):
        write_labels(tmp_path / "labels.txt", PartLabels(["a"], np.array([0])))


@pytest.mark.parametrize("face_labels", [["0", "x"], [0, None]])
def test_label_file_with_non_numeric_labels_gives_value_error(tmp_path: Path, face_labels: list) -> None:
    path = tmp_path / "strings.json"
    path.write_text(json.dumps({"parts": ["a"], "face_labels": face_labels}))
    with pytest.raises(ValueError, match="bad label file"):
        read_labels(path)


def test_label_file_with_parts_as_a_string_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "parts.json"
    path.write_text(json.dumps({"parts": "ab", "face_labels": [0, 1]}))
    with pytest.raises(ValueError, match="parts"):
        read_labels(path)
