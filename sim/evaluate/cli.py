"""The command line of `python -m sim.evaluate`: options -> `RunConfig` -> run (under the folder's lock) -> report."""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path
from typing import Sequence

from seggrasp.grasp.select import TOP_K
from seggrasp.method import METHODS
from sim.evaluate.config import (
    DEFAULT_METHODS,
    QUICK_CATEGORIES,
    QUICK_METHODS,
    QUICK_TOP_K,
    REAL_DETECTORS,
    SIMULATED_PRESETS,
    RunConfig,
)
from sim.evaluate.records import OutputLock, prepare_out
from sim.evaluate.report import write_summary
from sim.evaluate.runner import evaluate_objects

LOG = logging.getLogger("sim.evaluate")
DESCRIPTION = ("`python -m sim.evaluate`: the benchmark on the bundled twin (or a real cell) — segmentation, part "
               "selection and grasp success per method, as the paper's Tables I-III.")


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m sim.evaluate", description=DESCRIPTION)
    parser.add_argument("--methods", help=f"comma-separated, from {','.join(METHODS)} (default: {','.join(DEFAULT_METHODS)})")
    parser.add_argument("--objects", help="comma-separated object ids (default: the whole twin)")
    parser.add_argument("--categories", help="comma-separated categories of the twin")
    parser.add_argument("--detector", default="typical",
                        help=f"simulated preset ({'|'.join(SIMULATED_PRESETS)}) or {'|'.join(REAL_DETECTORS)} with --weights")
    parser.add_argument("--weights", help="local weights directory (or hub id) for a real detector")
    parser.add_argument("--embodiment", choices=("arm", "floating"), default="arm")
    parser.add_argument("--workers", type=int, default=1, help="processes evaluating objects in parallel")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--top-k", type=int, default=None, help=f"grasps executed per prompt (default {TOP_K}; --quick {QUICK_TOP_K})")
    parser.add_argument("--out", default=None, help="output folder (default results/evaluate-<detector>-<embodiment>)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run recorded in --out (same settings; its methods and objects are kept)")
    parser.add_argument("--quick", action="store_true",
                        help=f"CI profile: the first object of the categories {','.join(QUICK_CATEGORIES)}, methods "
                        f"{','.join(QUICK_METHODS)}, top-{QUICK_TOP_K}, floating gripper unless --embodiment is given")
    parser.add_argument("--backend", choices=("sim", "real"), default="sim")
    parser.add_argument("--config", help="cell.yaml of the real cell (--backend real)")
    parser.add_argument("--dry-run", action="store_true", help="real backend: plan and check, never move the robot")
    parser.add_argument("--perceive", action="store_true", help="plan on a mesh fused from the cameras, not the twin's")
    parser.add_argument("--prompts", help="comma-separated part names (default: each object's own; required for real)")
    parser.add_argument("--record", type=int, default=0, metavar="N",
                        help="twin only: save a picture strip (pre-grasp, closed, lifted, held) of the first N executed "
                        "slots per method and object to OUT/strips/")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    args.embodiment_given = any(a == "--embodiment" or a.startswith("--embodiment=") for a in (argv or sys.argv[1:]))
    return args


def _split(text: str | None) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()] if text else []


def _check_choices(args: argparse.Namespace, methods: list[str]) -> None:
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {unknown}; choose from {list(METHODS)}")
    if args.detector not in SIMULATED_PRESETS + REAL_DETECTORS:
        raise ValueError(f"unknown detector {args.detector!r}; use {list(SIMULATED_PRESETS + REAL_DETECTORS)}")
    if args.detector in REAL_DETECTORS and not args.weights:
        raise ValueError(f"--detector {args.detector} needs --weights (a local weights directory or hub id)")
    if args.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {args.workers}")
    if args.record < 0:
        raise ValueError(f"--record must be at least 0, got {args.record}")
    if args.record and args.backend == "real":
        raise ValueError("--record needs the twin: the real cell cannot record picture strips (drop --record)")


