"""`--perceive` criterion: segmentation on the mesh reconstructed from the twin's cameras vs on the true mesh.

    python bench/bench_perceive.py                          # every twin object, coarse voting, simulated detector
    python bench/bench_perceive.py --objects mug_classic --refine full --out /tmp/perceive.json

For each object the simulated cell (`sim.cell.SimCell`, its virtual D435s with depth noise) captures RGB-D frames;
`seggrasp.perception.perceive_object` turns them into a mesh, which is moved into the object frame with the true
pose. Ground-truth labels are transferred to the reconstructed mesh face by face (label of the nearest true face to
each face centre). Both meshes are segmented with the same pipeline (`seggrasp.segment`, simulated detector with
the same preset and seed) and scored against their own ground truth (area-weighted mIoU). The criterion is
mIoU(reconstructed) / mIoU(true) >= 90%, reported per object and as the ratio of the means.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path


import numpy as np  # noqa: E402
import trimesh  # noqa: E402
from tqdm import tqdm  # noqa: E402


from seggrasp.detect.simulated import SimulatedDetector  # noqa: E402
from seggrasp.io import atomic_write_json  # noqa: E402
from seggrasp.labels import PartLabels  # noqa: E402
from seggrasp.mesh import prepare_mesh  # noqa: E402
from seggrasp.metrics import shape_miou, surface_distances  # noqa: E402
from seggrasp.perception import PerceptionConfig, Workspace, perceive_object  # noqa: E402
from seggrasp.segment import SegmentationConfig, segment  # noqa: E402
from seggrasp.truth import SIMULATED_PRESETS, parse_detector  # noqa: E402
from sim.cell import EMBODIMENTS  # noqa: E402

TARGET_RATIO = 0.9


def twin_workspace() -> Workspace:
    """The box around the twin's object area: 25 cm each way from the workspace centre, 3 cm below the table top."""
    from sim.world import TABLE_TOP_Z, WORKSPACE_CENTER

    x, y = (float(v) for v in WORKSPACE_CENTER)
    return Workspace(
        lower=(x - 0.25, y - 0.25, TABLE_TOP_Z - 0.03), upper=(x + 0.25, y + 0.25, TABLE_TOP_Z + 0.4),
        table_height=TABLE_TOP_Z,
    )


def transfer_labels(source: trimesh.Trimesh, source_labels: np.ndarray, target: trimesh.Trimesh) -> np.ndarray:
    """Label of every target face = label of the source face nearest to its centre."""
    _, _, nearest_face = trimesh.proximity.closest_point(source, target.triangles_center)
    return np.asarray(source_labels)[nearest_face]


def segmentation_miou(
    mesh: trimesh.Trimesh, labels: np.ndarray, prompts: list[str], preset: str, config: SegmentationConfig
) -> float:
    """Area-weighted mIoU of `segment` on `mesh` (simulated detector from `labels`) against `labels`."""
    prepared = prepare_mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces))
    detector = SimulatedDetector(PartLabels(prompts, prepared.from_source(labels)), preset=preset, seed=config.seed)
    result = segment(prepared, prompts, detector, config)
    return shape_miou(result.labels, labels, len(prompts), np.asarray(mesh.area_faces))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", nargs="*", help="twin object ids (default: all)")
    parser.add_argument("--preset", default="typical", choices=SIMULATED_PRESETS,
                        help="simulated-detector preset (default: typical)")
    parser.add_argument("--refine", default="none", help="segmentation refinement mode (default: none = coarse)")
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--cameras", type=int, default=2, help="virtual D435s in the cell (default: the cell's 2)")
    parser.add_argument("--embodiment", default="arm", choices=EMBODIMENTS)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="write the records as JSON here")
    args = parser.parse_args(argv)

    from seggrasp.objects import load_asset, load_asset_set
    from sim.cell import SimCell

    try:
        objects = [load_asset(i) for i in args.objects] if args.objects else load_asset_set()
        config = SegmentationConfig(n_views=args.views, refine=args.refine, seed=args.seed)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    workspace = twin_workspace()
    records = []
    with SimCell(objects=objects, embodiment=args.embodiment, seed=args.seed, n_cameras=args.cameras) as cell:
        for model in tqdm(objects, desc="objects"):
            if model.labels is None:
                continue
            cell.reset(seed=args.seed, object_id=model.object_id)
            frames = cell.capture()
            true_mesh, T_world_obj = cell.object_mesh()
            prompts = list(model.prompts)
            true_labels = model.labels.remap_to(prompts)
            start = time.perf_counter()
            perceived = perceive_object(frames, workspace, PerceptionConfig(), seed=args.seed)
            perceive_seconds = time.perf_counter() - start
            perceived.apply_transform(np.linalg.inv(T_world_obj))
            perceived_labels = transfer_labels(true_mesh, true_labels, perceived)
            chamfer, p95 = surface_distances(perceived, true_mesh)
            miou_true = segmentation_miou(true_mesh, true_labels, prompts, args.preset, config)
            miou_perceived = segmentation_miou(perceived, perceived_labels, prompts, args.preset, config)
            records.append({
                "object": model.object_id, "category": model.category, "prompts": prompts,
                "faces_true": int(len(true_mesh.faces)), "faces_perceived": int(len(perceived.faces)),
                "watertight": bool(perceived.is_watertight), "chamfer_mm": 1000 * chamfer, "p95_mm": 1000 * p95,
                "perceive_s": perceive_seconds, "miou_true": miou_true, "miou_perceived": miou_perceived,
                "ratio": miou_perceived / miou_true if miou_true > 0 else float("nan"),
            })

    detector = parse_detector(args.preset).label
    print(f"--perceive: {len(records)} twin objects, detector {detector}, refine={args.refine}, "
          f"{args.cameras} cameras, {args.views} views, seed {args.seed}")
    print(f"{'object':24s} {'faces':>7s} {'chamfer':>8s} {'p95':>7s} {'mIoU true':>9s} {'mIoU perc':>9s} {'ratio':>6s}")
    for r in records:
        print(f"{r['object']:24s} {r['faces_perceived']:7d} {r['chamfer_mm']:6.2f}mm {r['p95_mm']:5.1f}mm "
              f"{r['miou_true']:9.3f} {r['miou_perceived']:9.3f} {r['ratio']:6.1%}")
    if not records:
        print("no labelled objects")
        return 1
    mean_true = float(np.mean([r["miou_true"] for r in records]))
    mean_perceived = float(np.mean([r["miou_perceived"] for r in records]))
    ratio = mean_perceived / mean_true
    print(f"mean mIoU true {mean_true:.3f}, perceived {mean_perceived:.3f}: ratio {ratio:.1%} "
          f"(target >= {TARGET_RATIO:.0%}: {'met' if ratio >= TARGET_RATIO else 'NOT met'})")
    if args.out:
        atomic_write_json(args.out, {
            "detector": detector, "refine": args.refine, "cameras": args.cameras, "views": args.views,
            "seed": args.seed, "records": records, "mean_miou_true": mean_true,
            "mean_miou_perceived": mean_perceived, "ratio": ratio,
        })
    return 0


if __name__ == "__main__":
    sys.exit(main())
