"""The emulated lab cell against the twin backend: the same objects, methods and seeds, perceived from the cameras.

    python -m bench.bench_lab [--objects mug_classic,hammer_claw] [--methods seggrasp,oracle] [--top-k 3]
                              [--seeds 0] [--work results/bench-lab] [--results docs/results/lab-emulated-cell.md]
    python -m bench.bench_lab --report      # the report again from the runs in --work

The wire side runs inside `python -m sim.lab run` (the twin-driven emulator, options from hardware/cell.emulated.yaml)
with the unchanged `hardware.RealCell` through ur_rtde, pyrealsense2 and the URCap socket (`EmulatedCell`); the twin
side is `SimCell` (arm) with `--perceive`. Both run `sim.evaluate.runner.run_object`, the episode loop of
`python -m sim.evaluate`, with every cell call timed. The report gives the wall time per grasp (the execution and
the reset before it), the emulator's real-time factor, and Suc. per method over all slots on both sides with the
failures that make the difference. The lines printed are also written to `--results` (atomically).
"""

from __future__ import annotations

import argparse
import json
import logging
import shlex
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

from seggrasp.io import atomic_write_text
from seggrasp.objects import load_asset
from sim.evaluate.config import TWIN_GRIPPER, RunConfig
from sim.evaluate.runner import run_object, subject_of

CONFIG = Path(__file__).resolve().parents[1] / "hardware" / "cell.emulated.yaml"
SIDES = ("wire", "twin")


class TimedCell:
    """A cell whose reset, capture, check_reach and execute calls are timed (wall seconds per call)."""

    TIMED = ("reset", "capture", "check_reach", "execute")

    def __init__(self, cell) -> None:
        self.cell = cell
        self.seconds: dict[str, list[float]] = {name: [] for name in self.TIMED}

    def __getattr__(self, name: str):
        attribute = getattr(self.cell, name)
        if name not in self.TIMED:
            return attribute

        def timed(*args, **kwargs):
            started = time.perf_counter()
            try:
                return attribute(*args, **kwargs)
            finally:
                self.seconds[name].append(time.perf_counter() - started)

        return timed


def run_side(side: str, args: argparse.Namespace) -> dict:
    """Every (object, seed) of one side into `work/side`; the cell calls' times (and the emulator's clock)."""
    out = Path(args.work) / side
    out.mkdir(parents=True, exist_ok=True)
    seconds: dict[str, list[float]] = {name: [] for name in TimedCell.TIMED}
    started = time.perf_counter()
    cell = None
    for seed in args.seeds:
        for object_id in args.objects:
            config = RunConfig(methods=args.methods, objects=args.objects, detector=args.detector, embodiment="arm",
                               seeds=[seed], top_k=args.top_k, backend="real" if side == "wire" else "sim",
                               config=str(args.config) if side == "wire" else None, perceive=True,
                               twin_gripper="" if side == "wire" else TWIN_GRIPPER)
            model = load_asset(object_id)
            if cell is None:
                cell = TimedCell(_cell(side, args, model))
            elif side == "twin":  # the twin cell holds one object: rebuilt for the next
                _merge(seconds, cell.seconds)
                cell.close()
                cell = TimedCell(_cell(side, args, model))
            context, truth = subject_of(object_id, config, cell, model)
            run_object(cell, context, truth, config, out)
    _merge(seconds, cell.seconds)
    report = {"side": side, "seconds": seconds, "wall_s": time.perf_counter() - started, "commit": commit()}
    if side == "wire":
        from sim.lab.control import request

        report["clock"] = request("twin_state")
    cell.close()
    return report


def command_line(script: str, argv: list[str] | None) -> str:
    """How a bench script was run (`argv`, default the process's arguments), for the page it writes."""
    return shlex.join(["python", f"bench/{script}", *(argv if argv is not None else sys.argv[1:])])


def publish(page: str, out: Path | None) -> None:
    """Print a bench's page and, given `out`, write it there too (atomically)."""
    print(page)
    if out is not None:
        atomic_write_text(out, page)