def _check_real(args: argparse.Namespace, methods: list[str], prompts: list[str]) -> None:
    if not args.config:
        raise ValueError("--backend real needs --config cell.yaml")
    if args.detector in SIMULATED_PRESETS:
        raise ValueError("--backend real needs a real detector (--detector grounding-dino|owlv2 --weights DIR)")
    if not prompts or not args.objects:
        raise ValueError("--backend real needs --objects (names for the records) and --prompts")
    if "oracle" in methods:
        raise ValueError("the oracle method needs ground-truth labels, which a real object does not have")


def build_config(args: argparse.Namespace) -> RunConfig:
    """Validate the arguments into a RunConfig (ValueError naming the problem)."""
    methods = _split(args.methods) or list(QUICK_METHODS if args.quick else DEFAULT_METHODS)
    _check_choices(args, methods)
    top_k = args.top_k if args.top_k is not None else (QUICK_TOP_K if args.quick else TOP_K)
    if top_k < 1:
        raise ValueError(f"--top-k must be at least 1, got {top_k}")
    embodiment = "floating" if args.quick and not args.embodiment_given else args.embodiment
    prompts = _split(args.prompts)
    if args.backend == "real":
        _check_real(args, methods, prompts)
        objects = _split(args.objects)
    else:
        objects = _select_objects(_split(args.objects), _split(args.categories), args.quick)
    return RunConfig(
        methods=methods, objects=objects, detector=args.detector, weights=args.weights, embodiment=embodiment,
        seed=args.seed, top_k=top_k, backend=args.backend, config=args.config,
        perceive=bool(args.perceive or args.backend == "real"), dry_run=args.dry_run, quick=args.quick,
        prompts=prompts, record=args.record,
    )


def _select_objects(object_ids: list[str], categories: list[str], quick: bool) -> list[str]:
    from seggrasp.objects import asset_ids

    if quick:
        if object_ids or categories:
            raise ValueError("--quick picks its own objects; drop --objects/--categories or --quick")
        return [asset_ids([category])[0] for category in QUICK_CATEGORIES]
    known = asset_ids(categories or None)
    if not known:
        raise ValueError(f"no twin objects in categories {categories}")
    if object_ids:
        missing = [o for o in object_ids if o not in known]
        if missing:
            raise ValueError(f"unknown object id(s) {missing}; the twin has {known}")
        return object_ids
    return known


def run(config: RunConfig, out: Path, workers: int = 1, resume: bool = False) -> tuple[dict, list[dict]]:
    """Evaluate every object (in `workers` processes) holding `out`'s lock, then write the summary; returns
    (summary, crashes)."""
    from tqdm import tqdm

    if resume and not out.is_dir():
        raise ValueError(f"cannot resume {out}: no such folder")
    with OutputLock(out):
        config = prepare_out(out, config, resume)
        started = time.time()
        with tqdm(total=len(config.objects), desc="objects", unit="obj") as bar:
            crashes = evaluate_objects(config, out, workers, lambda status: _report(status, bar))
        return write_summary(config, out, time.time() - started, crashes), crashes


def _report(status: dict, bar) -> list[dict]:
    bar.update(1)
    if status["ok"]:
        bar.set_postfix_str(f"{status['object_id']}: {status['new_trials']} trials in {status['seconds']:.0f} s")
        return []
    LOG.error("object %s crashed: %s\n%s", status["object_id"], status["error"], status["traceback"])
    return [status]


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        config = build_config(args)
        out = Path(args.out or f"results/evaluate-{config.detector}-{config.embodiment}{'-quick' if config.quick else ''}")
        summary, crashes = run(config, out, workers=args.workers, resume=args.resume)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print((out / "summary.md").read_text())
    run_info = summary["run"]
    print(f"{run_info['recorded_trials']}/{run_info['expected_trials']} trials recorded in {out} "
          f"({run_info['wall_time_s']:.0f} s)")
    if crashes:
        print(f"error: {len(crashes)} object(s) crashed: {', '.join(c['object_id'] for c in crashes)}", file=sys.stderr)
        return 1
    return 0
