"""The command line of `python -m sim.evaluate`: options -> `RunConfig` -> run (under the folder's lock) -> report."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Sequence

from seggrasp.grasp.select import TOP_K
from seggrasp.method import METHODS
from seggrasp.truth import REAL_DETECTORS, SIMULATED_PRESETS, parse_detector
from sim.cell import EMBODIMENTS, ROBOTS
from sim.evaluate import emulated
from sim.evaluate.config import (
    DEFAULT_METHODS,
    DEFAULT_OBJECTS_PER_SCENE,
    MAX_SEEDS,
    MAX_TOP_K,
    DEFAULT_ROBOT,
    QUICK_CATEGORIES,
    QUICK_METHODS,
    QUICK_TOP_K,
    TWIN_GRIPPER,
    RunConfig,
)
from sim.evaluate.records import OutputLock, error_message, load_run, prepare_out
from sim.evaluate.report import write_summary
from sim.evaluate.runner import RunStopped, evaluate_objects
from sim.scenes import KINDS as SCENE_KINDS
from sim.scenes import N_OBJECTS as SCENE_SIZE

LOG = logging.getLogger("sim.evaluate")
DESCRIPTION = ("`python -m sim.evaluate`: the benchmark on the bundled twin (or a real cell) — segmentation, part "
               "selection and grasp success per method, as the paper's Tables I-III.")


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line; a run setting not given is None (build_config fills the default or the recorded value)."""
    parser = argparse.ArgumentParser(prog="python -m sim.evaluate", description=DESCRIPTION,
                                     epilog="With --resume, a setting not given is the recorded run's and one given "
                                     "must match it; --methods, --objects and --seeds given are added to it.")
    parser.add_argument("--methods", help=f"comma-separated, from {','.join(METHODS)} (default: "
                        f"{','.join(DEFAULT_METHODS)}; --quick {','.join(QUICK_METHODS)})")
    parser.add_argument("--objects", help="comma-separated object ids (default: the whole twin)")
    parser.add_argument("--categories", help="comma-separated categories of the twin (default: all)")
    parser.add_argument("--detector", help=f"simulated preset ({'|'.join(SIMULATED_PRESETS)}, also spelled "
                        f"simulated:PRESET) or {'|'.join(REAL_DETECTORS)} with --weights (default: typical)")
    parser.add_argument("--weights", help="local weights directory (or hub id) for a real detector (default: none)")
    parser.add_argument("--embodiment", choices=EMBODIMENTS,
                        help="twin only: arm, the UR5 carries the 2F-85 (reach and collisions checked), or floating, "
                        "the 2F-85 alone is placed at each grasp (default: arm; --quick: floating)")
    parser.add_argument("--robots", help=f"twin only: comma-separated robot systems, from {','.join(ROBOTS)} (ur5: the "
                        "UR5 with the Robotiq 2F-85; panda: the Franka Panda with the Franka Hand); every method runs "
                        f"on each and the report gives each one's tables and their average (default: {DEFAULT_ROBOT})")
    parser.add_argument("--workers", type=int, default=1,
                        help="(object, seed) tasks run in parallel (local processes, or a local Ray instance's CPUs; "
                        "default: 1)")
    parser.add_argument("--seed", type=int, default=None, help="the run seed (default: 0); --seeds for several")
    parser.add_argument("--seeds", help=f"several run seeds, e.g. 0-4 or 0,3,7 (at most {MAX_SEEDS}): each redraws "
                        "the detector's errors, the scene poses and the grasps; the report gives 95%% intervals over "
                        "objects and seeds")
    parser.add_argument("--engine", choices=("local", "ray"), default="local",
                        help="local processes or Ray tasks (a local Ray instance, or --address; default: local)")
    parser.add_argument("--address", help="--engine ray: join the Ray cluster at this address (e.g. auto, "
                        "HEAD:6379; default: start a local instance)")
    parser.add_argument("--top-k", type=int, default=None,
                        help=f"grasps executed per prompt, 1-{MAX_TOP_K} (default: {TOP_K}; --quick {QUICK_TOP_K})")
    parser.add_argument("--out", default=None,
                        help="output folder (default: results/evaluate-<detector>-<embodiment>, -quick added for "
                        "--quick)")
    parser.add_argument("--resume", action="store_true",
                        help="continue the run recorded in --out: its methods, objects, seeds and settings are kept")
    parser.add_argument("--quick", action="store_true", default=None,
                        help=f"CI profile: the first object of the categories {','.join(QUICK_CATEGORIES)}, methods "
                        f"{','.join(QUICK_METHODS)}, top-{QUICK_TOP_K}, floating gripper unless --embodiment is given")
    parser.add_argument("--backend", choices=("sim", "real"),
                        help="sim, the PyBullet twin, or real, the robot cell of --config (default: sim)")
    parser.add_argument("--config", help="cell.yaml of the real cell (--backend real; default: none)")
    parser.add_argument("--dry-run", action="store_true", default=None,
                        help="real backend: plan and check, never move the robot")
    parser.add_argument("--perceive", action="store_true", default=None,
                        help="plan on a mesh fused from the cameras, not the twin's (always on with --backend real)")
    parser.add_argument("--prompts", help="comma-separated part names (default: each object's own; required for real)")
    parser.add_argument("--record", type=int, default=0, metavar="N",
                        help="twin only: save a picture strip (pre-grasp, closed, lifted, held; captioned with the "
                        "trial's result) of the first N slots with a grasp per method and object to OUT/strips/, "
                        "slots whose outcome is reused simulated again for the strip (default: 0)")
    parser.add_argument("--grip-force", type=float, default=None, metavar="N",
                        help="twin only: the gripper's force in N, within each robot's hand's range ("
                        + "; ".join(f"{name}: {hand.grip_force_range[0]:g}-{hand.grip_force_range[1]:g}"
                                    for name, hand in ROBOTS.items())
                        + "); default: each hand's own ("
                        + ", ".join(f"{name} {hand.default_grip_force:g}" for name, hand in ROBOTS.items())
                        + "); the grasp sampler's torsion limit follows it. A real cell grips with its cell.yaml's "
                        "gripper.force")
    parser.add_argument("--scene", choices=SCENE_KINDS, default=None,
                        help="each object among other objects on the table, packed (upright, close) or pile (dropped "
                        "onto each other): the twin and the emulated cell lay out the twin's others, a real cell's "
                        "operator lays out the table (the kind is recorded); the twin's grasps must not hit them and "
                        "its trials record how far each moved; with --perceive (always on a real cell) the object is "
                        "found among them from the cameras (split into instances, the one the detector boxes for its "
                        "name; not found: every slot fails as not_found) (default: the object alone)")
    parser.add_argument("--objects-per-scene", type=int, default=None, metavar="N",
                        help=f"--scene: objects on the table, the requested one included, {SCENE_SIZE[0]}-"
                        f"{SCENE_SIZE[1]} (default: {DEFAULT_OBJECTS_PER_SCENE})")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log every step, debug messages included (default: warnings and errors only)")
    return parser.parse_args(argv)