def commit() -> str:
    """The checked-out commit, marked when tracked files have uncommitted changes (what a side was measured at)."""
    root = Path(__file__).resolve().parents[1]

    def git(*argv: str) -> str:
        return subprocess.run(["git", *argv], cwd=root, capture_output=True, text=True, timeout=30,
                              check=False).stdout.strip()

    return git("rev-parse", "--short", "HEAD") + (" with uncommitted changes" if git("status", "--porcelain",
                                                                                      "--untracked-files=no") else "")


def _cell(side: str, args: argparse.Namespace, model):
    if side == "wire":
        from sim.evaluate.emulated import EmulatedCell

        return EmulatedCell.from_config(args.config)
    from sim.cell import SimCell

    return SimCell(objects=[model], embodiment="arm")


def _merge(total: dict[str, list[float]], more: dict[str, list[float]]) -> None:
    for name, values in more.items():
        total[name] += values


def wire_side_in_emulator(args: argparse.Namespace, argv: list[str]) -> None:
    """The wire side, run by this script again inside a fresh emulator (it writes `work/wire.json`)."""
    from sim.evaluate.emulated import _config, serve_options

    command = [sys.executable, "-m", "sim.lab", "run", *serve_options(_config(str(args.config))),
               "--object", args.objects[0], "--", sys.executable, "-m", "bench.bench_lab", "--side", "wire", *argv]
    code = subprocess.call(command)
    if code != 0:
        raise SystemExit(f"bench_lab: the wire side exited with {code}")


def trials_of(work: Path, side: str) -> list[dict]:
    path = work / side / "trials.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def summary_lines(args: argparse.Namespace, reports: dict[str, dict]) -> list[str]:
    work = Path(args.work)
    trials = {side: trials_of(work, side) for side in SIDES}
    lines = [
        "# The emulated lab cell against the twin backend",
        "",
        f"`python -m bench.bench_lab --objects {','.join(args.objects)} --methods {','.join(args.methods)} "
        f"--top-k {args.top_k} --seeds {','.join(map(str, args.seeds))}` (detector `{args.detector}`, arm, both sides "
        "perceive the object from the cameras). Wire: `hardware.RealCell` through ur_rtde, pyrealsense2 and the URCap "
        "socket against `python -m sim.lab` driven by the twin (hardware/cell.emulated.yaml); twin: `SimCell`.",
        "",
        f"Measured at {reports['wire'].get('commit', 'an unrecorded commit')} (wire) and "
        f"{reports['twin'].get('commit', 'an unrecorded commit')} (twin); this report written at {commit()}. "
        "Times are wall-clock on the machine that ran it (here 2 cores shared with other work).",
        "",
        "## Time",
        "",
        "| | wire | twin |",
        "|---|---|---|",
    ]
    for name, label in (("execute", "execute, per grasp (s)"), ("reset", "reset, per call (s)"),
                        ("capture", "capture, per call (s)"), ("check_reach", "check_reach, per grasp checked (s)")):
        cells = []
        for side in SIDES:
            values = reports[side]["seconds"][name]
            cells.append(f"{np.mean(values):.2f} (n = {len(values)})" if values else "-")
        lines.append(f"| {label} | {cells[0]} | {cells[1]} |")
    executed = {side: sum(t["executed"] and t["reachable"] for t in trials[side]) for side in SIDES}
    per_grasp = {side: _per_grasp(reports[side]) for side in SIDES}
    lines += [f"| per executed grasp: execute + the reset before it (s) | {per_grasp['wire']:.2f} | "
              f"{per_grasp['twin']:.2f} |",
              f"| whole run (s), grasps executed | {reports['wire']['wall_s']:.0f}, {executed['wire']} | "
              f"{reports['twin']['wall_s']:.0f}, {executed['twin']} |", ""]
    clock = reports["wire"]["clock"]
    lines += [f"The emulator's clock: {clock['simulated_s']:.0f} s simulated in {clock['wall_s']:.0f} s of wall time "
              f"({clock['paused_s']:.0f} s paused while placing): real-time factor {clock['real_time_factor']:.3f} "
              f"(simulated / running wall time), headroom {clock['headroom']:.1f}x (simulated / time spent "
              f"stepping), longest physics step {clock['longest_step_ms']:.1f} ms, lag dropped "
              f"{clock['dropped_s']:.2f} s.", "", "## Suc. (all slots) and what failed", "",
              "| method | wire | twin | wire failures | twin failures |", "|---|---|---|---|---|"]
    for method in args.methods:
        row = [method]
        for side in SIDES:
            slots = [t for t in trials[side] if t["method"] == method]
            row.append(f"{np.mean([bool(t['success']) for t in slots]):.3f} ({len(slots)} slots)" if slots else "-")
        for side in SIDES:
            failures = Counter(t["failure"] or "success" for t in trials[side] if t["method"] == method)
            row.append(", ".join(f"{name} {count}" for name, count in failures.most_common()))
        lines.append("| " + " | ".join(row) + " |")
    return lines + ["", *difference_lines(trials["wire"], trials["twin"], arm_in_view(args.objects[0]))]


