"""The detector protocol: boxes with confidences per prompt, for a batch of views."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from seggrasp.views import View


@dataclass
class Detections:
    """Boxes found in one image: `boxes` (N, 4) pixel xyxy, `scores` (N,) in [0, 1], `prompt_index` (N,) ints."""

    boxes: np.ndarray
    scores: np.ndarray
    prompt_index: np.ndarray

    def __post_init__(self) -> None:
        self.boxes = np.asarray(self.boxes, dtype=np.float64).reshape(-1, 4)
        self.scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        self.prompt_index = np.asarray(self.prompt_index, dtype=np.int64).reshape(-1)
        if not (len(self.boxes) == len(self.scores) == len(self.prompt_index)):
            raise ValueError(
                f"detections disagree in length: {len(self.boxes)} boxes, {len(self.scores)} scores, "
                f"{len(self.prompt_index)} prompt indices"
            )

    @classmethod
    def empty(cls) -> "Detections":
        return cls(np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype=np.int64))

    def __len__(self) -> int:
        return int(len(self.scores))


@runtime_checkable
class Detector(Protocol):
    """Open-vocabulary box detector. Every result says which detector produced it via `name`."""

    name: str

    def detect(self, views: Sequence[View], prompts: Sequence[str]) -> list[Detections]:
        """One `Detections` per view; `prompt_index` refers to `prompts`."""


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