#: The run settings an option sets (RunConfig fields; the option is the field with dashes): a resumed run keeps the
#: recorded value of each one not given and refuses one given that differs.
SETTINGS = ("detector", "weights", "embodiment", "top_k", "backend", "config", "perceive", "dry_run", "prompts",
            "grip_force", "quick", "scene", "objects_per_scene")
#: The value of each setting not given, on a fresh run (`embodiment` and `top_k`: see `_defaults`).
DEFAULTS = {"detector": "typical", "weights": None, "backend": "sim", "config": None, "perceive": False,
            "dry_run": False, "prompts": None, "grip_force": None, "quick": False, "robots": DEFAULT_ROBOT,
            "scene": None}


def _split(text: str | None) -> list[str]:
    return [t.strip() for t in text.split(",") if t.strip()] if text else []


def _unique(values: list[str], option: str) -> list[str]:
    """`values` of a comma-separated option, refused when one is given twice (a run would record it twice)."""
    repeated = sorted({v for v in values if values.count(v) > 1})
    if repeated:
        raise ValueError(f"{option} lists {', '.join(repeated)} more than once; give each once")
    return values


def parse_seeds(text: str) -> list[int]:
    """`0-4`, `0,3,7` or a mix (`0-2,9`) as a list of distinct non-negative seeds, at most `MAX_SEEDS` of them
    (ValueError naming the problem)."""
    seeds: list[int] = []
    seen: set[int] = set()
    for item in (t.strip() for t in text.split(",")):
        low, dash, high = item.partition("-")
        if not (low.isdigit() and (high.isdigit() if dash else True)) or max(len(low), len(high)) > 18:
            raise ValueError(f"--seeds {text[:60]!r}: {item[:30]!r} is not a seed or a range like 0-4 (integers "
                             "0 to 10^18)")
        first, last = int(low), int(high) if dash else int(low)
        if last < first:
            raise ValueError(f"--seeds {text[:60]!r}: the range {item} goes down; write {last}-{first}")
        if len(seeds) + last - first + 1 > MAX_SEEDS:
            raise ValueError(f"--seeds {text[:60]!r} gives more than {MAX_SEEDS} seeds, the most one run takes; "
                             "split it into several runs")
        span = range(first, last + 1)
        repeated = [s for s in span if s in seen]
        if repeated:
            raise ValueError(f"--seeds {text[:60]!r}: seed(s) {repeated[:10]} given twice")
        seen.update(span)
        seeds += span
    return seeds


