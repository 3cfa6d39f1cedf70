"""bench/bench_collision_fit.py: how far collision hulls stand off the mesh."""

import numpy as np
import trimesh

from bench.bench_collision_fit import collision_fit, main, outside_samples


def _box(lower, upper) -> trimesh.Trimesh:
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    return trimesh.creation.box(extents=upper - lower, transform=trimesh.transformations.translation_matrix((lower + upper) / 2))


def test_faces_two_hulls_share_are_not_outside_surface():
    points, owner = outside_samples([_box((0, 0, 0), (1, 1, 1)), _box((1, 0, 0), (2, 1, 1))], per_hull=3000)
    assert len(points) > 3000  # five outer faces of each box remain
    assert not np.any(np.isclose(points[:, 0], 1.0, atol=1e-9))  # nothing on the shared face x = 1
    assert set(owner) == {0, 1}


def test_a_hull_that_bridges_a_notch_stands_off_by_the_notch_depth():
    # an L-shaped prism: [0, 2] x [0, 1] with [0, 1] x [1, 2], 1 deep; one convex hull bridges the notch at (1, 1)
    mesh = trimesh.boolean.union([_box((0, 0, 0), (2, 1, 1)), _box((0, 0.999, 0), (1, 2, 1))], engine="manifold")
    fit = collision_fit("ell", mesh, [mesh.convex_hull], ["body_0"], per_hull=20000)
    # the bridging face x + y = 3 lies at most 0.5 from the notch's faces (at its middle, (1.5, 1.5))
    assert 0.45 < fit.distances.max() <= 0.5 + 1e-3
    assert np.median(fit.distances) < 1e-6  # elsewhere the hull is the mesh's own surface
    assert fit.worst_part == "body" and fit.hulls == 1


def test_an_exact_hull_fits_everywhere():
    mesh = _box((0, 0, 0), (0.1, 0.05, 0.02))
    fit = collision_fit("box", mesh, [mesh.copy()], ["body_0"], per_hull=2000)
    assert fit.distances.max() < 1e-9


def test_an_unknown_object_is_one_sentence_and_exit_2(capsys):
    assert main(["--objects", "no_such_thing"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no_such_thing" in err
