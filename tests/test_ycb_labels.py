"""The shipped YCB part labels: they match the scans, cover every face, and every part is one plausible region."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from seggrasp.datasets import (YCB_CATEGORIES, YCB_LABEL_DIR, YCBDataMissing, load_ycb_scan, load_ycb_set,
                               read_ycb_labels, ycb_data_dir)

#: Plausible area share of each part (a wrong cut or a swapped label falls outside).
AREA_SHARE = {
    ("025_mug", "handle"): (0.02, 0.15), ("025_mug", "body"): (0.85, 0.98),
    ("033_spatula", "handle"): (0.3, 0.7), ("033_spatula", "blade"): (0.3, 0.7),
    ("035_power_drill", "handle"): (0.1, 0.4), ("035_power_drill", "body"): (0.6, 0.9),
    ("044_flat_screwdriver", "handle"): (0.7, 0.95), ("044_flat_screwdriver", "shaft"): (0.05, 0.3),
    ("048_hammer", "handle"): (0.45, 0.8), ("048_hammer", "head"): (0.2, 0.55),
}
#: Connected regions per part (the drill's body is barrel + battery pack, joined only through the handle).
REGIONS = {("035_power_drill", "body"): 2}


@pytest.fixture(scope="module")
def scans():
    try:
        return load_ycb_set()
    except YCBDataMissing as exc:
        pytest.skip(str(exc))


def test_label_files_name_the_parts_and_a_hash_without_the_scans() -> None:
    for name in YCB_CATEGORIES:
        record = read_ycb_labels(name)
        assert len(record["mesh_sha256"]) == 64
        assert len(record["face_labels"]) == 16384
        assert {(name, p) for p in record["parts"]} <= set(AREA_SHARE)


def test_labels_cover_every_face_with_one_plausible_region_per_part(scans) -> None:
    from assets.ycb_labels import face_graph, part_regions

    assert [s.name for s in scans] == list(YCB_CATEGORIES)
    for scan in scans:
        labels, areas = scan.labels.face_labels, scan.mesh.area_faces
        assert labels.shape == (len(scan.mesh.faces),)
        assert (labels >= 0).all(), f"{scan.name}: unlabelled faces"
        graph = face_graph(scan.mesh)
        for k, part in enumerate(scan.labels.parts):
            share = areas[labels == k].sum() / areas.sum()
            low, high = AREA_SHARE[(scan.name, part)]
            assert low <= share <= high, f"{scan.name} {part}: area share {share:.3f} outside [{low}, {high}]"
            regions = part_regions(graph, labels, k, areas)
            # the scans hold a few loose two-face slivers; they do not count as regions
            big = [r for r in regions if areas[r].sum() > 1e-3 * areas[labels == k].sum()]
            assert len(big) == REGIONS.get((scan.name, part), 1), f"{scan.name} {part}: {len(big)} regions"


def test_a_changed_scan_is_refused(tmp_path: Path) -> None:
    source = ycb_data_dir() / "048_hammer" / "textured.obj"
    if not source.is_file():
        pytest.skip(f"YCB scans not found at {ycb_data_dir()}")
    (tmp_path / "048_hammer").mkdir()
    text = source.read_text()
    (tmp_path / "048_hammer" / "textured.obj").write_text(text.replace("v ", "v  ", 1))
    with pytest.raises(ValueError, match="sha256"):
        load_ycb_scan("048_hammer", tmp_path)


def test_missing_scans_and_unknown_objects_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(YCBDataMissing, match="not found"):
        load_ycb_set(tmp_path / "absent")
    with pytest.raises(YCBDataMissing, match="SEGGRASP_YCB_DIR"):
        load_ycb_scan("025_mug", tmp_path)
    with pytest.raises(ValueError, match="unknown YCB object"):
        load_ycb_scan("999_anvil", tmp_path)


def test_a_label_file_for_another_face_count_is_refused(tmp_path: Path) -> None:
    source = ycb_data_dir() / "025_mug"
    if not source.is_dir():
        pytest.skip(f"YCB scans not found at {ycb_data_dir()}")
    shutil.copytree(YCB_LABEL_DIR / "025_mug", tmp_path / "labels" / "025_mug")
    path = tmp_path / "labels" / "025_mug" / "labels.json"
    record = json.loads(path.read_text())
    record["face_labels"] = record["face_labels"][:-1]
    path.write_text(json.dumps(record))
    with pytest.raises(ValueError, match="16383 labels"):
        load_ycb_scan("025_mug", label_dir=tmp_path / "labels")


def test_the_labelling_script_reproduces_the_shipped_labels(tmp_path: Path) -> None:
    from assets.ycb_labels import main

    if not (ycb_data_dir() / "044_flat_screwdriver").is_dir():
        pytest.skip(f"YCB scans not found at {ycb_data_dir()}")
    assert main(["--objects", "044_flat_screwdriver", "--out", str(tmp_path), "--pictures", str(tmp_path)]) == 0
    made = json.loads((tmp_path / "044_flat_screwdriver" / "labels.json").read_text())
    shipped = read_ycb_labels("044_flat_screwdriver")
    assert made["mesh_sha256"] == shipped["mesh_sha256"]
    assert np.mean(np.equal(made["face_labels"], shipped["face_labels"])) == 1.0
    assert (tmp_path / "044_flat_screwdriver.png").stat().st_size > 1000
