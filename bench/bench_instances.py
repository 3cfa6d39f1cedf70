"""Finding the requested object among others from the twin's cameras: how well instances are split, how often the
detector's boxes pick the right one.

    python bench/bench_instances.py                                  # packed and pile, 4 objects, seeds 0-4
    python bench/bench_instances.py --kinds packed --seeds 0-1 --out /tmp/instances.md

For each scene kind, seed and target (the first object of each category of the twin) the twin lays out the scene as
`python -m sim.evaluate --scene` does (`SimCell(scene=...)`, the UR5 parked), its two virtual D435s capture it and
`seggrasp.perception.split_instances` splits the fused points into instances. Each object of the scene is matched
to the instance with the highest IoU against its points by the twin's segmentation masks
(`seggrasp.target.instance_iou`); it counts as separated when that IoU is at least `SEPARATED`. Then
`seggrasp.target.find_target` picks the target with the simulated object detector (`--detector` preset, the run
seed as its seed, as an episode does): found, the chosen instance's IoU after and before its boxes cut off what
lies outside them, and whether it is the target's best instance. The Markdown report goes to `--out`, with the command, the date and the commit.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
from tqdm import tqdm

from bench.bench_lab import commit
from seggrasp.detect.simulated import PRESETS, SimulatedObjectDetector
from seggrasp.io import atomic_write_text
from seggrasp.objects import load_asset_set
from seggrasp.perception import split_instances
from seggrasp.target import find_target, instance_iou, object_name
from sim.cell import SimCell
from sim.evaluate.cli import parse_seeds
from sim.scenes import KINDS

#: An object whose best instance has at least this IoU with its points is separated from the others.
SEPARATED = 0.8
DEFAULT_OUT = Path("docs/results/instance-split.md")


@dataclass
class Scene:
    """One scene's figures: objects and instances, each object's best IoU, and the target search."""

    kind: str
    seed: int
    target_id: str
    n_objects: int
    n_instances: int
    best_ious: dict[str, float]  # per object of the scene, target first
    target_best: float
    found: bool
    chosen_iou: float | None  # the chosen instance's IoU with the target, cut by its boxes (None: not found)
    uncut_iou: float | None  # the same before the cut (`seggrasp.target.cut_by_boxes`)
    right_instance: bool


def measure(cell: SimCell, kind: str, seed: int, target_id: str, preset: str) -> Scene:
    """Lay out one scene, split it and search its target (module docstring)."""
    cell.reset(seed=seed, object_id=target_id)
    truth = cell.scene_truth()
    instances = split_instances(cell.capture(), cell.workspace)
    ious = {body: [instance_iou(instances, k, body) for k in range(len(instances))] for body in truth.names}
    best = {body: max(values) for body, values in ious.items()}
    detector = SimulatedObjectDetector(truth.names, preset=preset, seed=seed)
    search = find_target(instances, detector, object_name(cell.current_object.category))
    chosen = instance_iou(search.instances, search.index, truth.target) if search.found else None
    named = {f"{truth.names[body]} ({body})": value for body, value in best.items()}
    uncut = ious[truth.target][search.index] if search.found else None
    return Scene(kind, seed, target_id, len(truth.names), len(instances), named, best[truth.target], search.found,
                 chosen, uncut, search.found and search.index == int(np.argmax(ious[truth.target])))


def kind_table(scenes: list[Scene]) -> list[str]:
    """The Markdown table of one row per scene kind."""
    lines = [
        "| scene | scenes | instances / objects | objects separated | target's best IoU | target found | chosen "
        "IoU (found) | before the boxes' cut | right instance |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for kind in sorted({s.kind for s in scenes}, key=KINDS.index):
        group = [s for s in scenes if s.kind == kind]
        objects = [v for s in group for v in s.best_ious.values()]
        chosen = [s.chosen_iou for s in group if s.found]
        uncut = [s.uncut_iou for s in group if s.found]
        lines.append(
            f"| {kind} | {len(group)} | {np.mean([s.n_instances for s in group]):.2f} / "
            f"{np.mean([s.n_objects for s in group]):.2f} | {np.mean([v >= SEPARATED for v in objects]):.3f} | "
            f"{np.mean([s.target_best for s in group]):.3f} | {np.mean([s.found for s in group]):.3f} | "
            f"{np.mean(chosen) if chosen else float('nan'):.3f} | {np.mean(uncut) if uncut else float('nan'):.3f} | "
            f"{np.mean([s.right_instance for s in group]):.3f} |")
    return lines


def report(scenes: list[Scene], command: str, seconds: float, preset: str, n_objects: int) -> list[str]:
    """The Markdown report: the table per scene kind, then the scenes whose target was not separated or not
    found."""
    lines = [
        "# Finding the object among others: instance splitting and the target's choice", "",
        f"`{command}`", "",
        f"Written {datetime.now(UTC):%Y-%m-%d %H:%M} UTC at commit {commit()}; {seconds / 60:.1f} min.", "",
        (f"Scenes of {n_objects} objects laid out by the twin as `sim.evaluate --scene` does, captured by its two "
         "virtual D435s and split by `seggrasp.perception.split_instances`; each object matched to its best "
         f"instance by the twin's masks (separated: IoU >= {SEPARATED}); the target picked by "
         f"`seggrasp.target.find_target` with the simulated object detector, preset `{preset}`, and cut by the boxes "
         "that picked it (`seggrasp.target.cut_by_boxes`; its IoU before the cut beside) (bench/bench_instances.py)."),
        "",
        *kind_table(scenes),
    ]
    missed = [s for s in scenes if s.target_best < SEPARATED or not s.right_instance]
    lines += ["", f"## Scenes whose target was not separated or not picked ({len(missed)})", "",
              "| scene | seed | target | instances | best IoU per object | found | chosen IoU |", "|---|---|---|---|---|---|---|"]
    for s in missed:
        per_object = ", ".join(f"{name} {value:.2f}" for name, value in s.best_ious.items())
        chosen = "-" if s.chosen_iou is None else f"{s.chosen_iou:.2f}"
        lines.append(f"| {s.kind} | {s.seed} | {s.target_id} | {s.n_instances} | {per_object} | {s.found} | {chosen} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", default=",".join(KINDS), help=f"comma-separated scene kinds, from {KINDS}")
    parser.add_argument("--seeds", default="0-4", help="scene seeds: 0-4, 0,3 or a mix")
    parser.add_argument("--objects-per-scene", type=int, default=4)
    parser.add_argument("--detector", choices=sorted(PRESETS), default="typical", help="simulated detector preset")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    kinds = [k.strip() for k in args.kinds.split(",") if k.strip()]
    try:
        seeds = parse_seeds(args.seeds)
        if not kinds or any(k not in KINDS for k in kinds):
            raise ValueError(f"--kinds must name scene kinds from {KINDS}, got {args.kinds!r}")
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    objects = load_asset_set()
    first_of: dict[str, str] = {}
    for model in objects:
        first_of.setdefault(model.category, model.object_id)
    targets = list(first_of.values())
    start, scenes = time.monotonic(), []
    for kind in kinds:
        cell = SimCell(objects=objects, scene=kind, objects_per_scene=args.objects_per_scene, seed=seeds[0])
        try:
            for seed in seeds:
                for target in tqdm(targets, desc=f"{kind} seed {seed}", leave=False):
                    scenes.append(measure(cell, kind, seed, target, args.detector))
        finally:
            cell.close()
    command = "python bench/bench_instances.py " + " ".join(argv if argv is not None else sys.argv[1:])
    lines = report(scenes, command.strip(), time.monotonic() - start, args.detector, args.objects_per_scene)
    atomic_write_text(args.out, "\n".join(lines) + "\n")
    print("\n".join(kind_table(scenes)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
