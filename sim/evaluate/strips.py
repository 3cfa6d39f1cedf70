"""`--record`'s picture strips: where each is written, filming a slot whose outcome was reused, and the caption
with the trial's verdict."""

from __future__ import annotations

import hashlib
import io
from pathlib import Path

from seggrasp.cell import Cell
from seggrasp.episode import EpisodeContext, Slot, TrialRecord
from seggrasp.io import atomic_write_bytes
from sim.evaluate.config import DEFAULT_ROBOT
from sim.evaluate.records import writing

#: The most bytes of a prompt a strip's file name holds (the rest is replaced by a digest).
MAX_PROMPT_IN_NAME = 80


def strip_path(out: Path, method: str, object_id: str, prompt: str, rank: int, seed: int = 0,
               robot: str = DEFAULT_ROBOT) -> Path:
    """Where `--record` writes the picture strip of one slot: OUT/strips/<method>-<object>-<prompt>-<rank>.png
    (seed 0, the UR5), ...-<rank>-seed<seed>.png for another seed, ...-<robot>.png on another robot system; a
    prompt of more than `MAX_PROMPT_IN_NAME` characters is cut and given a digest of the whole, so the name stays
    within what a file system takes."""
    safe_prompt = "".join(c if c.isalnum() or c in "_." else "_" for c in prompt)
    if len(safe_prompt.encode("utf-8")) > MAX_PROMPT_IN_NAME:
        digest = hashlib.sha1(prompt.encode("utf-8")).hexdigest()[:10]
        safe_prompt = f"{safe_prompt.encode('utf-8')[:MAX_PROMPT_IN_NAME].decode('utf-8', 'ignore')}_{digest}"
    suffix = (f"-seed{seed}" if seed else "") + (f"-{robot}" if robot != DEFAULT_ROBOT else "")
    return out / "strips" / f"{method}-{object_id}-{safe_prompt}-{rank}{suffix}.png"


def film(cell: Cell, context: EpisodeContext, slot: Slot, path: Path) -> None:
    """Execute `slot`'s grasp once more in a freshly reset scene, recording it to `path`, and reset the scene again
    (a deterministic twin gives the outcome the slot reused; the episode's next step finds the scene as reset)."""
    cell.reset(seed=context.scene_seed, object_id=context.object_id)
    cell.record_next(path)
    cell.execute(slot.grasp.poses[0], float(slot.grasp.widths[0]))
    cell.reset(seed=context.scene_seed, object_id=context.object_id)


def strip_caption(record: TrialRecord) -> str:
    """A strip's caption: the trial and its result as the records score it, then what the cell reported."""
    verdict = "success" if record.success else f"failed: {record.failure or 'other'}"
    return (f"{record.method} {record.object_id} '{record.prompt}' #{record.rank}: {verdict} "
            f"(cell: {record.message}{', outcome reused' if record.reused_outcome else ''})")


def caption_strip(path: Path, record: TrialRecord) -> None:
    """Write the trial's caption (`strip_caption`) under the frames of the strip at `path` and into its PNG text
    (`caption`, `failure`), replacing the cell's own caption, which knows the outcome but not the prompted part."""
    from PIL import Image, ImageDraw
    from PIL.PngImagePlugin import PngInfo

    from sim.recording import FRAME_SIZE

    caption = strip_caption(record)
    with Image.open(path) as image:
        strip = image.convert("RGB")
    draw = ImageDraw.Draw(strip)
    draw.rectangle((0, FRAME_SIZE[1], strip.width, strip.height), fill="white")
    draw.text((6, FRAME_SIZE[1] + 5), caption, fill=(0, 0, 0))
    info = PngInfo()
    info.add_text("caption", caption)
    info.add_text("failure", "" if record.success else record.failure)
    buffer = io.BytesIO()
    strip.save(buffer, format="PNG", pnginfo=info)
    with writing(path):
        atomic_write_bytes(path, buffer.getvalue())
