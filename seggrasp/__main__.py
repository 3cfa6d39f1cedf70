"""Command line: `python -m seggrasp segment MESH --prompt handle --prompt body --out DIR`.

Writes DIR/labels.json (parts = the prompts; one label per face of MESH in file order, -1 = unknown),
DIR/scores.npy (faces x prompts, same order), DIR/segmented.ply (the repaired mesh coloured by label),
DIR/labels.png (a picture of it), DIR/views.png (the rendered views with the detector's boxes),
DIR/partitions.png (the decompositions, when refinement ran) and DIR/summary.json (detector, settings, timings
and, with --labels, the IoUs). Bad input (including an --out that cannot be written, checked before any work) and
absurd work sizes: a message on stderr and exit code 2. Progress goes to stderr (-q: warnings only). SIGTERM and
SIGINT stop the run and its CoACD processes (exit 143 / 130).
"""

from __future__ import annotations

import argparse
import errno
import logging
import os
import signal
import sys
import tempfile
from pathlib import Path

import numpy as np

from seggrasp.arguments import bounded_int
from seggrasp.decompose import MAX_COACD_FACES, RUN_TIMEOUT_S, SweepTimeout
from seggrasp.decompose.config import MAX_SEED
from seggrasp.detect import check_weights, make_detector
from seggrasp.fusion import REFINE_MODES
from seggrasp.io import atomic_save_npy, atomic_write_json
from seggrasp.labels import PartLabels, find_prompt, read_labels, write_labels
from seggrasp.mesh import PreparedMesh, load_mesh
from seggrasp.render import MAX_IMAGE_SIZE, MAX_RIG_PIXELS, MAX_VIEWS, MIN_IMAGE_SIZE, check_rig
from seggrasp.truth import REAL_DETECTORS, SIMULATED_PRESETS, parse_detector

EXIT_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
#: Largest input mesh `segment` takes (faces): rendering and fusion stay within a few GB and about a minute.
MAX_SEGMENT_FACES = 5_000_000


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m seggrasp", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    seg = commands.add_parser("segment", help="segment a mesh into prompted parts",
                              description="Segment MESH into the prompted parts (render, detect, vote, refine).")
    seg.add_argument("mesh", type=Path, metavar="MESH", help="mesh file in metres (OBJ, PLY, OFF, STL, GLB)")
    seg.add_argument("--prompt", action="append", required=True, dest="prompts", metavar="PART",
                     help="part name; repeat for every part (label k = k-th prompt)")
    seg.add_argument("--detector", default="typical",
                     help=f"box detector: a simulated preset ({'|'.join(SIMULATED_PRESETS)}, also spelled "
                          f"simulated:PRESET; needs --labels) or {'|'.join(REAL_DETECTORS)} with --weights "
                          "(default: typical)")
    seg.add_argument("--weights", help="weights of grounding-dino/owlv2: a local folder, or a hub id (transformers "
                                       "downloads it into the hub cache; without a download, HF_HUB_OFFLINE set or no "
                                       "network, only a hub id already in the cache is taken, others are refused at once)")
    seg.add_argument("--labels", type=Path, metavar="GT.json",
                     help="ground-truth part labels of MESH (JSON or NPZ); needed by the simulated detector, and "
                          "when given the per-part IoU and mIoU are printed")
    seg.add_argument("--views", type=int, default=10,
                     help=f"number of rendered views, 1..{MAX_VIEWS} (default 10)")
    seg.add_argument("--image-size", type=int, default=512,
                     help=f"rendered image size in pixels, {MIN_IMAGE_SIZE}..{MAX_IMAGE_SIZE} (default 512); views x "
                          f"size^2 at most {MAX_RIG_PIXELS // 2**20} Mpx")
    seg.add_argument("--refine", choices=REFINE_MODES, default="full",
                     help="refinement after voting (default full GeoFusion; none = coarse votes only)")
    seg.add_argument("--no-anchor", dest="anchor", action="store_false",
                     help="no prompt anchoring after refinement (the paper's GeoFusion labels; by default every "
                          "prompt gets its own convex part, see seggrasp/fusion.py)")
    seg.add_argument("--decomposition", choices=("fast", "reference"), default="fast",
                     help="CoACD sweep mode for refinement (default fast)")
    seg.add_argument("--cache-dir", type=Path, help="decomposition cache folder (default: the user cache)")
    seg.add_argument("--workers", type=int, help="parallel CoACD processes (default: decided by the sweep)")
    seg.add_argument("--coacd-timeout", type=float, metavar="SECONDS",
                     help=f"time budget of one CoACD run of the sweep in CPU seconds (default {RUN_TIMEOUT_S['fast']:.0f} s fast, "
                          f"{RUN_TIMEOUT_S['reference']:.0f} s reference); a run over it is dropped with a warning")
    seg.add_argument("--seed", type=bounded_int(0, MAX_SEED), default=0,
                     help=f"seed of the camera rig, detector and decomposition, 0..{MAX_SEED} (default 0). The bundled "
                          "decompositions of the twin (assets/decompositions/) are for seed 0: with another seed the "
                          "sweep runs CoACD cold (much slower; its runs are then cached in --cache-dir)")
    seg.add_argument("--out", type=Path, required=True, metavar="DIR", help="output folder")
    seg.add_argument("-q", "--quiet", action="store_true", help="no progress messages, only warnings and errors")
    seg.add_argument("-v", "--verbose", action="store_true", help="debug messages too")
    seg.epilog = (f"Limits: --views <= {MAX_VIEWS}, --image-size <= {MAX_IMAGE_SIZE}, views x size^2 <= "
                  f"{MAX_RIG_PIXELS // 2**20} Mpx; meshes up to {MAX_SEGMENT_FACES:,} faces; CoACD sees at most "
                  f"{MAX_COACD_FACES:,} faces (larger working meshes are decimated for the decomposition only).")
    return parser


