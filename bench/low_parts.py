"""Why no 2F-85 grasp holds some parts from the table: their cross-sections beside the fingers' lowest poses.

    python bench/low_parts.py                                  # the parts every oracle slot leaves without a grasp
    python bench/low_parts.py --parts knife_chef:blade --out /tmp/strips

For each (object, part) the twin's mesh is cut by a vertical plane through the part's centroid, across the part's
long horizontal axis, with the object as the twin drops it on the table (its mesh frame, lowest point on the
table; settling moves part tops by about a millimetre: twin-physics.md has them measured after settling). Two
panels show the section (the part in colour, the rest grey) with the sampler's box model of the 2F-85 fingers
(`seggrasp.hands.ROBOTIQ_2F85`) straight down at its lowest poses (`AntipodalConfig`):

- an ordinary grasp: fingertips `table_clearance` above the table, contact at the deepest `contact_depths` entry;
- a fingertip pinch: fingertips `pinch_table_clearance` above the table, the pads touching the part's side over
  at least `pinch_min_band`.

The fingers are drawn at the part's extent in the section. The numbers (part top, section height, the two
lowest contact heights) are printed as a table and the pictures written to --out, one PNG per part.
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import numpy as np
import trimesh
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle


from seggrasp.grasp.antipodal import AntipodalConfig  # noqa: E402
from seggrasp.hands import ROBOTIQ_2F85, Hand  # noqa: E402
from seggrasp.io import atomic_write_bytes  # noqa: E402
from seggrasp.objects import load_asset_set  # noqa: E402

#: The parts whose oracle slots were all `no_grasp` in the five-seed full run (docs/results/twin-physics.md).
DEFAULT_PARTS = ("knife_chef:blade", "wine_glass_red:base", "scissors_office:blade", "scissors_office:pivot",
                 "eyeglasses_aviator:rim", "eyeglasses_aviator:bridge")
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "results" / "strips"
MM = 1000.0


def lowest_contacts(config: AntipodalConfig, gripper: Hand) -> tuple[float, float, float]:
    """Heights above the table (m) of the lowest ordinary contact, of the lowest pinch contact, and of the top of
    the side a pinch needs (fingertips + `pinch_min_band`), for a straight-down approach."""
    ordinary = config.table_clearance + gripper.tip_beyond_origin - max(config.contact_depths)
    pinch = config.pinch_table_clearance + gripper.tip_beyond_origin - max(config.pinch_contact_depths)
    return ordinary, pinch, config.pinch_table_clearance + config.pinch_min_band


def part_section(mesh: trimesh.Trimesh, part_faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segments (n, 2, 2) of the vertical section across the part's long horizontal axis, in the section's
    (across, height above the table) coordinates, and whether each segment lies on a face of the part."""
    areas = mesh.area_faces[part_faces]
    centres = mesh.triangles_center[part_faces]
    origin = np.average(centres, axis=0, weights=areas)
    spread = np.cov((centres[:, :2] - origin[:2]).T, aweights=areas)
    long_axis = np.linalg.eigh(spread)[1][:, -1]
    normal = np.array([long_axis[0], long_axis[1], 0.0])
    across = np.cross([0.0, 0.0, 1.0], normal)
    lines, faces = trimesh.intersections.mesh_plane(mesh, normal, origin, return_faces=True)
    if len(lines) == 0:
        raise ValueError("the section plane through the part's centroid misses the mesh")
    table = float(mesh.vertices[:, 2].min())
    segments = np.stack([(lines - origin) @ across, lines[..., 2] - table], axis=-1)
    return segments, np.isin(faces, part_faces)


def draw_fingers(axes, left: float, right: float, tip_height: float, gripper: Hand) -> None:
    """Both fingers' boxes (mm) straight down, inner faces at `left` / `right` (m), fingertips at `tip_height`."""
    origin = tip_height + gripper.tip_beyond_origin
    for inner_face, sign in ((left, -1.0), (right, 1.0)):
        for inner, outer, _, z_min, z_max in gripper.finger_boxes:
            x0, x1 = sorted((inner_face + sign * inner, inner_face + sign * outer))
            bottom = origin - z_max
            axes.add_patch(Rectangle((x0 * MM, bottom * MM), (x1 - x0) * MM, (z_max - z_min) * MM,
                                     facecolor="#9aa7b8", edgecolor="#44505e", alpha=0.55, lw=0.8))


