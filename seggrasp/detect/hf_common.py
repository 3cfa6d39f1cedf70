"""Helpers shared by the transformers-based detectors: weight loading with clear errors, prompts, boxes, NMS."""

from __future__ import annotations

import functools
import os
import re
import socket
import threading
import urllib.parse
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Sequence, TypeVar

import numpy as np

from seggrasp.detect.base import box_iou
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


#: Seconds the hub may take to accept a TCP connection before it counts as unreachable (DNS included).
HUB_PROBE_TIMEOUT_S = 1.5
_OFFLINE_VALUES = {"1", "true", "yes", "on"}


def hub_offline_reason() -> str | None:
    """Why nothing can be downloaded from the Hugging Face hub, or None when it can: HF_HUB_OFFLINE or
    TRANSFORMERS_OFFLINE set, or the hub endpoint (HF_ENDPOINT, through HTTPS_PROXY if set) refusing a connection
    within HUB_PROBE_TIMEOUT_S (no network). The probe runs once per process."""
    for variable in ("HF_HUB_OFFLINE", "TRANSFORMERS_OFFLINE"):
        if os.environ.get(variable, "").strip().lower() in _OFFLINE_VALUES:
            return f"{variable}=1"
    return _probe_hub(os.environ.get("HF_ENDPOINT", "https://huggingface.co"),
                      os.environ.get("HTTPS_PROXY") or os.environ.get("https_proxy") or "")


@functools.lru_cache(maxsize=None)
def _probe_hub(endpoint: str, proxy: str) -> str | None:
    """None if a TCP connection to the endpoint (or the proxy) opens within HUB_PROBE_TIMEOUT_S, else why not."""
    target = urllib.parse.urlsplit(proxy or endpoint)
    host, port = target.hostname or "", target.port or (443 if target.scheme == "https" else 80)
    outcome: list[str | None] = []

    def connect() -> None:  # in a thread: name resolution has no timeout of its own
        try:
            socket.create_connection((host, port), timeout=HUB_PROBE_TIMEOUT_S).close()
            outcome.append(None)
        except OSError as exc:
            outcome.append(f"{host}:{port} cannot be reached: {exc.strerror or exc}")

    thread = threading.Thread(target=connect, daemon=True)
    thread.start()
    thread.join(HUB_PROBE_TIMEOUT_S + 0.5)
    return outcome[0] if outcome else f"{host}:{port} did not answer within {HUB_PROBE_TIMEOUT_S} s"


def _in_hub_cache(repo_id: str) -> bool:
    """Whether the local hub cache holds the config.json of `repo_id` (then it loads without a download)."""
    from huggingface_hub import try_to_load_from_cache

    return isinstance(try_to_load_from_cache(repo_id, "config.json"), str)


def resolve_weights(weights: str | os.PathLike | None, model: str, example_hub_id: str) -> str:
    """Check a weights argument and return what `from_pretrained` should receive.

    An existing folder must contain config.json. A string shaped like a hub id ("name" or "owner/name") that is not
    a local folder is passed on as a hub id if the hub can be used (`hub_offline_reason`) or its files are in the
    local hub cache; without either it is refused at once (a download would only time out). Anything else must be an
    existing folder. Raises `WeightsNotFoundError` with instructions otherwise.
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
    offline = hub_offline_reason()
    if offline is not None and not _in_hub_cache(str(weights)):
        raise WeightsNotFoundError(
            f"{model} weights {str(weights)!r}: no such local folder, not in the local hub cache, and nothing can be "
            f"downloaded ({offline}); give a local weights folder (config.json and the model files, as "
            "save_pretrained writes them)"
        )
    return str(weights)


def local_files_only(source: str) -> bool:
    """Whether `from_pretrained(source)` must not try the hub: a hub id while `hub_offline_reason` says no download
    is possible (the files then come from the local hub cache, without waiting for the network)."""
    return not Path(source).is_dir() and hub_offline_reason() is not None


def load_pretrained(loader: Callable[[str], T], source: str, model: str, example_hub_id: str, part: str) -> T:
    """Call `loader(source)` (a `from_pretrained`), turning missing-file errors into `WeightsNotFoundError`."""
    offline = os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in _OFFLINE_VALUES
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
    options = {"local_files_only": True} if local_files_only(source) else {}
    loaded = LoadedDetector(
        source=source,
        image_processor=load_pretrained(functools.partial(image_processor_cls.from_pretrained, **options), source,
                                        model, example_hub_id, "image processor"),
        tokenizer=load_pretrained(functools.partial(AutoTokenizer.from_pretrained, **options), source, model,
                                  example_hub_id, "tokenizer"),
        model=load_pretrained(functools.partial(model_cls.from_pretrained, **options), source, model,
                              example_hub_id, "model"),
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


def check_unit_interval(value: float, what: str) -> float:
    """Return `value` as float; ValueError unless it lies in [0, 1]."""
    value = float(value)
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{what} must lie in [0, 1], got {value}")
    return value
