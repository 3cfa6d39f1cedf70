"""Picture strips of one grasp trial: a virtual camera that follows the gripper, one frame per stage.

`SimCell.record_next(path)` arms a `TrialRecorder` for the next `execute()`: the grasp primitive calls
`snap(stage)` at the pre-grasp, after closing, after the lift and after the hold, and the recorder writes the
frames side by side as one PNG (atomically), captioned with the stage and, at the end, the outcome.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from seggrasp.io import atomic_write_bytes
from seggrasp.views import look_at
from sim.cameras import VirtualD435

#: Stages the grasp primitive captures, in order.
STAGES = ("pre-grasp", "closed", "lifted", "held")
#: Size of one frame of the strip (pixels).
FRAME_SIZE = (320, 240)
#: Where the camera sits relative to the gripper's TCP (world frame, m): in front of the robot, a little up.
CAMERA_OFFSET = np.array([0.30, -0.22, 0.16])


class TrialRecorder:
    """Collects captioned frames of one trial from a camera aimed at the gripper's TCP, then writes a strip."""

    def __init__(self, path: str | Path, size: tuple[int, int] = FRAME_SIZE) -> None:
        self.path = Path(path)
        self.size = size
        self.frames: list[tuple[str, np.ndarray]] = []

    def snap(self, client, stage: str, T_world_tcp: np.ndarray) -> None:
        """Render the scene from `CAMERA_OFFSET` beside the TCP, looking at it, and keep it captioned `stage`."""
        target = np.asarray(T_world_tcp, dtype=float)[:3, 3]
        camera = VirtualD435("recorder", look_at(target + CAMERA_OFFSET, target), *self.size)
        rgb, _, _ = camera.render(client)
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
