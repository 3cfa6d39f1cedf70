"""Grasp selection per request: all-slot Part Sel. and Suc. over several seeds, with paired differences.

Reads the `trials.jsonl` of `python -m sim.evaluate` runs (folders of one or several seeds, per detector) and writes
docs/results/grasp-selection.md (or `--out`):

    python bench/bench_selection.py --runs typical=/tmp/select/typ-s0,/tmp/select/typ-s1,/tmp/select/typ-s2 \
        --runs hard=/tmp/select/hard-s0,/tmp/select/hard-s1,/tmp/select/hard-s2 --planned typical \
        --out docs/results/grasp-selection.md

A request is one (seed, object, prompt); its Part Sel. and Suc. are the shares of its top-k slots whose planned
contacts lie on the prompted part / that lifted the object by it (a slot without a grasp is a miss). Paired
differences are taken over the requests both methods have, with the standard error and a 95 % bootstrap interval
over requests. `--planned DETECTOR` adds a physics-free ablation of the selection policy on that detector's runs:
every variant's Part Sel. from its planned contacts (the benchmark's own ground-truth test), using the runs' cached
votes and the same grasp candidates the episode samples. `--replan DETECTOR` instead plans `--methods` again on
that detector's runs (no physics) and compares their Part Sel. per category with what the runs recorded, and with
`--rerun` folders (runs of this checkout) their Part Sel. and Suc.; `--seeds` keeps only those run seeds:

    python bench/bench_selection.py --runs typical=/tmp/lead/s5 --replan typical --methods shapegrasp,seggrasp,oracle \
        --rerun /tmp/contacts/sg-s0,/tmp/contacts/sg-s12 --seeds 0,1,2 --out docs/results/shapegrasp-contacts.md
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from seggrasp.io import atomic_write_text

TARGETS = ("coarse", "shapegrasp")
SHOWN = ("seggrasp", "seggrasp-nearest", "anchored", "seggrasp-agree", "coarse", "shapegrasp", "oracle")
BOOTSTRAP = 2000


def read_trials(folder: Path) -> list[dict]:
    """The unique trial records of one run (`sim.evaluate.records.read_unique`: a torn last line is skipped)."""
    from sim.evaluate.records import read_unique, trial_key

    path = folder / "trials.jsonl"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no trials (is {folder} a sim.evaluate output folder?)")
    return read_unique(path, trial_key)


def per_request(trials: list[dict]) -> dict[str, dict[tuple, np.ndarray]]:
    """method -> (seed, object, prompt) -> [Part Sel., Suc. (shares of its slots), executed slots, top-1 Suc.]."""
    from sim.evaluate.records import seed_of

    slots: dict[str, dict[tuple, list[dict]]] = defaultdict(lambda: defaultdict(list))
    for r in trials:
        slots[r["method"]][(seed_of(r), r["object_id"], r["prompt"])].append(r)
    out: dict[str, dict[tuple, np.ndarray]] = {}
    for method, requests in slots.items():
        out[method] = {}
        for key, rows in requests.items():
            rows.sort(key=lambda r: r["rank"])
            out[method][key] = np.array([np.mean([bool(r["contacts_on_part"]) for r in rows]),
                                         np.mean([bool(r["success"]) for r in rows]),
                                         sum(bool(r["executed"]) for r in rows), float(bool(rows[0]["success"]))])
    return out


Requests = dict[tuple, np.ndarray]


def paired(
    a: Requests, b: Requests, column: int, rng, within: set | None = None
) -> tuple[float, float, float, float, int]:
    """Mean of a - b over the shared requests (those in `within` if given), its standard error and 95 % bootstrap
    interval, and their count."""
    keys = sorted(set(a) & set(b) & (within if within is not None else set(a)))
    d = np.array([a[k][column] - b[k][column] for k in keys])
    if len(d) < 2:
        return float("nan"), float("nan"), float("nan"), float("nan"), len(d)
    boot = d[rng.integers(0, len(d), size=(BOOTSTRAP, len(d)))].mean(axis=1)
    lo, hi = np.percentile(boot, [2.5, 97.5])
    return float(d.mean()), float(d.std(ddof=1) / np.sqrt(len(d))), float(lo), float(hi), len(d)


def detector_section(name: str, folders: list[Path], only_seeds: set[int] | None = None) -> tuple[list[str], list[str]]:
    """Markdown lines of one detector's table, paired differences and done-when checks (and the check lines), over
    the seeds in `only_seeds` (default: all)."""
    merged = defaultdict(dict)
    for folder in folders:
        for method, requests in per_request(read_trials(folder)).items():
            merged[method].update({k: v for k, v in requests.items() if only_seeds is None or k[0] in only_seeds})
    merged = defaultdict(dict, {method: requests for method, requests in merged.items() if requests})
    seeds = sorted({key[0] for requests in merged.values() for key in requests})
    methods = [m for m in SHOWN if m in merged] + sorted(m for m in merged if m not in SHOWN)

    def seed_mean(method: str, column: int, seed: int) -> float:
        values = [v[column] for k, v in merged[method].items() if k[0] == seed]
        return float(np.mean(values)) if values else float("nan")

    def executed(method: str, seed: int) -> int:
        return int(sum(v[2] for k, v in merged[method].items() if k[0] == seed))

    graspable = {k for k, v in merged.get("oracle", {}).items() if v[2] > 0}

    def graspable_mean(method: str, column: int) -> str:
        values = [v[column] for k, v in merged[method].items() if k in graspable]
        return f"{np.mean(values):.3f}" if values else "—"

    lines = [f"## Detector `{name}`: seeds {', '.join(map(str, seeds))}", "",
             "Each cell: mean over the seeds a method ran on (per seed in brackets, — = not run). Part Sel. and Suc.",
             "over all top-k slots. The last two columns: the same over the requests whose part has a graspable",
             f"region (the oracle executes at least one grasp there: {len(graspable)} requests over all seeds), pooled",
             "over the seeds the method ran on.", "",
             "| method | Part Sel. (all slots) | Suc. (all slots) | top-1 Suc. | executed slots per seed | "
             "Part Sel. (graspable) | Suc. (graspable) |",
             "|---|---|---|---|---|---|---|"]
    means = {}
    for m in methods:
        cells = []
        for column in (0, 1, 3):
            per_seed = [seed_mean(m, column, s) for s in seeds]
            means[(m, column)] = float(np.nanmean(per_seed))
            shown = " / ".join("—" if np.isnan(v) else f"{v:.3f}" for v in per_seed)
            cells.append(f"{means[(m, column)]:.3f} ({shown})")
        ran = [s for s in seeds if any(k[0] == s for k in merged[m])]
        ex = [executed(m, s) for s in ran]
        means[(m, "executed")] = float(np.mean(ex))
        ex_cell = " / ".join(str(executed(m, s)) if s in ran else "—" for s in seeds)
        lines.append(f"| {m} | {' | '.join(cells)} | {ex_cell} (mean {np.mean(ex):.0f}) | "
                     f"{graspable_mean(m, 0)} | {graspable_mean(m, 1)} |")
    difference_rows, diffs = differences(merged, methods, graspable)
    lines += ["", "Paired differences over requests (seed, object, prompt): mean ± standard error [95 % bootstrap "
              "interval], number of requests; over all requests, then over the graspable ones.", "",
              "| difference | Part Sel. (all slots) | Suc. (all slots) | Part Sel. (graspable) | Suc. (graspable) |",
              "|---|---|---|---|---|", *difference_rows]
    checks = done_when(name, means, diffs)
    return lines + ["", "Done-when checks:", "", *checks], checks


def differences(merged: dict[str, Requests], methods: list[str], graspable: set) -> tuple[list[str], dict]:
    """Table rows of `seggrasp` minus every other method (Part Sel., Suc.; all requests, then the `graspable`
    ones), and (method, column) -> (mean, lo, hi) over all requests."""
    rng = np.random.default_rng(0)
    rows, diffs = [], {}
    if "seggrasp" not in merged:
        return rows, diffs
    for other in [m for m in methods if m != "seggrasp"]:
        cells = []
        for within, column in ((None, 0), (None, 1), (graspable, 0), (graspable, 1)):
            mean, se, lo, hi, n = paired(merged["seggrasp"], merged[other], column, rng, within)
            if within is None:
                diffs[(other, column)] = (mean, lo, hi)
            cells.append(f"{mean:+.3f} ± {se:.3f} [{lo:+.3f}, {hi:+.3f}], n={n}")
        rows.append(f"| seggrasp − {other} | {' | '.join(cells)} |")
    return rows, diffs


def done_when(name: str, means: dict, diffs: dict) -> list[str]:
    """The issue's criteria for `seggrasp`, each met or missed with its margin."""
    if ("seggrasp", 0) not in means:
        return ["- seggrasp was not run"]
    checks = []
    for other in TARGETS:
        for column, label in ((0, "Part Sel."), (1, "Suc.")):
            if (other, column) not in diffs:
                continue
            mean, lo, hi = diffs[(other, column)]
            verdict = "met" if lo > 0 else "MISSED"
            checks.append(f"- [{name}] {label} all slots beats {other}: difference {mean:+.3f}, 95 % interval "
                          f"[{lo:+.3f}, {hi:+.3f}] -> {verdict}")
    if ("oracle", 0) in means:
        ratio = means[("seggrasp", 0)] / means[("oracle", 0)]
        ours, oracle = means[("seggrasp", 0)], means[("oracle", 0)]
        checks.append(f"- [{name}] Part Sel. >= 0.9 x oracle: {ours:.3f} / {oracle:.3f} = {ratio:.3f} x -> "
                      f"{'met' if ratio >= 0.9 else 'MISSED'}")
        executed = means[("seggrasp", "executed")] / means[("oracle", "executed")]
        ours, oracle = means[("seggrasp", "executed")], means[("oracle", "executed")]
        checks.append(f"- [{name}] executed slots >= 95 % of oracle's: {ours:.0f} / {oracle:.0f} = {executed:.1%} -> "
                      f"{'met' if executed >= 0.95 else 'MISSED'}")
    return checks


