"""Grounding DINO through transformers, with an exact mapping from caption tokens back to prompt indices.

All prompts go into one caption per forward pass, the way Grounding DINO was trained: lower-cased phrases joined
with ". " and ended with "." (transformers' sub-sentence attention mask keeps the phrases from attending to each
other). Each token is mapped to the prompt whose character span contains it, using the tokenizer's offset
mapping, so multi-token names ("frying pan") and prompts that share words ("pan" and "pan handle") are told apart
by position, never by decoding text. A box's score for prompt k is the highest sigmoid token probability over
prompt k's tokens (the original post-processing takes the same maximum over the whole caption); the box goes to the
prompt with the highest score and is kept when that score exceeds `box_threshold` and `text_threshold` (the latter
is the threshold the original code uses to decide which tokens name the box, so a kept box always names its
prompt). When the prompts do not fit into the model's text length they are split over several captions.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

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

MODEL, EXAMPLE_HUB_ID = HF_MODELS["grounding-dino"]


@dataclass
class Caption:
    """One text input: the caption, its token ids and the prompt index of every token (-1 = none)."""

    text: str
    input_ids: list[int]
    token_type_ids: list[int]
    token_prompt: np.ndarray  # (n_tokens,) int


def build_caption(tokenizer, phrases: Sequence[str], prompt_ids: Sequence[int]) -> Caption:
    """Join phrases into a Grounding DINO caption and map each of its tokens to a prompt index by character span."""
    spans: list[tuple[int, int, int]] = []
    text = ""
    for phrase, prompt in zip(phrases, prompt_ids):
        if text:
            text += " "
        spans.append((len(text), len(text) + len(phrase), prompt))
        text += phrase + "."
    encoding = tokenizer(text, return_offsets_mapping=True, return_token_type_ids=True)
    token_prompt = np.full(len(encoding["input_ids"]), -1, dtype=np.int64)
    for token, (start, end) in enumerate(encoding["offset_mapping"]):
        if end <= start:  # special tokens
            continue
        for span_start, span_end, prompt in spans:
            if start >= span_start and end <= span_end:
                token_prompt[token] = prompt
                break
    missing = sorted(set(prompt_ids) - set(token_prompt.tolist()))
    if missing:
        raise ValueError(f"prompts {missing} produced no tokens in the caption {text!r}")
    return Caption(text, list(encoding["input_ids"]), list(encoding["token_type_ids"]), token_prompt)


def split_into_captions(tokenizer, prompts: Sequence[str], max_tokens: int) -> list[Caption]:
    """Captions holding all prompts in order, each within the model's text length."""
    captions: list[Caption] = []
    group: list[int] = []
    for index in range(len(prompts)):
        trial = build_caption(tokenizer, [prompts[i] for i in group + [index]], group + [index])
        if len(trial.input_ids) <= max_tokens:
            group.append(index)
            continue
        if not group:
            raise ValueError(
                f"prompt {prompts[index]!r} alone needs {len(trial.input_ids)} tokens, more than the model's "
                f"{max_tokens}"
            )
        captions.append(build_caption(tokenizer, [prompts[i] for i in group], group))
        group = [index]
    captions.append(build_caption(tokenizer, [prompts[i] for i in group], group))
    return captions