def check_output_folder(out: Path, option: str = "--out") -> None:
    """ValueError unless `out` (given as `option`) is, or can be created as, a writable folder; creates nothing that
    stays."""
    try:
        if out.exists() and not out.is_dir():
            raise ValueError(f"{option} {out} exists and is not a folder")
        existing = out
        while not existing.exists():
            existing = existing.parent
        if not existing.is_dir():
            raise ValueError(f"{option} {out} cannot be created: {existing} is not a folder")
        tempfile.TemporaryDirectory(dir=existing, prefix=".seggrasp-write-test-").cleanup()
        longest = os.pathconf(existing, "PC_NAME_MAX")
        for part in out.relative_to(existing).parts:  # the folders still to be made
            if len(os.fsencode(part)) > longest:
                raise OSError(errno.ENAMETOOLONG, f"a name of {len(os.fsencode(part))} bytes, more than the "
                              f"{longest} the file system takes")
    except OSError as exc:
        raise ValueError(f"{option} {str(out)[:120]} is not writable: {exc.strerror or exc}") from exc


def _read_ground_truth(path: Path, prepared: PreparedMesh, prompts: list[str]) -> PartLabels:
    labels = read_labels(path)
    labels.check_faces(prepared.n_source_faces, what=f"mesh {prepared.source_path}")
    if not (labels.remap_to(prompts) >= 0).any():
        raise ValueError(f"no prompt {prompts} names a part of the ground truth {labels.parts} (matched by name)")
    return labels


def _face_areas_in_file_order(prepared: PreparedMesh) -> np.ndarray:
    """Area of every input face (a duplicate face has its original's); faces dropped as degenerate have none."""
    areas = prepared.to_source(np.asarray(prepared.mesh.area_faces, dtype=np.float64)).copy()
    areas[prepared.dropped_faces] = 0.0
    return areas