def planned_variants():
    """name -> how the variant picks grasps: ("labels", which) or ("policy", evidence names, PartPolicy)."""
    from seggrasp.grasp.policy import PartPolicy

    default = PartPolicy()
    return {
        "coarse labels": ("labels", "coarse"),
        "anchored labels (`anchored`)": ("labels", "anchored"),
        "anchored labels where they agree with the votes (`seggrasp-agree`)": ("labels", "agree"),
        "probabilities from GeoFusion only": ("policy", ("geofusion",), default),
        "probabilities from GeoFusion + anchored labels": ("policy", ("geofusion", "anchored"), default),
        "probabilities from GeoFusion + votes + anchored labels (`seggrasp`)":
            ("policy", ("geofusion", "votes", "anchored"), default),
        "... + ShapeGrasp's part per prompt": ("policy", ("geofusion", "votes", "anchored", "shapegrasp"), default),
        "`seggrasp`, nearest face only (`seggrasp-nearest`)":
            ("policy", ("geofusion", "votes", "anchored"), PartPolicy(footprint_radius=0.0)),
        "`seggrasp`, ranked by probability alone (no region in the generator's order)":
            ("policy", ("geofusion", "votes", "anchored"), PartPolicy(region_fraction=1.0)),
        "ground-truth labels (`oracle`)": ("labels", "truth"),
    }


