"""`python -m sim.evaluate.bench`: wall time of one evaluation profile under the local and Ray engines with 1 and 2
workers, measured side by side (the configurations take turns, round after round, so a drift of the machine's load
hits all of them alike); writes the table of medians, speedups and Ray's overhead, and where a Ray run's time goes
(from the time stamps the Ray engine writes to $SEGGRASP_RAY_TRACE), to a Markdown file.

Two Ray configurations: `ray` starts and stops a local instance inside the run (what `--engine ray` without
`--address` does), `ray-cluster` joins an instance started beforehand with `ray start --head --num-cpus W` (what a
run on a cluster does, with token authentication; starting and stopping that instance is not timed, and `ray stop`
ends every Ray process of the machine after each such run).

    nice python -m sim.evaluate.bench --rounds 2 --profile "--quick --seeds 0-1" --write docs/results/evaluate-scale.md

`--write` puts the profile's section into the file between markers named after the profile (replacing that
section, keeping the rest), so the sections of several profiles and the prose around them live in one file.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Sequence

from seggrasp.io import atomic_write_text
from sim.evaluate.ray_engine import TRACE_ENV

#: `ray`: the run starts and stops its own local instance; `ray-cluster`: it joins one started beforehand.
ENGINES = ("local", "ray", "ray-cluster")
CONFIGS = tuple((engine, workers) for engine in ENGINES for workers in (1, 2))
ENGINE_NAMES = {"ray": "Ray", "ray-cluster": "Ray joining a running instance"}
#: The port of the instance the `ray-cluster` configurations join (not Ray's default, to keep clear of a user's).
CLUSTER_PORT = 6391
#: Where a Ray run's wall time goes, from its trace (ray_engine.Trace) and the process's start time t0.
PHASES = (
    ("driver start-up: interpreter, imports, arguments, output folder (s)", lambda s, t, b, t0: s["engine"] - t0),
    ("ray.init: the local instance started, or the running one joined (s; the objects are packed meanwhile)",
     lambda s, t, b, t0: s["connected"] - s["engine"]),
    ("packing the run's objects, in a thread (s, overlapped)", lambda s, t, b, t0: s["packed"] - s["engine"]),
    ("objects put in the object store, once each (MB)", lambda s, t, b, t0: b / 1e6),
    ("ray.init's end to the first task's start in a worker: worker start-up, imports (s)",
     lambda s, t, b, t0: min(x["started"] for x in t) - s["connected"]),
    ("tasks in the workers (s, sum)", lambda s, t, b, t0: sum(x["finished"] - x["started"] for x in t)),
    ("hand-over: a task's end in its worker to its records written (s, mean)",
     lambda s, t, b, t0: statistics.mean(x["received"] - x["finished"] for x in t)),
    ("last task done to Ray stopped, or left when joined (s; the summary is written meanwhile)",
     lambda s, t, b, t0: s["stopped"] - s["done"] if "stopped" in s else float("nan")),
)


def _ray_cli(*arguments: str, env: dict | None = None) -> None:
    """Run the `ray` command line (of this interpreter's Ray) and raise if it fails."""
    result = subprocess.run([sys.executable, "-m", "ray.scripts.scripts", *arguments], capture_output=True, text=True,
                            env=env)
    if result.returncode != 0:
        raise RuntimeError(f"ray {' '.join(arguments)} failed ({result.returncode}): {result.stderr[-2000:]}")


def time_run(engine: str, workers: int, profile: Sequence[str], out: Path) -> tuple[float, float | None, dict]:
    """Wall seconds of one `python -m sim.evaluate` run (a fresh output folder), its CPU seconds (the process and
    the children it reaped: complete for the local engine; None for Ray, whose workers are its instance's children)
    and, for Ray, its phases (PHASES); raises if it fails. `ray-cluster` runs join an instance started (and
    stopped) around the timed run."""
    trace = out.with_suffix(".trace.json")
    env = dict(os.environ, **({TRACE_ENV: str(trace)} if engine != "local" else {}))
    command = [sys.executable, "-m", "sim.evaluate", *profile, "--engine", engine.split("-")[0], "--workers",
               str(workers), "--out", str(out)]
    if engine == "ray-cluster":  # token authentication, as a cluster of Ray >= 2.59 has (README)
        env["RAY_AUTH_MODE"] = "token"
        _ray_cli("get-auth-token", "--generate", env=env)
        _ray_cli("start", "--head", "--port", str(CLUSTER_PORT), "--num-cpus", str(workers),
                 "--include-dashboard=false", "--disable-usage-stats", env=env)
        command += ["--address", f"127.0.0.1:{CLUSTER_PORT}"]
    try:
        cpu_before = resource.getrusage(resource.RUSAGE_CHILDREN)
        started, wall_start = time.perf_counter(), time.time()
        result = subprocess.run(command, capture_output=True, text=True, env=env)
        seconds = time.perf_counter() - started
        cpu_after = resource.getrusage(resource.RUSAGE_CHILDREN)
    finally:
        if engine == "ray-cluster":
            _ray_cli("stop", env=env)
    if result.returncode != 0:
        raise RuntimeError(f"{engine} x{workers} failed ({result.returncode}): {result.stderr[-2000:]}")
    cpu = cpu_after.ru_utime + cpu_after.ru_stime - cpu_before.ru_utime - cpu_before.ru_stime
    if engine == "local":
        return seconds, cpu, {}
    recorded = json.loads(trace.read_text())
    phases = {title: phase(recorded["stamps"], recorded["tasks"], recorded["packed_bytes"], wall_start)
              for title, phase in PHASES}
    return seconds, None, phases


def measure(profile: Sequence[str], rounds: int) -> tuple[dict, list[float], dict, dict]:
    """Per configuration over `rounds` rounds (the order rotates each round): wall times, the 1-minute load
    average before each run, CPU times (local engine) and Ray's phases."""
    times: dict[tuple[str, int], list[float]] = {c: [] for c in CONFIGS}
    cpus: dict[tuple[str, int], list[float]] = {c: [] for c in CONFIGS}
    phases: dict[tuple[str, int], list[dict]] = {c: [] for c in CONFIGS}
    loads = []
    with tempfile.TemporaryDirectory(prefix="evaluate-bench-") as root:
        for r in range(rounds):
            for i in range(len(CONFIGS)):
                engine, workers = CONFIGS[(i + r) % len(CONFIGS)]
                loads.append(os.getloadavg()[0])
                seconds, cpu, phase = time_run(engine, workers, profile, Path(root) / f"{engine}-{workers}-{r}")
                times[(engine, workers)].append(seconds)
                if cpu is not None:
                    cpus[(engine, workers)].append(cpu)
                if phase:
                    phases[(engine, workers)].append(phase)
                print(f"round {r}: {engine} x{workers}: {seconds:.1f} s", flush=True)
    return times, loads, cpus, phases


def report(times: dict[tuple[str, int], list[float]], loads: list[float], command: str, cpus: dict | None = None,
           phases: dict | None = None) -> str:
    """The Markdown tables: median wall (and CPU) time per configuration, 2-over-1 speedups, Ray over local per
    worker count, and the median of each of Ray's phases."""
    median = {c: statistics.median(v) for c, v in times.items()}
    cpus, phases = cpus or {}, phases or {}
    rows = [f"| {engine} | {workers} | {median[(engine, workers)]:.1f} | "
            f"{', '.join(f'{t:.1f}' for t in times[(engine, workers)])} | "
            f"{f'{statistics.median(cpus[(engine, workers)]):.1f}' if cpus.get((engine, workers)) else '—'} |"
            for engine, workers in CONFIGS if (engine, workers) in times]
    engines = [e for e in ENGINES if (e, 1) in median and (e, 2) in median]
    lines = [
        f"Measured with `{command}` on {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}, on a 2-core machine "
        f"shared with other jobs: 1-minute load average {min(loads):.1f}-{max(loads):.1f} "
        f"(median {statistics.median(loads):.1f}) before the runs. Wall time of a whole `python -m sim.evaluate` "
        "process (`ray`: including starting and stopping the local Ray instance; `ray-cluster`: joining one started "
        "beforehand); configurations take turns.", "",
        "| engine | workers | median wall (s) | runs (s) | median CPU (s) |", "|---|---|---|---|---|", *rows, "",
        "CPU: the run's process and the processes it reaped (user + system); not measured for Ray, whose workers "
        "are its instance's children.", "",
        "| figure | value |", "|---|---|",
        *(f"| speedup of 2 workers over 1, {e} | {median[(e, 1)] / median[(e, 2)]:.2f}x |" for e in engines),
        *(f"| {ENGINE_NAMES[e]} overhead over local, {w} worker(s) | "
          f"{100 * (median[(e, w)] / median[('local', w)] - 1):+.1f} % |" for e in engines[1:] for w in (1, 2)),
    ]
    ray_configs = [c for c in CONFIGS if phases.get(c)]
    if ray_configs:
        lines += ["", "Where a Ray run's wall time goes (median over its runs; the Ray engine's time stamps):", "",
                  f"| phase | {' | '.join(f'{e} x{w}' for e, w in ray_configs)} |",
                  "|---" * (1 + len(ray_configs)) + "|",
                  *(f"| {title} | " + " | ".join(_median_cell([p[title] for p in phases[c]]) for c in ray_configs)
                    + " |" for title, _ in PHASES)]
    return "\n".join(lines) + "\n"


def _median_cell(values: list[float]) -> str:
    finite = [v for v in values if v == v]
    return f"{statistics.median(finite):.2f}" if finite else "—"


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim.evaluate.bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=2, help="runs of each configuration (default 2)")
    parser.add_argument("--profile", default="--quick", help="arguments of the measured run (default --quick)")
    parser.add_argument("--write", type=Path, help="write the profile's section into this Markdown file")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        print("error: --rounds must be at least 1", file=sys.stderr)
        return 2
    times, loads, cpus, phases = measure(args.profile.split(), args.rounds)
    arguments = argv if argv is not None else sys.argv[1:]
    command = ("nice " if os.nice(0) > 0 else "") + shlex.join(["python", "-m", "sim.evaluate.bench", *arguments])
    text = f"## Profile `{args.profile}`\n\n" + report(times, loads, command, cpus, phases)
    print(text)
    if args.write:
        write_section(args.write, args.profile, text)
    return 0


def write_section(path: Path, key: str, text: str) -> None:
    """Put `text` into the Markdown file `path` between the markers of `key`, replacing what they held (appended
    when the file has none), the rest of the file kept; written atomically."""
    begin, end = f"<!-- bench {key} -->\n", f"<!-- /bench {key} -->"
    old = path.read_text() if path.is_file() else ""
    if begin in old and end in old.split(begin, 1)[1]:
        head, rest = old.split(begin, 1)
        new = head + begin + text + end + rest.split(end, 1)[1]
    else:
        new = old + ("\n" if old and not old.endswith("\n\n") else "") + begin + text + end + "\n"
    atomic_write_text(path, new)


if __name__ == "__main__":
    sys.exit(main())
