"""Ground-truth part labels for the five YCB scans in ../shared/data/ycb, made by geometric rules.

    python -m assets.ycb_labels [--data DIR] [--out assets/ycb] [--pictures DIR]

Every object is cut by a rule on its own geometry (no hand-painted faces), then cleaned by region growing over the
face adjacency; the result is written to assets/ycb/<object>/labels.json with the sha256 of the scan file it labels
(one label per face of that file, in file order) and a picture per object (four views, faces coloured by part).

Frame. The scan is loaded like any input mesh (`seggrasp.mesh.load_mesh`: duplicate vertices merged); the rules
work on the area-weighted principal axes of the face centroids: `t` along the first (longest) axis, `w` and `h`
along the second and third. A *profile* is the extent (2nd..98th percentile) of the vertices along `w` (or `h`) in
slabs 2 mm thick along `t`. A *cut* is a plane across `t`: walking along the profile from the narrow part's end
towards the wide part, the first slab whose extent exceeds narrow + CUT_FRACTION * (wide - narrow), where narrow and
wide are the median extents of the two parts' reference slabs (named per object below). Faces whose centroid lies
beyond the cut take the part on the wide side.

Rules (the part on the far side of the cut, and what it includes):
- 048_hammer: `head` = the wide end of the `w` profile (head, face and claw); faces further than the handle's
  half-width (+ 4 mm) from the handle's centre line in the head's half also go to the head (the claw curls back
  beside the handle). `handle` = the rest.
- 033_spatula: `blade` = the wide end of the `w` profile, its flared shoulders included; `handle` = grip and the
  narrow neck.
- 044_flat_screwdriver: `shaft` = the thin end of the `w` profile (shaft and flat tip); `handle` = grip and ferrule.
- 035_power_drill: the grip runs along `t` between the battery pack (wide `w` end) and the barrel (thick `h` end).
  `handle` = the grip between the two cuts; `body` = barrel (motor, chuck) and battery pack, so `body` is two
  regions, joined only through the handle.
- 025_mug (upright in its file, z up): the body's axis is the vertical line through the area-weighted centre of the
  downward-facing base faces; the handle's bearing is that of the vertex furthest from the axis. Per 2 mm height
  slab the body radius is the 99th percentile of the radius of the faces more than 90 degrees away from the
  handle's bearing; `handle` = faces within 75 degrees of the handle's bearing and more than 2.5 mm outside the
  body radius of their slab; `body` = the rest (outside, inside, rim and base).

Region growing: per part, every connected region (face adjacency) except the part's largest (the drill body's two
largest) is given to the part its neighbouring faces have most, repeated until nothing changes; regions with no
neighbour of another part (tiny loose pieces of the scan) keep their label.

Licence: the YCB Object and Model Set (Calli et al., 2015) is CC BY 4.0; see assets/ycb/README.md.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from seggrasp.io import atomic_write_text
from seggrasp.mesh import load_mesh

YCB_LABEL_DIR = Path(__file__).resolve().parent / "ycb"
SLAB_M = 0.002
CUT_FRACTION = 0.3


def principal_frame(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """(centre (3,), axes (3, 3) as rows, longest first) from the area-weighted covariance of face centroids."""
    centroids, areas = mesh.triangles_center, mesh.area_faces
    centre = (centroids * areas[:, None]).sum(axis=0) / areas.sum()
    _, vectors = np.linalg.eigh(np.cov((centroids - centre).T, aweights=areas))
    return centre, vectors[:, ::-1].T


def profile(t: np.ndarray, extent_of: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(slab centres, extent of `extent_of` per slab) over SLAB_M slabs along `t` (NaN for slabs with < 3 points)."""
    edges = np.arange(t.min(), t.max() + SLAB_M, SLAB_M)
    index = np.clip(np.digitize(t, edges) - 1, 0, len(edges) - 2)
    extent = np.full(len(edges) - 1, np.nan)
    for k in range(len(edges) - 1):
        values = extent_of[index == k]
        if len(values) >= 3:
            extent[k] = np.percentile(values, 98) - np.percentile(values, 2)
    return 0.5 * (edges[:-1] + edges[1:]), extent