def object_evidence(episode) -> dict[str, np.ndarray]:
    """The per-face evidence and labellings of one episode's object (the `seggrasp` method's inputs)."""
    from seggrasp.fusion import (agreed_labels, assign_parts_to_prompts, coarsest_with_parts, part_mean_scores,
                                 refine_labels)
    from seggrasp.grasp.policy import one_hot
    from seggrasp.vote import labels_from_scores

    coarse = episode.coarse_scores()
    segmenter, mesh = episode.segmenter, episode.observation.mesh
    refined, anchored = refine_labels(coarse, segmenter.partitions(), mesh.area_faces, "full", True)
    part_of_face = coarsest_with_parts(segmenter.partitions(), coarse.shape[1]).part_of_face
    shape = np.zeros_like(coarse)
    for k, part in enumerate(assign_parts_to_prompts(part_mean_scores(coarse, part_of_face, mesh.area_faces))):
        if part >= 0:
            shape[part_of_face == part, k] = 1.0
    coarse_labels = labels_from_scores(coarse)
    return {"geofusion": refined, "votes": coarse, "anchored": one_hot(anchored, coarse.shape[1]), "shapegrasp": shape,
            "labels:coarse": coarse_labels, "labels:anchored": anchored,
            "labels:agree": agreed_labels(anchored, coarse_labels), "labels:truth": episode.truth_on_mesh}


