"""The three- and four-part generated categories (pliers, kettle, eyeglasses) waiting to be wired into the catalog."""

import numpy as np

from assets.catalog import BUILDERS, CATEGORY_PARTS
from assets.catalog_multipart import MULTIPART_PARTS, MULTIPART_SPECS, multipart_meshes, registered


def test_every_multipart_object_is_one_closed_labelled_surface_with_all_its_parts():
    meshes = multipart_meshes()
    assert [g.spec.object_id for g in meshes] == [s.object_id for s in MULTIPART_SPECS]
    for generated in meshes:
        parts = MULTIPART_PARTS[generated.spec.category]
        assert len(parts) >= 3 and tuple(generated.labels.parts) == parts
        assert generated.mesh.is_watertight
        labels, areas = generated.labels.face_labels, generated.mesh.area_faces
        assert (labels >= 0).all()
        shares = np.bincount(labels, weights=areas, minlength=len(parts)) / areas.sum()
        assert (shares > 0.01).all(), f"{generated.spec.object_id}: a part has almost no surface: {shares}"
        assert len(generated.spec.materials) == len(parts)


def test_registration_is_undone_after_the_block():
    before = (dict(BUILDERS), dict(CATEGORY_PARTS))
    with registered():
        assert set(MULTIPART_PARTS) <= set(BUILDERS)
    assert (dict(BUILDERS), dict(CATEGORY_PARTS)) == before
