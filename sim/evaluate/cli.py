"""The command line of `python -m sim.evaluate`: options -> `RunConfig` -> run (under the folder's lock) -> report."""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path
from typing import Sequence

from seggrasp.cell import DEFAULT_GRIP_FORCE, GRIP_FORCE_RANGE
from seggrasp.grasp.select import TOP_K
from seggrasp.method import METHODS
from sim.evaluate.config import (
    DEFAULT_METHODS,
    QUICK_CATEGORIES,
    QUICK_METHODS,
    QUICK_TOP_K,
    REAL_DETECTORS,
    SIMULATED_PRESETS,
    TWIN_GRIPPER,
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
    parser.add_argument("--workers", type=int, default=1,
                        help="(object, seed) tasks run in parallel (local processes, or a local Ray instance's CPUs)")
    parser.add_argument("--seed", type=int, default=None, help="the run seed (default 0); --seeds for several")
    parser.add_argument("--seeds", help="several run seeds, e.g. 0-4 or 0,3,7: each redraws the detector's errors, "
                        "the scene poses and the grasps; the report gives 95%% intervals over objects and seeds")
    parser.add_argument("--engine", choices=("local", "ray"), default="local",
                        help="local processes (default) or Ray tasks (a local Ray instance, or --address)")
    parser.add_argument("--address", help="--engine ray: join the Ray cluster at this address (e.g. auto, HEAD:6379)")
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
    parser.add_argument("--grip-force", type=float, default=None, metavar="N",
                        help=f"twin only: the gripper's force in N, {GRIP_FORCE_RANGE[0]:g}-{GRIP_FORCE_RANGE[1]:g} like the "
                        f"2F-85 (default {DEFAULT_GRIP_FORCE:g}, the example cell.yaml's gripper.force); the grasp "
                        "sampler's torsion limit follows it. A real cell grips with its cell.yaml's gripper.force")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    args.embodiment_given = any(a == "--embodiment" or a.startswith("--embodiment=") for a in (argv or sys.argv[1:]))
    return args


def _split(text: str | None) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()] if text else []


def parse_seeds(text: str) -> list[int]:
    """`0-4`, `0,3,7` or a mix (`0-2,9`) as a list of distinct non-negative seeds (ValueError naming the problem)."""
    seeds: list[int] = []
    for item in (t.strip() for t in text.split(",")):
        low, dash, high = item.partition("-")
        if not (low.isdigit() and (high.isdigit() if dash else True)):
            raise ValueError(f"--seeds {text!r}: {item!r} is not a seed or a range like 0-4 (non-negative integers)")
        first, last = int(low), int(high) if dash else int(low)
        if last < first:
            raise ValueError(f"--seeds {text!r}: the range {item} goes down; write {last}-{first}")
        seeds += range(first, last + 1)
    repeated = sorted({s for s in seeds if seeds.count(s) > 1})
    if repeated:
        raise ValueError(f"--seeds {text!r}: seed(s) {repeated} given twice")
    return seeds


def _seeds(args: argparse.Namespace) -> list[int]:
    if args.seeds is not None and args.seed is not None:
        raise ValueError("give either --seed S or --seeds LIST, not both")
    if args.seeds is not None:
        return parse_seeds(args.seeds)
    seed = 0 if args.seed is None else args.seed
    if seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {seed}")
    return [seed]


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
    if args.address and args.engine != "ray":
        raise ValueError("--address joins a Ray cluster: it needs --engine ray")
    if args.engine == "ray" and args.backend == "real":
        raise ValueError("--engine ray runs the twin; the real cell is one robot (drop --engine ray)")
    _check_twin_settings(args)


def _check_twin_settings(args: argparse.Namespace) -> None:
    if args.grip_force is None:
        return
    if args.backend == "real":
        raise ValueError("--grip-force sets the twin's gripper; the real cell grips with gripper.force in its cell.yaml")
    low, high = GRIP_FORCE_RANGE
    if not low <= args.grip_force <= high:  # also rejects nan
        raise ValueError(f"--grip-force {args.grip_force:g} N is outside the 2F-85's range {low:g}-{high:g} N")


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
        seeds=_seeds(args), top_k=top_k, backend=args.backend, config=args.config,
        perceive=bool(args.perceive or args.backend == "real"), dry_run=args.dry_run, quick=args.quick,
        prompts=prompts, record=args.record,
        grip_force=DEFAULT_GRIP_FORCE if args.grip_force is None else args.grip_force,
        twin_gripper=TWIN_GRIPPER if args.backend == "sim" else "",
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


def run(config: RunConfig, out: Path, workers: int = 1, resume: bool = False, engine: str = "local",
        address: str | None = None) -> tuple[dict, list[dict]]:
    """Evaluate every (object, seed) (in `workers` processes, or on Ray) holding `out`'s lock, then write the
    summary; returns (summary, crashes)."""
    from tqdm import tqdm

    if resume and not out.is_dir():
        raise ValueError(f"cannot resume {out}: no such folder")
    with OutputLock(out):
        config = prepare_out(out, config, resume)
        started = time.time()
        with tqdm(total=len(config.objects) * len(config.seeds), desc="objects x seeds", unit="task") as bar:
            on_status = lambda status: _report(status, bar)  # noqa: E731
            if engine == "ray":
                from sim.evaluate.ray_engine import evaluate_on_ray  # lazy: ray is imported only when asked for

                crashes = evaluate_on_ray(config, out, workers, address, on_status)
            else:
                crashes = evaluate_objects(config, out, workers, on_status)
        return write_summary(config, out, time.time() - started, crashes), crashes


def _report(status: dict, bar) -> list[dict]:
    bar.update(1)
    if status["ok"]:
        bar.set_postfix_str(f"{status['object_id']} seed {status['seed']}: {status['new_trials']} trials in "
                            f"{status['seconds']:.0f} s")
        return []
    LOG.error("object %s (seed %s) crashed: %s\n%s", status["object_id"], status["seed"], status["error"],
              status["traceback"])
    return [status]


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        config = build_config(args)
        out = Path(args.out or f"results/evaluate-{config.detector}-{config.embodiment}{'-quick' if config.quick else ''}")
        summary, crashes = run(config, out, workers=args.workers, resume=args.resume, engine=args.engine,
                               address=args.address)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print((out / "summary.md").read_text())
    run_info = summary["run"]
    print(f"{run_info['recorded_trials']}/{run_info['expected_trials']} trials recorded in {out} "
          f"({run_info['wall_time_s']:.0f} s)")
    if crashes:
        names = ", ".join(f"{c['object_id']} (seed {c['seed']})" for c in crashes)
        print(f"error: {len(crashes)} task(s) crashed: {names}", file=sys.stderr)
        return 1
    return 0