def planned_object(episode, top_k: int) -> dict[str, list[tuple[float, int]]]:
    """variant -> per prompt (Part Sel. share of the top-k slots, executed slots), from planned contacts."""
    from seggrasp.grasp import contact_faces, select_per_prompt
    from seggrasp.grasp.policy import face_part_probabilities

    evidence, grasps, mesh = object_evidence(episode), episode.grasps(), episode.observation.mesh
    truth = evidence["labels:truth"]
    n_prompts = evidence["votes"].shape[1]
    faces = contact_faces(grasps, mesh)
    results = {}
    for name, variant in planned_variants().items():
        if variant[0] == "labels":
            chosen = select_per_prompt(grasps, mesh, evidence[f"labels:{variant[1]}"], n_prompts, top_k, episode.footprint)
        else:
            probs = face_part_probabilities([evidence[e] for e in variant[1]])
            chosen = variant[2].select(grasps, mesh, probs, top_k)
        on_part = [float((truth[faces[c]] == k).all(axis=1).sum()) / top_k for k, c in enumerate(chosen)]
        results[name] = [(share, len(c)) for share, c in zip(on_part, chosen)]
    return results


def run_seeds(folder: Path) -> list[int]:
    """The seeds of one `sim.evaluate` run (`--seeds` runs list them; older one-seed runs name their seed)."""
    run = json.loads((folder / "run.json").read_text())
    return [int(s) for s in run["seeds"]] if "seeds" in run else [int(run["seed"])]


def run_episodes(folders: list[Path], only_seeds: set[int] | None = None):
    """(seed, episode) for every object and seed of the runs in `folders` (those in `only_seeds` if given): the
    run's scenes, detector, decomposition seed and cached votes, planned again by this checkout's code."""
    from seggrasp.episode import Episode, EpisodeSettings
    from sim.cell import SimCell
    from sim.evaluate.config import DECOMPOSITION_SEED, RunConfig
    from sim.evaluate.records import VoteCache
    from sim.evaluate.runner import subject_of

    for folder in folders:
        run = json.loads((folder / "run.json").read_text())
        for seed in [s for s in run_seeds(folder) if only_seeds is None or s in only_seeds]:
            config = RunConfig(methods=["seggrasp"], objects=run["objects"], detector=run["detector"],
                               embodiment=run["embodiment"], seeds=[seed], top_k=run["top_k"],
                               decomposition_seed=run.get("decomposition_seed", DECOMPOSITION_SEED))
            settings = EpisodeSettings(seed=seed, top_k=config.top_k, decomposition_seed=config.decomposition_seed)
            with SimCell(embodiment=config.embodiment, seed=seed) as cell:
                for object_id in config.objects:
                    context, truth = subject_of(object_id, config, cell)
                    yield seed, Episode(cell, context, config.object_detector(object_id), truth, settings,
                                        vote_cache=VoteCache(folder / "cache" / object_id))
                    print(f"planned: seed {seed} {object_id}", file=sys.stderr, flush=True)


