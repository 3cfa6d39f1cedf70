"""Replay the executed grasps of an evaluation run in the twin under other solver iterations and grip forces.

    python bench/bench_replay.py --run DIR --objects kettle_gooseneck,frying_pan_crepe --prompt handle \
        --settings 100:100,300:100,100:235 [--seed 0] [--limit 8] [--out docs/results/replay.md] [--contacts DIR]

Each grasp is re-executed in its recorded scene (`scene_seed`) with the recorded pose and width; a setting is
`ITERATIONS:FORCE` (solver iterations for the whole trial, grip force in N). The table counts the trials that
lifted and names the failures of the others, so that what a converged solve holds can be told from what the
twin's default settings drop. The lines printed are also written to `--out` (atomically). With `--contacts DIR`,
each replayed trial also writes what the fingertips pressed on at each stage (`sim.recording.ContactLog`: points,
normals against the closing axis, forces, the object's height) to DIR/OBJECT-PROMPT-seedS-rankR-ITERATIONSxFORCE.md.
"""

from __future__ import annotations

import argparse
import collections
import logging
import time
from pathlib import Path

import numpy as np

from seggrasp.io import atomic_write_text
from seggrasp.objects import load_asset_set
from sim.cell import SimCell
from sim.evaluate.records import JsonLines, robot_of, seed_of
from sim.gripper import GripperSettings
from sim.world import PhysicsSettings


def parse_setting(text: str) -> tuple[int, float]:
    """'ITERATIONS:FORCE' -> (iterations, force in N)."""
    try:
        iterations, force = text.split(":")
        return int(iterations), float(force)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a setting is ITERATIONS:FORCE (e.g. 300:100), got {text!r}") from None


def recorded_grasps(run: Path, object_id: str, prompt: str, seed: int, limit: int) -> list[dict]:
    """The first `limit` executed trials of `object_id` / `prompt` at `seed` in a run's trials.jsonl."""
    rows = [r for r in JsonLines(run / "trials.jsonl").read()
            if (r["object_id"], r["prompt"], seed_of(r)) == (object_id, prompt, seed) and r["executed"]]
    return sorted(rows, key=lambda r: (r["method"], r["rank"]))[:limit]


def contact_log_name(row: dict, iterations: int, force: float) -> str:
    """The file name of a replayed trial's contact log (module doc)."""
    return f"{row['object_id']}-{row['prompt']}-seed{seed_of(row)}-rank{row['rank']}-{iterations}x{force:g}.md"


def replay(model, rows: list[dict], iterations: int, force: float, contacts: Path | None = None
           ) -> tuple[collections.Counter, float, float]:
    """Outcomes (failure name, "lifted" for success) of the recorded grasps, each on its trial's robot system, the
    median wall time of a trial and the median squeeze the pads delivered at the end of the hold (half the summed
    normal force of both pads, N; NaN if no grasp was held); with `contacts`, a contact log of each trial is written
    there (module doc)."""
    outcomes, times, squeezes = collections.Counter(), [], []
    physics = PhysicsSettings(solver_iterations=iterations, light_object_iterations=None)
    for robot in dict.fromkeys(map(robot_of, rows)):  # each trial on the robot system it ran on
        with SimCell([model], embodiment="arm", robot=robot, seed=0, image_size=(64, 48), physics=physics,
                     gripper=GripperSettings(force)) as cell:
            for row in (r for r in rows if robot_of(r) == robot):
                cell.reset(seed=row["scene_seed"], object_id=model.object_id)
                if contacts is not None:
                    cell.log_contacts_next(contacts / contact_log_name(row, iterations, force))
                start = time.perf_counter()
                outcome = cell.execute(np.array(row["T_world_grasp"]), row["width"])
                times.append(time.perf_counter() - start)
                outcomes[outcome.failure or "lifted"] += 1
                if outcome.contact_force > 0:
                    squeezes.append(0.5 * outcome.contact_force)
    return outcomes, float(np.median(times)), float(np.median(squeezes)) if squeezes else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, required=True, help="an evaluation output folder (trials.jsonl)")
    parser.add_argument("--objects", required=True, help="comma-separated twin object ids")
    parser.add_argument("--prompt", required=True, help="the part name whose grasps are replayed")
    parser.add_argument("--settings", required=True, type=lambda s: [parse_setting(t) for t in s.split(",")],
                        help="comma-separated ITERATIONS:FORCE")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--limit", type=int, default=8, help="grasps per object")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--contacts", type=Path, default=None, metavar="DIR",
                        help="write a contact log of every replayed trial into this folder")
    args = parser.parse_args()
    if not (args.run / "trials.jsonl").is_file():
        parser.error(f"--run {args.run}: no trials.jsonl there")
    models = {o.object_id: o for o in load_asset_set()}
    unknown = [o for o in args.objects.split(",") if o not in models]
    if unknown:
        parser.error(f"unknown object id(s) {unknown}")
    if args.contacts is not None:
        args.contacts.mkdir(parents=True, exist_ok=True)
    logging.basicConfig(level=logging.WARNING)
    lines = ["| object | grasps | iterations | force (N) | squeeze delivered (N, median) | lifted | failures "
             "| trial (s, median) |", "|---|---|---|---|---|---|---|---|"]
    print("\n".join(lines), flush=True)
    for object_id in args.objects.split(","):
        rows = recorded_grasps(args.run, object_id, args.prompt, args.seed, args.limit)
        if not rows:
            parser.error(f"no executed {object_id} / {args.prompt} trial at seed {args.seed} in {args.run}")
        for iterations, force in args.settings:
            outcomes, trial_s, squeeze = replay(models[object_id], rows, iterations, force, args.contacts)
            failures = ", ".join(f"{name} {n}" for name, n in sorted(outcomes.items()) if name != "lifted") or "-"
            lines.append(f"| {object_id} | {len(rows)} | {iterations} | {force:g} | {squeeze:.0f} "
                         f"| {outcomes['lifted']} | {failures} | {trial_s:.2f} |")
            print(lines[-1], flush=True)
    if args.out is not None:
        command = (f"python bench/bench_replay.py --run {args.run} --objects {args.objects} --prompt {args.prompt} "
                   f"--settings {','.join(f'{i}:{f:g}' for i, f in args.settings)} --seed {args.seed} "
                   f"--limit {args.limit}")
        atomic_write_text(args.out, f"# bench_replay\n\n```\n$ {command}\n```\n\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
