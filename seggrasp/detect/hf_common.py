"""Helpers shared by the transformers-based detectors: weight loading with clear errors, prompts, boxes, NMS."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence, TypeVar

import numpy as np

from seggrasp.labels import check_prompts, prompt_key
from seggrasp.views import View

T = TypeVar("T")


class WeightsNotFoundError(ValueError):
    """The detector's weights could not be found; the message says how to provide them."""


def _how_to_provide(model: str, example_hub_id: str) -> str:
    return (
        f"Provide {model} weights as either (a) a local folder holding config.json, the model weights, the image "
        f"processor config and the tokenizer files, e.g. made on a machine with internet by "
        f"`from_pretrained('{example_hub_id}')` followed by `save_pretrained(DIR)` on the model, image processor and "
        f"tokenizer, or a downloaded hub snapshot folder; or (b) a hub id such as '{example_hub_id}' on a machine "
        "with internet access (HF_HUB_OFFLINE must be unset; with HF_HUB_OFFLINE=1 only the local hub cache is used)."
    )


#: A hub id is "name" or "owner/name"; anything else that does not exist locally is a missing folder.
_HUB_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*(/[A-Za-z0-9][A-Za-z0-9_.-]*)?$")


def resolve_weights(weights: str | os.PathLike | None, model: str, example_hub_id: str) -> str:
    """Check a weights argument and return what `from_pretrained` should receive.

    An existing folder must contain config.json. A string shaped like a hub id ("name" or "owner/name") that is not
    a local folder is passed on as a hub id; anything else must be an existing folder. Raises `WeightsNotFoundError`
    with instructions otherwise.
    """
    if weights is None or str(weights).strip() == "":
        raise WeightsNotFoundError(f"no weights given for {model}. " + _how_to_provide(model, example_hub_id))
    text = os.path.expanduser(str(weights))
    path = Path(text)
    if path.is_dir():
        if not (path / "config.json").is_file():
            raise WeightsNotFoundError(
                f"{model} weights folder {path} has no config.json. " + _how_to_provide(model, example_hub_id)
            )
        return str(path)
    if path.exists():
        raise WeightsNotFoundError(
            f"{model} weights must be a folder, but {path} is a file. " + _how_to_provide(model, example_hub_id)
        )
    if isinstance(weights, os.PathLike) or not _HUB_ID.match(str(weights)):
        raise WeightsNotFoundError(
            f"{model} weights folder {path} does not exist. " + _how_to_provide(model, example_hub_id)
        )
    return str(weights)


def load_pretrained(loader: Callable[[str], T], source: str, model: str, example_hub_id: str, part: str) -> T:
    """Call `loader(source)` (a `from_pretrained`), turning missing-file errors into `WeightsNotFoundError`."""
    offline = os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in {"1", "true", "yes", "on"}
    try:
        return loader(source)
    except (OSError, ValueError) as exc:
        where = f"folder {source}" if Path(source).is_dir() else f"hub id {source!r} (no local folder of that name)"
        mode = " (HF_HUB_OFFLINE=1: nothing is downloaded, only the local hub cache is searched)" if offline else ""
        raise WeightsNotFoundError(
            f"could not load the {model} {part} from {where}{mode}: {exc}\n" + _how_to_provide(model, example_hub_id)
        ) from exc


@dataclass
class LoadedDetector:
    """The pieces of a transformers detector loaded from one source, in eval mode on `device`."""

    source: str
    image_processor: Any
    tokenizer: Any
    model: Any
    device: Any


def load_detector(
    weights: str | os.PathLike, image_processor_cls: Any, model_cls: Any, model: str, example_hub_id: str,
    device: str, batch_size: int,
) -> LoadedDetector:
    """Resolve `weights`, load image processor, tokenizer and model with clear errors, and check `batch_size`."""
    import torch
    from transformers import AutoTokenizer

    if batch_size < 1:
        raise ValueError(f"batch_size must be at least 1, got {batch_size}")
    source = resolve_weights(weights, model, example_hub_id)
    loaded = LoadedDetector(
        source=source,
        image_processor=load_pretrained(image_processor_cls.from_pretrained, source, model, example_hub_id,
                                        "image processor"),
        tokenizer=load_pretrained(AutoTokenizer.from_pretrained, source, model, example_hub_id, "tokenizer"),
        model=load_pretrained(model_cls.from_pretrained, source, model, example_hub_id, "model"),
        device=torch.device(device),
    )
    loaded.model.to(loaded.device).eval()
    return loaded


