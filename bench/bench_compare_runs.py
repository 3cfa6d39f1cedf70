"""Methods in two runs (before and after a change): Part Sel. and Suc. over all slots per seed and per category,
failures by name, and the paired difference per request with its standard error over requests and over objects.

    python bench/bench_compare_runs.py --before /tmp/lead/s6 --after /tmp/lead/p1/s7 --methods oracle,seggrasp \
        --label "fingertip pinches" --out docs/results/twin-physics-pinch-seeds0-4.md

Reads the runs' `trials.jsonl` (`python -m sim.evaluate` output folders; each side may be several runs, e.g. one per
robot system); runs on several robot systems (`--robots`) are compared per system both sides ran, one section per
method and system. A request is one (seed, object, prompt); its Part Sel. and Suc. are the shares of its top-k
slots (a slot without a grasp is a miss). Where a run judged requests infeasible, Suc. over the slots of those it
judged feasible follows, with the requests whose judgement changed. The paired difference
is taken over the requests both runs have; its standard error is given over requests and with the objects as
clusters (a request's slots and an object's prompts share its shape, so the clustered one is the honest one).
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_lab import command_line, publish  # noqa: E402
from bench.bench_selection import per_request, read_trials  # noqa: E402
from sim.evaluate.records import robot_of, seed_of  # noqa: E402

COLUMNS = {"Part Sel. (all slots)": 0, "Suc. (all slots)": 1, "top-1 Suc.": 3}


def clustered_standard_error(d: np.ndarray, clusters: list[str]) -> float:
    """Standard error of the mean of `d` with the observations grouped in `clusters` (sum of each cluster's
    residuals, squared, summed: the cluster-robust variance of a mean)."""
    residual = defaultdict(float)
    for value, cluster in zip(d - d.mean(), clusters):
        residual[cluster] += value
    return float(np.sqrt(sum(r * r for r in residual.values())) / len(d))


def compare(before: list[dict], after: list[dict], method: str, robot: str | None = None) -> list[str]:
    """Markdown lines comparing `method` in the two runs' trial records (those of robot system `robot` if given)."""
    if robot is not None:
        before = [r for r in before if robot_of(r) == robot]
        after = [r for r in after if robot_of(r) == robot]
    a, b = per_request(after).get(method, {}), per_request(before).get(method, {})
    keys = sorted(set(a) & set(b))
    if not keys:
        on = f" on {robot}" if robot is not None else ""
        raise ValueError(f"the two runs share no request of method {method!r}{on}")
    category = {r["object_id"]: r["category"] for r in after + before}
    seeds = sorted({k[0] for k in keys})
    lines = [f"Requests compared: {len(keys)} (seeds {', '.join(map(str, seeds))}, "
             f"{len({k[1] for k in keys})} objects).", "",
             "| metric | before | after | after − before ± SE over requests / over objects | per seed (after − before) |",
             "|---|---|---|---|---|"]
    for name, column in COLUMNS.items():
        d = np.array([a[k][column] - b[k][column] for k in keys])
        se_requests = float(d.std(ddof=1) / np.sqrt(len(d))) if len(d) > 1 else float("nan")
        se_objects = clustered_standard_error(d, [k[1] for k in keys])
        per_seed = " / ".join(f"{np.mean([x for x, k in zip(d, keys) if k[0] == s]):+.3f}" for s in seeds)
        before_mean = np.mean([b[k][column] for k in keys])
        after_mean = np.mean([a[k][column] for k in keys])
        lines.append(f"| {name} | {before_mean:.3f} | {after_mean:.3f} | {d.mean():+.3f} ± {se_requests:.3f} / "
                     f"{se_objects:.3f} | {per_seed} |")
    lines += ["", "Part Sel. / Suc. over all slots per category, before → after:", "",
              "| category | requests | Part Sel. | Suc. |", "|---|---|---|---|"]
    for cat in sorted({category[k[1]] for k in keys}):
        mine = [k for k in keys if category[k[1]] == cat]
        cells = [f"{np.mean([b[k][c] for k in mine]):.2f} → {np.mean([a[k][c] for k in mine]):.2f}" for c in (0, 1)]
        lines.append(f"| {cat} | {len(mine)} | {' | '.join(cells)} |")
    shared = set(keys)

    def failures(records: list[dict]) -> Counter:
        return Counter(r.get("failure") or "other" for r in records if r["method"] == method and not r["success"]
                       and (seed_of(r), r["object_id"], r["prompt"]) in shared)

    fb, fa = failures(before), failures(after)
    lines += ["", "Failed slots by name, before → after: "
              + ", ".join(f"{name} {fb[name]} → {fa[name]}" for name in sorted(set(fb) | set(fa))) + "."]
    return lines + feasible_lines(before, after, method, shared)


