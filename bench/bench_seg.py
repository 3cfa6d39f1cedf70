"""Segmentation benchmark: per-stage times and mIoU on labelled meshes, cold and warm decomposition cache.

    python bench/bench_seg.py                              # fast mode, twin + primitive meshes, cold then warm
    python bench/bench_seg.py --compare reference --seeds 20  # fast vs the paper's literal sweep, same coarse scores
    python bench/bench_seg.py --normalisations             # GeoFusion S_rev normalisations on cached sweeps
    python bench/bench_seg.py --meshes twin --quality      # mIoU per method over the twin, seeds 0-4, paired SEs
    python bench/bench_seg.py --meshes ycb --quality       # the same on the five labelled YCB scans
    python bench/bench_seg.py --meshes twin --quality --first-seed 5 --min-ratios 0.2,0.4  # seeds 5-9, gate study
    python bench/bench_seg.py --meshes ycb,perceived,big --big-faces 30000,300000,3000000 --seeds 3 --no-warm \
        --cold-results table.md                            # issue 16's real-like meshes cold (times, memory, mIoU)
    python bench/bench_seg.py --compare reference --rescore  # both modes' stored partitions under seeds 0-2

Coarse scores come from the simulated detector (preset `typical` unless --preset), 10 views of `camera_rig`, and
are computed once per mesh and detector seed (0..--seeds-1), so every mode sees the same views, boxes and seeds;
mIoU is the mean over those seeds (one seed's draw swings a mesh's mIoU by tens of points). Cold runs use a fresh
cache folder per (mesh, mode) and never the bundled twin caches; the warm run repeats the default mode on the
cache the cold run filled. Every (mesh, mode) decomposition runs in a forked child process so that its peak memory
(max RSS, including its CoACD workers) can be reported. Records are appended to a JSON Lines file (--out) and a re-run with --resume skips what is recorded.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import resource
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path


import numpy as np  # noqa: E402
import trimesh  # noqa: E402


from seggrasp.decompose import PAPER_THRESHOLDS, DecompositionConfig, SweepStats, decompose_sweep, default_cache_dir  # noqa: E402
from seggrasp.detect.simulated import SimulatedDetector  # noqa: E402
from seggrasp.io import atomic_save_npz, atomic_write_text  # noqa: E402
from seggrasp.fusion import (  # noqa: E402
    ANCHOR_MODES, NORMALISATIONS, REFINE_MODES, refine_labels, refine_scores, soft_anchor_prompts,
)
from seggrasp.labels import PartLabels, read_labels  # noqa: E402
from seggrasp.mesh import mesh_hash  # noqa: E402
from seggrasp.metrics import mean_over_categories, shape_miou  # noqa: E402
from seggrasp.render import camera_rig, render_views  # noqa: E402
from seggrasp.truth import SIMULATED_PRESETS  # noqa: E402
from seggrasp.vote import labels_from_scores, vote  # noqa: E402

ASSETS = Path(__file__).resolve().parents[1] / "assets"
#: Row names of the --quality report.
METHOD_NAMES = {"none": "coarse", "full": "GeoFusion (paper)", "default": "default (refine_labels)"}


@dataclass
class LabelledMesh:
    name: str
    category: str
    mesh: trimesh.Trimesh
    labels: PartLabels


# ------------------------------------------------------------------------------------------------- datasets


def _assemble(name: str, category: str, parts: list[tuple[str, trimesh.Trimesh]]) -> LabelledMesh:
    """One mesh made of distinct primitive parts; each face is labelled with the part it came from."""
    mesh = trimesh.util.concatenate([part for _, part in parts])
    face_labels = np.concatenate([np.full(len(part.faces), k) for k, (_, part) in enumerate(parts)])
    return LabelledMesh(name, category, mesh, PartLabels([n for n, _ in parts], face_labels))


def _placed(mesh: trimesh.Trimesh, rotation_axis=None, angle=0.0, offset=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    if rotation_axis is not None:
        mesh.apply_transform(trimesh.transformations.rotation_matrix(angle, rotation_axis))
    mesh.apply_translation(offset)
    return mesh


def primitive_meshes() -> list[LabelledMesh]:
    """Labelled meshes built from trimesh primitives (distinct parts, 1-4k faces)."""
    mug = _assemble("prim_mug", "mug", [
        ("body", trimesh.creation.cylinder(radius=0.04, height=0.1, sections=64)),
        ("handle", _placed(trimesh.creation.torus(0.03, 0.007, major_sections=48, minor_sections=16),
                           [1, 0, 0], np.pi / 2, (0.055, 0, 0))),
    ])
    hammer = _assemble("prim_hammer", "hammer", [
        ("handle", trimesh.creation.cylinder(radius=0.012, height=0.25, sections=32)),
        ("head", _placed(trimesh.creation.box([0.11, 0.03, 0.03]).subdivide().subdivide(), offset=(0.0, 0.0, 0.14))),
    ])
    pan = _assemble("prim_pan", "frying_pan", [
        ("body", trimesh.creation.annulus(r_min=0.09, r_max=0.1, height=0.04, sections=96)),
        ("base", _placed(trimesh.creation.cylinder(radius=0.09, height=0.006, sections=96), offset=(0, 0, -0.017))),
        ("handle", _placed(trimesh.creation.capsule(height=0.16, radius=0.01, count=[24, 24]), [0, 1, 0], np.pi / 2,
                           (0.19, 0.0, 0.0))),
    ])
    return [mug, hammer, pan]


def twin_meshes(twin_dir: Path | None = None) -> list[LabelledMesh]:
    """The twin's objects (`seggrasp.objects.load_asset_set()`), or <id>/mesh.obj + labels.json under `twin_dir`
    (a frozen copy, so that a long comparison keeps its meshes while the twin is regenerated)."""
    from seggrasp.object_physics import read_obj_arrays
    from seggrasp.objects import load_asset_set

    if twin_dir is None:
        return [LabelledMesh(m.object_id, m.category, m.mesh, m.labels) for m in load_asset_set() if m.labels]
    found = []
    for folder in sorted(Path(twin_dir).glob("*/")):
        if (folder / "mesh.obj").is_file() and (folder / "labels.json").is_file():
            vertices, faces = read_obj_arrays(folder / "mesh.obj")[0]
            found.append(LabelledMesh(folder.name, folder.name.split("_")[0],
                                      trimesh.Trimesh(vertices, faces, process=False), read_labels(folder / "labels.json")))
    return found


MULTIPART_CATEGORIES = ("scissors", "kettle", "eyeglasses")


def multipart_meshes() -> list[LabelledMesh]:
    """The twin's three- and four-part categories with thin parts (scissors, kettle, eyeglasses)."""
    return [m for m in twin_meshes() if m.category in MULTIPART_CATEGORIES]