def run_segment(args: argparse.Namespace) -> dict:
    """Run the `segment` command; returns the summary it writes to DIR/summary.json."""
    from seggrasp.fusion import found_prompts
    from seggrasp.labels import check_prompts
    from seggrasp.segment import SegmentationConfig, segment
    from seggrasp.viz import save_coloured_mesh, save_contact_sheet, save_label_preview, save_partition_previews

    prompts = check_prompts(args.prompts)
    check_output_folder(args.out)
    if args.cache_dir is not None:
        check_output_folder(args.cache_dir, "--cache-dir")
    spec = parse_detector(args.detector, args.weights, seed=args.seed)
    check_weights(spec.name, spec.weights)  # before any work: an unreachable hub id fails in a moment
    log = logging.getLogger("seggrasp.cli")  # __name__ is "__main__" under python -m
    if args.mesh.is_file():
        log.info("loading %s (%.1f MB)", args.mesh, args.mesh.stat().st_size / 1e6)
    prepared = load_mesh(args.mesh)
    if prepared.n_source_faces > MAX_SEGMENT_FACES:
        raise ValueError(f"{args.mesh} has {prepared.n_source_faces:,} faces; segment takes at most "
                         f"{MAX_SEGMENT_FACES:,}: decimate it first")
    log.info("loaded %s: %d faces", args.mesh, prepared.n_source_faces)
    ground_truth = _read_ground_truth(args.labels, prepared, prompts) if args.labels else None
    working_truth = (
        PartLabels(ground_truth.parts, prepared.from_source(ground_truth.face_labels)) if ground_truth else None
    )
    detector = make_detector(spec.name, weights=spec.weights, gt_labels=working_truth, preset=spec.preset,
                             seed=spec.seed)
    decomposition = None
    if args.refine != "none":
        from seggrasp.decompose import DecompositionConfig

        decomposition = DecompositionConfig(mode=args.decomposition, seed=args.seed, run_timeout=args.coacd_timeout)
        if args.seed != 0:
            log.info("decomposition seed %d: the bundled twin decompositions are for seed 0, so the sweep may run "
                     "CoACD cold (cached afterwards)", args.seed)
    config = SegmentationConfig(n_views=args.views, image_size=args.image_size, refine=args.refine,
                                anchor=args.anchor, decomposition=decomposition, cache_dir=args.cache_dir,
                                workers=args.workers, seed=args.seed)
    result = segment(prepared, prompts, detector, config)

    out: Path = args.out
    out.mkdir(parents=True, exist_ok=True)
    write_labels(out / "labels.json", PartLabels(prompts, result.labels))
    atomic_save_npy(out / "scores.npy", result.scores)
    working_labels = prepared.from_source(result.labels)
    save_coloured_mesh(out / "segmented.ply", prepared.mesh, working_labels, len(prompts))
    save_label_preview(out / "labels.png", prepared.mesh, working_labels, prompts)
    save_contact_sheet(out / "views.png", result.views, result.detections, prompts,
                       title=f"{args.mesh.name}: boxes of {result.detector}")
    if result.partitions:
        save_partition_previews(prepared.mesh, result.partitions, out / "partitions.png")

    summary = {
        "mesh": str(args.mesh),
        "prompts": prompts,
        "detector": result.detector,
        "refine": result.refine,
        "anchored": result.anchored,
        "views": args.views,
        "image_size": args.image_size,
        "seed": args.seed,
        "n_faces": prepared.n_source_faces,
        "faces_per_prompt": {p: int((result.labels == k).sum()) for k, p in enumerate(prompts)},
        "unknown_faces": int((result.labels == -1).sum()),
        "not_found": [p for p, found in zip(prompts, found_prompts(result.coarse_scores)) if not found],
        "n_partitions": len(result.partitions),
        "timings_s": {stage: round(seconds, 4) for stage, seconds in result.timings.items()},
    }
    if summary["not_found"]:
        log.warning("not found (no box of the detector in any view, so no faces): %s", ", ".join(summary["not_found"]))
    if ground_truth is not None:
        summary["evaluation"] = _evaluate(result, ground_truth, prompts, _face_areas_in_file_order(prepared))
    atomic_write_json(out / "summary.json", summary)
    return summary


