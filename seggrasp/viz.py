"""Pictures of a segmentation: coloured meshes, a contact sheet of the views with boxes, partition previews."""

from __future__ import annotations

import io
import math
import os
from typing import TYPE_CHECKING, Sequence

import numpy as np
import trimesh
from matplotlib import colormaps
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import hsv_to_rgb
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle

from seggrasp.detect.base import Detections
from seggrasp.io import atomic_write_bytes
from seggrasp.render import CAMERA_DISTANCE, look_at, render_views
from seggrasp.views import View

if TYPE_CHECKING:
    from seggrasp.decompose import Partition

#: Colour of unknown (-1) faces.
UNKNOWN_COLOUR = np.array([170, 170, 170, 255], dtype=np.uint8)
#: Viewpoint of the partition previews: from the front-left, 30 degrees above the equator.
PREVIEW_DIRECTION = np.array([math.cos(math.radians(30)) * math.cos(math.radians(-60)),
                              math.cos(math.radians(30)) * math.sin(math.radians(-60)), math.sin(math.radians(30))])


def palette(n_colours: int) -> np.ndarray:
    """(n_colours, 4) uint8 RGBA colours: matplotlib's tab10 first, then hues spaced by the golden ratio."""
    base = np.array(colormaps["tab10"].colors)
    extra = n_colours - len(base)
    if extra > 0:
        hues = (0.13 + np.arange(extra) * 0.618034) % 1.0
        values = 0.65 + 0.3 * (np.arange(extra) % 2)
        base = np.concatenate([base, hsv_to_rgb(np.stack([hues, np.full(extra, 0.7), values], axis=1))])
    rgba = np.full((n_colours, 4), 255, dtype=np.uint8)
    rgba[:, :3] = np.round(base[:n_colours] * 255).astype(np.uint8)
    return rgba


def label_colours(labels: np.ndarray, n_labels: int) -> np.ndarray:
    """(F, 4) uint8 colour per face: palette colour of its label, grey for unknown (-1)."""
    labels = np.asarray(labels, dtype=np.int64)
    if labels.size and (labels.min() < -1 or labels.max() >= n_labels):
        raise ValueError(f"labels must lie in -1..{n_labels - 1}")
    table = np.concatenate([palette(n_labels), UNKNOWN_COLOUR[None]])
    return table[labels]  # -1 picks the trailing unknown colour


def save_coloured_mesh(path: str | os.PathLike, mesh: trimesh.Trimesh, labels: np.ndarray, n_labels: int) -> None:
    """Write `mesh` with its faces coloured by `labels` (one per face of `mesh`) atomically; format from suffix."""
    labels = np.asarray(labels)
    if labels.shape != (len(mesh.faces),):
        raise ValueError(f"need one label per face ({len(mesh.faces)}), got shape {labels.shape}")
    coloured = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False,
                               face_colors=label_colours(labels, n_labels))
    file_type = os.fspath(path).rsplit(".", 1)[-1].lower()
    atomic_write_bytes(path, trimesh.exchange.export.export_mesh(coloured, None, file_type=file_type))


def _save_figure(figure: Figure, path: str | os.PathLike) -> None:
    buffer = io.BytesIO()
    FigureCanvasAgg(figure)
    figure.savefig(buffer, format="png", dpi=figure.dpi)
    atomic_write_bytes(path, buffer.getvalue())


def _grid(n_panels: int, columns: int, panel_inches: float) -> tuple[Figure, list]:
    columns = max(1, min(columns, n_panels))
    rows = math.ceil(n_panels / columns)
    figure = Figure(figsize=(columns * panel_inches, rows * panel_inches), dpi=100, layout="constrained")
    axes = figure.subplots(rows, columns, squeeze=False).ravel().tolist()
    for axis in axes:
        axis.set_axis_off()
    return figure, axes


