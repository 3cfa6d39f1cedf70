"""Records of one grasp trial, taken at its stages: a picture strip, or a log of what the fingertips press on.

`SimCell.record_next(path)` arms a `TrialRecorder` for the next `execute()`, `SimCell.log_contacts_next(path)` a
`ContactLog`. The grasp primitive calls the armed recorder's `snap(trial, stage)` (itself) at the pre-grasp,
after closing, after the lift and after the hold, then `write(caption)` with the outcome. A `TrialRecorder` writes
the frames side by side as one PNG, a `ContactLog` a markdown table of every fingertip contact (both atomically).
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
from PIL import Image, ImageDraw

from seggrasp.io import atomic_write_bytes, atomic_write_text
from seggrasp.views import look_at
from sim.cameras import VirtualD435
from sim.world import TABLE_TOP_Z

if TYPE_CHECKING:
    from sim.grasp_primitive import GraspPrimitive

#: Stages the grasp primitive captures, in order.
STAGES = ("pre-grasp", "closed", "lifted", "held")
#: Size of one frame of the strip (pixels).
FRAME_SIZE = (320, 240)
#: Where the camera sits relative to the gripper's TCP (world frame, m): in front of the robot, a little up.
CAMERA_OFFSET = np.array([0.30, -0.22, 0.16])


class StageRecorder(Protocol):
    """What the grasp primitive calls on an armed recorder: `snap` at each stage, `write` once with the outcome."""

    def snap(self, trial: GraspPrimitive, stage: str) -> None: ...

    def write(self, caption: str) -> Path: ...


class TrialRecorder:
    """Collects captioned frames of one trial from a camera aimed at the gripper's TCP, then writes a strip."""

    def __init__(self, path: str | Path, size: tuple[int, int] = FRAME_SIZE) -> None:
        self.path = Path(path)
        self.size = size
        self.frames: list[tuple[str, np.ndarray]] = []

    def snap(self, trial: GraspPrimitive, stage: str) -> None:
        """Render the scene from `CAMERA_OFFSET` beside the TCP, looking at it, and keep it captioned `stage`."""
        target = trial.T_world_tcp()[:3, 3]
        camera = VirtualD435("recorder", look_at(target + CAMERA_OFFSET, target), *self.size)
        rgb, _, _ = camera.render(trial.world.client)
        self.frames.append((stage, np.asarray(rgb)[..., :3]))

    def write(self, caption: str) -> Path:
        """Write the frames side by side (a blank frame if none was taken) with `caption` under them."""
        width, height = self.size
        frames = self.frames or [("no frame", np.full((height, width, 3), 255, dtype=np.uint8))]
        strip = Image.new("RGB", (width * len(frames), height + 22), "white")
        draw = ImageDraw.Draw(strip)
        for index, (stage, rgb) in enumerate(frames):
            strip.paste(Image.fromarray(rgb), (index * width, 0))
            draw.text((index * width + 6, 6), stage, fill=(0, 0, 0))
        draw.text((6, height + 5), caption, fill=(0, 0, 0))
        buffer = io.BytesIO()
        strip.save(buffer, format="PNG")
        atomic_write_bytes(self.path, buffer.getvalue())
        return self.path


class ContactLog:
    """What the fingertips press on at each stage of one trial, for telling why a grasp failed: per fingertip contact
    (`GraspPrimitive.pad_contacts`) the side, the point and the contact normal in the object's frame (the URDF frame,
    as its mesh), the normal's angle to the gripper's closing axis and the normal force; per stage, the height of the
    object's origin over the table and its tilt (far below zero: the object fell through the table)."""

    HEADER = ("| stage | object origin over the table (mm) | object tilt (deg) | side | point (mm, object frame) "
              "| normal (object frame) | normal to closing axis (deg) | normal force (N) |")

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.rows: list[str] = []

    def snap(self, trial: GraspPrimitive, stage: str) -> None:
        """Log the object's pose and every fingertip contact now, under `stage`."""
        T_world_obj = trial.world.body_pose(trial.object_body)
        tilt = np.degrees(np.arccos(np.clip(T_world_obj[2, 2], -1.0, 1.0)))
        stage_cells = f"| {stage} | {1000.0 * (T_world_obj[2, 3] - TABLE_TOP_Z):.1f} | {tilt:.1f} "
        closing = T_world_obj[:3, :3].T @ trial.T_world_tcp()[:3, 0]  # in the object's frame, as the contacts
        contacts = trial.pad_contacts()
        for c in contacts:
            angle = np.degrees(np.arccos(np.clip(abs(c.normal @ closing), 0.0, 1.0)))
            self.rows.append(stage_cells + f"| {c.side} | {_vector(1000.0 * c.point, 1)} | {_vector(c.normal, 2)} "
                             f"| {angle:.1f} | {c.force:.1f} |")
        if not contacts:
            self.rows.append(stage_cells + "| - | - | - | - | 0 |")

    def write(self, caption: str) -> Path:
        """Write the logged contacts as a markdown table under `caption` (atomically)."""
        table = [self.HEADER, "|" + "---|" * 8, *self.rows]
        atomic_write_text(self.path, f"{caption}\n\n" + "\n".join(table) + "\n")
        return self.path


def _vector(values: np.ndarray, decimals: int) -> str:
    return "(" + ", ".join(f"{v:.{decimals}f}" for v in values) + ")"