def cut_position(centres: np.ndarray, extent: np.ndarray, narrow: tuple[float, float], wide: tuple[float, float]
                 ) -> float:
    """`t` of the cut between a narrow and a wide part, each given by a `t` range of reference slabs."""
    def median_in(span: tuple[float, float]) -> float:
        inside = (centres >= min(span)) & (centres <= max(span)) & np.isfinite(extent)
        return float(np.median(extent[inside]))

    threshold = median_in(narrow) + CUT_FRACTION * (median_in(wide) - median_in(narrow))
    towards_wide = np.sign(np.mean(wide) - np.mean(narrow))
    start = np.mean(narrow)
    order = np.argsort(towards_wide * centres)
    for k in order:
        if towards_wide * (centres[k] - start) > 0 and np.isfinite(extent[k]) and extent[k] > threshold:
            return float(centres[k] - towards_wide * 0.5 * SLAB_M)
    raise ValueError(f"no slab beyond the narrow part exceeds the cut threshold {threshold:.4f}")


def _coordinates(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertex and face-centroid coordinates in the principal frame, and the frame's range along `t`."""
    centre, axes = principal_frame(mesh)
    vertices = (mesh.vertices - centre) @ axes.T
    centroids = (mesh.triangles_center - centre) @ axes.T
    return vertices, centroids, np.array([vertices[:, 0].min(), vertices[:, 0].max()])


def _fraction(span: np.ndarray, a: float, b: float) -> tuple[float, float]:
    """The `t` range from fraction a to b of `span`."""
    return float(span[0] + a * (span[1] - span[0])), float(span[0] + b * (span[1] - span[0]))


def _oriented(vertices: np.ndarray, centroids: np.ndarray, column: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Flip `t` so that the half with the largest extent along `column` is at +t."""
    centres, extent = profile(vertices[:, 0], vertices[:, column])
    finite = np.isfinite(extent)
    half = len(extent) // 2
    if np.max(extent[:half][finite[:half]]) > np.max(extent[half:][finite[half:]]):
        vertices, centroids = vertices * [-1, 1, 1], centroids * [-1, 1, 1]
    return vertices, centroids, np.array([vertices[:, 0].min(), vertices[:, 0].max()])


def label_hammer(mesh: trimesh.Trimesh) -> tuple[list[str], np.ndarray]:
    """handle / head: cut across the `w` profile, plus the claw beside the handle (module docstring)."""
    vertices, centroids, _ = _coordinates(mesh)
    vertices, centroids, span = _oriented(vertices, centroids, 1)
    centres, extent = profile(vertices[:, 0], vertices[:, 1])
    cut = cut_position(centres, extent, narrow=_fraction(span, 0.55, 0.7), wide=_fraction(span, 0.85, 1.0))
    in_handle = (vertices[:, 0] > span[0] + 0.1 * np.ptp(span)) & (vertices[:, 0] < cut)
    line = np.polyfit(vertices[in_handle, 0], vertices[in_handle, 1], 1)
    half_width = np.percentile(np.abs(vertices[in_handle, 1] - np.polyval(line, vertices[in_handle, 0])), 99)
    lateral = np.abs(centroids[:, 1] - np.polyval(line, centroids[:, 0]))
    head = (centroids[:, 0] >= cut) | ((lateral > half_width + 0.004) & (centroids[:, 0] > np.mean(span)))
    return ["handle", "head"], head.astype(np.int64)


def label_spatula(mesh: trimesh.Trimesh) -> tuple[list[str], np.ndarray]:
    """handle / blade: the blade is the wide end of the `w` profile."""
    vertices, centroids, _ = _coordinates(mesh)
    vertices, centroids, span = _oriented(vertices, centroids, 1)
    centres, extent = profile(vertices[:, 0], vertices[:, 1])
    cut = cut_position(centres, extent, narrow=_fraction(span, 0.5, 0.6), wide=_fraction(span, 0.7, 0.95))
    return ["handle", "blade"], (centroids[:, 0] >= cut).astype(np.int64)


def label_screwdriver(mesh: trimesh.Trimesh) -> tuple[list[str], np.ndarray]:
    """handle / shaft: the shaft is the thin end of the `w` profile."""
    vertices, centroids, _ = _coordinates(mesh)
    vertices, centroids, span = _oriented(vertices, centroids, 1)  # handle (wide) at +t
    centres, extent = profile(vertices[:, 0], vertices[:, 1])
    cut = cut_position(centres, extent, narrow=_fraction(span, 0.1, 0.4), wide=_fraction(span, 0.7, 0.9))
    return ["handle", "shaft"], (centroids[:, 0] < cut).astype(np.int64)


def label_drill(mesh: trimesh.Trimesh) -> tuple[list[str], np.ndarray]:
    """handle / body: the grip between the battery pack's cut (`w` profile) and the barrel's cut (`h` profile)."""
    vertices, centroids, _ = _coordinates(mesh)
    vertices, centroids, span = _oriented(vertices, centroids, 1)  # barrel (widest along w) at +t
    centres, width = profile(vertices[:, 0], vertices[:, 1])
    _, height = profile(vertices[:, 0], vertices[:, 2])
    grip = _fraction(span, 0.4, 0.6)
    barrel_cut = cut_position(centres, height, narrow=grip, wide=_fraction(span, 0.8, 0.95))
    battery_cut = cut_position(centres, width, narrow=grip, wide=_fraction(span, 0.05, 0.25))
    handle = (centroids[:, 0] > battery_cut) & (centroids[:, 0] < barrel_cut)
    return ["handle", "body"], np.where(handle, 0, 1).astype(np.int64)


def label_mug(mesh: trimesh.Trimesh) -> tuple[list[str], np.ndarray]:
    """handle / body: faces outside the body's radius within the handle's bearing (module docstring)."""
    normals, areas, centroids = mesh.face_normals, mesh.area_faces, mesh.triangles_center
    base = normals[:, 2] < -0.9
    axis = (centroids[base, :2] * areas[base, None]).sum(axis=0) / areas[base].sum()
    offset = mesh.vertices[:, :2] - axis
    far = int(np.argmax(np.linalg.norm(offset, axis=1)))
    bearing = np.arctan2(offset[far, 1], offset[far, 0])
    radial = centroids[:, :2] - axis
    radius = np.linalg.norm(radial, axis=1)
    angle = np.abs((np.arctan2(radial[:, 1], radial[:, 0]) - bearing + np.pi) % (2 * np.pi) - np.pi)
    slab = ((centroids[:, 2] - centroids[:, 2].min()) // SLAB_M).astype(np.int64)
    body_radius = np.zeros(slab.max() + 1)
    away = angle > np.pi / 2
    for k in range(len(body_radius)):
        in_slab = away & (slab == k)
        body_radius[k] = np.percentile(radius[in_slab], 99) if in_slab.sum() >= 3 else np.inf
    handle = (angle < np.radians(75)) & (radius > body_radius[slab] + 0.0025)
    return ["handle", "body"], np.where(handle, 0, 1).astype(np.int64)


#: object folder -> (rule, number of regions each part is left with by the region growing)
RULES: dict[str, tuple[Callable[[trimesh.Trimesh], tuple[list[str], np.ndarray]], dict[str, int]]] = {
    "025_mug": (label_mug, {}),
    "033_spatula": (label_spatula, {}),
    "035_power_drill": (label_drill, {"body": 2}),
    "044_flat_screwdriver": (label_screwdriver, {}),
    "048_hammer": (label_hammer, {}),
}


def face_graph(mesh: trimesh.Trimesh):
    """Sparse symmetric face adjacency matrix (faces sharing an edge)."""
    pairs = np.asarray(mesh.face_adjacency)
    n = len(mesh.faces)
    ones = np.ones(2 * len(pairs))
    return coo_matrix((ones, (np.r_[pairs[:, 0], pairs[:, 1]], np.r_[pairs[:, 1], pairs[:, 0]])), shape=(n, n)).tocsr()


def part_regions(graph, labels: np.ndarray, part: int, areas: np.ndarray) -> list[np.ndarray]:
    """Connected regions of one part's faces, largest area first."""
    faces = np.flatnonzero(labels == part)
    if len(faces) == 0:
        return []
    _, component = connected_components(graph[faces][:, faces], directed=False)
    regions = [faces[component == c] for c in range(component.max() + 1)]
    return sorted(regions, key=lambda r: -areas[r].sum())


def grow_regions(mesh: trimesh.Trimesh, labels: np.ndarray, keep: dict[int, int]) -> np.ndarray:
    """Give every stray region of a part (all but its `keep[part]` (default 1) largest) to the part most of its
    neighbouring faces have; repeat until stable."""
    labels = labels.copy()
    graph, areas = face_graph(mesh), mesh.area_faces
    for _ in range(20):
        changed = False
        for part in np.unique(labels):
            for region in part_regions(graph, labels, part, areas)[keep.get(int(part), 1):]:
                neighbours = labels[graph[region].indices]
                neighbours = neighbours[neighbours != part]
                if len(neighbours):
                    labels[region] = np.bincount(neighbours).argmax()
                    changed = True
        if not changed:
            return labels
    raise RuntimeError("region growing did not settle")


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def label_object(data_dir: Path, name: str) -> dict:
    """The label record of one scan: parts, one label per face of the file, the file's sha256, region counts."""
    rule, regions = RULES[name]
    path = data_dir / name / "textured.obj"
    prepared = load_mesh(path)
    parts, labels = rule(prepared.mesh)
    keep = {parts.index(p): n for p, n in regions.items()}
    labels = grow_regions(prepared.mesh, labels, keep)
    return {
        "object": name, "source": f"{name}/textured.obj", "mesh_sha256": file_sha256(path),
        "parts": parts, "regions": {p: regions.get(p, 1) for p in parts},
        "rule": f"assets/ycb_labels.py {rule.__name__}", "face_labels": prepared.to_source(labels).tolist(),
    }


def save_pictures(path: Path, mesh: trimesh.Trimesh, labels: np.ndarray, parts: list[str], title: str) -> None:
    """PNG of four views of `mesh` (sides and top, bottom), faces coloured by part."""
    from matplotlib.patches import Rectangle

    from seggrasp.render import CAMERA_DISTANCE, render_views
    from seggrasp.views import look_at
    from seggrasp.viz import _grid, _paint, _save_figure, label_colours, palette

    directions = [(1, -1, 0.6), (-1, 1, 0.6), (0.02, 0.02, 1.0), (0.02, -0.02, -1.0)]
    poses = [look_at(CAMERA_DISTANCE * np.asarray(d) / np.linalg.norm(d), up=np.array([0.0, 1.0, 0.0])
                     if abs(d[2]) > 0.9 else np.array([0.0, 0.0, 1.0])) for d in directions]
    colours = label_colours(labels, len(parts))
    figure, axes = _grid(len(poses), 4, 3.0)
    for axis, view in zip(axes, render_views(mesh, poses, image_size=384)):
        axis.imshow(_paint(view, colours))
    handles = [Rectangle((0, 0), 1, 1, color=c) for c in palette(len(parts))[:, :3] / 255.0]
    axes[0].legend(handles, parts, loc="lower left", fontsize=7)
    figure.suptitle(title, fontsize=9)
    _save_figure(figure, path)


def main(argv: list[str] | None = None) -> int:
    from seggrasp.datasets import ycb_data_dir

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=None, help="folder of the YCB scans (default: ycb_data_dir())")
    parser.add_argument("--out", type=Path, default=YCB_LABEL_DIR)
    parser.add_argument("--pictures", type=Path, default=YCB_LABEL_DIR, help="where <object>.png pictures go")
    parser.add_argument("--objects", default=",".join(RULES), help=f"comma list of {sorted(RULES)}")
    args = parser.parse_args(argv)
    data = args.data if args.data is not None else ycb_data_dir()
    if not data.is_dir():
        parser.error(f"YCB scans not found at {data} (set --data or SEGGRASP_YCB_DIR)")
    for name in [n.strip() for n in args.objects.split(",") if n.strip()]:
        if name not in RULES:
            parser.error(f"unknown object {name!r}; known: {sorted(RULES)}")
        record = label_object(data, name)
        atomic_write_text(args.out / name / "labels.json", json.dumps(record, separators=(",", ":")) + "\n")
        prepared = load_mesh(data / name / "textured.obj")
        labels = np.asarray(record["face_labels"])[prepared.source_face]
        shares = {p: round(float(prepared.mesh.area_faces[labels == k].sum() / prepared.mesh.area), 3)
                  for k, p in enumerate(record["parts"])}
        save_pictures(args.pictures / f"{name}.png", prepared.mesh, labels, record["parts"], f"{name}: {shares}")
        print(f"{name}: area shares {shares}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
