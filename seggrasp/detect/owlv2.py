"""OWLv2 through transformers: every prompt is its own text query, so a box's label is directly a prompt index.

OWLv2 pads each image to a square (bottom and right) before resizing, so its normalised boxes refer to the padded
square; they are scaled by max(H, W) and clipped to the image. Every image patch predicts one box, so overlapping
boxes of the same prompt are suppressed with NMS (the OWL-ViT authors' demo uses IoU 0.3).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from scipy.special import expit

from seggrasp.detect import HF_MODELS
from seggrasp.detect.base import Detections
from seggrasp.detect.hf_common import (
    batches,
    check_unit_interval,
    clean_prompts,
    cxcywh_to_xyxy,
    has_area,
    load_detector,
    nms_per_prompt,
    view_images,
)
from seggrasp.views import View

logger = logging.getLogger(__name__)

MODEL, EXAMPLE_HUB_ID = HF_MODELS["owlv2"]


class OwlV2:
    """Open-vocabulary detector: OWLv2 loaded with `from_pretrained` from a local folder or a hub id.

    Uses `Owlv2ImageProcessorPil` (no torchvision needed). A box is kept when the sigmoid of its best prompt logit
    exceeds `score_threshold`; `batch_size` views go through the model at once.
    """

    name = "owlv2"

    def __init__(
        self,
        weights: str | os.PathLike,
        score_threshold: float = 0.1,
        device: str = "cpu",
        batch_size: int = 2,
        nms_iou: float | None = 0.3,
    ) -> None:
        from transformers import Owlv2ForObjectDetection, Owlv2ImageProcessorPil

        self.score_threshold = check_unit_interval(score_threshold, "score_threshold")
        self.nms_iou = None if nms_iou is None else check_unit_interval(nms_iou, "nms_iou")
        loaded = load_detector(
            weights, Owlv2ImageProcessorPil, Owlv2ForObjectDetection, MODEL, EXAMPLE_HUB_ID, device, batch_size
        )
        self.batch_size = int(batch_size)
        self.weights, self.device = loaded.source, loaded.device
        self.image_processor, self.tokenizer, self.model = loaded.image_processor, loaded.tokenizer, loaded.model
        self.max_text_len = int(self.model.config.text_config.max_position_embeddings)
        logger.info("loaded %s from %s on %s", MODEL, Path(self.weights).name or self.weights, self.device)

    def detect(self, views: Sequence[View], prompts: Sequence[str]) -> list[Detections]:
        """One `Detections` per view, boxes in pixel xyxy of `view.rgb`, `prompt_index` into `prompts`."""
        queries = clean_prompts(prompts)
        images = view_images(views)
        if not images:
            return []
        text = self.tokenizer(queries, padding="max_length", max_length=self.max_text_len, return_tensors="pt")
        too_long = [q for q, mask in zip(queries, text["attention_mask"]) if int(mask.sum()) > self.max_text_len]
        if too_long:
            raise ValueError(f"prompts longer than OWLv2's {self.max_text_len} tokens: {too_long}")
        results: list[Detections] = []
        for batch in batches(len(images), self.batch_size):
            results.extend(self._detect_batch([images[i] for i in batch], text["input_ids"], text["attention_mask"]))
        return results

    @torch.inference_mode()
    def _detect_batch(
        self, images: list[np.ndarray], input_ids: torch.Tensor, attention_mask: torch.Tensor
    ) -> list[Detections]:
        pixels = self.image_processor(images=images, return_tensors="pt")
        n = len(images)
        outputs = self.model(
            pixel_values=pixels["pixel_values"].to(self.device),
            input_ids=input_ids.repeat(n, 1).to(self.device),  # (n * prompts, L): the same queries for every image
            attention_mask=attention_mask.repeat(n, 1).to(self.device),
        )
        logits = outputs.logits.float().cpu().numpy()  # (B, patches, prompts)
        pred_boxes = outputs.pred_boxes.float().cpu().numpy()  # (B, patches, 4) cx, cy, w, h of the padded square
        found = []
        for b, image in enumerate(images):
            best = logits[b].argmax(axis=1)
            score = expit(logits[b][np.arange(len(best)), best])
            keep = np.flatnonzero(score > self.score_threshold)
            height, width = image.shape[:2]
            side = max(height, width)
            boxes = cxcywh_to_xyxy(pred_boxes[b, keep], side, side, width, height)
            inside = has_area(boxes)
            boxes, keep = boxes[inside], keep[inside]
            scores, prompt_index = score[keep].astype(np.float64), best[keep].astype(np.int64)
            if self.nms_iou is not None and len(keep):
                order = nms_per_prompt(boxes, scores, prompt_index, self.nms_iou)
            else:
                order = np.argsort(-scores, kind="stable")
            found.append(Detections(boxes[order], scores[order], prompt_index[order]))
        return found
