"""Open-vocabulary box detectors behind one protocol (`seggrasp.detect.base.Detector`).

`make_detector` builds one by name: "simulated" (ground-truth labels plus an error model, for the twin),
"grounding-dino" or "owlv2" (transformers, weights from a local folder or a hub id; imported only when asked for).
"""

from __future__ import annotations

import os

from seggrasp.detect.base import Detections, Detector
from seggrasp.labels import PartLabels

#: The transformers detectors: (model name in messages, example hub id).
HF_MODELS = {"grounding-dino": ("Grounding DINO", "IDEA-Research/grounding-dino-tiny"),
             "owlv2": ("OWLv2", "google/owlv2-base-patch16-ensemble")}
#: The names `make_detector` builds (a harness reads a detector's name with `seggrasp.truth.parse_detector`).
DETECTOR_NAMES = ("simulated", *HF_MODELS)


def check_weights(name: str, weights: str | os.PathLike | None) -> None:
    """For a transformers detector, `seggrasp.detect.hf_common.resolve_weights` without importing torch (a missing
    folder, or a hub id that cannot be downloaded, fails in a moment); nothing for the others."""
    if name in HF_MODELS:
        from seggrasp.detect.hf_common import resolve_weights

        resolve_weights(weights, *HF_MODELS[name])


def make_detector(
    name: str,
    *,
    weights: str | os.PathLike | None = None,
    gt_labels: PartLabels | None = None,
    preset: str = "typical",
    seed: int = 0,
) -> Detector:
    """A detector by name. "simulated" needs `gt_labels` (one label per face of the rendered mesh) and uses `preset`
    and `seed`; the transformers detectors need `weights` (a local weights folder or a hub id)."""
    if name == "simulated":
        if gt_labels is None:
            raise ValueError(
                "the simulated detector needs ground-truth part labels (give --labels GT.json on the command line)"
            )
        from seggrasp.detect.simulated import SimulatedDetector

        return SimulatedDetector(gt_labels, preset=preset, seed=seed)
    if name == "grounding-dino":
        from seggrasp.detect.grounding_dino import GroundingDino

        return GroundingDino(weights)
    if name == "owlv2":
        from seggrasp.detect.owlv2 import OwlV2

        return OwlV2(weights)
    raise ValueError(f"unknown detector {name!r}; choose one of {', '.join(DETECTOR_NAMES)}")


__all__ = ["DETECTOR_NAMES", "HF_MODELS", "Detections", "Detector", "check_weights", "make_detector"]
