"""Ground-truth labels moved onto another mesh (seggrasp.truth.transfer_labels): exact near the labelled surface,
bounded far from it (a perceived instance that is another object)."""

from __future__ import annotations

import numpy as np
import trimesh

from seggrasp.truth import transfer_labels


def labelled_bar() -> tuple[trimesh.Trimesh, np.ndarray]:
    """A 12 cm bar along x, its faces labelled 1 where x > 0 (a 'handle') and 0 elsewhere."""
    bar = trimesh.creation.box([0.12, 0.02, 0.02]).subdivide().subdivide()
    return bar, (bar.triangles_center[:, 0] > 0).astype(np.int64)


def test_faces_on_the_labelled_surface_take_their_exactly_nearest_face_s_label() -> None:
    bar, labels = labelled_bar()
    perceived = trimesh.creation.box([0.121, 0.021, 0.021]).subdivide().subdivide().subdivide()
    moved = transfer_labels(bar, labels, perceived, np.eye(4))
    _, _, nearest = trimesh.proximity.closest_point(bar, perceived.triangles_center)
    assert np.array_equal(moved, labels[nearest])
    x = perceived.triangles_center[:, 0]
    assert np.all(moved[x > 0.005] == 1) and np.all(moved[x < -0.005] == 0)


def test_a_mesh_far_from_the_labelled_one_gets_the_labels_of_its_nearest_samples() -> None:
    bar, labels = labelled_bar()
    other = trimesh.creation.icosphere(subdivisions=4, radius=0.03)
    T = np.eye(4)
    T[:3, 3] = [0.0, 0.3, 0.0]  # 30 cm beside the bar's middle: every face centre is far from it
    moved = transfer_labels(bar, labels, other, T)
    centres = other.triangles_center + T[:3, 3]
    _, _, nearest = trimesh.proximity.closest_point(bar, centres)
    assert 0.2 < labels[nearest].mean() < 0.8  # the nearest faces lie on both sides of the label boundary
    assert len(moved) == len(other.faces) and np.mean(moved == labels[nearest]) > 0.95
