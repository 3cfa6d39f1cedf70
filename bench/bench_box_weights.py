"""Study: weighting each detector box's vote by how specific it is, against eq. 1's confidence alone.

    python bench/bench_box_weights.py --meshes twin --results docs/results/seg-box-weights-twin.md
    python bench/bench_box_weights.py --meshes ycb --results docs/results/seg-box-weights-ycb.md

Real open-vocabulary detectors answer a part prompt with a box around the whole object, or around another part,
as often as with the part (the simulated detector's `typical` preset: half of its boxes are whole-object boxes).
Two ways to discount such boxes before eq. 1, both applied to the box confidences handed to `seggrasp.vote.vote`:

- specificity^p: confidence x (object pixels in the view / object pixels in the box)^p, so a box around the
  whole object spreads the mass a part box concentrates (p = 0.5, 1);
- contrast: confidence x (1 - the box's largest IoU with a box of another prompt in the same view), so a region
  two prompts both claim (two whole-object boxes, a part boxed for the wrong prompt) votes for neither; half
  contrast subtracts half of that IoU.

For each labelled mesh and detector/camera seed, every variant's votes go through coarse argmax and the shipped
default refinement (`seggrasp.fusion.refine_labels`); the report is `bench_seg.py --quality`'s, plus the paired
differences of every variant against eq. 1.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np


from bench.bench_seg import LabelledMesh, paired_over_seeds, quality_report, twin_meshes, ycb_meshes  # noqa: E402
from seggrasp.decompose import DecompositionConfig, decompose_sweep  # noqa: E402
from seggrasp.detect.base import Detections  # noqa: E402
from seggrasp.detect.base import box_iou  # noqa: E402
from seggrasp.detect.simulated import SimulatedDetector  # noqa: E402
from seggrasp.fusion import refine_labels, refine_scores  # noqa: E402
from seggrasp.io import atomic_write_text  # noqa: E402
from seggrasp.metrics import shape_miou  # noqa: E402
from seggrasp.render import camera_rig, render_views  # noqa: E402
from seggrasp.truth import SIMULATED_PRESETS  # noqa: E402
from seggrasp.views import View  # noqa: E402
from seggrasp.vote import labels_from_scores, pixels_in_boxes, vote  # noqa: E402

#: Variant name -> (kind, parameter); eq. 1 itself is the baseline.
VARIANTS = {"specificity^0.5": ("specificity", 0.5), "specificity^1": ("specificity", 1.0),
            "contrast": ("contrast", 1.0), "half contrast": ("contrast", 0.5)}


def box_weights(view: View, found: Detections, kind: str, parameter: float) -> np.ndarray:
    """The factor each box's confidence is multiplied by (see the module docstring)."""
    if kind == "specificity":
        faces, inside = pixels_in_boxes(view, found.boxes)
        return (len(faces) / np.maximum(inside.sum(axis=1), 1)) ** parameter
    if kind == "contrast":
        other_prompt = found.prompt_index[:, None] != found.prompt_index[None, :]
        ious = np.stack([box_iou(box, found.boxes) for box in found.boxes])
        overlap = np.where(other_prompt, ious, 0.0).max(axis=1)
        return 1.0 - parameter * overlap
    raise ValueError(f"unknown box weighting {kind!r}; choose specificity or contrast")


def weighted_votes(views: list[View], detections: list[Detections], n_faces: int, n_prompts: int, kind: str,
                   parameter: float) -> np.ndarray:
    """Eq. 1 with every box's confidence multiplied by its `box_weights` factor."""
    reweighted = [found if len(found) == 0 else
                  Detections(found.boxes, found.scores * box_weights(view, found, kind, parameter), found.prompt_index)
                  for view, found in zip(views, detections)]
    return vote(views, reweighted, n_faces, n_prompts)


def records_of(item: LabelledMesh, preset: str, seeds: range) -> list[dict]:
    """Per seed: mIoU of eq. 1's coarse / GeoFusion / default labels and of every variant's coarse and default."""
    partitions = decompose_sweep(item.mesh, DecompositionConfig(seed=0), workers=1)
    areas, gt, n_parts = item.mesh.area_faces, item.labels.face_labels, len(item.labels.parts)
    records = []
    for seed in seeds:
        views = render_views(item.mesh, camera_rig(n_views=10, seed=seed), image_size=512)
        detections = SimulatedDetector(item.labels, preset=preset, seed=seed).detect(views, item.labels.parts)
        plain = vote(views, detections, len(item.mesh.faces), n_parts)
        labels = {"none": labels_from_scores(plain),
                  "full": labels_from_scores(refine_scores(plain, partitions, areas, "full")),
                  "default": refine_labels(plain, partitions, areas)[1]}
        for name, (kind, parameter) in VARIANTS.items():
            scores = weighted_votes(views, detections, len(item.mesh.faces), n_parts, kind, parameter)
            labels[f"coarse, {name}"] = labels_from_scores(scores)
            labels[f"default, {name}"] = refine_labels(scores, partitions, areas)[1]
        records.append({"mesh": item.name, "category": item.category, "seed": seed,
                        "miou": {m: shape_miou(pred, gt, n_parts, areas) for m, pred in labels.items()}})
        print(f"{item.name} seed {seed}: default {records[-1]['miou']['default']:.3f}", flush=True)
    return records


def variant_table(records: list[dict]) -> str:
    """Markdown: every variant's paired difference (mean over seeds +- SE) against eq. 1 at the same stage."""
    lines = ["| variant | coarse - coarse (eq. 1) | default - default (eq. 1) |", "|---|---|---|"]
    for name in VARIANTS:
        (d_coarse, se_coarse), (d_default, se_default) = (
            paired_over_seeds(records, f"coarse, {name}", "none"),
            paired_over_seeds(records, f"default, {name}", "default"))
        lines.append(f"| {name} | {d_coarse:+.3f} +- {se_coarse:.3f} | {d_default:+.3f} +- {se_default:.3f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", choices=["twin", "ycb"], default="twin")
    parser.add_argument("--preset", default="typical", choices=SIMULATED_PRESETS)
    parser.add_argument("--seeds", type=int, default=5, help="detector/camera seeds --first-seed.. (default 5)")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--only", help="comma list of mesh names (default: all of --meshes)")
    parser.add_argument("--results", type=Path, help="also write the report (markdown) here")
    args = parser.parse_args(argv)
    if args.seeds < 2 or args.first_seed < 0:
        parser.error("need --seeds >= 2 (a paired standard error) and --first-seed >= 0")
    try:
        items = twin_meshes() if args.meshes == "twin" else ycb_meshes()
    except FileNotFoundError as error:
        parser.error(str(error))
    if args.only:
        wanted = {name.strip() for name in args.only.split(",") if name.strip()}
        unknown = wanted - {item.name for item in items}
        if unknown:
            parser.error(f"unknown meshes {sorted(unknown)}; known: {sorted(item.name for item in items)}")
        items = [item for item in items if item.name in wanted]
    started = time.perf_counter()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    records = [record for item in items for record in records_of(item, args.preset, seeds)]
    title = (f"Box weights: --meshes {args.meshes}, preset {args.preset}, seeds {seeds.start}-{seeds.stop - 1} "
             f"({time.perf_counter() - started:.0f} s)")
    report = (quality_report(records, title) + "\n### Every variant against eq. 1 (paired over seeds)\n\n"
              + variant_table(records))
    print(report)
    if args.results is not None:
        command = "python bench/bench_box_weights.py " + " ".join(sys.argv[1:] if argv is None else argv)
        atomic_write_text(args.results, f"{report}\nMeasured by `{command}`.\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
