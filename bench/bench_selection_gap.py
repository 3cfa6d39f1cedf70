"""Why `seggrasp` chooses grasps off the named part on requests the oracle can grasp, and what selection changes do.

Reads one `python -m sim.evaluate` run folder (its trials.jsonl and segmentations.jsonl, and its vote cache) and
writes docs/results/selection-gap.md (or `--out`):

    python bench/bench_selection_gap.py --run /tmp/lead/s5 --cache /tmp/select/gap --out docs/results/selection-gap.md

Step 1 (`--cache`): every (seed, object) of the run is rebuilt without physics (scene, planning mesh, the run's
cached coarse votes, the decomposition sweep, the grasp candidates) and kept as a pickle of plain arrays, so the
analysis reruns in seconds. The rebuilt `seggrasp` selection is checked slot by slot against the run's records.
`--detector hard --votes DIR` rebuilds the same scenes with another detector preset (votes computed and cached in
DIR): the held-out check.

Step 2: on the slots the oracle executes (its top-k from the same candidates, restricted to grasps whose two
contacts lie on the true part), every slot `seggrasp` loses is given one cause (table "Where the slots go").

Step 3: variants of the selection (evidence and ranking), each as Part Sel. over all slots from planned contacts
(the benchmark's own test) per seed, and its paired difference to the run's policy over requests
(seed, object, prompt) with the standard error, split into the seeds used to choose (`--tune-seeds`) and the rest.
The baseline is the diagnosed run's policy (`BASELINE_REGION`), checked against its records slot by slot.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from collections import Counter, defaultdict
from pathlib import Path
from typing import Callable

import numpy as np

TOP_K = 10
#: The region of the diagnosed run's PartPolicy (main at the time of /tmp/lead/s5): the baseline of every difference,
#: pinned so that the report does not change when PartPolicy's default does.
BASELINE_REGION = 0.65


def collect(run: Path, cache: Path, seeds: list[int], detector: str | None, votes: Path | None) -> None:
    """Rebuild every (seed, object) of `run` and pickle its planning inputs under `cache` (skips existing ones)."""
    from seggrasp.episode import Episode, EpisodeSettings
    from sim.cell import SimCell
    from sim.evaluate.config import RunConfig
    from sim.evaluate.records import VoteCache
    from sim.evaluate.runner import subject_of

    info = json.loads((run / "run.json").read_text())
    votes = votes or run / "cache"
    cache.mkdir(parents=True, exist_ok=True)
    for seed in seeds:
        config = RunConfig(methods=["seggrasp"], objects=info["objects"], detector=detector or info["detector"],
                           embodiment=info["embodiment"], seeds=[seed], top_k=info["top_k"],
                           decomposition_seed=info["decomposition_seed"])
        with SimCell(embodiment=config.embodiment, seed=seed) as cell:
            for object_id in config.objects:
                path = cache / f"{seed}-{object_id}.pkl"
                if path.exists():
                    continue
                context, truth = subject_of(object_id, config, cell)
                settings = EpisodeSettings(seed=seed, top_k=config.top_k, decomposition_seed=config.decomposition_seed)
                episode = Episode(cell, context, config.object_detector(object_id), truth, settings,
                                  vote_cache=VoteCache(votes / object_id))
                mesh, grasps = episode.observation.mesh, episode.grasps()
                record = dict(seed=seed, object_id=object_id, prompts=list(context.prompts),
                              vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces),
                              coarse=episode.coarse_scores(), truth=episode.truth_on_mesh,
                              partitions=[(p.threshold, p.part_of_face) for p in episode.segmenter.partitions()],
                              grasps=(grasps.poses, grasps.widths, grasps.scores, grasps.contacts))
                tmp = path.with_suffix(".tmp")
                tmp.write_bytes(pickle.dumps(record))
                tmp.replace(path)
                print(f"collected: seed {seed} {object_id}", file=sys.stderr, flush=True)


def load_object(path: Path) -> dict:
    """One collected (seed, object) with what every variant needs: contact faces, footprints, evidence, truth."""
    import scipy.sparse as sp
    import trimesh
    from scipy.spatial import cKDTree

    from seggrasp.decompose.mapping import Partition
    from seggrasp.grasp import GraspSet
    from seggrasp.grasp.policy import PartPolicy
    from seggrasp.grasp.select import contact_faces
    from seggrasp.method import ObjectSegmenter

    record = pickle.loads(path.read_bytes())
    mesh = trimesh.Trimesh(record["vertices"], record["faces"], process=False)
    grasps = GraspSet(*record["grasps"])
    partitions = [Partition(t, p) for t, p in record["partitions"]]
    segmenter = ObjectSegmenter(mesh, record["prompts"], None, "cached", coarse_scores=record["coarse"],
                                partitions=partitions)
    plan = segmenter.plan("seggrasp", np.eye(4))
    n_prompts = len(record["prompts"])
    obj = dict(seed=record["seed"], object_id=record["object_id"], prompts=record["prompts"], truth=record["truth"],
               coarse=segmenter.coarse_scores(), refined=segmenter.refined_scores("full"), labels=plan.labels,
               areas=mesh.area_faces, centres=mesh.triangles_center, partitions=partitions, n=len(grasps),
               scores=grasps.scores, footprints={})
    if len(grasps) == 0:
        obj["baseline"] = [np.zeros(0, dtype=np.int64)] * n_prompts
        return obj
    obj["faces"] = contact_faces(grasps, mesh)
    run_policy = PartPolicy(footprint_radius=plan.policy.footprint_radius, region_fraction=BASELINE_REGION,
                            min_probability=plan.policy.min_probability)
    obj["baseline"] = run_policy.select(grasps, mesh, plan.face_probabilities, TOP_K)
    tree = cKDTree(mesh.triangles_center)
    for radius in (0.008, 0.012):
        rows, cols = [], []
        for i, (near, face) in enumerate(zip(tree.query_ball_point(grasps.contacts.reshape(-1, 3), radius),
                                             obj["faces"].reshape(-1))):
            under = [*near, face]
            rows += [i] * len(under)
            cols += under
        rows, cols = np.asarray(rows), np.asarray(cols)
        obj["footprints"][radius] = sp.csr_matrix((mesh.area_faces[cols], (rows, cols)), shape=(2 * len(grasps),
                                                                                            len(mesh.faces)))
    return obj


def load_objects(cache: Path, seeds: set[int] | None = None) -> list[dict]:
    """Every collected object under `cache` (only `seeds` if given), ordered by seed and object."""
    paths = sorted(cache.glob("*.pkl"))
    if not paths:
        raise FileNotFoundError(f"{cache}: nothing collected (run with --collect first)")
    objects = []
    for path in paths:
        if seeds is None or int(path.name.split("-", 1)[0]) in seeds:
            objects.append(load_object(path))
            print(f"loaded: {path.name}", file=sys.stderr, flush=True)
    return objects


# --- the selection variants -------------------------------------------------------------------------------------

def evidence(obj: dict, names: tuple[str, ...] = ("geofusion", "votes", "anchored")) -> list[np.ndarray]:
    """The (F, P) evidence matrices of `seggrasp` (GeoFusion scores, coarse votes, anchored labels) and the priors."""
    from seggrasp.grasp.policy import one_hot

    n_prompts = len(obj["prompts"])
    named = {"geofusion": lambda: obj["refined"], "votes": lambda: obj["coarse"],
             "anchored": lambda: one_hot(obj["labels"], n_prompts),
             "part prior": lambda: part_prior(obj, gated=False),
             "gated part prior": lambda: part_prior(obj, gated=True),
             "gated part prior, 2 levels": lambda: part_prior(obj, gated=True, levels=2)}
    return [named[n]() for n in names]


def part_prior(obj: dict, gated: bool, levels: int = 1) -> np.ndarray:
    """(F, P) one-part-per-prompt prior: on the `levels` coarsest decompositions with a part per prompt, each
    prompt's assigned part (ShapeGrasp's assignment of the coarse votes' part distributions); `gated`: only the
    prompts `seggrasp.fusion.competing_prompts` lets compete (issue 15's evidence gate)."""
    from seggrasp.fusion import (ANCHOR_MIN_RATIO, assign_parts_to_prompts, coarsest_with_parts, competing_prompts,
                                 part_mean_scores)

    n_prompts, partitions = len(obj["prompts"]), obj["partitions"]
    chosen = sorted((p for p in partitions if p.n_parts >= n_prompts), key=lambda p: -p.threshold)[:levels]
    prior = np.zeros((len(obj["areas"]), n_prompts))
    for partition in chosen or [coarsest_with_parts(partitions, n_prompts)]:
        means = part_mean_scores(obj["coarse"], partition.part_of_face, obj["areas"])
        shares = means / np.maximum(means.sum(axis=1, keepdims=True), 1e-18)
        prompts = np.flatnonzero(competing_prompts(shares, ANCHOR_MIN_RATIO if gated else 0.0))
        for k, part in zip(prompts, assign_parts_to_prompts(shares[:, prompts]) if len(prompts) else []):
            if part >= 0:
                prior[partition.part_of_face == part, k] += 1.0
    return prior


def pad_probabilities(obj: dict, face_probs: np.ndarray, radius: float = 0.008, core: bool = False) -> np.ndarray:
    """(N, 2, P) per contact the area-weighted mean of `face_probs` under the pad's footprint (as
    `seggrasp.grasp.policy.pad_probabilities`), or with `core` the least probable face under it."""
    footprint = obj["footprints"][radius]
    if not core:
        weight = np.asarray(footprint.sum(axis=1)).ravel()
        pads = footprint @ face_probs / np.maximum(weight, 1e-18)[:, None]
    else:
        coo = footprint.tocoo()
        pads = np.full((footprint.shape[0], face_probs.shape[1]), np.inf)
        np.minimum.at(pads, coo.row, face_probs[coo.col])
    return pads.reshape(obj["n"], 2, -1)


def label_depth(obj: dict, k: int) -> np.ndarray:
    """(F,) distance from each face labelled `k` (anchored labels) to the nearest face labelled otherwise (0 off)."""
    from scipy.spatial import cKDTree

    inside = obj["labels"] == k
    depth = np.zeros(len(inside))
    if inside.any() and (~inside).any():
        depth[inside] = cKDTree(obj["centres"][~inside]).query(obj["centres"][inside])[0]
    return depth


def policy_variant(
    names=("geofusion", "votes", "anchored"), radius=0.008, core=False, balance=False, share=False, depth=None,
    region=BASELINE_REGION, min_probability=0.05, geometric=False,
) -> Callable[[dict], list[np.ndarray]]:
    """A selection that differs from the run's `PartPolicy` in the named ingredient(s): evidence `names`,
    footprint `radius`, `core` (least probable face under the pad instead of the mean), `balance` (each prompt's
    face probabilities divided by its object-wide mean, then renormalised per face), `share` (rank by the share of
    p_on among the prompts: a grasp belongs to one part), `depth` (p_on times min(1, depth inside the prompt's
    labelled region / depth)), `region` and `min_probability` (`PartPolicy`'s), `geometric` (the evidence
    pooled by the geometric mean of its shares, each mixed with 10 % of the uniform distribution, instead of the mean:
    one source that denies a face the prompt vetoes it)."""
    from seggrasp.fusion import row_shares
    from seggrasp.grasp.policy import PartPolicy, face_part_probabilities

    policy = PartPolicy(region_fraction=region, min_probability=min_probability)

    def select(obj: dict) -> list[np.ndarray]:
        probs = face_part_probabilities(evidence(obj, names))
        if geometric:
            shares = [0.9 * row_shares(e) + 0.1 / len(obj["prompts"]) for e in evidence(obj, names)]
            probs = row_shares(np.exp(np.mean(np.log(shares), axis=0)))
        if balance:
            mean = obj["areas"] @ probs / obj["areas"].sum()
            probs = row_shares(probs / np.where(mean > 0, mean, np.inf))
        pads = pad_probabilities(obj, probs, radius, core)
        p_on = pads[:, 0] * pads[:, 1]
        if share:
            total = p_on.sum(axis=1, keepdims=True)
            p_on = np.divide(p_on, total, out=np.zeros_like(p_on), where=total > 0)
        chosen = []
        for k in range(p_on.shape[1]):
            picked = policy.rank(p_on[:, k], obj["scores"], TOP_K)
            if depth is not None:  # the deep grasps first, then the run's order fills the rest
                deep = p_on[:, k] * np.minimum(1.0, label_depth(obj, k)[obj["faces"]].min(axis=1) / depth)
                first = policy.rank(np.where(p_on[:, k] > min_probability, deep, 0.0), obj["scores"], TOP_K)
                picked = np.concatenate([first, [i for i in picked if i not in set(first)]])[:TOP_K].astype(int)
            chosen.append(picked)
        return chosen

    return select


def baseline(obj: dict) -> list[np.ndarray]:
    """The diagnosed run's `seggrasp` selection (seggrasp.method's evidence, PartPolicy with BASELINE_REGION)."""
    return obj["baseline"]


def on_labels(obj: dict, labels: np.ndarray) -> list[np.ndarray]:
    """Label-based selection (`seggrasp.grasp.select.select_per_prompt`): per prompt the best-scored grasps whose
    two contact faces both carry its label."""
    pair = np.asarray(labels)[obj["faces"]]
    out = []
    for k in range(len(obj["prompts"])):
        on = np.flatnonzero((pair == k).all(axis=1))
        out.append(on[np.argsort(-obj["scores"][on], kind="stable")][:TOP_K])
    return out


def oracle(obj: dict) -> list[np.ndarray]:
    """The oracle's selection: on the true labels."""
    return on_labels(obj, obj["truth"])


def coarse(obj: dict) -> list[np.ndarray]:
    """The `coarse` method's selection: on the coarse votes' argmax labels."""
    from seggrasp.vote import labels_from_scores

    return on_labels(obj, labels_from_scores(obj["coarse"]))


VARIANTS: dict[str, Callable[[dict], list[np.ndarray]]] = {
    "the run's `seggrasp` (GeoFusion + votes + anchored labels, 8 mm footprint mean, region 0.65)": baseline,
    "+ part-per-prompt prior (ShapeGrasp's assignment of the votes), ungated":
        policy_variant(("geofusion", "votes", "anchored", "part prior")),
    "+ part-per-prompt prior, gated (competing_prompts, ANCHOR_MIN_RATIO)":
        policy_variant(("geofusion", "votes", "anchored", "gated part prior")),
    "+ part-per-prompt prior, gated, 2 coarsest levels":
        policy_variant(("geofusion", "votes", "anchored", "gated part prior, 2 levels")),
    "core over border: least probable face under the pad": policy_variant(core=True),
    "wider footprint (12 mm)": policy_variant(radius=0.012),
    "depth inside the labelled part (p_on x min(1, depth / 5 mm))": policy_variant(depth=0.005),
    "prompt-balanced face probabilities": policy_variant(balance=True),
    "evidence pooled by geometric mean (one source can veto)": policy_variant(geometric=True),
    "a grasp belongs to one part: rank by p_on's share among the prompts": policy_variant(share=True),
    "narrower region (0.8 x best): the tuning seeds' choice": policy_variant(region=0.8),
    "never abstain (min probability 0)": policy_variant(min_probability=0.0),
}


# --- scoring ----------------------------------------------------------------------------------------------------

Requests = dict[tuple, tuple[float, int]]


def score(objects: list[dict], select: Callable[[dict], list[np.ndarray]]) -> Requests:
    """(seed, object, prompt) -> (Part Sel. over the top-k slots from planned contacts, executed slots)."""
    out = {}
    for obj in objects:
        chosen = select(obj) if obj["n"] else [np.zeros(0, dtype=np.int64)] * len(obj["prompts"])
        for k, prompt in enumerate(obj["prompts"]):
            on = (obj["truth"][obj["faces"][chosen[k]]] == k).all(axis=1).sum() if len(chosen[k]) else 0
            out[(obj["seed"], obj["object_id"], prompt)] = (float(on) / TOP_K, len(chosen[k]))
    return out


def paired(a: Requests, b: Requests, keys: list[tuple]) -> str:
    """Mean of a - b in Part Sel. over `keys`, its standard error and normal 95 % interval, and the count."""
    d = np.array([a[k][0] - b[k][0] for k in keys])
    if len(d) < 2:
        return "—"
    mean, se = d.mean(), d.std(ddof=1) / np.sqrt(len(d))
    return f"{mean:+.3f} ± {se:.3f} [{mean - 1.96 * se:+.3f}, {mean + 1.96 * se:+.3f}], n={len(d)}"


def check_against_records(objects: list[dict], trials: Path) -> tuple[int, int]:
    """(matching, total) slots where the rebuilt `seggrasp` selection gives the run's contacts_on_part and
    number of candidates."""
    wanted = {(o["seed"], o["object_id"]) for o in objects}
    recorded = {}
    with trials.open() as f:
        for line in f:
            r = json.loads(line)
            if r["method"] == "seggrasp" and (r["seed"], r["object_id"]) in wanted:
                recorded[(r["seed"], r["object_id"], r["prompt"], r["rank"])] = r
    match = total = 0
    for obj in objects:
        for k, prompt in enumerate(obj["prompts"]):
            chosen = obj["baseline"][k]
            for rank in range(TOP_K):
                r = recorded.get((obj["seed"], obj["object_id"], prompt, rank))
                if r is None:
                    continue
                on = rank < len(chosen) and bool((obj["truth"][obj["faces"][chosen[rank]]] == k).all())
                total += 1
                match += on == bool(r["contacts_on_part"]) and len(chosen) == r["n_candidates"]
    return match, total


# --- diagnosis ----------------------------------------------------------------------------------------------------

EVIDENCE_STATES = {
    "A": "labels miss the part: every on-part candidate has p_on <= min probability",
    "B": "labels put the prompt elsewhere: best on-part p_on < 0.65 x the request's best",
    "C": "the probable region holds on- and off-part grasps; generator order picks off-part ones",
}


def prompt_iou(obj: dict, k: int) -> float:
    """Area-weighted IoU of prompt `k`'s (anchored) labels with its true part."""
    truth, label, area = obj["truth"] == k, obj["labels"] == k, obj["areas"]
    return float(area[truth & label].sum() / max(area[truth | label].sum(), 1e-18))


def diagnose(objects: list[dict]) -> tuple[Counter, dict, list]:
    """Slots `seggrasp` loses against the oracle: (kind of slot, evidence state) -> count; per request
    (object, prompt) -> (lost, oracle slots, evidence states, IoUs); and (state, IoU, lost) per request."""
    from seggrasp.grasp.policy import PartPolicy, face_part_probabilities

    policy = PartPolicy(region_fraction=BASELINE_REGION)
    lost_by = Counter()
    per_request: dict[tuple, list] = defaultdict(lambda: [0, 0, Counter(), []])
    for obj in objects:
        if obj["n"] == 0:
            continue
        truth = obj["truth"][obj["faces"]]
        pads = pad_probabilities(obj, face_part_probabilities(evidence(obj)))
        p_on = pads[:, 0] * pads[:, 1]
        for k, (ours, theirs) in enumerate(zip(obj["baseline"], oracle(obj))):
            if len(theirs) == 0:
                continue
            on_part = (truth == k).all(axis=1)
            hits = on_part[ours]
            best_on, best = p_on[on_part, k].max(), p_on[:, k].max()
            state = ("A" if best_on <= policy.min_probability
                     else "B" if best_on < policy.region_fraction * best else "C")
            missing = max(0, len(theirs) - len(ours))
            wrong = len(theirs) - int(hits.sum()) - missing
            lost_by[("no grasp (abstained)", state)] += missing
            if wrong > 0:
                pads_on = (truth[ours[~hits]] == k).sum(axis=1)
                straddle = float((pads_on == 1).mean())
                lost_by[("grasp with one pad on the part (straddles a border)", state)] += wrong * straddle
                lost_by[("grasp with no pad on the part", state)] += wrong * (1 - straddle)
            entry = per_request[(obj["object_id"], obj["prompts"][k])]
            entry[0] += len(theirs) - int(hits.sum())
            entry[1] += len(theirs)
            entry[2][state] += len(theirs) - int(hits.sum())
            entry[3].append(prompt_iou(obj, k))
    return lost_by, per_request


def evidence_bound(objects: list[dict]) -> tuple[Requests, Requests]:
    """Part Sel. if the true parts were known and only named by the method's evidence: each prompt gets the
    oracle's grasps when the true part with the highest mean face probability of the prompt is its own
    (argmax), or when the one-part-per-prompt assignment of those means gives it its own part."""
    from scipy.optimize import linear_sum_assignment

    from seggrasp.grasp.policy import face_part_probabilities

    by_argmax, by_assignment = {}, {}
    for obj in objects:
        probs, area, n_prompts = face_part_probabilities(evidence(obj)), obj["areas"], len(obj["prompts"])
        means = np.array([area[obj["truth"] == j] @ probs[obj["truth"] == j] / max(area[obj["truth"] == j].sum(),
                                                                                  1e-18) for j in range(n_prompts)])
        parts, prompts = linear_sum_assignment(-means)
        assigned = dict(zip(prompts, parts))
        slots = [len(c) for c in oracle(obj)] if obj["n"] else [0] * n_prompts
        for k, prompt in enumerate(obj["prompts"]):
            key = (obj["seed"], obj["object_id"], prompt)
            by_argmax[key] = (slots[k] / TOP_K if means[:, k].argmax() == k else 0.0, 0)
            by_assignment[key] = (slots[k] / TOP_K if assigned.get(k) == k else 0.0, 0)
    return by_argmax, by_assignment


def records_by_category(run: Path) -> list[str]:
    """Table rows from the run's records alone: per category, on the slots the oracle executes, how often
    `seggrasp`'s slot is on the part, has no grasp, and its mean per-prompt IoU (segmentations.jsonl)."""
    slots: dict[str, dict[tuple, dict]] = defaultdict(dict)
    with (run / "trials.jsonl").open() as f:
        for line in f:
            r = json.loads(line)
            if r["method"] in ("seggrasp", "oracle"):
                slots[r["method"]][(r["seed"], r["object_id"], r["prompt"], r["rank"])] = r
    iou = {}
    with (run / "segmentations.jsonl").open() as f:
        for line in f:
            r = json.loads(line)
            if r["method"] == "seggrasp":
                iou.update({(r["seed"], r["object_id"], p): v for p, v in zip(r["prompts"], r["part_ious"])})
    by_category = defaultdict(list)
    for key, r in slots["oracle"].items():
        if r["executed"]:
            ours = slots["seggrasp"][key]
            by_category[r["category"]].append((bool(ours["contacts_on_part"]), not ours["executed"], iou[key[:3]]))
    rows = []
    for category, values in sorted(by_category.items(), key=lambda kv: -sum(not v[0] for v in kv[1])):
        v = np.array(values, dtype=float)
        rows.append(f"| {category} | {len(v)} | {int((1 - v[:, 0]).sum())} | {v[:, 0].mean():.3f} | "
                    f"{v[:, 1].mean():.3f} | {v[:, 2].mean():.2f} |")
    total = np.array([x for values in by_category.values() for x in values], dtype=float)
    rows.append(f"| all | {len(total)} | {int((1 - total[:, 0]).sum())} | {total[:, 0].mean():.3f} | "
                f"{total[:, 1].mean():.3f} | {total[:, 2].mean():.2f} |")
    return rows


def per_seed(requests: Requests, seeds: list[int], column: int = 0) -> list[float]:
    """Mean over each seed's requests (column 0: Part Sel.; 1: executed slots, summed)."""
    values = [[v[column] for k, v in requests.items() if k[0] == s] for s in seeds]
    return [float(np.mean(v)) if column == 0 else float(np.sum(v)) for v in values]


def variant_table(objects: list[dict], tune: set[int]) -> list[str]:
    """Markdown rows: per variant Part Sel. (all slots) per seed, executed slots, and the paired difference to
    the run's selection on the tuning seeds and on the held-out ones."""
    seeds = sorted({o["seed"] for o in objects})
    base = score(objects, baseline)
    tune_keys = sorted(k for k in base if k[0] in tune)
    held_keys = sorted(k for k in base if k[0] not in tune)
    rows = []
    extra = {"`coarse` (labels of the coarse votes)": coarse, "`oracle` (ground-truth labels)": oracle}
    for name, select in {**VARIANTS, **extra}.items():
        result = score(objects, select)
        cells = " / ".join(f"{v:.3f}" for v in per_seed(result, seeds))
        executed = " / ".join(str(int(v)) for v in per_seed(result, seeds, 1))
        rows.append(f"| {name} | {np.mean(per_seed(result, seeds)):.3f} ({cells}) | {executed} | "
                    f"{paired(result, base, tune_keys)} | {paired(result, base, held_keys)} |")
    for name, result in zip(("evidence names the true parts (argmax)", "... one part per prompt (assignment)"),
                            evidence_bound(objects)):
        cells = " / ".join(f"{v:.3f}" for v in per_seed(result, seeds))
        rows.append(f"| bound: {name} | {np.mean(per_seed(result, seeds)):.3f} ({cells}) | — | "
                    f"{paired(result, base, tune_keys)} | {paired(result, base, held_keys)} |")
    return rows


def report(run: Path, objects: list[dict], hard: list[dict], tune: set[int], command: str) -> list[str]:
    """The markdown of docs/results/selection-gap.md."""
    seeds = sorted({o["seed"] for o in objects})
    match, total = check_against_records(objects, run / "trials.jsonl")
    lost_by, per_request = diagnose(objects)
    lines = [*HEADER, "", f"Regenerate: `{command}`", "",
             f"## On the slots the oracle executes, per category (records of {run}, all its seeds)", "",
             "| category | oracle-executed slots | lost by `seggrasp` | `seggrasp` on the part | `seggrasp` no grasp | "
             "mean IoU of the prompt's labels |", "|---|---|---|---|---|---|", *records_by_category(run), "",
             f"## Where the lost slots go (rebuilt without physics, seeds {', '.join(map(str, seeds))})", "",
             f"The rebuilt `seggrasp` selection reproduces the run's records on {match} of {total} slots (same "
             "contacts_on_part and number of candidates). A slot is lost where the oracle has an on-part grasp and "
             "`seggrasp` has none there; the candidate set never lacks on-part grasps on these slots (the oracle "
             "draws from the same candidates). Evidence states:", "",
             *[f"- {s}: {text}" for s, text in EVIDENCE_STATES.items()], "",
             "| lost slot | evidence state | slots | share of lost |", "|---|---|---|---|"]
    total_lost = sum(lost_by.values())
    for (kind, state), n in sorted(lost_by.items(), key=lambda kv: -kv[1]):
        if n > 0:
            lines.append(f"| {kind} | {state} | {n:.0f} | {n / total_lost:.1%} |")
    by_state = Counter()
    for (_, state), n in lost_by.items():
        by_state[state] += n
    lines += ["", "Per evidence state: " + "; ".join(f"{s} {by_state[s]:.0f} ({by_state[s] / total_lost:.0%})"
                                                      for s in sorted(by_state)) + f" of {total_lost:.0f} lost slots.",
              "", "Requests that lose the most (summed over seeds): lost / oracle slots, states, the prompt's label "
              "IoU per seed.", "", "| object | prompt | lost / oracle slots | states | IoU per seed |",
              "|---|---|---|---|---|"]
    for (obj, prompt), (lost, oracle_slots, states, ious) in sorted(per_request.items(), key=lambda kv: -kv[1][0])[:20]:
        lines.append(f"| {obj} | {prompt} | {lost} / {oracle_slots} | "
                     f"{', '.join(f'{s} {n}' for s, n in sorted(states.items()) if n)} | "
                     f"{' / '.join(f'{v:.2f}' for v in ious)} |")
    table_head = ["| selection | Part Sel. all slots: mean (per seed) | executed slots per seed | "
                  "paired diff. to the run's, tuning seeds | paired diff. to the run's, held-out seeds |",
                  "|---|---|---|---|---|"]
    lines += ["", f"## Selection variants, detector `typical` (chosen on seeds {sorted(tune)}, held out: the rest)", "",
              *VARIANT_NOTE, "", *table_head, *variant_table(objects, tune), ""]
    if hard:
        hard_seeds = sorted({o["seed"] for o in hard})
        lines += [f"## Selection variants, detector `hard` (held out; seeds {', '.join(map(str, hard_seeds))})", "",
                  "The run's scenes and grasp candidates with the `hard` preset's coarse votes (computed by",
                  "`--collect-hard`); no physics. The oracle is the same as above.", "",
                  *table_head, *variant_table(hard, set()), ""]
    return lines + FOOTER


HEADER = [
    "# The selection gap: why `seggrasp` grasps off the named part where the oracle can grasp it",
    "",
    "Written by `bench/bench_selection_gap.py` from a `python -m sim.evaluate` run (full twin, arm, 36 objects, 84",
    "prompts, top-10 slots) and its vote cache. The oracle selects, from the same grasp candidates, the best-scored",
    "grasps whose two contacts lie on the true part; where it has none (parts too low or thin for the 2F-85) no",
    "selection can score, so the gap is measured on the slots it executes. Part Sel. here is the benchmark's own",
    "test on planned contacts (no physics needed): both contacts nearest to faces of the prompted part.",
]
VARIANT_NOTE = [
    "Each variant changes one ingredient of the run's policy (seggrasp/grasp/policy.py, seggrasp/method.py);",
    "paired differences are over requests (seed, object, prompt): mean ± standard error [normal 95 % interval].",
    "The two `bound` rows are not selections: they assume the true parts are known and only ask whether the",
    "method's evidence names them right (the prompt's mean face probability is highest on its own part, or the",
    "one-part-per-prompt assignment of those means gives it its own part); then the oracle's grasps count.",
]
FOOTER = [
    "## Reading",
    "",
    "- The lost slots are decided by the evidence more than by the ranking. In states A and B the prompt's",
    "  probability is low on its part or higher elsewhere (the label IoU of those requests is mostly near zero): no",
    "  ranking of the same probabilities finds the part. The `bound` rows go further: with the true parts known and",
    "  only named by the same evidence (per part, or one part per prompt), Part Sel. stays near the run's and far",
    "  below 0.9 x the oracle. Closing the gap needs better evidence (detector, votes, fusion), not a better pick.",
    "- State C: the part's grasps lie in the probable region, but so do grasps on the neighbouring part (a pan's rim",
    "  next to its handle, a bottle's neck under its cap, a kettle's lid on its body), and the generator's order",
    "  prefers those. A narrower region (0.8 x the best p_on) keeps fewer of them. It was the best variant on the",
    "  tuning seeds and the one chosen there; it held on the held-out `typical` seeds, but on the `hard` preset its",
    "  difference is within noise (on `hard` seeds 2-4, the last looked at, it is below the run's), so",
    "  it was not adopted: PartPolicy keeps region 0.65.",
    "- Also not adopted: the part-per-prompt prior (ungated, gated as issue 15 gates soft anchoring, or on two",
    "  levels), the least probable face under the pad (core over border), a wider footprint, the depth inside the",
    "  labelled part, prompt-balanced probabilities, geometric pooling, ranking by the share among prompts: each is",
    "  below or within noise of the run's policy on the tuning seeds.",
    "- 'Never abstain' only fills slots the run leaves empty (it cannot lower Part Sel. or Suc. over all slots), so",
    "  its gain is sure but small; it executes grasps the evidence gives at most a 5 % chance of lying on the part,",
    "  against the issue's 'abstain only when no candidate is plausibly on the part': a decision for the lead.",
]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--run", required=True, type=Path, help="a sim.evaluate output folder (with trials.jsonl)")
    parser.add_argument("--cache", required=True, type=Path, help="folder of the rebuilt objects (pickles)")
    parser.add_argument("--collect", action="store_true", help="rebuild the objects missing from --cache first")
    parser.add_argument("--seeds", help="seeds to collect (default: the run's)")
    parser.add_argument("--tune-seeds", default="0,1", help="the seeds the variants were chosen on")
    parser.add_argument("--hard-cache", type=Path, help="rebuilt objects with the `hard` detector (held out)")
    parser.add_argument("--collect-hard", help="collect --hard-cache for these seeds (votes cached in it)")
    parser.add_argument("--out", default="docs/results/selection-gap.md")
    args = parser.parse_args(argv)
    try:
        if not (args.run / "run.json").is_file() or not (args.run / "trials.jsonl").is_file():
            raise ValueError(f"{args.run}: not a sim.evaluate output folder (needs run.json and trials.jsonl)")
        info = json.loads((args.run / "run.json").read_text())
        seeds = [int(s) for s in args.seeds.split(",")] if args.seeds else [int(s) for s in info["seeds"]]
        tune = {int(s) for s in args.tune_seeds.split(",") if s}
        if args.collect_hard and not args.hard_cache:
            raise ValueError("--collect-hard needs --hard-cache")
    except (ValueError, KeyError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.collect:
        collect(args.run, args.cache, seeds, None, None)
    if args.collect_hard:
        collect(args.run, args.hard_cache, [int(s) for s in args.collect_hard.split(",")], "hard",
                args.hard_cache / "votes")
    try:
        objects = load_objects(args.cache, set(seeds))
        hard = load_objects(args.hard_cache) if args.hard_cache else []
    except FileNotFoundError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    options = [f"--run {args.run}", f"--cache {args.cache}", f"--tune-seeds {args.tune_seeds}"]
    options += [f"--seeds {args.seeds}"] if args.seeds else []
    options += [f"--hard-cache {args.hard_cache}"] if args.hard_cache else []
    command = "python bench/bench_selection_gap.py " + " ".join(options + [f"--out {args.out}"])
    lines = report(args.run, objects, hard, tune, command)
    from seggrasp.io import atomic_write_text

    atomic_write_text(Path(args.out), "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