def planned_section(detector: str, folders: list[Path], only_seeds: set[int] | None = None) -> list[str]:
    """Markdown lines of the physics-free ablation over the runs' seeds (votes from their caches)."""
    per_variant: dict[str, dict[int, list[tuple[float, int]]]] = defaultdict(lambda: defaultdict(list))
    seeds = []
    for seed, episode in run_episodes(folders, only_seeds):
        if seed not in seeds:
            seeds.append(seed)
        for name, rows in planned_object(episode, episode.settings.top_k).items():
            per_variant[name][seed] += rows
    lines = [f"## Ablation of the selection without physics (detector `{detector}`, seeds "
             f"{', '.join(map(str, seeds))})", "",
             "Part Sel. over all top-10 slots from the planned contacts (both contacts' nearest faces on the prompted",
             "part: the benchmark's own test, which needs no simulation), mean over seeds (per seed in brackets), and",
             "executed slots per seed. Same grasp candidates and votes as the runs above.", "",
             "| grasps chosen by | Part Sel. (all slots) | executed slots per seed |", "|---|---|---|"]
    for name, by_seed in per_variant.items():
        ps = [np.mean([r[0] for r in by_seed[s]]) for s in seeds]
        ex = [sum(r[1] for r in by_seed[s]) for s in seeds]
        lines.append(f"| {name} | {np.mean(ps):.3f} ({' / '.join(f'{v:.3f}' for v in ps)}) | "
                     f"{' / '.join(map(str, ex))} |")
    return lines + [""]


def replanned_trials(folders: list[Path], methods: list[str], only_seeds: set[int] | None) -> list[dict]:
    """Trial-like records of `methods`' slots planned again without physics on the runs' scenes: Part Sel. from
    the planned contacts as the episode scores them (`Episode.contacts_on_part`), and whether the slot's grasp
    touches anything (finite contacts)."""
    records = []
    for seed, episode in run_episodes(folders, only_seeds):
        context = episode.context
        for method in methods:
            for slot in episode.slots(episode.plan(method)):
                touches = slot.grasp is not None and bool(np.isfinite(slot.grasp.contacts).all())
                records.append({"object_id": context.object_id, "category": context.category, "method": method,
                                "prompt": context.prompts[slot.prompt_index], "rank": slot.rank, "seed": seed,
                                "contacts_on_part": episode.contacts_on_part(slot), "touches": touches,
                                "executed": slot.grasp is not None})
    return records


def rate(rows: list[dict], key: str) -> str:
    """Share of `rows` whose `key` is true (a missing or None value counts as false), or — without rows."""
    return f"{np.mean([bool(r.get(key)) for r in rows]):.3f}" if rows else "—"


def category_rows(before: list[dict], after: list[dict], method: str, columns: list[tuple[str, str]]) -> list[str]:
    """Table rows per category and overall: for each (key, which) column the share in `before` or `after`, over
    the (seed, object, prompt, rank) slots of `method` that both hold."""
    from sim.evaluate.records import trial_key

    old = {trial_key(r): r for r in before if r["method"] == method}
    new = {trial_key(r): r for r in after if r["method"] == method}
    keys = sorted(set(old) & set(new))
    category = {k: old[k].get("category") or new[k].get("category") for k in keys}
    lines = []
    for name in sorted(set(category.values())) + ["all"]:
        chosen = [k for k in keys if name in ("all", category[k])]
        cells = [rate([(old if which == "before" else new)[k] for k in chosen], key) for key, which in columns]
        lines.append(f"| {method} | {name} | {len(chosen)} | {' | '.join(cells)} |")
    return lines


