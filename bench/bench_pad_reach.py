"""How far into its pads an executed grasp first landed, against whether it lifted the object by the part (issue 36).

    python bench/bench_pad_reach.py --run DIR [--robots ur5,panda] [--out docs/results/pad-reach.md]

For every executed oracle trial of an evaluation run (`python -m sim.evaluate --methods oracle ...`) on a request
judged feasible, the episode is rebuilt as the run built it (`bench.bench_infeasible.episode_of`: the run's scene
seed, the robot system's hand) and the grasp is moved back into the object frame. `PadSurface.first_touch` reads,
for each pad, how far into the pad from its fingertip end its first touch reaches (0 where only the fingertip beyond
the pad lands); a grasp counts the smaller of its two pads. The page bins the trials of each robot system by that reach and gives Suc. per bin and the requests most
frequent in it. It backs each hand's `pad_end_margin` (seggrasp/hands.py): the reach from which a pad holds. A run
made after that margin took effect executes few grasps below it; measure on a run made before. The page is
rewritten by the command (atomically), with the command, the date, the commit and the run's folder.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter, defaultdict
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_infeasible import episode_of
from bench.bench_lab import command_line, commit, publish
from bench.bench_selection import read_trials
from seggrasp.grasp.types import GraspSet
from seggrasp.objects import load_asset
from sim.evaluate.records import robot_of, seed_of

#: Bin edges (mm) of the smaller pad's reach.
EDGES_MM = (0.0, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0, np.inf)
#: Requests named per bin.
NAMED = 4


def executed_trials(run: Path, robots: list[str]) -> dict[tuple[str, str], list[dict]]:
    """The run's executed oracle trials of feasible requests, per (robot, object)."""
    trials: dict[tuple[str, str], list[dict]] = defaultdict(list)
    for record in read_trials(run):
        if record.get("method") == "oracle" and record.get("executed") and not record.get("infeasible") \
                and robot_of(record) in robots:
            trials[(robot_of(record), record["object_id"])].append(record)
    return trials


def measure(robot: str, object_id: str, trials: list[dict]) -> list[tuple[float, bool, str]]:
    """(the smaller pad's reach in m, success, "object part failure") of each trial, in its rebuilt episode."""
    from sim.cell import SimCell
    from sim.evaluate.config import RunConfig
    from sim.gripper import GripperSettings

    model = load_asset(object_id)
    config = RunConfig(methods=["oracle"], objects=[object_id], embodiment="arm", seeds=[0], robots=[robot])
    measured = []
    with SimCell([model], embodiment="arm", seed=0, robot=robot,
                 gripper=GripperSettings(grip_force=config.hand_grip_force, hand=config.hand)) as cell:
        by_seed: dict[int, list[dict]] = defaultdict(list)
        for trial in trials:
            by_seed[seed_of(trial)].append(trial)
        for seed, seeded in sorted(by_seed.items()):
            episode = episode_of(cell, object_id, robot, seed, model)
            T_obj_world = np.linalg.inv(episode.observation.T_world_obj)
            poses = np.stack([T_obj_world @ np.asarray(t["T_world_grasp"]) for t in seeded])
            grasps = GraspSet(poses, [t["width"] for t in seeded], np.zeros(len(seeded)), np.zeros((len(seeded), 2, 3)))
            surface = episode.footprint.on(episode.observation.mesh)
            _, reach = surface.first_touch(grasps, np.zeros(len(episode.observation.mesh.faces), dtype=bool))
            measured += [(float(r), bool(t["success"]), f"{object_id} {t['prompt']} {t['failure'] or 'lifted'}")
                         for r, t in zip(reach.min(axis=1), seeded)]
    return measured


def table(measured: list[tuple[float, bool, str]]) -> list[str]:
    """Markdown rows: per reach bin, trials, Suc. and the most frequent requests with their outcomes."""
    rows = ["| smaller pad's reach (mm) | trials | Suc. | most frequent (object part outcome: trials) |",
            "|---|---|---|---|"]
    reach_mm = np.array([1000.0 * m[0] for m in measured])
    bins = [("0: only the fingertip beyond the pad lands", reach_mm == 0.0)]
    bins += [(f"{low:g}-{'' if np.isinf(high) else f'{high:g}'}", (reach_mm > 0.0) & (reach_mm >= low) & (reach_mm < high))
             for low, high in zip(EDGES_MM[:-1], EDGES_MM[1:])]
    for label, selected in bins:
        inside = [m for m, chosen in zip(measured, selected) if chosen]
        if not inside:
            continue
        success = sum(m[1] for m in inside)
        named = ", ".join(f"{what}: {n}" for what, n in Counter(m[2] for m in inside).most_common(NAMED))
        rows.append(f"| {label} | {len(inside)} | {success}/{len(inside)} = {success / len(inside):.2f} | {named} |")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", type=Path, required=True, help="an evaluation output folder with oracle trials")
    parser.add_argument("--robots", default="ur5,panda", help="comma-separated robot systems (default: ur5,panda)")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    robots = [r for r in args.robots.split(",") if r]
    if not (args.run / "trials.jsonl").is_file():
        print(f"bench_pad_reach: {args.run / 'trials.jsonl'} does not exist; --run takes an evaluation output "
              "folder", file=sys.stderr)
        return 2
    started = time.perf_counter()
    try:
        trials = executed_trials(args.run, robots)
    except ValueError as error:
        print(f"bench_pad_reach: {error}", file=sys.stderr)
        return 2
    lines = [
        "# How far into its pads a grasp first lands, and whether it lifts",
        "",
        f"`{command_line('bench_pad_reach.py', argv)}`",
        "",
        f"Written {datetime.now(UTC):%Y-%m-%d %H:%M} UTC at commit {commit()}, from the run {args.run}; "
        "SECONDS s.",
        "",
        "Executed oracle trials of feasible requests, binned by how far into the pad from its fingertip end the "
        "first touch of the worse of the two pads reaches (`PadSurface.first_touch`, bench/bench_pad_reach.py's "
        "docstring). Suc.: lifted by the part.",
    ]
    for robot in robots:
        measured = []
        for (system, object_id), object_trials in sorted(trials.items()):
            if system == robot:
                measured += measure(robot, object_id, object_trials)
        lines += ["", f"## {robot}", ""] + (table(measured) if measured else ["No executed oracle trial."])
    page = "\n".join(lines).replace("SECONDS", f"{time.perf_counter() - started:.0f}") + "\n"
    publish(page, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