def save_contact_sheet(
    path: str | os.PathLike,
    views: Sequence[View],
    detections: Sequence[Detections],
    prompts: Sequence[str],
    columns: int = 5,
    title: str | None = None,
) -> None:
    """PNG grid of the rendered views with every detector box drawn in its prompt's colour and its confidence."""
    if len(views) != len(detections):
        raise ValueError(f"{len(views)} views but {len(detections)} detection sets")
    if not views:
        raise ValueError("no views to draw")
    colours = palette(len(prompts))[:, :3] / 255.0
    figure, axes = _grid(len(views), columns, 3.0)
    for index, (axis, view, found) in enumerate(zip(axes, views, detections)):
        axis.imshow(view.rgb)
        axis.set_title(f"view {index}: {len(found)} boxes", fontsize=8)
        for (x0, y0, x1, y1), score, prompt in zip(found.boxes, found.scores, found.prompt_index):
            colour = colours[prompt]
            axis.add_patch(Rectangle((x0, y0), x1 - x0, y1 - y0, fill=False, edgecolor=colour, linewidth=1.5))
            axis.text(x0, y0, f"{prompts[prompt]} {score:.2f}", color="white", fontsize=6, va="bottom",
                      bbox={"facecolor": colour, "alpha": 0.8, "pad": 1, "linewidth": 0})
    if title:
        figure.suptitle(title, fontsize=10)
    _save_figure(figure, path)


def _preview_view(mesh: trimesh.Trimesh, image_size: int) -> View:
    (view,) = render_views(mesh, [look_at(CAMERA_DISTANCE * PREVIEW_DIRECTION)], image_size=image_size)
    return view


def _paint(view: View, per_face_colour: np.ndarray) -> np.ndarray:
    """The view with every face painted `per_face_colour` (F, 3+) and keeping the rendered shading."""
    shade = view.rgb.astype(float).mean(axis=2, keepdims=True) / 255.0
    visible = view.face_ids >= 0
    image = np.full(view.rgb.shape, 255, dtype=np.uint8)
    paint = per_face_colour[view.face_ids[visible], :3].astype(float)
    image[visible] = np.clip(paint * (0.35 + 0.9 * shade[visible]), 0, 255).astype(np.uint8)
    return image


def save_label_preview(
    path: str | os.PathLike, mesh: trimesh.Trimesh, labels: np.ndarray, prompts: Sequence[str], image_size: int = 384
) -> None:
    """PNG of `mesh` with faces coloured by label (one per face of `mesh`) and a legend of the prompts."""
    labels = np.asarray(labels)
    if labels.shape != (len(mesh.faces),):
        raise ValueError(f"need one label per face ({len(mesh.faces)}), got shape {labels.shape}")
    image = _paint(_preview_view(mesh, image_size), label_colours(labels, len(prompts)))
    figure, (axis,) = _grid(1, 1, 4.0)
    axis.imshow(image)
    colours = palette(len(prompts))[:, :3] / 255.0
    handles = [Rectangle((0, 0), 1, 1, color=c) for c in colours]
    handles.append(Rectangle((0, 0), 1, 1, color=UNKNOWN_COLOUR[:3] / 255))
    axis.legend(handles, list(prompts) + ["unknown"], loc="lower right", fontsize=7)
    _save_figure(figure, path)


def save_partition_previews(
    mesh: trimesh.Trimesh, partitions: Sequence[Partition], path: str | os.PathLike, image_size: int = 256,
    columns: int = 4,
) -> None:
    """PNG grid with one picture per partition (`part_of_face` per face of `mesh`), parts in distinct colours."""
    if not partitions:
        raise ValueError("no partitions to draw")
    view = _preview_view(mesh, image_size)
    figure, axes = _grid(len(partitions), columns, 2.6)
    for axis, partition in zip(axes, partitions):
        parts = np.asarray(partition.part_of_face, dtype=np.int64)
        if parts.shape != (len(mesh.faces),):
            raise ValueError(f"partition has {parts.shape[0]} entries for a mesh of {len(mesh.faces)} faces")
        axis.imshow(_paint(view, palette(int(parts.max()) + 1)[parts]))
        axis.set_title(f"threshold {partition.threshold:g}: {len(np.unique(parts))} parts", fontsize=8)
    _save_figure(figure, path)