def ycb_meshes() -> list[LabelledMesh]:
    """The five labelled YCB scans (`seggrasp.datasets.load_ycb_set`; FileNotFoundError if the scans are absent)."""
    from seggrasp.datasets import load_ycb_set

    return [LabelledMesh(s.name, s.category, s.mesh, s.labels) for s in load_ycb_set()]


def subdivided(item: LabelledMesh, n_faces: int) -> LabelledMesh:
    """`item` refined (manifold3d: edges split until shorter than a length found by bisection) to about `n_faces`
    faces; it stays a closed manifold and every new face keeps the label of the face it came from."""
    import manifold3d

    solid = manifold3d.Manifold(manifold3d.Mesh64(np.asarray(item.mesh.vertices, np.float64),
                                                  np.asarray(item.mesh.faces, np.uint64)))
    low, high = 1e-5, float(np.linalg.norm(item.mesh.extents))
    refined = None
    for _ in range(40):
        length = np.sqrt(low * high)
        refined = solid.refine_to_length(length).to_mesh64()
        count = len(refined.tri_verts)
        if 0.97 * n_faces <= count <= 1.05 * n_faces:
            break
        low, high = (length, high) if count > n_faces else (low, length)
    mesh = trimesh.Trimesh(np.ascontiguousarray(refined.vert_properties[:, :3], dtype=np.float64),
                           np.asarray(refined.tri_verts, np.int64), process=False)
    labels = item.labels.face_labels[np.asarray(refined.face_id, dtype=np.int64)]
    return LabelledMesh(f"{item.name}_{round(len(mesh.faces) / 1000)}k", item.category, mesh,
                        PartLabels(item.labels.parts, labels))


def perceived(item: LabelledMesh, noise: float = 0.001, n_points: int = 30_000, seed: int = 0) -> LabelledMesh:
    """A mesh like the robot's depth fusion makes: `n_points` points sampled on `item`'s surface with Gaussian noise
    of `noise` metres, reconstructed by `seggrasp.perception.reconstruct_mesh` (normals from the source faces); each
    face takes the label of the nearest source face."""
    from scipy.spatial import cKDTree

    from seggrasp.perception import reconstruct_mesh

    rng = np.random.default_rng(seed)
    points, faces = trimesh.sample.sample_surface(item.mesh, n_points, seed=seed)
    points = points + rng.normal(0.0, noise, points.shape)
    mesh = reconstruct_mesh(points, item.mesh.face_normals[faces])
    _, nearest = cKDTree(item.mesh.triangles_center).query(mesh.triangles_center)
    return LabelledMesh(f"{item.name}_perceived", item.category, mesh,
                        PartLabels(item.labels.parts, item.labels.face_labels[nearest]))


# ----------------------------------------------------------------------------------------------- the stages


def coarse_scores(item: LabelledMesh, preset: str, seed: int, n_views: int, image_size: int) -> tuple[np.ndarray, dict]:
    """Render, detect (simulated) and vote; returns S and the stage times."""
    times = {}
    started = time.perf_counter()
    views = render_views(item.mesh, camera_rig(n_views=n_views, seed=seed), image_size=image_size)
    times["render"] = time.perf_counter() - started
    started = time.perf_counter()
    detections = SimulatedDetector(item.labels, preset=preset, seed=seed).detect(views, item.labels.parts)
    times["detect"] = time.perf_counter() - started
    started = time.perf_counter()
    scores = vote(views, detections, len(item.mesh.faces), len(item.labels.parts))
    times["vote"] = time.perf_counter() - started
    return scores, times