def plot_part(name: str, part: str, segments: np.ndarray, on_part: np.ndarray, heights: tuple[float, float, float],
              config: AntipodalConfig, gripper: Hand) -> bytes:
    """PNG of the two panels (ordinary grasp, fingertip pinch) for one part."""
    ordinary, pinch, band_top = heights
    part_points = segments[on_part].reshape(-1, 2)
    left, right = float(part_points[:, 0].min()), float(part_points[:, 0].max())
    top = float(part_points[:, 1].max())
    figure = Figure(figsize=(9.0, 3.9), dpi=110)
    panels = (("ordinary grasp, lowest pose", config.table_clearance, ordinary),
              ("fingertip pinch, lowest pose", config.pinch_table_clearance, pinch))
    for index, (title, tip, contact) in enumerate(panels):
        axes = figure.add_subplot(1, 2, index + 1)
        axes.add_collection(LineCollection(segments[~on_part] * MM, colors="#9a9a9a", linewidths=1.0))
        axes.add_collection(LineCollection(segments[on_part] * MM, colors="#d62728", linewidths=2.0))
        draw_fingers(axes, left, right, tip, gripper)
        axes.axhspan(-5.0, 0.0, color="#c8b38a")
        axes.axhline(contact * MM, color="#1f77b4", ls="--", lw=1.0)
        subtitle = f"lowest contact {contact * MM:.1f} mm (dashed)"
        if index == 1:
            axes.axhspan(config.pinch_table_clearance * MM, band_top * MM, color="#1f77b4", alpha=0.15)
            subtitle += (f";\nthe pads need the part's side from {config.pinch_table_clearance * MM:.1f} "
                         f"to {band_top * MM:.1f} mm (shaded)")
        half_span = max(right - left, 0.03) * MM / 2 + 30.0
        centre = (left + right) * MM / 2
        axes.set_xlim(centre - half_span, centre + half_span)
        axes.set_ylim(-5.0, max(top, ordinary) * MM + 35.0)
        axes.set_aspect("equal")
        axes.set_xlabel("across the part (mm)")
        axes.set_ylabel("above the table (mm)")
        axes.set_title(f"{title}\n{subtitle}", fontsize=8)
    figure.suptitle(f"{name}: {part} (red), top {top * MM:.1f} mm in this section", fontsize=10)
    figure.tight_layout()
    out = io.BytesIO()
    figure.savefig(out, format="png")
    return out.getvalue()


def parse_parts(text: str) -> list[tuple[str, str]]:
    """`object:part,object:part` -> [(object, part), ...]; ValueError naming a malformed entry."""
    pairs = []
    for item in filter(None, (s.strip() for s in text.split(","))):
        name, sep, part = item.partition(":")
        if not sep or not name or not part:
            raise ValueError(f"--parts entries are object:part, got {item!r}")
        pairs.append((name, part))
    return pairs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--parts", default=",".join(DEFAULT_PARTS), help="comma list of object:part")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="folder for the PNGs")
    args = parser.parse_args(argv)
    try:
        wanted = parse_parts(args.parts)
    except ValueError as error:
        parser.error(str(error))
    objects = {model.object_id: model for model in load_asset_set()}
    config, gripper = AntipodalConfig(), ROBOTIQ_2F85
    heights = lowest_contacts(config, gripper)
    print(f"lowest ordinary contact {heights[0] * MM:.1f} mm, lowest pinch contact {heights[1] * MM:.1f} mm, "
          f"a pinch needs the part's side from {config.pinch_table_clearance * MM:.1f} up to {heights[2] * MM:.1f} mm")
    print("| object | part | part top (mm) | top in the section (mm) | picture |")
    print("|---|---|---|---|---|")
    for name, part in wanted:
        if name not in objects:
            parser.error(f"unknown object {name!r}; known: {', '.join(sorted(objects))}")
        model = objects[name]
        if part not in model.labels.parts:
            parser.error(f"{name} has no part {part!r}; its parts: {', '.join(model.labels.parts)}")
        part_faces = np.flatnonzero(model.labels.face_labels == model.labels.parts.index(part))
        segments, on_part = part_section(model.mesh, part_faces)
        if not on_part.any():
            parser.error(f"the section through {name}'s {part} centroid does not cut the part")
        png = plot_part(name, part, segments, on_part, heights, config, gripper)
        path = args.out / f"{name}-{part}-section.png"
        atomic_write_bytes(path, png)
        part_top = float(model.mesh.vertices[model.mesh.faces[part_faces]][..., 2].max() - model.mesh.bounds[0, 2])
        print(f"| {name} | {part} | {part_top * MM:.1f} | {segments[on_part][..., 1].max() * MM:.1f} | {path.name} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