def _seeds(args: argparse.Namespace) -> list[int] | None:
    """The seeds given (None: neither --seed nor --seeds)."""
    if args.seeds is not None and args.seed is not None:
        raise ValueError("give either --seed S or --seeds LIST, not both")
    if args.seeds is not None:
        return parse_seeds(args.seeds)
    if args.seed is None:
        return None
    if args.seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {args.seed}")
    return [args.seed]


def _given(args: argparse.Namespace) -> dict:
    """The run settings the command line gives (SETTINGS; `prompts` as a list)."""
    given = {name: getattr(args, name) for name in SETTINGS if getattr(args, name) is not None}
    if "prompts" in given:
        given["prompts"] = _unique(_split(given["prompts"]), "--prompts")
    return given


def _defaults(args: argparse.Namespace) -> argparse.Namespace:
    """The arguments with every run setting not given at its fresh-run default."""
    filled = argparse.Namespace(**vars(args))
    for name, value in DEFAULTS.items():
        if getattr(filled, name) is None:
            setattr(filled, name, value)
    if filled.embodiment is None:
        filled.embodiment = "floating" if filled.quick else "arm"
    if filled.top_k is None:
        filled.top_k = QUICK_TOP_K if filled.quick else TOP_K
    return filled


def _check_given(args: argparse.Namespace) -> None:
    """Checks of what the command line gives, fresh run or resumed; a detector given is put in the run's spelling
    (a preset's bare name, `typical` for `simulated:typical`)."""
    if args.detector is not None:
        spec = parse_detector(args.detector, args.weights)
        args.detector = spec.preset if spec.name == "simulated" else spec.name
    if args.top_k is not None and not 1 <= args.top_k <= MAX_TOP_K:
        raise ValueError(f"--top-k must be 1-{MAX_TOP_K} (grasps executed per prompt), got {args.top_k}")
    if args.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {args.workers}")
    if args.record < 0:
        raise ValueError(f"--record must be at least 0, got {args.record}")
    if args.address and args.engine != "ray":
        raise ValueError("--address joins a Ray cluster: it needs --engine ray")
    if args.objects_per_scene is not None and not SCENE_SIZE[0] <= args.objects_per_scene <= SCENE_SIZE[1]:
        raise ValueError(f"--objects-per-scene must be {SCENE_SIZE[0]}-{SCENE_SIZE[1]} (the requested object "
                         f"included), got {args.objects_per_scene}")


def _check_choices(args: argparse.Namespace, methods: list[str]) -> None:
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {unknown}; choose from {list(METHODS)}")
    parse_detector(args.detector, args.weights)
    _check_backend(args)
    check_grip_force(args.grip_force, _robots(args.robots))


def _check_backend(args: argparse.Namespace) -> None:
    """What the real cell and the floating gripper cannot do (fresh run or resumed: `args.backend` and
    `args.embodiment` are the run's)."""
    robots = _split(args.robots) if isinstance(args.robots, str) else list(args.robots or [])
    other = [robot for robot in robots if robot != DEFAULT_ROBOT]
    if other and args.backend == "real":
        raise ValueError(f"--robots {','.join(other)}: the real cell is a UR5 with a 2F-85 (drop --robots)")
    if other and args.embodiment == "floating":
        raise ValueError(f"--robots {','.join(other)}: the floating gripper is the 2F-85 alone; the "
                         f"{', '.join(other)} runs with --embodiment arm")
    if args.record and args.backend == "real":
        raise ValueError("--record needs the twin: the real cell cannot record picture strips (drop --record)")
    if args.engine == "ray" and args.backend == "real":
        raise ValueError("--engine ray runs the twin; the real cell is one robot (drop --engine ray)")
    if args.grip_force is not None and args.backend == "real":
        raise ValueError("--grip-force sets the twin's gripper; the real cell grips with gripper.force in its cell.yaml")
    if (getattr(args, "objects_per_scene", None) is not None and args.backend == "real"
            and not emulated.declared(args.config)):
        raise ValueError("--objects-per-scene lays out the twin's table; a real cell's holds what its operator put "
                         "there (drop --objects-per-scene)")