def _sweep_child(conn, mesh, config, cache_dir, workers) -> None:
    stats = SweepStats()
    started = time.perf_counter()
    partitions = decompose_sweep(mesh, config, cache_dir=cache_dir, workers=workers, stats=stats, bundled=False)
    elapsed = time.perf_counter() - started
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    peak_kb = max(own.ru_maxrss, children.ru_maxrss)
    cpu = own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime
    conn.send(([(p.threshold, p.part_of_face) for p in partitions], stats, elapsed, peak_kb / 1024.0, cpu))
    conn.close()


def sweep_in_child(mesh, config, cache_dir, workers):
    """decompose_sweep in a forked child: (partitions, stats, seconds, peak RSS in MB, CPU seconds of the child and
    its CoACD workers)."""
    from seggrasp.decompose import Partition

    context = multiprocessing.get_context("fork")
    receive, send = context.Pipe(duplex=False)
    child = context.Process(target=_sweep_child, args=(send, mesh, config, cache_dir, workers))
    child.start()
    send.close()
    result = receive.recv()
    child.join()
    if child.exitcode != 0:
        raise RuntimeError(f"decomposition child failed with exit code {child.exitcode}")
    partitions, stats, elapsed, peak_mb, cpu = result
    return [Partition(t, p) for t, p in partitions], stats, elapsed, peak_mb, cpu


def evaluate_modes(item: LabelledMesh, scores: np.ndarray, partitions, normalisation: str) -> dict:
    """mIoU (area-weighted and face-count) of every refinement mode, plus fusion time of "full"."""
    areas = item.mesh.area_faces
    gt = item.labels.face_labels
    n_parts = len(item.labels.parts)
    result = {}
    for mode in REFINE_MODES:
        started = time.perf_counter()
        labels = labels_from_scores(refine_scores(scores, partitions, areas, mode, normalisation))
        elapsed = time.perf_counter() - started
        result[mode] = {"miou": shape_miou(labels, gt, n_parts, areas), "miou_faces": shape_miou(labels, gt, n_parts),
                        "seconds": elapsed}
    return result


# ------------------------------------------------------------------------------------------------------ runs


def run_mesh(item: LabelledMesh, modes: list[str], args, done: set) -> list[dict]:
    """Cold (and warm) sweeps of `item` in every mode; mIoU is the mean over detector seeds 0..--seeds-1, whose
    coarse scores every mode shares. Stage times are those of the first seed."""
    records = []
    seeds = list(range(args.seeds))
    coarse = [coarse_scores(item, args.preset, seed, args.views, args.image_size) for seed in seeds]
    seed_scores, coarse_times = [scores for scores, _ in coarse], coarse[0][1]
    for mode in modes:
        if (item.name, mode) in done:
            continue
        config = DecompositionConfig(mode=mode, seed=args.seed)
        if mode == "fast" and args.fast_from is not None:
            config = DecompositionConfig(mode=mode, seed=args.seed,
                                         thresholds=tuple(t for t in PAPER_THRESHOLDS if t >= args.fast_from - 1e-9))
        with tempfile.TemporaryDirectory(prefix="seggrasp-bench-") as cache:
            partitions, stats, decompose_s, peak_mb, decompose_cpu = sweep_in_child(item.mesh, config, cache,
                                                                                    args.workers)
            warm = None
            if args.warm:
                started = time.perf_counter()
                warm_scores, warm_times = coarse_scores(item, args.preset, seeds[0], args.views, args.image_size)
                warm_stats = SweepStats()
                sweep_started = time.perf_counter()
                warm_partitions = decompose_sweep(item.mesh, config, cache_dir=cache, stats=warm_stats, bundled=False)
                warm_times["decompose"] = time.perf_counter() - sweep_started
                fusion_started = time.perf_counter()
                labels_from_scores(refine_scores(warm_scores, warm_partitions, item.mesh.area_faces, "full"))
                warm_times["fusion"] = time.perf_counter() - fusion_started
                warm_times["total_without_detector"] = time.perf_counter() - started - warm_times["detect"]
                warm = {"times": warm_times, "coacd_runs": len(warm_stats.run_seconds)}
        per_seed = [evaluate_modes(item, scores, partitions, args.normalisation) for scores in seed_scores]
        sidecar = args.out.parent / f"{args.out.stem}_arrays" / f"{item.name}_{mode}.npz"
        atomic_save_npz(sidecar, coarse_scores=seed_scores[0], thresholds=np.array([p.threshold for p in partitions]),
                        partitions=np.stack([p.part_of_face for p in partitions]).astype(np.int32))
        times = dict(coarse_times, decompose=decompose_s, fusion=per_seed[0]["full"]["seconds"])
        times["total_without_detector"] = sum(v for k, v in times.items() if k != "detect")
        records.append({
            "mesh": item.name, "category": item.category, "faces": int(len(item.mesh.faces)), "mode": mode,
            "mesh_hash": mesh_hash(item.mesh),
            "preset": args.preset, "seed": args.seed, "detector_seeds": seeds, "times": times, "peak_rss_mb": peak_mb,
            "decompose_cpu_s": decompose_cpu,
            "bench_peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
            "coacd_seconds": {f"{t:.2f}": s for t, s in sorted(stats.run_seconds.items())},
            "thresholds_run": sorted(stats.evaluated), "distinct_partitions": [p.threshold for p in partitions],
            "parts_per_partition": [p.n_parts for p in partitions],
            "miou": {m: float(np.mean([q[m]["miou"] for q in per_seed])) for m in REFINE_MODES},
            "miou_faces": {m: float(np.mean([q[m]["miou_faces"] for q in per_seed])) for m in REFINE_MODES},
            "miou_per_seed": {m: [q[m]["miou"] for q in per_seed] for m in REFINE_MODES}, "warm": warm,
        })
    return records