def replan_section(detector: str, folders: list[Path], methods: list[str], only_seeds: set[int] | None,
                   rerun: list[Path]) -> list[str]:
    """Markdown lines: per method and category, the all-slot Part Sel. the runs recorded and the one this
    checkout plans on the same scenes (no physics); with `rerun` folders (runs of this checkout), also their
    recorded Part Sel. and Suc. beside the original runs'."""
    recorded = [r for f in folders for r in read_trials(f) if only_seeds is None or r.get("seed", 0) in only_seeds]
    replanned = replanned_trials(folders, methods, only_seeds)
    seeds = sorted({r["seed"] for r in replanned})
    lines = [f"## Planned contacts again, without physics (detector `{detector}`, seeds {', '.join(map(str, seeds))})",
             "", "All-slot Part Sel. (both planned contacts nearest to faces of the prompted part; a slot without a",
             "grasp, or whose pads touch nothing, fails) as the runs recorded it and as this checkout plans it on the",
             "same scenes, detector errors and cached votes; `touches`: share of slots whose pads meet the object.", "",
             "| method | category | slots | Part Sel. recorded | Part Sel. planned now | touches (planned now) |",
             "|---|---|---|---|---|---|"]
    for method in methods:
        lines += category_rows(recorded, replanned, method,
                               [("contacts_on_part", "before"), ("contacts_on_part", "after"), ("touches", "after")])
    if rerun:
        again = [r for f in rerun for r in read_trials(f) if only_seeds is None or r.get("seed", 0) in only_seeds]
        ran = sorted({r["method"] for r in again})
        lines += ["", f"## Executed again: {', '.join(map(str, rerun))}", "",
                  "The same slots executed on the twin by this checkout (`sim.evaluate`, same seeds and scenes) beside",
                  "the original runs: all-slot Part Sel. and Suc.", "",
                  "| method | category | slots | Part Sel. before | Part Sel. after | Suc. before | Suc. after |",
                  "|---|---|---|---|---|---|---|"]
        for method in ran:
            columns = [("contacts_on_part", "before"), ("contacts_on_part", "after"), ("success", "before"),
                       ("success", "after")]
            lines += category_rows(recorded, again, method, columns)
    return lines + [""]