def check_grip_force(grip_force: float | None, robots: Sequence[str]) -> None:
    """A grip force (None: each hand's default) must be within the hand's range on every robot of the run."""
    if grip_force is None:
        return
    for robot in robots:
        hand = ROBOTS[robot]
        low, high = hand.grip_force_range
        if not low <= grip_force <= high:  # also rejects nan
            raise ValueError(f"--grip-force {grip_force:g} N is outside the {robot}'s {hand.name} range "
                             f"{low:g}-{high:g} N")


def _robots(text: str) -> list[str]:
    robots = _unique(_split(text), "--robots")
    unknown = [robot for robot in robots if robot not in ROBOTS]
    if unknown or not robots:
        raise ValueError(f"unknown robot(s) {unknown or [text]}; choose from {list(ROBOTS)}")
    return robots


def _check_real(args: argparse.Namespace, methods: list[str], prompts: list[str]) -> None:
    if not args.config:
        raise ValueError("--backend real needs --config cell.yaml")
    if emulated.declared(args.config):  # the emulated cell's objects are twin objects: their truth is known
        return
    if args.detector in SIMULATED_PRESETS:
        raise ValueError("--backend real needs a real detector (--detector grounding-dino|owlv2 --weights DIR)")
    if not prompts or not args.objects:
        raise ValueError("--backend real needs --objects (names for the records) and --prompts")
    if "oracle" in methods:
        raise ValueError("the oracle method needs ground-truth labels, which a real object does not have")


def build_config(args: argparse.Namespace, recorded: RunConfig | None = None) -> RunConfig:
    """Validate the arguments into a RunConfig (ValueError naming the problem); with `recorded` (a resumed run's
    run.json), the recorded settings where none is given, the given methods, objects and seeds added to its own."""
    _check_given(args)
    if recorded is not None:
        return _resumed(args, recorded)
    seeds = _seeds(args)
    args = _defaults(args)
    methods = _unique(_split(args.methods), "--methods") or list(QUICK_METHODS if args.quick else DEFAULT_METHODS)
    _check_choices(args, methods)
    prompts = _unique(_split(args.prompts), "--prompts")
    if args.backend == "real":
        _check_real(args, methods, prompts)
    if args.backend == "real" and not emulated.declared(args.config):
        objects = _unique(_split(args.objects), "--objects")
    else:
        objects = _select_objects(_unique(_split(args.objects), "--objects"),
                                  _unique(_split(args.categories), "--categories"), args.quick)
    return RunConfig(
        methods=methods, objects=objects, detector=args.detector, weights=args.weights, embodiment=args.embodiment,
        seeds=seeds or [0], top_k=args.top_k, backend=args.backend, config=args.config,
        perceive=bool(args.perceive or args.backend == "real"), dry_run=args.dry_run, quick=args.quick,
        prompts=prompts, record=args.record, grip_force=args.grip_force,
        twin_gripper=TWIN_GRIPPER if args.backend == "sim" else "", robots=_robots(args.robots), scene=args.scene,
        objects_per_scene=_objects_per_scene(args),
    )


def _objects_per_scene(args: argparse.Namespace) -> int | None:
    """The objects on the table of a scene run (None: the object alone); refused without --scene."""
    if args.scene is None:
        if args.objects_per_scene is not None:
            raise ValueError("--objects-per-scene sets a scene's size: it needs --scene packed|pile")
        return None
    if args.backend == "real" and not emulated.declared(args.config):
        return None  # what the operator put on the table
    return DEFAULT_OBJECTS_PER_SCENE if args.objects_per_scene is None else args.objects_per_scene