class GroundingDino:
    """Open-vocabulary detector: Grounding DINO loaded with `from_pretrained` from a local folder or a hub id.

    Uses `GroundingDinoImageProcessorPil` (no torchvision needed). `batch_size` views go through the model at once;
    boxes of the same prompt overlapping by more than `nms_iou` are suppressed (None disables this).
    """

    name = "grounding-dino"

    def __init__(
        self,
        weights: str | os.PathLike,
        box_threshold: float = 0.25,
        text_threshold: float = 0.25,
        device: str = "cpu",
        batch_size: int = 2,
        nms_iou: float | None = 0.5,
    ) -> None:
        from transformers import GroundingDinoForObjectDetection, GroundingDinoImageProcessorPil

        self.box_threshold = check_unit_interval(box_threshold, "box_threshold")
        self.text_threshold = check_unit_interval(text_threshold, "text_threshold")
        self.nms_iou = None if nms_iou is None else check_unit_interval(nms_iou, "nms_iou")
        loaded = load_detector(
            weights, GroundingDinoImageProcessorPil, GroundingDinoForObjectDetection, MODEL, EXAMPLE_HUB_ID,
            device, batch_size,
        )
        self.batch_size = int(batch_size)
        self.weights, self.device = loaded.source, loaded.device
        self.image_processor, self.tokenizer, self.model = loaded.image_processor, loaded.tokenizer, loaded.model
        self.max_text_len = int(self.model.config.max_text_len)
        logger.info("loaded %s from %s on %s", MODEL, Path(self.weights).name or self.weights, self.device)

    def detect(self, views: Sequence[View], prompts: Sequence[str]) -> list[Detections]:
        """One `Detections` per view, boxes in pixel xyxy of `view.rgb`, `prompt_index` into `prompts`."""
        phrases = clean_prompts(prompts)
        images = view_images(views)
        if not images:
            return []
        captions = split_into_captions(self.tokenizer, phrases, self.max_text_len)
        per_view: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = [[] for _ in images]
        for caption in captions:
            for batch in batches(len(images), self.batch_size):
                for view_index, found in zip(batch, self._detect_batch([images[i] for i in batch], caption)):
                    per_view[view_index].append(found)
        results = []
        for parts in per_view:
            boxes = np.concatenate([p[0] for p in parts])
            scores = np.concatenate([p[1] for p in parts])
            prompt_index = np.concatenate([p[2] for p in parts])
            if self.nms_iou is not None and len(scores):
                keep = nms_per_prompt(boxes, scores, prompt_index, self.nms_iou)
            else:
                keep = np.argsort(-scores, kind="stable")
            results.append(Detections(boxes[keep], scores[keep], prompt_index[keep]))
        return results

    @torch.inference_mode()
    def _detect_batch(
        self, images: list[np.ndarray], caption: Caption
    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        pixels = self.image_processor(images=images, return_tensors="pt")
        n = len(images)
        input_ids = torch.tensor([caption.input_ids] * n, dtype=torch.long, device=self.device)
        outputs = self.model(
            pixel_values=pixels["pixel_values"].to(self.device),
            pixel_mask=pixels["pixel_mask"].to(self.device),
            input_ids=input_ids,
            token_type_ids=torch.tensor([caption.token_type_ids] * n, dtype=torch.long, device=self.device),
            attention_mask=torch.ones_like(input_ids),
        )
        n_tokens = len(caption.input_ids)
        token_probs = torch.sigmoid(outputs.logits[:, :, :n_tokens]).float().cpu().numpy()  # (B, Q, T)
        pred_boxes = outputs.pred_boxes.float().cpu().numpy()  # (B, Q, 4) normalised cx, cy, w, h
        prompts_here = np.unique(caption.token_prompt[caption.token_prompt >= 0])
        # prompt_scores[b, q, j] = best token probability of prompt prompts_here[j] for query q
        prompt_scores = np.stack(
            [token_probs[:, :, caption.token_prompt == p].max(axis=2) for p in prompts_here], axis=2
        )
        threshold = max(self.box_threshold, self.text_threshold)
        found = []
        for b, image in enumerate(images):
            best = prompt_scores[b].argmax(axis=1)
            score = prompt_scores[b][np.arange(len(best)), best]
            keep = np.flatnonzero(score > threshold)
            height, width = image.shape[:2]
            boxes = cxcywh_to_xyxy(pred_boxes[b, keep], width, height, width, height)
            inside = has_area(boxes)
            boxes, keep = boxes[inside], keep[inside]
            found.append((boxes, score[keep].astype(np.float64), prompts_here[best[keep]].astype(np.int64)))
        return found
