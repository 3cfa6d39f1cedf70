"""The report of a run: Tables I-III, the failures per category and the threshold curve, as summary.json and
summary.md, read back from the result files.

Per-request numbers are the headline: Part Sel. and Suc. over all top-k slots (a slot without a grasp is a miss:
a method that leaves a prompt without a grasp has failed that request), top-1 Suc. (the first slot of every
request: what a user gets from one try), and beside them the paper's executed-only Part Sel., Suc. and sigma^2.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from seggrasp.io import atomic_write_json, atomic_write_text
from seggrasp.method import RECIPES
from seggrasp.metrics import mean_over_categories, quaternion_variance
from sim.evaluate.config import RunConfig, prompts_of
from sim.evaluate.plots import write_plots
from sim.evaluate.records import RESULT_KEYS, read_unique, robot_of, writing
from sim.evaluate.stats import (
    CONFIDENCE,
    GRASP_METRICS,
    N_RESAMPLES,
    method_intervals,
    paired_differences,
    system_averages,
)

ABLATION_METHODS = ("coarse", "multi", "opt", "geofusion", "anchored", "seggrasp")
#: Paired differences the report gives (when both methods ran): SegGrasp against its coarse votes and GeoFusion.
DIFFERENCE_PAIRS = (("seggrasp", "coarse"), ("seggrasp", "geofusion"))
#: The metrics of the interval tables: (summary key, column title); per-request (all-slot) ones first.
INTERVAL_COLUMNS = (("miou", "mIoU"), ("part_selection_all_slots", "Part Sel."), ("success_all_slots", "Suc."),
                    ("success_top1", "top-1 Suc."), ("part_selection", "Part Sel. (executed)"),
                    ("success", "Suc. (executed)"), ("success_feasible", "Suc. (feasible requests)"))
UNNAMED_FAILURE = "other"


def _method_order(config_methods: Sequence[str], seen: Iterable[str]) -> list[str]:
    ordered = list(config_methods)
    return ordered + sorted(set(seen) - set(ordered))


def summarise(trials: list[dict], segmentations: list[dict], curves: list[dict], methods: Sequence[str]) -> dict:
    """Tables I-III with intervals over objects and seeds, the paired differences, the failures and the threshold
    curve as one JSON-ready dict."""
    summary: dict = {"methods": {}, "curve": _summarise_curves(curves)}
    ordered = _method_order(methods, [r["method"] for r in trials] + [r["method"] for r in segmentations])
    intervals = method_intervals(trials, segmentations, ordered)
    for method in ordered:
        segs = [r for r in segmentations if r["method"] == method]
        rows = [r for r in trials if r["method"] == method]
        entry: dict = {"n_objects": len({r["object_id"] for r in rows} | {r["object_id"] for r in segs})}
        if segs:
            entry["miou"] = mean_over_categories([(r["category"], r["miou"]) for r in segs])
            entry["miou_faces"] = mean_over_categories([(r["category"], r["miou_faces"]) for r in segs])
        if rows:
            entry.update(grasp_metrics(rows))
            categories = sorted({r["category"] for r in rows})
            entry["categories"] = {c: grasp_metrics([r for r in rows if r["category"] == c]) for c in categories}
            entry["infeasible_parts"] = infeasible_parts(rows)
        entry["detector"] = ", ".join(sorted({r["detector"] for r in rows + segs}))
        entry["seeds"] = sorted({int(r.get("seed", 0)) for r in rows + segs})
        entry["intervals"] = intervals[method]
        summary["methods"][method] = entry
    pairs = [(a, b) for a, b in DIFFERENCE_PAIRS if a in summary["methods"] and b in summary["methods"]]
    summary["differences"] = paired_differences(trials, segmentations, pairs)
    return summary


def failure_name(record: dict) -> str:
    """Why a trial failed ("" for a success); records written before trials named their failure are classified
    the same way the episode does, as far as they allow."""
    if record.get("success"):
        return ""
    if "failure" in record:
        return record["failure"] or UNNAMED_FAILURE
    if not record["executed"]:
        return "no_grasp"
    named = (record.get("outcome") or {}).get("failure", "")
    if named:
        return named
    return "wrong_part" if record.get("lifted") and record.get("touched_on_part") is False else UNNAMED_FAILURE


def grasp_metrics(rows: list[dict]) -> dict:
    """Per-request Part Sel. and Suc. over all slots, top-1 Suc., the executed-only figures (docs/design.md section 5;
    each metric's rule is stats.GRASP_METRICS, which the intervals use too), sigma^2 of the executed grasps'
    orientations per request, and the failure counts."""
    executed = [r for r in rows if r["executed"]]
    groups: dict[tuple, list[np.ndarray]] = {}
    for r in executed:
        groups.setdefault((r["object_id"], r["prompt"]), []).append(np.array(r["T_world_grasp"])[:3, :3])
    variances = [quaternion_variance(np.stack(g)) for g in groups.values() if len(g) >= 2]
    failures = Counter(failure_name(r) for r in rows if not r.get("success"))
    requests = {(r["object_id"], int(r.get("seed", 0)), r["prompt"]): r.get("infeasible") for r in rows}
    rates = {}
    for name, value in GRASP_METRICS.items():  # each a 0/1 value per counted record: its rate is the mean
        values = [v for v in map(value, rows) if v is not None]
        rates[name] = float(np.mean(values)) if values else None
    return {
        "trials": len(rows),
        "executed": len(executed),
        "reachable": int(sum(r["reachable"] for r in executed)),
        **rates,
        "sigma2": float(np.mean(variances)) if variances else None,
        "failures": dict(sorted(failures.items())),
        "requests": len(requests),
        "infeasible_requests": sum(v is True for v in requests.values()),
        "judged_requests": sum(v is not None for v in requests.values()),
        **_disturbance(executed),
        **_target_search(rows),
    }


#: An object moved at least this much (m) by a grasp of another one counts as disturbed.
DISTURBED = 0.01


def _disturbance(executed: list[dict]) -> dict:
    """In a scene of several objects, over the executed trials: the median and 90th percentile of the farthest any
    other object moved (mm; not the mean: an object knocked off the twin's table falls on for the rest of the trial,
    metres), the share of trials that moved one at least `DISTURBED` and the share that lifted one along ({} for
    objects alone)."""
    moved = [(r.get("outcome") or {}).get("disturbance") for r in executed]
    if not any(moved):
        return {}
    farthest = [max(m) if m else 0.0 for m in moved]
    lifted = [(r.get("outcome") or {}).get("lifted_along", 0) > 0 for r in executed]
    median, p90 = (1000 * float(v) for v in np.percentile(farthest, [50, 90]))
    return {"disturbance_median_mm": median, "disturbance_p90_mm": p90,
            "disturbed": float(np.mean([f >= DISTURBED for f in farthest])), "lifted_along": float(np.mean(lifted))}


def _target_search(rows: list[dict]) -> dict:
    """In a scene run that perceived, per scene kind over the requests: how many, the share whose target was found
    among the perceived instances and the mean IoU of the chosen instance against the twin's truth, over the
    requests it was found in ({} when no record searched for its target)."""
    requests: dict[tuple, dict] = {}
    for r in rows:
        if r.get("target_found") is not None:
            kind = ((r.get("extra") or {}).get("scene") or {}).get("kind", "?")
            requests.setdefault((kind, r["object_id"], int(r.get("seed", 0)), r["prompt"]), r)
    if not requests:
        return {}
    search = {}
    for kind in sorted({key[0] for key in requests}):
        found = [r["target_found"] for key, r in requests.items() if key[0] == kind]
        ious = [r["target_iou"] for key, r in requests.items() if key[0] == kind and r["target_found"]
                and r.get("target_iou") is not None]
        search[kind] = {"requests": len(found), "found": float(np.mean(found)),
                        "instance_iou": float(np.mean(ious)) if ious else None}
    return {"target_search": search}


def infeasible_parts(rows: list[dict]) -> dict:
    """{"object: part": {"requests": how many (seed) requests were judged infeasible, "reason": the first one's}}."""
    parts: dict[str, dict] = {}
    seen = set()
    for r in rows:
        request = (r["object_id"], int(r.get("seed", 0)), r["prompt"])
        if r.get("infeasible") is not True or request in seen:
            continue
        seen.add(request)
        entry = parts.setdefault(f"{r['object_id']}: {r['prompt']}", {"requests": 0, "reason": r.get("message", "")})
        entry["requests"] += 1
    return dict(sorted(parts.items()))


def _summarise_curves(curves: list[dict]) -> dict:
    """Mean mIoU over objects at every threshold any object used (each object's partition at a threshold t is its
    partition with the largest threshold <= t, since identical partitions are stored once, at their finest)."""
    if not curves:
        return {}
    grid = sorted({t for c in curves for t in c["thresholds"]})
    spread, full = [], []
    for t in grid:
        s_values, f_values = [], []
        for c in curves:
            below = [i for i, ct in enumerate(c["thresholds"]) if ct <= t + 1e-12]
            if not below:
                continue
            index = max(below, key=lambda i: c["thresholds"][i])
            s_values.append(c["spread"][index])
            f_values.append(c["full"][index])
        spread.append(float(np.mean(s_values)) if s_values else None)
        full.append(float(np.mean(f_values)) if f_values else None)
    return {"thresholds": grid, "spread": spread, "full": full, "n_objects": len(curves)}


def _fmt(value: float | None, digits: int = 3) -> str:
    return "—" if value is None else f"{value:.{digits}f}"


def _table(header: Sequence[str], rows: Iterable[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"]
    return lines + ["| " + " | ".join(row) + " |" for row in rows]


def _table_one(methods: dict) -> list[str]:
    categories = sorted({c for m in methods.values() if "miou" in m for c in m["miou"]["categories"]})
    rows = [[name, *(_fmt(m["miou"]["categories"].get(c)) for c in categories), _fmt(m["miou"]["overall"]),
             _fmt(m["miou_faces"]["overall"])] for name, m in methods.items() if "miou" in m]
    return ["## Table I — segmentation mIoU (area-weighted) per category", "",
            *_table(["method", *categories, "overall", "overall (face count)"], rows)]


def _table_two(methods: dict) -> list[str]:
    rows = []
    for name, m in methods.items():
        if "trials" not in m:
            continue
        miou = m["miou"]["overall"] if "miou" in m else None
        rows.append([name, _fmt(miou), _fmt(m["part_selection_all_slots"]), _fmt(m["success_all_slots"]),
                     _fmt(m["success_top1"]), _fmt(m["part_selection"]), _fmt(m["success"]),
                     _fmt(m["success_feasible"]), _fmt(m["sigma2"], 4), f"{m['executed']} / {m['trials']}",
                     str(m["reachable"])])
    return ["## Table II — grasping", "",
            "Per request first: Part Sel. and Suc. over all top-k slots (a slot without a grasp is a miss) and top-1 "
            "Suc. (the first slot of every request); then Part Sel., Suc. and σ² over the executed grasps only "
            "(the paper's definition); Suc. over the requests the hand can hold (those judged feasible before the "
            "robot moved).", "",
            *_table(["method", "mIoU", "Part Sel.", "Suc.", "top-1 Suc.", "Part Sel. (executed)", "Suc. (executed)",
                     "Suc. (feasible)", "σ² (executed)", "executed / slots", "reachable"], rows)]


def _table_three(methods: dict) -> list[str]:
    ablation = [a for a in ABLATION_METHODS if a in methods]
    if len(ablation) < 2:
        return []
    rows = []
    for name in ablation:
        m, recipe = methods[name], RECIPES[name]
        ticks = ["✓" if step else "" for step in (recipe.multi_fusion, recipe.fine_grained, recipe.anchor,
                                                     recipe.on_agreement)]
        miou = m["miou"]["overall"] if "miou" in m else None
        rows.append([name, *ticks, _fmt(miou), _fmt(m.get("part_selection_all_slots")),
                     _fmt(m.get("success_all_slots"))])
    return ["", "## Table III — ablation", "",
            *_table(["method", "multi-fusion", "fine-grained opt.", "prompt anchoring",
                     "grasps where labels agree with votes", "mIoU", "Part Sel.", "Suc."], rows)]


def _per_category(methods: dict) -> list[str]:
    categories = sorted({c for m in methods.values() for c in m.get("categories", {})})
    if not categories:
        return []
    rows = [[name, *(f"{_fmt(m['categories'][c]['part_selection_all_slots'], 2)} / "
                     f"{_fmt(m['categories'][c]['success_all_slots'], 2)}" if c in m["categories"] else "—"
                     for c in categories)] for name, m in methods.items() if "categories" in m]
    return ["", "## Part Sel. / Suc. per category (all slots)", "", *_table(["method", *categories], rows)]


def _failures(methods: dict) -> list[str]:
    lines = []
    for name, m in methods.items():
        per_category = {c: v["failures"] for c, v in m.get("categories", {}).items()}
        names = sorted({f for counts in per_category.values() for f in counts})
        if not names:
            continue
        rows = [[c, str(m["categories"][c]["trials"]), *(str(counts.get(f, 0)) for f in names)]
                for c, counts in per_category.items()]
        lines += ["", f"### {name}", "", *_table(["category", "slots", *names], rows)]
    if not lines:
        return []
    return ["", "## Failures per category", "",
            f"Failed slots by failure name (`{UNNAMED_FAILURE}`: the cell named no failure)."] + lines


def _curve_table(curve: dict) -> list[str]:
    if not curve.get("thresholds"):
        return []
    rows = [[f"{t:.3f}", _fmt(s), _fmt(f)] for t, s, f in zip(curve["thresholds"], curve["spread"], curve["full"])]
    return ["", "## GeoSpreading vs GeoFusion over the decomposition threshold (mIoU)", "",
            *_table(["threshold", "GeoSpreading", "GeoFusion (from this threshold up)"], rows)]


def seeds_label(seeds: Sequence[int]) -> str:
    """`0-4` for a run of seeds 0..4, `0, 3, 7` otherwise."""
    seeds = sorted(seeds)
    if len(seeds) > 2 and seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ", ".join(str(s) for s in seeds)


def _with_interval(d: dict | None) -> str:
    if not d:
        return "—"
    if d["ci_low"] is None:  # one object: no interval
        return f"{d['mean']:.3f} [—]"
    return f"{d['mean']:.3f} [{d['ci_low']:.3f}, {d['ci_high']:.3f}]"


def _interval_tables(summary: dict, seeds: Sequence[int]) -> list[str]:
    """The headline: mean [95 % interval] per method and metric, per-seed values, paired differences."""
    methods, confidence = summary["methods"], f"{CONFIDENCE * 100:g} %"
    rows = [[name, *(_with_interval(m["intervals"].get(key)) for key, _ in INTERVAL_COLUMNS)]
            for name, m in methods.items()]
    lines = [f"## Headline — mean [{confidence} interval] over objects and seeds", "",
             f"Intervals: percentile cluster bootstrap over objects ({N_RESAMPLES} resamples; a drawn object brings "
             "all its seeds, prompts and slots; sim/evaluate/stats.py). Part Sel. and Suc. per request (all top-k "
             "slots; a slot without a grasp is a miss), then over the executed grasps only.", "",
             *_table(["method", *(title for _, title in INTERVAL_COLUMNS)], rows)]
    if len(seeds) > 1:
        per_seed = [[name, key_title, *(_fmt(m["intervals"][key]["per_seed"].get(str(s))) for s in seeds)]
                    for name, m in methods.items() for key, key_title in INTERVAL_COLUMNS[:3]
                    if m["intervals"].get(key)]
        lines += ["", "## Per seed", "", *_table(["method", "metric", *(f"seed {s}" for s in seeds)], per_seed)]
    differences = summary.get("differences") or {}
    if differences:
        rows = [[name, *(_with_interval(d.get(key)) for key, _ in INTERVAL_COLUMNS[:4])]
                for name, d in differences.items()]
        lines += ["", f"## Paired differences — mean [{confidence} interval]", "",
                  "Both methods on the same objects, seeds and requests; an interval that excludes 0 separates them.",
                  "", *_table(["difference", *(title for _, title in INTERVAL_COLUMNS[:4])], rows)]
    return lines + [""]


def _infeasible(methods: dict) -> list[str]:
    """The requests judged infeasible for the hand, per category and per part, from the oracle's records (every
    method's requests are judged alike on the twin: from its labelled mesh), with the oracle's Suc. over the rest."""
    name = "oracle" if "oracle" in methods else next((n for n, m in methods.items() if "categories" in m), None)
    if name is None or "categories" not in methods[name] or not methods[name]["judged_requests"]:
        return []
    m = methods[name]
    rows = [[c, str(v["requests"]), str(v["infeasible_requests"]), _fmt(v.get("success_feasible"))]
            for c, v in m["categories"].items()]
    rows.append(["all", str(m["requests"]), str(m["infeasible_requests"]), _fmt(m.get("success_feasible"))])
    parts = [[part, str(v["requests"]), v["reason"]] for part, v in m.get("infeasible_parts", {}).items()]
    lines = ["", "## Requests the hand cannot hold", "",
             "Judged per request before the robot moves, from the labelled mesh: no candidate grasp has both contacts "
             "on the part with the pads pressing on it and able to keep the object's weight from turning it "
             "(seggrasp/grasp/feasibility.py). Such a request is recorded "
             f"as `infeasible`, not executed, and counts as failed in every Suc. but the feasible one ({name}'s "
             "records).", "", *_table(["category", "requests", "infeasible", f"{name} Suc. (feasible requests)"], rows)]
    if parts:
        lines += ["", *_table(["object: part", "infeasible requests", "why (first one)"], parts)]
    return lines


def _neighbours(methods: dict) -> list[str]:
    """A scene run's table of what each method's executed grasps did to the other objects."""
    rows = [[name, _fmt(m["success_all_slots"]), f"{m['disturbance_median_mm']:.1f}",
             f"{m['disturbance_p90_mm']:.1f}", _fmt(m["disturbed"]), _fmt(m["lifted_along"]), str(m["executed"])]
            for name, m in methods.items() if "disturbance_median_mm" in m]
    if not rows:
        return []
    return ["", "## The other objects on the table", "",
            "Over the executed grasps: how far the farthest-moved other object went (mm: the median and the 90th "
            "percentile; an object knocked off the twin's table falls on for the rest of the trial, so a mean would "
            f"count metres of fall), the share of grasps that moved one at least {DISTURBED * 1000:.0f} mm and the "
            "share that lifted one along.", "",
            *_table(["method", "Suc.", "farthest moved, median (mm)", "90th percentile (mm)",
                     f"moved one >= {DISTURBED * 1000:.0f} mm", "lifted one along", "executed"], rows)]


def _target_table(methods: dict) -> list[str]:
    """A perceived scene run's table of how often each method's requests found their object among the others."""
    rows = [[name, kind, str(v["requests"]), _fmt(v["found"]), _fmt(v["instance_iou"])]
            for name, m in methods.items() for kind, v in m.get("target_search", {}).items()]
    if not rows:
        return []
    return ["", "## Finding the object among the others", "",
            "Per request: whether the detector's boxes for the object's name on the camera images picked one of the "
            "perceived instances (not found: every slot fails as `not_found`), and the chosen instance's IoU with "
            "the object's points by the twin's segmentation masks (mean over the requests it was found in; "
            "seggrasp/target.py).", "",
            *_table(["method", "scene", "requests", "target found", "instance IoU"], rows)]


def _body(summary: dict, seeds: Sequence[int]) -> list[str]:
    """One system's sections: the interval tables, Tables I-III, how often a perceived scene found the object,
    what a scene's grasps did to the other objects, per-category results, failures, the requests it cannot hold
    and the threshold curve."""
    methods = summary["methods"]
    lines = _interval_tables(summary, seeds) if any("intervals" in m for m in methods.values()) else []
    lines += _table_one(methods) + [""] + _table_two(methods) + _target_table(methods) + _neighbours(methods)
    lines += _table_three(methods)
    lines += _curve_table(summary.get("curve") or {}) + _per_category(methods) + _failures(methods)
    return lines + _infeasible(methods)


def _average_table(average: dict, robots: Sequence[str]) -> list[str]:
    confidence = f"{CONFIDENCE * 100:g} %"
    columns = [(key, title) for key, title in INTERVAL_COLUMNS if key != "miou"]
    rows = [[name, *(_with_interval(metrics.get(key)) for key, _ in columns)] for name, metrics in average.items()]
    return [f"## Average over the robot systems ({', '.join(robots)}) — mean [{confidence} interval]", "",
            "The paper reports Suc. as the average over its two systems. Each metric is the mean of the systems' own "
            "values; the interval is the cluster bootstrap over objects, each drawn object bringing its records on "
            "every system.", "", *_table(["method", *(title for _, title in columns)], rows), ""]


def _header_line(header: dict, seeds: Sequence[int]) -> str:
    robots = header.get("robots", [])
    return (f"Detector: `{header['detector']}` · embodiment: `{header['embodiment']}` · backend: `{header['backend']}`"
            + (f" · robots: {', '.join(robots)}" if robots else "")
            + (f" · scene: {header['scene']}" if header.get("scene") else "")
            + (f", {header['objects_per_scene']} objects" if header.get("scene") and header.get("objects_per_scene")
               else "")
            + f" · perceive: {header['perceive']} · seeds: {seeds_label(seeds)} · top-k: {header['top_k']}"
            f" · objects: {header['n_objects']} · wall time: {header['wall_time_s']:.0f} s"
            + (f" · trials recorded: {header['recorded_trials']} of {header['expected_trials']}"
               if "expected_trials" in header else ""))


def markdown_report(summary: dict, header: dict) -> str:
    """The report as Markdown: one system's sections, or for several systems their average and then each one's."""
    seeds = header.get("seeds", [header.get("seed", 0)])
    lines = ["# SegGrasp evaluation", "", _header_line(header, seeds), ""]
    systems = summary.get("systems")
    if not systems:
        return "\n".join(lines + _body(summary, seeds)) + "\n"
    lines += _average_table(summary["average"], list(systems))
    for robot, system in systems.items():
        lines += [f"# {robot}: {system['hand']}", "", *_body(system, seeds), ""]
    return "\n".join(lines) + "\n"


def expected_trials(config: RunConfig) -> int:
    """How many trial records a complete run holds."""
    n_prompts = sum(len(prompts_of(config, object_id)) for object_id in config.objects)
    return n_prompts * len(config.methods) * config.top_k * len(config.seeds) * len(config.robots)


def write_summary(config: RunConfig, out: Path, wall_time: float, crashes: list[dict]) -> dict:
    """Read the result files back (first record per key) and write summary.json, summary.md and the plots (one
    system's summary; for several robot systems, each one's under `systems` and their average)."""
    wanted = set(config.objects)

    def of_run(records: list[dict], robot: str, by_method: bool = True) -> list[dict]:
        return [r for r in records if r["object_id"] in wanted and int(r.get("seed", 0)) in config.seeds
                and robot_of(r) == robot and (not by_method or r["method"] in config.methods)]

    files = {name: read_unique(out / name, key) for name, key in RESULT_KEYS.items()}
    trials = {robot: of_run(files["trials.jsonl"], robot) for robot in config.robots}
    segmentations = {robot: of_run(files["segmentations.jsonl"], robot) for robot in config.robots}
    systems = {robot: dict(summarise(trials[robot], segmentations[robot],
                                     of_run(files["curves.jsonl"], robot, by_method=False), config.methods),
                           hand=config.at_robot(robot).hand.name)
               for robot in config.robots}
    if len(systems) == 1:
        summary = next(iter(systems.values()))
    else:
        summary = {"systems": systems, "average": system_averages(trials, segmentations, config.methods)}
    header = {
        "detector": config.at_seed(config.seeds[0]).detector_spec().label, "embodiment": config.embodiment,
        "backend": config.backend, "robots": config.robots, "perceive": config.perceive, "seeds": config.seeds,
        "decomposition_seed": config.decomposition_seed, "top_k": config.top_k, "n_objects": len(config.objects),
        "wall_time_s": wall_time, "recorded_trials": sum(map(len, trials.values())),
        "expected_trials": expected_trials(config), "scene": config.scene,
        "objects_per_scene": config.objects_per_scene,
    }
    summary["run"] = dict(header, methods=config.methods, objects=config.objects,
                          crashed_objects=sorted({c["object_id"] for c in crashes}),
                          crashed_tasks=[{"object_id": c["object_id"], "seed": c["seed"]} for c in crashes])
    with writing(out / "summary.json"):
        atomic_write_json(out / "summary.json", summary)
    with writing(out / "summary.md"):
        atomic_write_text(out / "summary.md", markdown_report(summary, header))
    with writing(out / "plots"):
        for robot, system in systems.items():
            write_plots(system, out / "plots" if len(systems) == 1 else out / "plots" / robot)
    return summary