def clean_prompts(prompts: Sequence[str]) -> list[str]:
    """Validate prompts (`seggrasp.labels.check_prompts`) and return them in matching form (`prompt_key`)."""
    return [prompt_key(p) for p in check_prompts(prompts)]


def view_images(views: Sequence[View]) -> list[np.ndarray]:
    """The RGB images of the views as (H, W, 3) uint8 arrays; ValueError for anything else."""
    images = []
    for i, view in enumerate(views):
        rgb = np.asarray(view.rgb)
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
            raise ValueError(f"view {i}: rgb must be an (H, W, 3) image, got shape {rgb.shape}")
        if rgb.dtype != np.uint8:
            raise ValueError(f"view {i}: rgb must be uint8, got {rgb.dtype}")
        images.append(np.ascontiguousarray(rgb))
    return images


def batches(n: int, batch_size: int) -> list[range]:
    """Consecutive index ranges of at most `batch_size` covering 0..n-1."""
    return [range(start, min(start + batch_size, n)) for start in range(0, n, batch_size)]


def cxcywh_to_xyxy(boxes: np.ndarray, scale_x: float, scale_y: float, width: int, height: int) -> np.ndarray:
    """Normalised (cx, cy, w, h) boxes -> pixel (x1, y1, x2, y2), scaled and clipped to a width x height image.

    A box lying wholly outside the image (e.g. in OWLv2's padding) ends up with zero area; see `has_area`.
    """
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    half_w, half_h = np.abs(boxes[:, 2]) / 2, np.abs(boxes[:, 3]) / 2
    xyxy = np.stack(
        [
            (boxes[:, 0] - half_w) * scale_x,
            (boxes[:, 1] - half_h) * scale_y,
            (boxes[:, 0] + half_w) * scale_x,
            (boxes[:, 1] + half_h) * scale_y,
        ],
        axis=1,
    )
    xyxy[:, [0, 2]] = np.clip(xyxy[:, [0, 2]], 0.0, float(width))
    xyxy[:, [1, 3]] = np.clip(xyxy[:, [1, 3]], 0.0, float(height))
    return xyxy


def has_area(boxes: np.ndarray) -> np.ndarray:
    """Mask of xyxy boxes with positive width and height."""
    return (boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1])


def nms_per_prompt(boxes: np.ndarray, scores: np.ndarray, prompt_index: np.ndarray, iou_threshold: float) -> np.ndarray:
    """Indices kept by greedy non-maximum suppression run separately for each prompt, best score first."""
    keep: list[int] = []
    for prompt in np.unique(prompt_index):
        candidates = np.flatnonzero(prompt_index == prompt)
        candidates = candidates[np.argsort(-scores[candidates], kind="stable")]
        while len(candidates):
            best, rest = candidates[0], candidates[1:]
            keep.append(int(best))
            candidates = rest[box_iou(boxes[best], boxes[rest]) <= iou_threshold]
    keep_array = np.array(sorted(keep, key=lambda i: (-scores[i], i)), dtype=np.int64)
    return keep_array


def box_iou(box: np.ndarray, others: np.ndarray) -> np.ndarray:
    """IoU of one xyxy box against an (N, 4) array of boxes."""
    x1 = np.maximum(box[0], others[:, 0])
    y1 = np.maximum(box[1], others[:, 1])
    x2 = np.minimum(box[2], others[:, 2])
    y2 = np.minimum(box[3], others[:, 3])
    intersection = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    area = (box[2] - box[0]) * (box[3] - box[1])
    other_areas = (others[:, 2] - others[:, 0]) * (others[:, 3] - others[:, 1])
    union = area + other_areas - intersection
    return np.where(union > 0, intersection / np.maximum(union, 1e-12), 0.0)


def check_unit_interval(value: float, what: str) -> float:
    """Return `value` as float; ValueError unless it lies in [0, 1]."""
    value = float(value)
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{what} must lie in [0, 1], got {value}")
    return value
