"""A PNG contact sheet of objects coloured by part (pyrender; headless through OSMesa without a display)."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image, ImageDraw

from seggrasp.gl import import_pyrender
from seggrasp.io import atomic_write_bytes
from seggrasp.objects import ObjectModel

#: Part colours in prompt order (label k -> PART_COLOURS[k]); unknown faces are grey.
PART_COLOURS = np.array([(230, 85, 60), (70, 130, 220), (90, 190, 100), (240, 190, 50)], dtype=np.uint8)
UNKNOWN_COLOUR = np.array((150, 150, 150), dtype=np.uint8)


def _look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray = np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """OpenGL camera pose (camera looks along its -z) at `eye` looking at `target`."""
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, np.cross(back, right), back, eye
    return pose


def render_object(model: ObjectModel, size: int = 320) -> np.ndarray:
    """(size, size, 3) uint8 image of one object from a fixed oblique view, faces coloured by part label."""
    pyrender = import_pyrender()

    mesh = model.mesh.copy()
    labels = model.labels.face_labels if model.labels is not None else np.full(len(mesh.faces), -1)
    colours = np.where(labels[:, None] >= 0, PART_COLOURS[np.clip(labels, 0, None) % len(PART_COLOURS)], UNKNOWN_COLOUR)
    mesh.visual = trimesh.visual.ColorVisuals(mesh, face_colors=np.column_stack([colours, np.full(len(colours), 255)]))
    centre = mesh.bounds.mean(axis=0)
    radius = float(np.linalg.norm(mesh.extents)) / 2
    scene = pyrender.Scene(bg_color=(1.0, 1.0, 1.0, 1.0), ambient_light=(0.35, 0.35, 0.35))
    scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=False))
    direction = np.array([0.55, -0.8, 0.6])
    eye = centre + direction / np.linalg.norm(direction) * radius * 2.6
    pose = _look_at(eye, centre)
    scene.add(pyrender.PerspectiveCamera(yfov=np.radians(45.0)), pose=pose)
    scene.add(pyrender.DirectionalLight(intensity=3.0), pose=pose)
    scene.add(pyrender.DirectionalLight(intensity=2.0), pose=_look_at(centre + np.array([-0.3, 0.5, 1.0]), centre))
    renderer = pyrender.OffscreenRenderer(size, size)
    try:
        colour, _ = renderer.render(scene)
    finally:
        renderer.delete()
    return np.asarray(colour[:, :, :3])


def gallery_png(models: Sequence[ObjectModel], path: str | os.PathLike, columns: int = 6, tile: int = 320) -> Path:
    """Render every object into one PNG grid, each tile captioned with its id and part colours; returns the path."""
    if not models:
        raise ValueError("no objects to render")
    rows = (len(models) + columns - 1) // columns
    caption = 34
    sheet = Image.new("RGB", (columns * tile, rows * (tile + caption)), "white")
    draw = ImageDraw.Draw(sheet)
    for i, model in enumerate(models):
        x, y = (i % columns) * tile, (i // columns) * (tile + caption)
        sheet.paste(Image.fromarray(render_object(model, tile)), (x, y))
        draw.text((x + 6, y + tile + 2), f"{model.object_id}  ({model.mesh.extents.max() * 1000:.0f} mm)", fill=(0, 0, 0))
        cursor = x + 6
        for k, prompt in enumerate(model.prompts):
            colour = tuple(int(c) for c in PART_COLOURS[k % len(PART_COLOURS)])
            draw.rectangle((cursor, y + tile + 18, cursor + 10, y + tile + 28), fill=colour)
            draw.text((cursor + 14, y + tile + 17), prompt, fill=(0, 0, 0))
            cursor += 20 + 7 * len(prompt)
    import io

    buffer = io.BytesIO()
    sheet.save(buffer, format="PNG", optimize=True)
    path = Path(path)
    atomic_write_bytes(path, buffer.getvalue())
    return path