def paired_difference(values: Sequence[float], baseline: Sequence[float]) -> tuple[float, float, int]:
    """Mean of the paired differences values - baseline, its standard error (nan for one pair) and the pair count."""
    diffs = np.subtract(values, baseline, dtype=np.float64)
    if diffs.ndim != 1 or diffs.size == 0:
        raise ValueError(f"paired_difference needs two equally long non-empty lists, got {np.shape(diffs)}")
    se = float(diffs.std(ddof=1) / np.sqrt(diffs.size)) if diffs.size > 1 else float("nan")
    return float(diffs.mean()), se, int(diffs.size)


def _per_seed_full(fast: dict, ref: dict, names: Sequence[str]) -> tuple[list[float], list[float]]:
    """Per-seed full mIoU of the records `fast[name]` and `ref[name]`, concatenated over `names`."""
    return ([v for n in names for v in fast[n]["miou_per_seed"]["full"]],
            [v for n in names for v in ref[n]["miou_per_seed"]["full"]])


def print_table(records: list[dict], modes: list[str]) -> None:
    print(f"\n{'mesh':24s} {'faces':>6s} {'mode':9s} {'render':>7s} {'vote':>6s} {'decomp':>8s} {'fusion':>7s} "
          f"{'total':>8s} {'peakMB':>7s} {'runs':>4s} {'parts':>5s} {'coarse':>7s} {'full':>6s} {'multi':>6s} "
          f"{'opt':>6s} {'spread':>6s} {'warm':>6s}")
    for r in records:
        t, m = r["times"], r["miou"]
        warm = f"{r['warm']['times']['total_without_detector']:6.2f}" if r.get("warm") else "     -"
        print(f"{r['mesh']:24s} {r['faces']:6d} {r['mode']:9s} {t['render']:7.2f} {t['vote']:6.2f} "
              f"{t['decompose']:8.1f} {t['fusion']:7.3f} {t['total_without_detector']:8.1f} {r['peak_rss_mb']:7.0f} "
              f"{len(r['coacd_seconds']):4d} {len(r['distinct_partitions']):5d} {m['none']:7.3f} {m['full']:6.3f} "
              f"{m['multi']:6.3f} {m['opt']:6.3f} {m['spread']:6.3f} {warm}")
    by_mode = {mode: [r for r in records if r["mode"] == mode] for mode in modes}
    print()
    for mode, rows in by_mode.items():
        if not rows:
            continue
        summary = mean_over_categories([(r["category"], r["miou"]["full"]) for r in rows])
        print(f"{mode:9s}: {len(rows)} meshes, decomposition {sum(r['times']['decompose'] for r in rows):8.1f} s, "
              f"total {sum(r['times']['total_without_detector'] for r in rows):8.1f} s, "
              f"mean mIoU coarse {np.mean([r['miou']['none'] for r in rows]):.3f} "
              f"full {np.mean([r['miou']['full'] for r in rows]):.3f} (category mean {summary['overall']:.3f})")
    if len(modes) == 2 and all(by_mode.values()):
        common = sorted({r["mesh"] for r in by_mode[modes[0]]} & {r["mesh"] for r in by_mode[modes[1]]})
        fast = {r["mesh"]: r for r in by_mode[modes[0]] if r["mesh"] in common}
        ref = {r["mesh"]: r for r in by_mode[modes[1]] if r["mesh"] in common}
        for name in common:
            print(f"  {name:24s} speed-up decomposition {ref[name]['times']['decompose'] / fast[name]['times']['decompose']:6.1f}x"
                  f"  total {ref[name]['times']['total_without_detector'] / fast[name]['times']['total_without_detector']:6.1f}x"
                  f"  mIoU full {fast[name]['miou']['full']:.3f} vs {ref[name]['miou']['full']:.3f}")
        dec = sum(ref[n]["times"]["decompose"] for n in common) / sum(fast[n]["times"]["decompose"] for n in common)
        tot = sum(ref[n]["times"]["total_without_detector"] for n in common) / sum(
            fast[n]["times"]["total_without_detector"] for n in common)
        gap = np.mean([fast[n]["miou"]["full"] for n in common]) - np.mean([ref[n]["miou"]["full"] for n in common])
        spread = ""
        if all(len(fast[n].get("detector_seeds", [])) == len(ref[n].get("detector_seeds", [])) > 1 for n in common):
            _, se, pairs = paired_difference(*_per_seed_full(fast, ref, common))
            spread = f" (paired standard error {100 * se:.2f} points over {pairs} mesh x detector-seed pairs)"
        print(f"TOTAL over {len(common)} meshes: speed-up decomposition {dec:.1f}x, whole segmentation {tot:.1f}x "
              f"(detector excluded); mean mIoU(full) {modes[0]} - {modes[1]} = {100 * gap:+.2f} points{spread}")