def _resumed(args: argparse.Namespace, recorded: RunConfig) -> RunConfig:
    """The recorded run continued: a setting given must equal the recorded one; methods, objects, seeds given are
    added; `--record` is this invocation's."""
    for name, value in _given(args).items():
        if value != getattr(recorded, name) and not (name == "perceive" and recorded.backend == "real"):
            option = "--" + name.replace("_", "-")
            shown = "" if isinstance(value, bool) else f" {','.join(value) if isinstance(value, list) else value}"
            raise ValueError(f"cannot resume: {option}{shown} contradicts the recorded run's {name} "
                             f"{getattr(recorded, name)!r} (settings differ); drop {option} to keep the recorded "
                             "one, or start another run in another --out")
    methods = _unique(_split(args.methods), "--methods")
    unknown = [m for m in methods + recorded.methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method(s) {unknown}; choose from {list(METHODS)}")
    objects = _unique(_split(args.objects), "--objects")
    categories = _unique(_split(args.categories), "--categories")
    if recorded.backend == "sim" and (objects or categories):
        objects = _select_objects(objects, categories, quick=False)
    seeds = _seeds(args) or []
    robots = _robots(args.robots) if args.robots is not None else []
    merged = {name: getattr(recorded, name) + [v for v in given if v not in getattr(recorded, name)]
              for name, given in (("methods", methods), ("objects", objects), ("seeds", seeds), ("robots", robots))}
    if len(merged["seeds"]) > MAX_SEEDS:
        raise ValueError(f"--seeds would give the run {len(merged['seeds'])} seeds, more than {MAX_SEEDS}")
    resumed = replace(recorded, **merged, record=args.record)
    _check_backend(argparse.Namespace(record=args.record, engine=args.engine, backend=recorded.backend,
                                      grip_force=args.grip_force, robots=resumed.robots,
                                      embodiment=recorded.embodiment))
    check_grip_force(resumed.grip_force, resumed.robots)
    return resumed


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
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file, not a folder; choose another --out")
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
    if status.get("fatal"):  # the output cannot be written: the other tasks would fail the same way
        raise ValueError(status["error"])
    bar.update(1)
    if status["ok"]:
        bar.set_postfix_str(f"{status['object_id']} seed {status['seed']}: {status['new_trials']} trials in "
                            f"{status['seconds']:.0f} s")
        return []
    LOG.error("object %s (seed %s) crashed: %s\n%s", status["object_id"], status["seed"], status["error"],
              status["traceback"])
    return [status]


def out_of(args: argparse.Namespace) -> Path:
    """The output folder: --out, or the default named after the detector and embodiment given (or their defaults)."""
    if args.out:
        return Path(args.out)
    filled = _defaults(args)
    return Path(f"results/evaluate-{filled.detector}-{filled.embodiment}{'-quick' if filled.quick else ''}")


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        _check_given(args)  # the arguments' own checks first: they need no file
        _check_backend(_defaults(args))
        if args.backend == "real" and args.config:  # an emulated cell's run executes inside the emulator
            code = emulated.run_inside_emulator(args.config, _split(args.objects),
                                                sys.argv[1:] if argv is None else argv)
            if code is not None:
                return code
        out = out_of(args)
        config = build_config(args, load_run(out) if args.resume else None)
        summary, crashes = run(config, out, workers=args.workers, resume=args.resume, engine=args.engine,
                               address=args.address)
        print((out / "summary.md").read_text())
    except (RunStopped, KeyboardInterrupt) as exc:  # a signal from outside; Ctrl-C is SIGINT
        stopped = exc if isinstance(exc, RunStopped) else RunStopped("stopped by SIGINT", 128 + signal.SIGINT)
        print(f"error: {stopped}; the records written so far are kept (--resume --out {out_of(args)} continues the "
              "run)", file=sys.stderr)
        return stopped.exit_code
    except (ValueError, OSError) as exc:
        print(f"error: {error_message(exc)}", file=sys.stderr)
        return 2
    run_info = summary["run"]
    print(f"{run_info['recorded_trials']}/{run_info['expected_trials']} trials recorded in {out} "
          f"({run_info['wall_time_s']:.0f} s)")
    if crashes:
        names = ", ".join(f"{c['object_id']} (seed {c['seed']})" for c in crashes)
        print(f"error: {len(crashes)} task(s) crashed: {names}", file=sys.stderr)
        return 1
    return 0
