"""Benchmark of the PyBullet cell: physics steps per second, one grasp-and-lift trial (UR5 arm, floating 2F-85 and the
Franka Panda), capture.

    python bench/bench_sim.py [--trials 5] [--scene-png docs/scene.png] [--against DIR] [--out docs/results/bench-sim.md]

Trials are scripted top-down grasps on a 5 x 5 x 8 cm box (0.2 kg), each from a fresh `reset`; the wall time of a
trial covers planning (IK, table checks) and the simulated approach, close, 20 cm lift and 1 s hold. With
`--against DIR` (another checkout of this repository, e.g. `git worktree add /tmp/before <commit>`), the arm trial
is also timed in both checkouts, one trial each in turn in fresh processes, so that both see the same machine load,
and the ratio of the medians is printed. The lines printed are also written to `--out` (atomically).
"""

from __future__ import annotations

import argparse
import io
import logging
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

from seggrasp.io import atomic_write_bytes, atomic_write_text
from seggrasp.views import look_at
from sim.cameras import VirtualD435
from sim.cell import EMBODIMENTS, ROBOTS, SimCell
from sim.primitives import primitive_object, top_down_grasp
from sim.world import PhysicsSettings


def bench_embodiment(
    box, embodiment: str, trials: int, physics: PhysicsSettings | None = None, idle_and_capture: bool = True,
    robot: str = "ur5",
) -> dict[str, float]:
    with SimCell([box], embodiment=embodiment, seed=0, robot=robot, image_size=(640, 480), physics=physics) as cell:
        reset_times, trial_times, steps, lifted = [], [], [], 0
        for seed in range(trials):
            start = time.perf_counter()
            cell.reset(seed=seed)
            reset_times.append(time.perf_counter() - start)
            _, T_world_obj = cell.object_mesh()
            steps_before = cell.world.step_count
            start = time.perf_counter()
            outcome = cell.execute(top_down_grasp(T_world_obj, 0.06), 0.05)
            trial_times.append(time.perf_counter() - start)
            steps.append(cell.world.step_count - steps_before)
            lifted += int(outcome.lifted)
        if not idle_and_capture:
            return {"trial_s": float(np.median(trial_times)), "lifted": lifted}
        cell.reset(seed=0)
        n_idle = 2000
        start = time.perf_counter()
        cell.world.step(n_idle)
        idle_rate = n_idle / (time.perf_counter() - start)
        start = time.perf_counter()
        for _ in range(5):
            cell.capture()
        capture_time = (time.perf_counter() - start) / 5
    return {
        "reset_s": float(np.median(reset_times)),
        "trial_s": float(np.median(trial_times)),
        "trial_max_s": float(np.max(trial_times)),
        "steps_per_trial": float(np.median(steps)),
        "idle_steps_per_s": idle_rate,
        "capture_s": capture_time,
        "lifted": lifted,
    }


def write_scene_png(path: Path) -> None:
    """Overview of the arm scene with the twin's first mug (or a box if the twin is absent)."""
    try:
        from seggrasp.objects import load_asset_set

        objects = load_asset_set("mug") or load_asset_set()
    except (FileNotFoundError, ValueError):
        objects = []
    with tempfile.TemporaryDirectory() as tmp:
        objects = objects or [primitive_object("box", (0.05, 0.05, 0.08), tmp)]
        with SimCell(objects, embodiment="arm", seed=0) as cell:
            overview = VirtualD435("overview", look_at([1.25, -0.85, 0.75], [0.3, 0.0, 0.12]))
            images = [cell.render(overview)] + [cell.render(camera) for camera in cell.cameras]
    top = images[0]
    bottom = np.concatenate([np.asarray(Image.fromarray(im).resize((320, 240))) for im in images[1:3]], axis=1)
    buffer = io.BytesIO()
    Image.fromarray(np.concatenate([top, bottom], axis=0)).save(buffer, format="PNG")
    atomic_write_bytes(path, buffer.getvalue())