def feasible_lines(before: list[dict], after: list[dict], method: str, shared: set[tuple]) -> list[str]:
    """Markdown lines on the requests (of `shared`) each run judged feasible: Suc. over their slots per run (the
    oracle's is the twin's fidelity measure), and the requests whose judgement changed."""
    judged = []
    for records in (before, after):
        mine = [r for r in records if r["method"] == method and (seed_of(r), r["object_id"], r["prompt"]) in shared]
        slots = [r for r in mine if not r.get("infeasible")]
        infeasible = {(r["object_id"], r["prompt"], seed_of(r)) for r in mine if r.get("infeasible")}
        judged.append((slots, infeasible))
    if not any(infeasible for _, infeasible in judged):
        return []
    lifted = [sum(r["success"] for r in slots) for slots, _ in judged]
    cells = [f"{n}/{len(slots)} = {n / len(slots):.3f}" if slots else "-" for n, (slots, _) in zip(lifted, judged)]
    lines = ["", f"Suc. over the slots of the requests each run judged feasible: before {cells[0]}, after {cells[1]}; "
             f"requests judged infeasible {len(judged[0][1])} → {len(judged[1][1])}."]
    (_, was), (_, now) = judged
    for name, changed in (("Newly infeasible", now - was), ("Newly feasible", was - now)):
        if changed:
            seeds = defaultdict(list)
            for obj, prompt, seed in sorted(changed):
                seeds[(obj, prompt)].append(str(seed))
            lines.append(f"{name}: " + ", ".join(f"{obj} {prompt} (seeds {','.join(s)})"
                                                  for (obj, prompt), s in seeds.items()) + ".")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", type=Path, nargs="+", required=True,
                        help="sim.evaluate output folder(s) before the change (several: e.g. one per robot system)")
    parser.add_argument("--after", type=Path, nargs="+", required=True, help="the same after the change")
    parser.add_argument("--methods", default="oracle", help="comma-separated; one section each")
    parser.add_argument("--label", default="the change", help="what changed, for the page's title")
    parser.add_argument("--out", type=Path, help="write the markdown here (atomically); default: print it")
    args = parser.parse_args(argv)
    try:
        before, after = ([r for run in runs for r in read_trials(run)] for runs in (args.before, args.after))
        systems = [{robot_of(r) for r in records} for records in (before, after)]
        robots = sorted(set.intersection(*systems))
        if not robots:
            raise ValueError("the two runs share no robot system")
        named = len(set.union(*systems)) > 1  # a system only one side ran is left out, and the sections say so
        sections = [(method, robot) for method in args.methods.split(",") for robot in robots]
        lines = [line for method, robot in sections
                 for line in (f"## `{method}`" + (f" on {robot}" if named else ""), "",
                              *compare(before, after, method, robot), "")]
    except (FileNotFoundError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    command = command_line("bench_compare_runs.py", argv)
    page = "\n".join([f"# Before and after {args.label}", "", f"Written by `{command}`.",
                      f"Before: {', '.join(f'`{f}`' for f in args.before)}; after: "
                      f"{', '.join(f'`{f}`' for f in args.after)}.", "", *lines])
    publish(page, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
