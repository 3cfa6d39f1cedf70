"""`python -m sim.evaluate.bench`: wall time of one evaluation profile under the local and Ray engines with 1 and 2
workers, measured side by side (the configurations take turns, round after round, so a drift of the machine's load
hits all of them alike); writes the table of medians, speedups and Ray's overhead to a Markdown file.

    nice python -m sim.evaluate.bench --rounds 2 --write docs/results/evaluate-scale.md
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from seggrasp.io import atomic_write_text

CONFIGS = (("local", 1), ("local", 2), ("ray", 1), ("ray", 2))


def time_run(engine: str, workers: int, profile: Sequence[str], out: Path) -> float:
    """Wall seconds of one `python -m sim.evaluate` run (a fresh output folder); raises if it fails."""
    started = time.perf_counter()
    result = subprocess.run([sys.executable, "-m", "sim.evaluate", *profile, "--engine", engine, "--workers",
                             str(workers), "--out", str(out)], capture_output=True, text=True)
    seconds = time.perf_counter() - started
    if result.returncode != 0:
        raise RuntimeError(f"{engine} x{workers} failed ({result.returncode}): {result.stderr[-2000:]}")
    return seconds


def measure(profile: Sequence[str], rounds: int) -> tuple[dict[tuple[str, int], list[float]], list[float]]:
    """Wall times per configuration over `rounds` rounds (the order rotates each round), and the 1-minute load
    average before each run."""
    times: dict[tuple[str, int], list[float]] = {c: [] for c in CONFIGS}
    loads = []
    with tempfile.TemporaryDirectory(prefix="evaluate-bench-") as root:
        for r in range(rounds):
            for i in range(len(CONFIGS)):
                engine, workers = CONFIGS[(i + r) % len(CONFIGS)]
                loads.append(os.getloadavg()[0])
                seconds = time_run(engine, workers, profile, Path(root) / f"{engine}-{workers}-{r}")
                times[(engine, workers)].append(seconds)
                print(f"round {r}: {engine} x{workers}: {seconds:.1f} s", flush=True)
    return times, loads


def report(times: dict[tuple[str, int], list[float]], loads: list[float], command: str) -> str:
    """The Markdown table: median wall time per configuration, 2-over-1 speedups, Ray over local per worker count."""
    median = {c: statistics.median(v) for c, v in times.items()}
    rows = [f"| {engine} | {workers} | {median[(engine, workers)]:.1f} | "
            f"{', '.join(f'{t:.1f}' for t in times[(engine, workers)])} |" for engine, workers in CONFIGS]
    lines = [
        "# Evaluation engines: local processes vs Ray", "",
        f"Measured with `{command}` on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, on a 2-core machine "
        f"shared with other jobs: 1-minute load average {min(loads):.1f}-{max(loads):.1f} "
        f"(median {statistics.median(loads):.1f}) before the runs. Wall time of a whole `python -m sim.evaluate` "
        "process (Ray: including starting and stopping the local Ray instance); configurations take turns.", "",
        "| engine | workers | median wall (s) | runs (s) |", "|---|---|---|---|", *rows, "",
        "| figure | value |", "|---|---|",
        *(f"| speedup of 2 workers over 1, {e} | {median[(e, 1)] / median[(e, 2)]:.2f}x |" for e in ("local", "ray")),
        *(f"| Ray overhead over local, {w} worker(s) | {100 * (median[('ray', w)] / median[('local', w)] - 1):+.1f} % |"
          for w in (1, 2)),
    ]
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.evaluate.bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=2, help="runs of each configuration (default 2)")
    parser.add_argument("--profile", default="--quick", help="arguments of the measured run (default --quick)")
    parser.add_argument("--write", type=Path, help="write the table to this Markdown file")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        print("error: --rounds must be at least 1", file=sys.stderr)
        return 2
    times, loads = measure(args.profile.split(), args.rounds)
    arguments = argv if argv is not None else sys.argv[1:]
    command = ("nice " if os.nice(0) > 0 else "") + " ".join(["python -m sim.evaluate.bench", *arguments])
    text = report(times, loads, command)
    print(text)
    if args.write:
        atomic_write_text(args.write, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