def _line(label: str, r: dict[str, float], trials: int) -> str:
    return (
        f"{label:8s} grasp-and-lift trial {r['trial_s']:.3f} s median (max {r['trial_max_s']:.3f} s, "
        f"{r['steps_per_trial']:.0f} physics steps, lifted {r['lifted']}/{trials}); "
        f"reset {r['reset_s']:.3f} s; idle physics {r['idle_steps_per_s']:.0f} steps/s; "
        f"capture 2x640x480 {r['capture_s']:.3f} s"
    )


#: One arm trial on the benchmark box in a fresh process, printed as JSON; run inside either checkout.
ONE_ARM_TRIAL = """
import json, sys, tempfile
from bench.bench_sim import bench_embodiment
from sim.primitives import primitive_object
with tempfile.TemporaryDirectory() as tmp:
    box = primitive_object("box", (0.05, 0.05, 0.08), tmp, mass=0.2)
    print(json.dumps(bench_embodiment(box, "arm", 1, idle_and_capture=False)))
"""


def arm_trial_in(checkout: Path) -> dict[str, float]:
    """{trial_s, lifted} of one arm trial run by the code of `checkout`."""
    env = dict(os.environ, PYTHONPATH=str(checkout))
    result = subprocess.run([sys.executable, "-c", ONE_ARM_TRIAL], cwd=checkout, env=env, capture_output=True,
                            text=True, check=False)
    if result.returncode:
        raise RuntimeError(f"the arm trial failed in {checkout}:\n{result.stderr[-2000:]}")
    return json.loads(result.stdout.strip().splitlines()[-1])


def compare_checkouts(other: Path, trials: int) -> list[str]:
    """Arm trials in this checkout and in `other`, alternating, one fresh process each; returns the printed lines."""
    here = Path(__file__).resolve().parents[1]
    times: dict[Path, list[float]] = {here: [], other: []}
    lifted = {here: 0, other: 0}
    for _ in range(trials):
        for checkout in (here, other):
            r = arm_trial_in(checkout)
            times[checkout].append(r["trial_s"])
            lifted[checkout] += int(r["lifted"])
    current, reference = (float(np.median(times[k])) for k in (here, other))
    return [
        f"arm trial, this checkout: {current:.3f} s median, lifted {lifted[here]}/{trials}",
        f"arm trial, {other}: {reference:.3f} s median, lifted {lifted[other]}/{trials}",
        f"ratio this / other: {current / reference:.2f}x",
    ]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--scene-png", type=Path, default=None, help="also write an overview image of the scene")
    parser.add_argument("--against", type=Path, default=None, metavar="DIR",
                        help="also time the arm trial in another checkout of this repository, side by side")
    parser.add_argument("--out", type=Path, default=Path("docs/results/bench-sim.md"), help="where to write the lines")
    args = parser.parse_args()
    if args.trials < 1:
        parser.error("--trials must be at least 1")
    if args.against is not None and not (args.against / "bench" / "bench_sim.py").is_file():
        parser.error(f"--against {args.against}: not a checkout of this repository (no bench/bench_sim.py there)")
    logging.basicConfig(level=logging.WARNING)
    lines = [f"load average before the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"]
    print(lines[0], flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        box = primitive_object("box", (0.05, 0.05, 0.08), tmp, mass=0.2)
        systems = [(embodiment, embodiment, "ur5") for embodiment in EMBODIMENTS]
        systems += [(robot, "arm", robot) for robot in ROBOTS if robot != "ur5"]
        for label, embodiment, robot in systems:
            lines.append(_line(label, bench_embodiment(box, embodiment, args.trials, robot=robot), args.trials))
            print(lines[-1], flush=True)
        if args.against is not None:
            for line in compare_checkouts(args.against.resolve(), args.trials):
                lines.append(line)
                print(line, flush=True)
    command = f"python bench/bench_sim.py --trials {args.trials}" + (f" --against {args.against}" if args.against else "")
    atomic_write_text(args.out, f"# bench_sim\n\n```\n$ {command}\n" + "\n".join(lines) + "\n```\n")
    if args.scene_png is not None:
        write_scene_png(args.scene_png)
        print(f"wrote {args.scene_png}")


if __name__ == "__main__":
    main()