def cold_report(records: list[dict], command: str) -> str:
    """Markdown table of cold runs: times (detector excluded), CPU seconds and peak memory of the decomposition,
    partitions and mIoU per mesh and mode; paired fast - reference differences where both modes ran."""
    lines = ["| mesh | faces | mode | render s | decomposition s (CPU s) | total s | peak MB (sweep / bench) | runs | "
             "parts (finest) | seeds | coarse mIoU | full mIoU |", "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in records:
        t = r["times"]
        cpu = f" ({r['decompose_cpu_s']:.1f})" if "decompose_cpu_s" in r else ""
        bench_mb = f" / {r['bench_peak_rss_mb']:.0f}" if "bench_peak_rss_mb" in r else ""
        lines.append(f"| {r['mesh']} | {r['faces']} | {r['mode']} | {t['render']:.1f} | {t['decompose']:.1f}{cpu} | "
                     f"{t['total_without_detector']:.1f} | {r['peak_rss_mb']:.0f}{bench_mb} | "
                     f"{len(r['coacd_seconds'])} | "
                     f"{r['parts_per_partition'][0]} | {len(r['detector_seeds'])} | {r['miou']['none']:.3f} | "
                     f"{r['miou']['full']:.3f} |")
    fast = {r["mesh"]: r for r in records if r["mode"] == "fast"}
    ref = {r["mesh"]: r for r in records if r["mode"] == "reference"}
    common = sorted(set(fast) & set(ref))
    if common:
        gap, se, pairs = paired_difference(*_per_seed_full(fast, ref, common))
        lines += ["", f"Full GeoFusion mIoU, fast - reference, on {', '.join(common)}: {100 * gap:+.2f} points "
                  f"(paired standard error {100 * se:.2f} points over {pairs} mesh x detector-seed pairs)."]
    return "\n".join(lines + ["", f"Measured by `{command}`."]) + "\n"


def normalisation_study(items: list[LabelledMesh], args) -> None:
    """mIoU of every refinement mode under every S_rev normalisation, on the (cached) default-mode sweeps."""
    rows = {n: {m: [] for m in REFINE_MODES} for n in NORMALISATIONS}
    for item in items:
        scores, _ = coarse_scores(item, args.preset, args.seed, args.views, args.image_size)
        partitions = decompose_sweep(item.mesh, DecompositionConfig(seed=args.seed), workers=args.workers)
        for normalisation in NORMALISATIONS:
            quality = evaluate_modes(item, scores, partitions, normalisation)
            for mode in REFINE_MODES:
                rows[normalisation][mode].append(quality[mode]["miou"])
        print(f"{item.name:24s} " + "  ".join(
            f"{n}: multi {rows[n]['multi'][-1]:.3f} full {rows[n]['full'][-1]:.3f}" for n in NORMALISATIONS)
            + f"  (coarse {rows[NORMALISATIONS[0]]['none'][-1]:.3f})")
    print(f"\nmean over {len(items)} meshes (preset {args.preset}, seed {args.seed}):")
    for normalisation in NORMALISATIONS:
        print(f"  {normalisation:15s} " + " ".join(f"{m} {np.mean(rows[normalisation][m]):.3f}" for m in REFINE_MODES))


def rescore(items: list[LabelledMesh], modes: list[str], args) -> None:
    """mIoU of every refinement mode on the partitions a --compare run stored, for several detector seeds.

    The decompositions do not depend on the detector, so this measures both modes' partitions under the same
    coarse scores for seeds 0..--seeds-1 without re-running CoACD.
    """
    folder = args.out.parent / f"{args.out.stem}_arrays"
    table: dict[str, dict[str, list[float]]] = {mode: {m: [] for m in REFINE_MODES} for mode in modes}
    for item in items:
        stored = {mode: folder / f"{item.name}_{mode}.npz" for mode in modes}
        if not all(path.is_file() for path in stored.values()):
            continue
        partitions = {}
        for mode, path in stored.items():
            from seggrasp.decompose import Partition

            with np.load(path) as data:
                partitions[mode] = [Partition(float(t), p.astype(np.int64))
                                    for t, p in zip(data["thresholds"], data["partitions"])]
        line = []
        for seed in range(args.seeds):
            scores, _ = coarse_scores(item, args.preset, seed, args.views, args.image_size)
            for mode in modes:
                quality = evaluate_modes(item, scores, partitions[mode], args.normalisation)
                for m in REFINE_MODES:
                    table[mode][m].append(quality[m]["miou"])
        for mode in modes:
            n = args.seeds
            line.append(f"{mode}: coarse {np.mean(table[mode]['none'][-n:]):.3f} full {np.mean(table[mode]['full'][-n:]):.3f}")
        print(f"{item.name:24s} " + "  ".join(line), flush=True)
    print(f"\nmean over meshes and seeds 0..{args.seeds - 1} (preset {args.preset}):")
    for mode in modes:
        print(f"  {mode:9s} " + " ".join(f"{m} {np.mean(table[mode][m]):.3f}" for m in REFINE_MODES))
    if len(modes) == 2 and table[modes[0]]["full"]:
        gap, se, pairs = paired_difference(table[modes[0]]["full"], table[modes[1]]["full"])
        print(f"full mIoU {modes[0]} - {modes[1]}: {100 * gap:+.2f} points (paired standard error {100 * se:.2f} "
              f"points over {pairs} mesh x detector-seed pairs)")


def method_labels(scores: np.ndarray, partitions, areas: np.ndarray,
                  min_ratios: Sequence[float] = ()) -> dict[str, np.ndarray]:
    """Labels of every refinement mode (`REFINE_MODES`, "full" = the paper's GeoFusion), of GeoFusion with every
    anchoring mode of `seggrasp.fusion.ANCHOR_MODES`, of soft anchoring without its evidence gate and with the
    gate at each of `min_ratios`, and of the shipped default (`refine_labels` defaults)."""
    labels = {mode: labels_from_scores(refine_scores(scores, partitions, areas, mode)) for mode in REFINE_MODES}
    for anchor in ANCHOR_MODES:
        if anchor != "off":
            labels[f"anchor-{anchor}"] = refine_labels(scores, partitions, areas, "full", anchor)[1]
    refined = refine_scores(scores, partitions, areas, "full")
    labels["anchor-soft-ungated"] = soft_anchor_prompts(labels["full"], refined, partitions, areas, min_ratio=0.0)
    for ratio in min_ratios:
        labels[f"anchor-soft-gate{ratio:g}"] = soft_anchor_prompts(labels["full"], refined, partitions, areas,
                                                                   min_ratio=ratio)
    labels["default"] = refine_labels(scores, partitions, areas)[1]
    return labels


def quality_records(items: list[LabelledMesh], args) -> list[dict]:
    """One record per (mesh, detector/camera seed --first-seed.. --first-seed + --seeds - 1): the mIoU of every
    method of `method_labels` (with --min-ratios) on the default-mode sweep (warm from the bundled caches for the
    twin, from $SEGGRASP_CACHE otherwise)."""
    records = []
    for item in items:
        partitions = decompose_sweep(item.mesh, DecompositionConfig(seed=args.seed), workers=args.workers)
        areas, gt, n_parts = item.mesh.area_faces, item.labels.face_labels, len(item.labels.parts)
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            scores, _ = coarse_scores(item, args.preset, seed, args.views, args.image_size)
            labels = method_labels(scores, partitions, areas, args.min_ratios)
            miou = {m: shape_miou(pred, gt, n_parts, areas) for m, pred in labels.items()}
            records.append({"mesh": item.name, "category": item.category, "seed": seed, "miou": miou})
    return records


def paired_over_seeds(records: list[dict], method: str, against: str) -> tuple[float, float]:
    """Mean over seeds of the per-seed category-mean mIoU difference method - against, and its standard error."""
    seeds = sorted({r["seed"] for r in records})
    per_seed = [[mean_over_categories([(r["category"], r["miou"][m]) for r in records if r["seed"] == s])["overall"]
                 for s in seeds] for m in (method, against)]
    gap, se, _ = paired_difference(*per_seed)
    return gap, se


def quality_report(records: list[dict], title: str) -> str:
    """Markdown: per method the category-mean mIoU (mean over seeds) with paired differences to coarse and to the
    paper's GeoFusion; per category (coarse, GeoFusion, default and the default's paired differences); per mesh
    (coarse, GeoFusion, default, default - GeoFusion)."""
    methods = list(records[0]["miou"])
    seeds = sorted({r["seed"] for r in records})
    per_mesh: dict[str, dict] = {}
    for r in records:
        entry = per_mesh.setdefault(r["mesh"], {"category": r["category"], "miou": {m: [] for m in methods}})
        for m in methods:
            entry["miou"][m].append(r["miou"][m])
    summaries = {m: mean_over_categories([(e["category"], np.mean(e["miou"][m])) for e in per_mesh.values()])
                 for m in methods}
    categories = list(summaries[methods[0]]["categories"])
    lines = [f"## {title}", "", f"{len(per_mesh)} meshes x {len(seeds)} detector/camera seeds {seeds}; mIoU = "
             "area-weighted, mean over seeds per mesh, then over meshes per category, then over categories. "
             "Differences are paired (same seed, same views and boxes); +- is the standard error over seeds of the "
             "per-seed category-mean difference.", "",
             "| method | mIoU | vs coarse | vs GeoFusion | " + " | ".join(categories) + " |",
             "|---|---|---|---|" + "---|" * len(categories)]
    for m in methods:
        d_coarse, se_coarse = paired_over_seeds(records, m, "none")
        d_geo, se_geo = paired_over_seeds(records, m, "full")
        lines.append(f"| {METHOD_NAMES.get(m, m)} | {summaries[m]['overall']:.3f} | {d_coarse:+.3f} +- {se_coarse:.3f} "
                     f"| {d_geo:+.3f} +- {se_geo:.3f} | "
                     + " | ".join(f"{summaries[m]['categories'][c]:.3f}" for c in categories) + " |")
    d_coarse, se_coarse = paired_over_seeds(records, "default", "none")
    below = [c for c in categories if summaries["default"]["categories"][c] <= summaries["full"]["categories"][c]]
    gaps = {n: np.mean(e["miou"]["default"]) - np.mean(e["miou"]["full"]) for n, e in per_mesh.items()}
    worst = min(gaps, key=gaps.get)
    far_below = [f"{n} {gaps[n]:+.3f}" for n in sorted(gaps, key=gaps.get) if gaps[n] < -0.05]
    lines += ["", f"Default vs coarse: {d_coarse:+.3f} +- {se_coarse:.3f}. Categories where the default is not above "
              f"GeoFusion: {', '.join(below) or 'none'}. Worst mesh, default - GeoFusion: {worst} {gaps[worst]:+.3f}. "
              f"Meshes more than 0.05 below GeoFusion: {', '.join(far_below) or 'none'}."]
    lines += ["", "| category | coarse | GeoFusion | default | default - GeoFusion (+- SE over seeds) | "
              "default - coarse |", "|---|---|---|---|---|---|"]
    for c in categories:
        in_category = [r for r in records if r["category"] == c]
        (d_geo, se_geo), (d_coarse, se_coarse) = (paired_over_seeds(in_category, "default", m)
                                                  for m in ("full", "none"))
        means = " | ".join(f"{summaries[m]['categories'][c]:.3f}" for m in ("none", "full", "default"))
        lines.append(f"| {c} | {means} | {d_geo:+.3f} +- {se_geo:.3f} | {d_coarse:+.3f} +- {se_coarse:.3f} |")
    lines += ["", "| mesh | category | coarse | GeoFusion | default | default - GeoFusion (+- SE over seeds) |",
              "|---|---|---|---|---|---|"]
    for name, e in sorted(per_mesh.items(), key=lambda kv: (kv[1]["category"], kv[0])):
        gap, se, _ = paired_difference(e["miou"]["default"], e["miou"]["full"])
        lines.append(f"| {name} | {e['category']} | {np.mean(e['miou']['none']):.3f} | {np.mean(e['miou']['full']):.3f} "
                     f"| {np.mean(e['miou']['default']):.3f} | {gap:+.3f} +- {se:.3f} |")
    return "\n".join(lines) + "\n"


def quality(items: list[LabelledMesh], args) -> None:
    """Category and overall mIoU of every method over detector/camera seeds 0..--seeds-1, with paired standard
    errors against coarse and GeoFusion; the report is printed and (with --results) written atomically."""
    started = time.perf_counter()
    records = quality_records(items, args)
    title = (f"Segmentation quality: --meshes {args.meshes}, preset {args.preset}, {args.views} views at "
             f"{args.image_size} px, CoACD seed {args.seed} ({time.perf_counter() - started:.0f} s)")
    report = quality_report(records, title)
    print(report)
    if args.results is not None:
        command = "python bench/bench_seg.py " + " ".join(sys.argv[1:]) if args.argv is None else \
            "python bench/bench_seg.py " + " ".join(args.argv)
        atomic_write_text(args.results, f"{report}\nMeasured by `{command}`.\n")
        atomic_write_text(args.results.with_suffix(".jsonl"), "".join(json.dumps(r) + "\n" for r in records))
        print(f"written: {args.results} (and per-seed records {args.results.with_suffix('.jsonl')})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--compare", choices=["reference"], help="also run the paper's literal sweep")
    parser.add_argument("--normalisations", action="store_true", help="compare GeoFusion S_rev normalisations")
    parser.add_argument("--rescore", action="store_true",
                        help="re-evaluate the partitions a --compare run stored beside --out, over --seeds seeds")
    parser.add_argument("--seeds", type=int, default=None,
                        help="detector/camera-rig seeds 0..N-1 whose mean mIoU is reported (same seeds for every "
                             "mode; default 5 with --quality, else 3)")
    parser.add_argument("--quality", action="store_true",
                        help="mIoU of every method, mean over categories, over --seeds detector/camera seeds, with "
                             "paired standard errors against coarse and the paper's GeoFusion")
    parser.add_argument("--results", type=Path, help="with --quality: also write the report (markdown) here")
    parser.add_argument("--cold-results", type=Path, help="write the table of the cold runs (markdown) here")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="with --quality: detector/camera seeds start here (e.g. 5 with --seeds 5: seeds 5-9)")
    parser.add_argument("--min-ratios", default="",
                        help="with --quality: comma list of evidence-gate ratios of soft anchoring to report "
                             "besides the default (seggrasp.fusion.ANCHOR_MIN_RATIO)")
    parser.add_argument("--rescore-modes", help="comma list of stored sweeps to rescore (default: the compared modes)")
    parser.add_argument("--fast-from", type=float, help="fast mode on the paper grid from this threshold (study)")
    parser.add_argument("--meshes", default="twin,primitives",
                        help="comma list of: twin, primitives, ycb (the labelled YCB scans, see "
                             "seggrasp.datasets), multipart (the twin's scissors, kettles and eyeglasses), big (a twin object subdivided to each of --big-faces), "
                             "perceived (--perceived-from with 1 mm noise, reconstructed by seggrasp.perception), "
                             "or "
                             "mesh names")
    parser.add_argument("--preset", default="typical", choices=SIMULATED_PRESETS)
    parser.add_argument("--seed", type=int, default=0, help="CoACD seed (and the detector seed of --normalisations)")
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--image-size", type=int, default=512)
    parser.add_argument("--workers", type=int, default=None)
    parser.add_argument("--big-from", default="knife_chef", help="twin object to subdivide for --meshes big")
    parser.add_argument("--perceived-from", default="mug_classic", help="twin object for --meshes perceived")
    parser.add_argument("--big-faces", default="30000",
                        help="face counts of the --meshes big meshes, comma list (e.g. 30000,300000)")
    parser.add_argument("--twin-dir", type=Path, help="read twin objects from <dir>/<id>/{mesh.obj,labels.json}")
    parser.add_argument("--normalisation", default=None, choices=NORMALISATIONS)
    parser.add_argument("--no-warm", dest="warm", action="store_false", help="skip the warm-cache run")
    parser.add_argument("--out", type=Path, default=default_cache_dir().parent / "bench" / "bench_seg.jsonl")
    parser.add_argument("--resume", action="store_true", help="skip (mesh, mode) pairs already in --out")
    parser.add_argument("--run-only", choices=["fast", "reference"],
                        help="run only this mode now (the table also shows the other mode's records with --resume)")
    args = parser.parse_args(argv)
    args.argv = argv
    if args.seeds is None:
        args.seeds = 5 if args.quality else 3
    if args.seeds < 1:
        parser.error(f"--seeds must be at least 1, got {args.seeds}")
    if args.results is not None and not args.quality:
        parser.error("--results needs --quality")
    if args.first_seed < 0:
        parser.error(f"--first-seed must be non-negative, got {args.first_seed}")
    try:
        args.min_ratios = [float(r) for r in args.min_ratios.split(",") if r.strip()]
    except ValueError:
        parser.error(f"--min-ratios must be a comma list of numbers, got {args.min_ratios!r}")
    if any(not 0.0 <= r <= 1.0 for r in args.min_ratios):
        parser.error(f"--min-ratios must lie in [0, 1], got {args.min_ratios}")
    if args.normalisation is None:
        from seggrasp.fusion import SHIPPED_NORMALISATION

        args.normalisation = SHIPPED_NORMALISATION

    wanted = [w.strip() for w in args.meshes.split(",") if w.strip()]
    items: list[LabelledMesh] = []
    needs_twin = bool({"twin", "big", "perceived"} & set(wanted)) or any("_" in w for w in wanted)
    twin = twin_meshes(args.twin_dir) if needs_twin else []
    if "twin" in wanted:
        items += twin
    if "primitives" in wanted:
        items += primitive_meshes()
    if "multipart" in wanted:
        items += multipart_meshes()
    if "ycb" in wanted:
        try:
            items += ycb_meshes()
        except FileNotFoundError as exc:
            parser.error(str(exc))
    if "perceived" in wanted:
        source = next((t for t in twin if t.name == args.perceived_from), None)
        if source is None:
            parser.error(f"--perceived-from {args.perceived_from!r} is not among the twin's objects")
        items.append(perceived(source))
    if "big" in wanted:
        if not twin:
            parser.error("--meshes big needs the twin's objects")
        source = next((t for t in twin if t.name == args.big_from), None)
        if source is None:
            parser.error(f"--big-from {args.big_from!r} is not among the twin's objects {[t.name for t in twin]}")
        items += [subdivided(source, int(n)) for n in args.big_faces.split(",")]
    named = [w for w in wanted if w not in ("twin", "primitives", "multipart", "ycb", "big", "perceived")]
    pool = {i.name: i for i in twin + primitive_meshes()}
    if any(name not in pool for name in named):  # one of the YCB scans by its name (e.g. 048_hammer)?
        try:
            pool.update({i.name: i for i in ycb_meshes()})
        except FileNotFoundError:
            pass
    for name in named:
        if name not in pool:
            parser.error(f"unknown mesh {name!r}; known: {sorted(pool)}")
        items.append(pool[name])
    if not items:
        parser.error("no meshes selected")

    if args.normalisations:
        normalisation_study(items, args)
        return 0
    if args.quality:
        quality(items, args)
        return 0

    modes = ["fast"] + ([args.compare] if args.compare else [])
    if args.rescore:
        rescore(items, args.rescore_modes.split(",") if args.rescore_modes else modes, args)
        return 0
    records = []
    if args.resume and args.out.is_file():
        records = [json.loads(line) for line in args.out.read_text().splitlines() if line.strip()]
        hashes = {i.name: mesh_hash(i.mesh) for i in items}
        records = [r for r in records if hashes.get(r["mesh"]) == r.get("mesh_hash") and r["mode"] in modes]
    done = {(r["mesh"], r["mode"]) for r in records}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    to_run = [args.run_only] if args.run_only else modes
    for item in items:
        for record in run_mesh(item, to_run, args, done):
            records.append(record)
            with args.out.open("a") as handle:  # one complete line per record; a resumed run skips it
                handle.write(json.dumps(record) + "\n")
            print(f"{record['mesh']} [{record['mode']}]: decomposition {record['times']['decompose']:.1f} s, "
                  f"mIoU coarse {record['miou']['none']:.3f} full {record['miou']['full']:.3f}", flush=True)
    print_table(records, modes)
    print(f"\nrecords: {args.out}")
    if args.cold_results is not None:
        atomic_write_text(args.cold_results, cold_report(records, "python bench/bench_seg.py " + " ".join(
            sys.argv[1:] if argv is None else argv)))
        print(f"written: {args.cold_results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