def parse_runs(values: list[str]) -> dict[str, list[Path]]:
    """`NAME=DIR,DIR,...` -> {NAME: [DIR, ...]}, each DIR an existing run folder."""
    runs = {}
    for value in values:
        name, _, dirs = value.partition("=")
        if not name or not dirs:
            raise ValueError(f"--runs takes NAME=DIR[,DIR...], got {value!r}")
        folders = [Path(d) for d in dirs.split(",") if d]
        for folder in folders:
            if not (folder / "run.json").is_file():
                raise ValueError(f"{folder}: not a sim.evaluate output folder (no run.json)")
        runs[name] = folders
    return runs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", action="append", required=True, help="DETECTOR=DIR,DIR,... (one folder per seed)")
    parser.add_argument("--planned", help="also run the physics-free policy ablation on this detector's runs")
    parser.add_argument("--replan", metavar="DETECTOR",
                        help="instead: plan --methods again on this detector's runs without physics and compare "
                             "their Part Sel. per category with what the runs recorded")
    parser.add_argument("--methods", default="shapegrasp,seggrasp,oracle", help="--replan: comma-separated methods")
    parser.add_argument("--rerun", default="", help="--replan: comma-separated folders of runs of this checkout on "
                        "the same seeds, compared with the original runs per category (Part Sel., Suc.)")
    parser.add_argument("--seeds", default="", help="only these run seeds, comma-separated (default: all)")
    parser.add_argument("--out", default="docs/results/grasp-selection.md")
    args = parser.parse_args(argv)
    try:
        runs = parse_runs(args.runs)
        for option, detector in (("--planned", args.planned), ("--replan", args.replan)):
            if detector and detector not in runs:
                raise ValueError(f"{option} {detector}: no --runs for that detector")
        only_seeds = {int(v) for v in args.seeds.split(",") if v.strip()} or None
        rerun = parse_runs([f"rerun={args.rerun}"])["rerun"] if args.rerun else []
        methods = [m.strip() for m in args.methods.split(",") if m.strip()]
        from seggrasp.method import check_method

        for method in methods:
            check_method(method)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    options = [f"--runs {v}" for v in args.runs] + ([f"--planned {args.planned}"] if args.planned else [])
    if args.replan:
        options += [f"--replan {args.replan} --methods {','.join(methods)}"]
        options += [f"--rerun {args.rerun}"] if rerun else []
    options += [f"--seeds {args.seeds}"] if only_seeds else []
    command = "python bench/bench_selection.py " + " ".join(options + [f"--out {args.out}"])
    if args.replan:
        lines = [*REPLAN_HEADER, "", "Regenerate: `" + command + "`", "",
                 *replan_section(args.replan, runs[args.replan], methods, only_seeds, rerun)]
    else:
        lines = [*HEADER, "", "Regenerate: `" + command + "`", ""]
        for name, folders in runs.items():
            lines += detector_section(name, folders, only_seeds)[0] + [""]
        if args.planned:
            lines += planned_section(args.planned, runs[args.planned], only_seeds)
        lines += FOOTER
    atomic_write_text(Path(args.out), "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


REPLAN_HEADER = [
    "# Planned contacts of a run, again with this checkout",
    "",
    "Written by `bench/bench_selection.py --replan` from `python -m sim.evaluate` runs on the full twin: the methods'",
    "slots planned again on the runs' scenes (same detector errors, cached votes and decomposition seed), scored by",
    "the episode's own Part Sel. test without executing them.",
]
HEADER = [
    "# Grasp selection: which grasps `seggrasp` executes for a request",
    "",
    "Written by `bench/bench_selection.py` from `python -m sim.evaluate` runs on the full twin (36 objects, 84",
    "prompts, top-10 slots per prompt, UR5 arm, simulated detector) with `--seed S` for each seed listed. Methods:",
    "`seggrasp` ranks grasps by the probability that both pads land on the prompted part (seggrasp/grasp/policy.py);",
    "`seggrasp-nearest` the same, read only at the face nearest each contact; `anchored` the same labels, grasps",
    "where both nearest faces carry the prompt's label; `seggrasp-agree` the earlier default (only where those",
    "labels agree with the coarse votes' argmax); `coarse`, `shapegrasp`, `oracle` as in `seggrasp.method`.",
    "Each run: `nice python -m sim.evaluate --embodiment arm --workers 1 --detector D --seed S --methods M --out DIR`",
    "(`--resume` with the extra methods where a folder already held a run; see the last section).",
]
FOOTER = [
    "## How the policy was chosen",
    "",
    "The policy's settings (evidence = GeoFusion scores + coarse votes + anchored labels, an 8 mm footprint, the",
    "region at 0.65 x the best probability, abstention below 0.05) were chosen on seeds 0 and 1 of the `typical`",
    "detector only, from the Part Sel. of planned contacts without physics (the benchmark's own ground-truth test)",
    "and the recorded outcomes of grasps the earlier runs had executed. Variants tried there and not kept:",
    "GeoFusion alone or without the votes (lower Part Sel.), ShapeGrasp's one part per prompt as a fourth evidence",
    "(lower), ranking by probability alone instead of the region in the generator's order (similar Part Sel., but",
    "it picks grasps the generator ranks low, and of those already executed far fewer had lifted), a wider region",
    "(0.5: lower Part Sel.) or a narrower one (0.8, 0.9: similar Part Sel., fewer recorded lifts).",
    "Seed 2 and the `hard` detector were not looked at before these settings were fixed: they are the confirmation.",
    "Seeds 0 and 1 reuse the trials of the earlier full runs for the methods whose code did not change (`coarse`,",
    "`anchored`, `shapegrasp`, `oracle`; `seggrasp-agree` is that run's `seggrasp`); the `hard` runs reuse the",
    "`oracle` trials of the same seed (the oracle plans from ground truth, not from the detector).",
    "",
    "Part Sel. over all slots counts every slot of a request, also where no grasp of the sampler touches the part",
    "alone (flat blades, closed scissors, folded eyeglasses: the oracle executes nothing there). `shapegrasp` fills",
    "those slots with its top-down grasp at the part's centroid; its planned contacts are where its pads first meet",
    "the surface, and a grasp whose pads pass above a low part touches nothing and fails Part Sel. (runs before",
    "docs/results/shapegrasp-contacts.md credited it with the face nearest the grasp origin). `seggrasp` abstains",
    "there. The graspable-request columns compare both where a grasp on the part exists.",
]

if __name__ == "__main__":
    sys.exit(main())
