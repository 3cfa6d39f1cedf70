"""Labelled real scans: the five YCB objects with the part labels shipped in assets/ycb/.

The scans themselves are not in the repository (CC BY 4.0, "YCB Object and Model Set", Calli et al. 2015); they are
read from `$SEGGRASP_YCB_DIR`, or from `shared/data/ycb` beside the repository. The labels
(`assets/ycb/<object>/labels.json`, made by `python -m assets.ycb_labels`) carry the sha256 of the scan file they
label, so a changed scan is an error instead of silently wrong labels.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from seggrasp.labels import PartLabels
from seggrasp.mesh import load_mesh

REPO_DIR = Path(__file__).resolve().parents[1]
YCB_LABEL_DIR = REPO_DIR / "assets" / "ycb"
#: YCB folder -> category (the twin's category name where the twin has one).
YCB_CATEGORIES = {
    "025_mug": "mug",
    "033_spatula": "spatula",
    "035_power_drill": "power_drill",
    "044_flat_screwdriver": "screwdriver",
    "048_hammer": "hammer",
}


class YCBDataMissing(FileNotFoundError):
    """The YCB scans are not on this machine (they are not shipped with the repository)."""


@dataclass
class LabelledScan:
    """A scan as `seggrasp.mesh.load_mesh` prepares it (duplicate vertices merged) and one label per face of it."""

    name: str
    category: str
    mesh: trimesh.Trimesh
    labels: PartLabels
    source_path: Path


def ycb_data_dir() -> Path:
    """`$SEGGRASP_YCB_DIR` if set, else `shared/data/ycb` beside the repository."""
    configured = os.environ.get("SEGGRASP_YCB_DIR")
    return Path(configured) if configured else REPO_DIR.parent / "shared" / "data" / "ycb"


def read_ycb_labels(name: str, label_dir: Path = YCB_LABEL_DIR) -> dict:
    """The label record of one YCB object (parts, per-file-face labels, mesh_sha256, regions)."""
    path = label_dir / name / "labels.json"
    if not path.is_file():
        raise FileNotFoundError(f"no YCB label file {path}; known objects: {sorted(YCB_CATEGORIES)}")
    return json.loads(path.read_text())


def load_ycb_scan(name: str, data_dir: Path | None = None, label_dir: Path = YCB_LABEL_DIR) -> LabelledScan:
    """One labelled YCB scan; YCBDataMissing if the scan is absent, ValueError if it is not the labelled file."""
    if name not in YCB_CATEGORIES:
        raise ValueError(f"unknown YCB object {name!r}; known: {sorted(YCB_CATEGORIES)}")
    data_dir = ycb_data_dir() if data_dir is None else Path(data_dir)
    path = data_dir / name / "textured.obj"
    if not path.is_file():
        raise YCBDataMissing(f"YCB scan {path} not found (set SEGGRASP_YCB_DIR to the folder of the YCB scans)")
    record = read_ycb_labels(name, label_dir)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    if digest != record["mesh_sha256"]:
        raise ValueError(f"{path} has sha256 {digest}, but {name}'s labels were made for {record['mesh_sha256']}; "
                         "relabel with `python -m assets.ycb_labels`")
    prepared = load_mesh(path)
    face_labels = np.asarray(record["face_labels"], dtype=np.int64)
    if face_labels.shape != (prepared.n_source_faces,):
        raise ValueError(f"{name}: {face_labels.size} labels for {prepared.n_source_faces} faces in {path}")
    labels = PartLabels(record["parts"], prepared.from_source(face_labels))
    return LabelledScan(name, YCB_CATEGORIES[name], prepared.mesh, labels, path)


def load_ycb_set(data_dir: Path | None = None, label_dir: Path = YCB_LABEL_DIR) -> list[LabelledScan]:
    """All five labelled YCB scans (YCBDataMissing naming the folder if the scans are absent)."""
    data_dir = ycb_data_dir() if data_dir is None else Path(data_dir)
    if not data_dir.is_dir():
        raise YCBDataMissing(f"YCB scans not found at {data_dir} (set SEGGRASP_YCB_DIR to the folder of the scans)")
    return [load_ycb_scan(name, data_dir, label_dir) for name in YCB_CATEGORIES]