def _evaluate(result, ground_truth: PartLabels, prompts: list[str], face_areas: np.ndarray) -> dict:
    """Area-weighted and face-count IoU per prompt whose name is a ground-truth part and their mean (mIoU), for the
    final and coarse labels; faces labelled with a prompt that names no ground-truth part count as wrong in the IoU
    of the part they belong to and are reported as `absent_prompt_faces`."""
    from seggrasp.metrics import part_ious

    truth = ground_truth.remap_to(prompts)
    present = [find_prompt(ground_truth.parts, p) is not None for p in prompts]
    evaluation = {}
    for name, labels in (("final", result.labels), ("coarse", result.coarse_labels)):
        for weighting, areas in (("area", face_areas), ("faces", None)):
            ious = part_ious(labels, truth, len(prompts), areas)
            scored = {p: v for p, v, known in zip(prompts, ious, present) if known}
            evaluation[f"{name}_{weighting}"] = {
                "part_iou": {p: None if np.isnan(v) else round(float(v), 4) for p, v in scored.items()},
                "miou": round(float(np.nanmean(list(scored.values()))), 4),
            }
        absent = [k for k, known in enumerate(present) if not known]
        evaluation[f"{name}_absent_prompt_faces"] = int(np.isin(labels, absent).sum())
    return evaluation


def _print_summary(summary: dict, out: Path) -> None:
    timings = ", ".join(f"{stage} {seconds:.2f} s" for stage, seconds in summary["timings_s"].items())
    print(f"{summary['mesh']}: {summary['n_faces']} faces, detector {summary['detector']}, refine {summary['refine']}")
    print("  faces per prompt: " + ", ".join(f"{p} {n}" for p, n in summary["faces_per_prompt"].items())
          + f", unknown {summary['unknown_faces']}")
    print(f"  time: {timings}")
    evaluation = summary.get("evaluation")
    if evaluation:
        for key, what in (("final_area", "area-weighted"), ("final_faces", "by face count"),
                          ("coarse_area", "coarse votes only, area-weighted")):
            scores = evaluation[key]
            parts = ", ".join(f"{p} {v:.3f}" for p, v in scores["part_iou"].items() if v is not None)
            print(f"  IoU ({what}): {parts}; mIoU {scores['miou']:.3f}")
        if evaluation["final_absent_prompt_faces"]:
            print(f"  faces labelled with prompts that name no ground-truth part: "
                  f"{evaluation['final_absent_prompt_faces']}")
    if summary["not_found"]:
        print("  not found (no detector box in any view): " + ", ".join(summary["not_found"]))
    print(f"  wrote {out}/labels.json, scores.npy, segmented.ply, labels.png, views.png"
          + (", partitions.png" if summary["n_partitions"] else "") + ", summary.json")


def _stop_on_sigterm(signum: int, frame) -> None:
    raise SystemExit(128 + signum)  # unwinds like SIGINT, so the sweep kills its CoACD processes


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("seggrasp").setLevel(
        logging.DEBUG if args.verbose else logging.WARNING if args.quiet else logging.INFO)
    try:
        check_rig(args.views, args.image_size)
    except ValueError as exc:
        parser.error(str(exc).replace("n_views (the number of views)", "--views").replace("image_size", "--image-size"))
    if args.coacd_timeout is not None and not args.coacd_timeout > 0:
        parser.error("--coacd-timeout must be a positive number of seconds")
    previous = signal.signal(signal.SIGTERM, _stop_on_sigterm)
    try:
        summary = run_segment(args)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except SweepTimeout as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_FAILED
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGTERM, previous)
    _print_summary(summary, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