#: Two grasps are the same when their poses differ by at most this much (m, rad): what the perceived meshes of the
#: two sides (the same renderings, the wire's quantised to z16 depth in the recordings) let the sampler move.
SAME_POSITION, SAME_ANGLE = 0.005, 0.1


def slot_key(trial: dict) -> tuple:
    """The slot a trial fills: object, seed, method, prompt and rank (the same on both sides)."""
    return trial["object_id"], trial["seed"], trial["method"], trial["prompt"], trial["rank"]


def same_grasp(a: dict, b: dict) -> bool:
    """Whether two trials executed (or would have) the same grasp: both have one, within `SAME_POSITION` and
    `SAME_ANGLE`."""
    if a.get("T_world_grasp") is None or b.get("T_world_grasp") is None:
        return False
    Ta, Tb = np.asarray(a["T_world_grasp"]), np.asarray(b["T_world_grasp"])
    cosine = np.clip((np.trace(Ta[:3, :3].T @ Tb[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return bool(np.linalg.norm(Ta[:3, 3] - Tb[:3, 3]) <= SAME_POSITION and np.arccos(cosine) <= SAME_ANGLE)


def compare_slots(wire: list[dict], twin: list[dict]) -> Counter:
    """How the slots both sides filled compare: the same grasp with the same or another result, another grasp
    (the perceived meshes differ), a grasp on one side only; and the slots one side did not record."""
    by_key = {slot_key(t): t for t in twin}
    counts: Counter = Counter()
    for trial in wire:
        other = by_key.pop(slot_key(trial), None)
        if other is None:
            counts["recorded on the wire only"] += 1
        elif same_grasp(trial, other):
            counts["same grasp, same result" if bool(trial["success"]) == bool(other["success"])
                   else "same grasp, other result"] += 1
        elif (trial.get("T_world_grasp") is None) != (other.get("T_world_grasp") is None):
            counts["a grasp on one side only"] += 1
        else:
            counts["another grasp" if trial.get("T_world_grasp") is not None else "no grasp on either side"] += 1
    counts["recorded on the twin only"] += len(by_key)
    return +counts


def difference_lines(wire: list[dict], twin: list[dict], arm_pixels: dict[str, float]) -> list[str]:
    """The slot-by-slot comparison behind the Suc. difference, and what makes the two sides differ."""
    counts = compare_slots(wire, twin)
    lines = ["## Where the two sides differ, slot by slot", "",
             f"Slots paired by (object, seed, method, prompt, rank); a grasp is the same within "
             f"{SAME_POSITION * 1000:.0f} mm and {SAME_ANGLE:g} rad.", "", "| slots | count |", "|---|---|"]
    lines += [f"| {name} | {count} |" for name, count in counts.most_common()]
    shown = ", ".join(f"{serial} {fraction:.1%}" for serial, fraction in arm_pixels.items())
    return lines + ["", DIFFERENCES.format(arm_turn=ARM_TURN * 1000, arm_pixels=shown)]


#: How far (rad, every joint) the arm is turned from home for `arm_in_view`: the emulated motion's settling error.
ARM_TURN = 1e-3


def arm_in_view(object_id: str) -> dict[str, float]:
    """Per camera, the fraction of depth pixels that change when the twin's arm stands `ARM_TURN` off home at a
    placement (the emulator renders the arm where its servos settled it; the twin backend exactly at home)."""
    import tempfile

    from sim.lab.twin import TwinScene

    with tempfile.TemporaryDirectory() as folder:
        scene = TwinScene(object_id, 0, folder)
        try:
            at_home = dict(scene._frames)
            scene.arm._q = scene.arm._q + ARM_TURN
            scene.place(object_id, 0)
            return {serial: float(np.mean(np.abs(frame.depth - scene._frames[serial].depth) > 1e-6))
                    for serial, frame in at_home.items()}
        finally:
            scene.close()


DIFFERENCES = """Why the sides differ. Both place the object as `SimCell.reset(scene seed, object)` (the same pose)
and render the same two D435 views with the same seeded depth noise, but not the same frames reach perception:
(1) the wire's depth is re-imaged from a depth imager beside the colour camera, quantised to z16 at 1 mm and
registered by the client's `rs.align`, the twin's is the colour-registered render; (2) the arm stands in the
cameras' views at home, and the emulator renders it where the real-time joint servos settled the wire's moveJ home
(a motion ends within 1e-3 rad of its target), the twin exactly at home: with every joint {arm_turn:g} mrad off
home, this share of the depth pixels changes: {arm_pixels}. So the fused meshes differ by millimetres, and with
them the coarse parts, the detector's votes and the ranking of the sampled grasps: almost every slot executes
another grasp, and since the servos settle differently each time, two wire runs need not agree either. Suc. per slot is therefore a different draw of grasps on
the same object, not the same grasp judged twice; the counts above say how often each side's grasp failed and
how. Where the grasp is close, the execution differs too: on the wire ur_rtde's moveL/moveJ profiles are tracked
in real time by the twin's servos, the fingers close through the URCap's registers and the hold is judged by the
gripper's OBJ flag; the real cell's check before a grasp covers IK and the limits only (`models_scene` False),
while the twin's also refuses motions that would hit the object or the table."""


def _per_grasp(report: dict) -> float:
    """Mean wall time of an executed grasp with the reset that precedes it (one reset per execution)."""
    executes, resets = report["seconds"]["execute"], report["seconds"]["reset"]
    return float(np.mean(executes) + (np.mean(resets) if resets else 0.0))


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m bench.bench_lab", description=__doc__.split("\n\n")[0])
    parser.add_argument("--objects", default="mug_classic,hammer_claw")
    parser.add_argument("--methods", default="seggrasp,oracle")
    parser.add_argument("--detector", default="typical")
    parser.add_argument("--top-k", type=int, default=3)
    parser.add_argument("--seeds", default="0", help="comma-separated run seeds")
    parser.add_argument("--config", default=str(CONFIG), help="the emulated cell's cell.yaml")
    parser.add_argument("--work", default="results/bench-lab", help="folder for both sides' runs")
    parser.add_argument("--results", default="docs/results/lab-emulated-cell.md")
    parser.add_argument("--report", action="store_true", help="only write the report of the runs in --work")
    parser.add_argument("--side", choices=SIDES, help=argparse.SUPPRESS)  # the wire side, inside the emulator
    args = parser.parse_args(argv)
    args.objects, args.methods = args.objects.split(","), args.methods.split(",")
    args.seeds = [int(s) for s in args.seeds.split(",")]
    return args


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    work = Path(args.work)
    if args.side == "wire":
        atomic_write_text(work / "wire.json", json.dumps(run_side("wire", args)))
        return 0
    if not args.report:
        for side in SIDES:
            if (work / side).exists():
                raise SystemExit(f"bench_lab: {work / side} exists; remove it, give another --work or --report")
        wire_side_in_emulator(args, argv)
        atomic_write_text(work / "twin.json", json.dumps(run_side("twin", args)))
    reports = {side: json.loads((work / f"{side}.json").read_text()) for side in SIDES}
    lines = summary_lines(args, reports)
    print("\n".join(lines))
    atomic_write_text(Path(args.results), "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
