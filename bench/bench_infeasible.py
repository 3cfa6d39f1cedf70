"""The feasibility judgement checked in the twin (issue 36): requests judged infeasible, executed anyway.

    python bench/bench_infeasible.py [--robots ur5,panda] [--seeds 0-4] [--objects knife_chef,scissors_office]
        [--out docs/results/infeasible-requests.md]

For every twin object (default: the whole twin), seed and robot system, the cell and the episode are built as
`python -m sim.evaluate --embodiment arm --robots ROBOT` builds them (`sim.evaluate.runner.subject_of`, the run's
scene seed, the hand's sampler at the hand's grip force) and every prompt is judged on the oracle's plan
(`Episode.feasibility`: the true part). For each request judged infeasible, the best grasp of a relaxed sampler
(`relaxed_config`: a pinch may touch the part over `RELAXED_PINCH_BAND` of its pads, the contact distance may come
within `RELAXED_WIDTH_MARGIN` of the stroke, the fingers as close to the table as the cell lets them, a sweep's pads
may meet surface up to `RELAXED_FACING_DEG` off, pinches may tilt `RELAXED_PINCH_TILT_DEG`, twice the surface
samples) whose two planned contacts lie on the part - what its pads press on is ignored - is executed anyway
from a reset of the scene: the first of the best `MIN_REACH_DEPTH` the cell would execute (`Episode.reaches`),
scored as the benchmark scores a slot (`Episode.execute`: lifted AND the pads touched mostly the part).

The check: per robot, requests lifted by the part / requests judged infeasible < `THRESHOLD` (a request with no
relaxed candidate, or none the cell reaches, counts as not lifted; both are reported). The output file is rewritten
by the command (atomically), with the command, the date and the commit.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_lab import commit
from seggrasp.episode import MIN_REACH_DEPTH, Episode, EpisodeSettings, Slot, table_plane_in_object_frame
from seggrasp.grasp.antipodal import AntipodalConfig, AntipodalSampler
from seggrasp.grasp.footprint import PadFootprint
from seggrasp.grasp.pads import box_corners, pad_bands
from seggrasp.grasp.select import assign_parts
from seggrasp.hands import ROBOTIQ_2F85, Hand
from seggrasp.io import atomic_write_text
from seggrasp.objects import asset_ids, load_asset
from sim.grasp_primitive import GraspSettings

DEFAULT_OUT = Path("docs/results/infeasible-requests.md")
#: The check: lifted by the part in fewer than this share of the requests judged infeasible.
THRESHOLD = 0.05
#: The relaxed sampler (the strict defaults: `AntipodalConfig`).
RELAXED_PINCH_BAND = 0.0  # m of pad on the part's side a pinch needs (strict: pinch_min_band, 0.5 mm)
RELAXED_WIDTH_MARGIN = 0.001  # m below the stroke the contact distance must stay (strict: the hand's width_margin)
RELAXED_FACING_DEG = 30.0  # a level or envelope pose's pads may meet surface this far off (strict: 18 deg)
RELAXED_PINCH_TILT_DEG = 20.0  # a pinch may come this far off straight down (strict: 10 deg)
RELAXED_SAMPLES = 2  # times the strict sampler's surface samples
#: Surface points the pad band of an executed grasp is measured on.
BAND_SAMPLES = 20000
#: A strict grasp within this distance (m) and angle (deg, approach and closing axes) is the same grasp.
STRICT_MATCH = (0.001, 5.0)
#: How low the relaxed sampler's hand may come to the table (`relaxed_config`).
CLEARANCES = ("cell", "sampler")
#: The reason kinds, by how `seggrasp.grasp.feasibility` words each sentence after "<part>: ".
REASON_KINDS = (
    ("no face", "no face of the mesh"),
    ("weight turns it", "wherever the pads hold it"),
    ("pads' share", "the pads press on it"),
    ("pads land elsewhere", "where the pads' footprint is mostly on it"),
    ("pads' ends", "where the pads press on it, they first land on it at most"),
    ("too low", "stands at most"),
    ("lies flat", "lies flat"),
    ("too wide", "narrowest section"),
    ("no pose", "no collision-free pose"),
)


@dataclass
class Request:
    """One judged request (object, part, robot, seed) and, when judged infeasible, what executing it anyway gave."""

    object_id: str
    category: str
    part: str
    robot: str
    seed: int
    feasible: bool
    reason: str = ""
    candidates: int = 0  # relaxed grasps with both planned contacts on the part
    checked: int = 0  # of them, how many were checked for reach before one was reachable (or all checked)
    executed: bool = False  # one was reachable and executed
    refusal: str = ""  # why the cell refuses the best one, when it refuses all checked
    lifted: bool = False
    by_part: bool = False  # lifted and the pads touched mostly the part: the benchmark's success
    failure: str = ""
    width: float | None = None
    tilt_deg: float | None = None  # the approach's angle from straight down
    contact_height: float | None = None  # the planned contacts' mean height above the table (m)
    # the executed grasp measured against the strict judgement (`Diagnosis`)
    share: float | None = None  # the smaller share of the part its two pads press on (the judgement's)
    band: float | None = None  # how far along the pads the surface they close on reaches (m, the smaller pad)
    tip_clearance: float | None = None  # the lowest finger box corner above the table at the pre-grasp opening (m)
    in_strict: bool | None = None  # the strict sampler has a grasp on the part at (nearly) the same pose
    checked_index: int = -1  # the executed grasp's index among the relaxed sampler's

    @property
    def kind(self) -> str:
        return reason_kind(self.reason) if not self.feasible else ""

    def strict_limits_broken(self, hand: Hand, footprint_share: float) -> list[str]:
        """Which of the strict judgement's limits the executed grasp breaks (module doc; the margins of `hand`'s
        sampler, the footprint's `footprint_share`): a guide to which relaxation made it."""
        strict, broken = AntipodalConfig.for_hand(hand), []
        if self.share is not None and self.share < footprint_share:
            broken.append(f"pads' share {100 * self.share:.0f} % < {100 * footprint_share:.0f} %")
        widest = strict.widest_contact_distance(hand)
        if self.width is not None and self.width > widest:
            broken.append(f"width {1000 * self.width:.1f} mm > {1000 * widest:.0f} mm")
        if self.tip_clearance is not None and self.tip_clearance < strict.table_clearance:
            # a pose as low as a pinch: the pinch's limits hold for it
            if self.tip_clearance < strict.pinch_table_clearance:
                broken.append(f"fingertips {1000 * self.tip_clearance:.1f} mm < "
                              f"{1000 * strict.pinch_table_clearance:.1f} mm above the table")
            if self.band is not None and self.band < strict.pinch_min_band:
                broken.append(f"pad band {1000 * self.band:.1f} mm < {1000 * strict.pinch_min_band:.1f} mm")
            if self.tilt_deg is not None and self.tilt_deg > strict.pinch_max_tilt_deg:
                broken.append(f"pinch tilt {self.tilt_deg:.0f} deg > {strict.pinch_max_tilt_deg:g} deg")
        return broken


def reason_kind(reason: str) -> str:
    """The kind of a judgement's reason sentence (`REASON_KINDS`; "other" for a wording this script does not know)."""
    text = reason.split(": ", 1)[-1]
    return next((kind for kind, start in REASON_KINDS if text.startswith(start)), "other")


def relaxed_config(hand: Hand, grip_force: float, clearance: str = "cell") -> AntipodalConfig:
    """The relaxed sampler's parameters for `hand`: the strict sampler's (`AntipodalConfig.for_hand`) with the margins
    the judgement rests on loosened; `clearance` "cell": the table clearances down to the least the twin's cell
    allows (`sim.grasp_primitive.GraspSettings`: fingertips `fingertip_table_clearance` above the table, the rest
    `table_clearance`), "sampler": the strict sampler's own."""
    if clearance not in CLEARANCES:
        raise ValueError(f"clearance must be one of {CLEARANCES}, got {clearance!r}")
    strict, cell = AntipodalConfig.for_hand(hand, grip_force=grip_force), GraspSettings()
    tables = {"pinch_table_clearance": cell.fingertip_table_clearance, "table_clearance": cell.table_clearance}
    if clearance == "sampler":
        tables = {"pinch_table_clearance": strict.pinch_table_clearance, "table_clearance": strict.table_clearance}
    return AntipodalConfig.for_hand(
        hand, grip_force=grip_force, pinch_min_band=RELAXED_PINCH_BAND, width_margin=RELAXED_WIDTH_MARGIN,
        level_facing_deg=RELAXED_FACING_DEG, pinch_max_tilt_deg=RELAXED_PINCH_TILT_DEG,
        n_surface_samples=RELAXED_SAMPLES * strict.n_surface_samples, **tables)


def episode_of(cell, object_id: str, robot: str, seed: int, model) -> Episode:
    """The oracle's episode of one object at one run seed on `cell`, built as `sim.evaluate.runner.run_object`
    builds it for `--embodiment arm --robots ROBOT` (no detector: only the oracle plans)."""
    from sim.evaluate.config import RunConfig
    from sim.evaluate.runner import subject_of

    config = RunConfig(methods=["oracle"], objects=[object_id], embodiment="arm", seeds=[seed], robots=[robot])
    context, truth = subject_of(object_id, config, cell, model)
    settings = EpisodeSettings(seed=config.seed, top_k=config.top_k, decomposition_seed=config.decomposition_seed)
    sampler = AntipodalSampler(AntipodalConfig.for_hand(cell.hand, grip_force=config.hand_grip_force), cell.hand)
    return Episode(cell, context, None, truth, settings, generator=sampler)


def judge_episode(episode: Episode, robot: str, grip_force: float, clearance: str = "cell") -> list[Request]:
    """Every prompt of the episode judged on the oracle's plan; each infeasible one executed anyway (module doc)."""
    context = episode.context
    plan = episode.plan("oracle")
    indices = episode.target_indices(None)
    judged = episode.feasibility(plan, indices)
    requests = [Request(context.object_id, context.category, context.prompts[k], robot, episode.settings.seed,
                        judged[k].feasible, judged[k].reason) for k in indices]
    infeasible = [k for k in indices if not judged[k].feasible]
    if not infeasible:
        return requests
    o = episode.observation
    plane = table_plane_in_object_frame(o.mesh, o.T_world_obj)
    sampler = AntipodalSampler(relaxed_config(episode.hand, grip_force, clearance), episode.hand)
    relaxed = sampler.generate(o.mesh, seed=episode.settings.seed, table_plane=plane,
                               center_of_mass=context.center_of_mass, mass=context.mass)  # sorted best first
    parts = assign_parts(relaxed, o.mesh, episode.truth_on_mesh) if len(relaxed) else np.zeros(0, dtype=np.int64)
    world = relaxed.transformed(o.T_world_obj)
    diagnosis = None
    for k in infeasible:
        execute_anyway(episode, requests[k], k, world, np.flatnonzero(parts == k), plane)
        if requests[k].executed:
            diagnosis = diagnosis or Diagnosis(episode, plane)
            diagnosis.measure(requests[k], relaxed.subset([requests[k].checked_index]), k)
    return requests


class Diagnosis:
    """Measures an executed relaxed grasp (object frame) against the strict judgement of its episode: the share of
    the part its pads press on (`PadSurface.part_shares`), the pad band, the fingers' lowest point above the table,
    and whether the strict sampler has a grasp on the part within `STRICT_MATCH` of its pose."""

    def __init__(self, episode: Episode, plane: np.ndarray) -> None:
        self.episode, self.plane = episode, plane
        mesh = episode.observation.mesh
        self.surface = replace(episode.footprint, margin=0.0).on(mesh)  # the judgement's bare pads
        self.cloud, _ = trimesh.sample.sample_surface(mesh, BAND_SAMPLES, seed=0)
        strict = episode.grasps()
        self.strict, self.strict_parts = strict, assign_parts(strict, mesh, episode.truth_on_mesh)

    def measure(self, request: Request, grasp, k: int) -> None:
        hand, labels = self.episode.hand, self.episode.truth_on_mesh
        request.share = float(self.surface.part_shares(grasp, labels == k)[0].min())
        opening = hand.pre_grasp_opening(grasp.widths)
        request.band = float(pad_bands(grasp.poses, opening, self.cloud, hand.pad_half_width, hand.pad_half_length,
                                       AntipodalConfig().pinch_band_tolerance)[0])
        pose = grasp.poses[0]
        corners = box_corners(hand.boxes(float(opening[0]))) @ pose[:3, :3].T + pose[:3, 3]
        request.tip_clearance = float((corners @ self.plane[:3] + self.plane[3]).min())
        same = self.strict.poses[self.strict_parts == k]
        close = np.linalg.norm(same[:, :3, 3] - pose[:3, 3], axis=1) <= STRICT_MATCH[0]
        cos = np.cos(np.deg2rad(STRICT_MATCH[1]))
        close &= (same[:, :3, 2] @ pose[:3, 2] >= cos) & (np.abs(same[:, :3, 0] @ pose[:3, 0]) >= cos)
        request.in_strict = bool(close.any())


def execute_anyway(episode: Episode, request: Request, k: int, world, on_part: np.ndarray, plane: np.ndarray) -> None:
    """Execute the first of the best `MIN_REACH_DEPTH` grasps `on_part` (indices into `world`, best first) that the
    cell would execute, from a reset; fill `request` with what it gave."""
    request.candidates = len(on_part)
    for i in on_part[:MIN_REACH_DEPTH]:
        request.checked += 1
        if episode.reaches(world.poses[i], float(world.widths[i])):
            request.checked_index = int(i)
            break
    else:
        if len(on_part):  # why the cell refuses the best one, in the scene as reset
            cell, context = episode.cell, episode.context
            cell.reset(seed=context.scene_seed, object_id=context.object_id)
            request.refusal = cell.check_reach(world.poses[on_part[0]], float(world.widths[on_part[0]]))
        return
    record = episode.execute(Slot("oracle", "relaxed", k, 0, world.subset([i]), len(on_part)))
    T_obj = episode.observation.T_world_obj
    contacts = (world.contacts[i] - T_obj[:3, 3]) @ T_obj[:3, :3]  # back into the object frame, where `plane` is
    request.executed, request.lifted, request.by_part = True, record.lifted, bool(record.success)
    request.failure = record.failure or ("" if record.success else "not scored")
    request.width = float(world.widths[i])
    request.tilt_deg = float(np.degrees(np.arccos(np.clip(-world.poses[i, 2, 2], -1.0, 1.0))))
    request.contact_height = float(np.mean(contacts @ plane[:3] + plane[3]))


def run(objects: list[str], robots: list[str], seeds: list[int], progress=None, clearance: str = "cell"
        ) -> list[Request]:
    """The requests of every object, robot and seed (module doc; `clearance`: `relaxed_config`'s); `progress` (a
    callable) sees each episode's requests and its seconds."""
    from sim.cell import SimCell
    from sim.evaluate.config import RunConfig
    from sim.gripper import GripperSettings

    requests: list[Request] = []
    for robot in robots:
        config = RunConfig(methods=["oracle"], objects=objects, embodiment="arm", seeds=seeds, robots=[robot])
        force = config.hand_grip_force  # the run's default: the hand's own
        for object_id in objects:
            model = load_asset(object_id)
            with SimCell([model], embodiment="arm", seed=seeds[0], robot=robot,
                         gripper=GripperSettings(grip_force=force, hand=config.hand)) as cell:
                for seed in seeds:
                    started = time.perf_counter()
                    judged = judge_episode(episode_of(cell, object_id, robot, seed, model), robot, force, clearance)
                    requests += judged
                    if progress is not None:
                        progress(judged, time.perf_counter() - started)
    return requests


@dataclass
class Counts:
    """What a group of requests gave."""

    judged: int = 0
    infeasible: int = 0
    no_candidate: int = 0
    candidate: int = 0
    reachable: int = 0
    lifted: int = 0
    by_part: int = 0

    def add(self, r: Request) -> None:
        self.judged += 1
        if r.feasible:
            return
        self.infeasible += 1
        self.no_candidate += r.candidates == 0
        self.candidate += r.candidates > 0
        self.reachable += r.executed
        self.lifted += r.lifted
        self.by_part += r.by_part

    @property
    def share(self) -> float:
        """Lifted by the part / judged infeasible (0 when none was judged infeasible)."""
        return self.by_part / self.infeasible if self.infeasible else 0.0

    def cells(self) -> str:
        return (f"{self.infeasible} | {self.no_candidate} | {self.candidate} | {self.reachable} | {self.lifted} | "
                f"{self.by_part}")


def counts_by(requests: list[Request], key) -> dict:
    """`Counts` per `key(request)` (first-seen order)."""
    groups: dict = {}
    for r in requests:
        groups.setdefault(key(r), Counts()).add(r)
    return groups


COUNT_HEADER = ("infeasible | no relaxed candidate on the part | relaxed candidate | reachable, executed | lifted "
                "(any part) | lifted by the part")


def report(requests: list[Request], robots: list[str], command: str, seconds: float, load: str,
           clearance: str = "cell") -> list[str]:
    """The Markdown report of the requests (module doc; `clearance`: the relaxed sampler's, `relaxed_config`)."""
    config = relaxed_config(ROBOTIQ_2F85, ROBOTIQ_2F85.default_grip_force, clearance)
    strict = AntipodalConfig()
    hands = _hands()

    def per_robot(metres: str, digits: int) -> str:  # a hand's number, in mm, for each robot
        return ", ".join(f"{1000 * getattr(hands[robot], metres):.{digits}f} mm for the {robot}" for robot in robots)

    pinches, margins = per_robot("pinch_table_clearance", 1), per_robot("width_margin", 0)
    lines = [
        "# Requests judged infeasible, executed anyway", "",
        f"`{command}`", "",
        (f"Written {datetime.now(UTC):%Y-%m-%d %H:%M} UTC at commit {commit()}; {seconds / 60:.1f} min, "
         f"{load}."), "",
        ("Issue 36: validate the feasibility judgement (`seggrasp.grasp.feasibility`) on the oracle. Every prompt of "
        "every object is judged as the benchmark's episode judges it (the true part, the hand's own sampler's "
        "candidates). For each request judged infeasible, the best grasp of a relaxed sampler with both planned "
        "contacts on the part (the pads' footprint share ignored) is executed anyway from a reset: the first of "
        f"its best {MIN_REACH_DEPTH} the cell would execute, scored as a benchmark slot (lifted and the pads touched "
        "mostly the part). The relaxed sampler, against the strict one: a pinch needs "
        f"{1000 * config.pinch_min_band:.1f} mm of pad on the part (strict {1000 * strict.pinch_min_band:.1f} mm); "
        f"the contact distance may come within {1000 * config.width_margin:.0f} mm of the stroke (strict: the "
        f"hand's, {margins}); fingertips of a pinch {1000 * config.pinch_table_clearance:.1f} mm "
        f"above the table (strict: the hand's, {pinches}) and the hand of an ordinary grasp "
        f"{1000 * config.table_clearance:.1f} mm (strict {1000 * strict.table_clearance:.1f} mm)"
        + (", the least the cell allows (`sim.grasp_primitive.GraspSettings`)" if clearance == "cell" else "")
        + "; a sweep's pads may meet surface "
        f"{config.level_facing_deg:g} deg off (strict {strict.level_facing_deg:g}); a pinch may tilt "
        f"{config.pinch_max_tilt_deg:g} deg (strict {strict.pinch_max_tilt_deg:g}); "
        f"{RELAXED_SAMPLES} x the surface samples. A request with no relaxed candidate on the part, or none the "
        "cell reaches, counts as not lifted."), "",
        f"## The check: lifted by the part in < {100 * THRESHOLD:.0f} % of the requests judged infeasible", "",
        f"| robot | requests judged | {COUNT_HEADER} | lifted by the part / infeasible | check |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    per_robot = counts_by(requests, lambda r: r.robot)
    for robot in robots:
        c = per_robot.get(robot, Counts())
        verdict = "pass" if c.share < THRESHOLD else "FAIL"
        lines.append(f"| {robot} | {c.judged} | {c.cells()} | {c.by_part}/{c.infeasible} = {100 * c.share:.1f} % | "
                     f"{verdict} |")
    lines += ["", "## Per category and robot", "",
              ("Categories without a request judged infeasible on either robot are left out (their requests are "
               "in the totals above)."), "",
              f"| category | robot | requests judged | {COUNT_HEADER} |", "|---|---|---|---|---|---|---|---|---|"]
    per_category = counts_by(requests, lambda r: (r.category, r.robot))
    shown = sorted({c for (c, _), n in per_category.items() if n.infeasible})
    for category in shown:
        for robot in robots:
            c = per_category.get((category, robot), Counts())
            lines.append(f"| {category} | {robot} | {c.judged} | {c.cells()} |")
    lines += ["", "## Per reason kind and robot", "",
              ("The kind is the judgement's reason: no face labelled; wherever the pads hold it, the weight's "
               "torque about the closing axis exceeds what whole pads hold; pads press on it under the footprint's "
               "share; where they do, their faces first land elsewhere (a prouder neighbour, or only the "
               "fingertips' ends reach it); where they land on it, only on their ends (the pads' ends, the hand's "
               "`pad_end_margin`); too low for a pinch; lying flat (too little side above the "
               "fingertips); narrowest section wider than the stroke allows; no collision-free pose."), "",
              f"| reason | robot | {COUNT_HEADER} |", "|---|---|---|---|---|---|---|---|"]
    infeasible = [r for r in requests if not r.feasible]
    per_kind = counts_by(infeasible, lambda r: (r.kind, r.robot))
    for kind in [k for k, _ in REASON_KINDS] + ["other"]:
        for robot in robots:
            if (kind, robot) in per_kind:
                lines.append(f"| {kind} | {robot} | {per_kind[(kind, robot)].cells()} |")
    lines += ["", "## Per part", "",
              ("Seeds: those the part was judged infeasible at, of the seeds run. Reason: the first such seed's "
               "sentence. Outcomes of the executed relaxed grasps (the cell's failure names; `wrong_part`: lifted "
               "by another part; `success`: lifted by the part)."), "",
              "| object | part | robot | seeds | reason | relaxed candidates (median) | executed | outcomes |",
              "|---|---|---|---|---|---|---|---|"]
    seeds_run = Counter((r.object_id, r.part, r.robot) for r in requests)
    groups: dict[tuple, list[Request]] = defaultdict(list)
    for r in infeasible:
        groups[(r.object_id, r.part, r.robot)].append(r)
    for (object_id, part, robot), rows in groups.items():
        outcomes = Counter("success" if r.by_part else r.failure for r in rows if r.executed)
        refused = Counter("unreachable" if r.refusal.startswith("unreachable") else "collision"
                          for r in rows if r.candidates and not r.executed)
        text = ", ".join(f"{name} x{n}" for name, n in outcomes.most_common())
        text += "; " * bool(text and refused) + ", ".join(f"none reachable ({name}) x{n}" for name, n in refused.items())
        median = int(np.median([r.candidates for r in rows]))
        lines.append(f"| {object_id} | {part} | {robot} | {len(rows)}/{seeds_run[(object_id, part, robot)]} | "
                     f"{rows[0].reason.split(': ', 1)[-1]} | {median} | {sum(r.executed for r in rows)} | "
                     f"{text or '-'} |")
    lifted = [r for r in infeasible if r.by_part]
    lines += ["", "## Lifted by the part", ""]
    if lifted:
        footprint = PadFootprint()
        lines += [("Each executed relaxed grasp that lifted the object by the part, measured against the strict "
                   "judgement: the smaller share of the part its pads press on (under them and where they first "
                   "land, `PadSurface.part_shares`; the judgement needs "
                   f"{100 * footprint.min_share:.0f} %), how far along the pads the surface they close on reaches "
                   "(a pinch needs the strict pinch band), the fingers' lowest point above the table at the "
                   "pre-grasp opening, and whether the strict sampler had a grasp on the part within "
                   f"{1000 * STRICT_MATCH[0]:.0f} mm and {STRICT_MATCH[1]:g} deg of it (then only the pads' share "
                   "kept it from the judgement)."), "",
                  ("| object: part | robot | seed | reason kind | width mm | tilt deg | contacts above the table mm "
                   "| pads' share | pad band mm | fingers above the table mm | strict candidate | strict limits it "
                   "breaks |"), "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        hands = _hands()
        lines += [f"| {r.object_id}: {r.part} | {r.robot} | {r.seed} | {r.kind} | {1000 * r.width:.1f} | "
                  f"{r.tilt_deg:.1f} | {1000 * r.contact_height:.1f} | {100 * r.share:.0f} % | {1000 * r.band:.1f} | "
                  f"{1000 * r.tip_clearance:.1f} | {'yes' if r.in_strict else 'no'} | "
                  f"{'; '.join(r.strict_limits_broken(hands[r.robot], footprint.min_share)) or '-'} |"
                  for r in lifted]
    else:
        lines.append("None: no relaxed grasp of a request judged infeasible lifted the object by the part.")
    return lines


def _hands() -> dict[str, Hand]:
    from sim.cell import ROBOTS

    return dict(ROBOTS)


def parse_arguments(args: argparse.Namespace) -> tuple[list[str], list[str], list[int]]:
    """(objects, robots, seeds) of the command line; ValueError (one sentence) naming a bad one."""
    from sim.cell import ROBOTS
    from sim.evaluate.cli import parse_seeds

    robots = [r.strip() for r in args.robots.split(",") if r.strip()]
    unknown = [r for r in robots if r not in ROBOTS]
    if not robots or unknown:
        raise ValueError(f"--robots {args.robots!r}: use robots of {', '.join(ROBOTS)}, comma-separated")
    known = asset_ids()
    objects = [o.strip() for o in args.objects.split(",") if o.strip()] if args.objects else known
    unknown = [o for o in objects if o not in known]
    if not objects or unknown:
        raise ValueError(f"--objects: {', '.join(unknown) or 'none given'} not in the twin (python -m assets lists it)")
    for option, values in (("--robots", robots), ("--objects", objects)):
        if len(set(values)) != len(values):
            raise ValueError(f"{option} lists an entry more than once; give each once")
    return objects, robots, parse_seeds(args.seeds)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", default="ur5,panda", help="comma-separated robot systems (sim.cell.ROBOTS)")
    parser.add_argument("--seeds", default="0-4", help="run seeds: 0-4, 0,3 or a mix")
    parser.add_argument("--objects", default="", help="comma-separated twin objects (default: the whole twin)")
    parser.add_argument("--clearance", choices=CLEARANCES, default="cell",
                        help="how low the relaxed sampler's hand may come to the table: the least the cell allows "
                             "(default) or the strict sampler's own")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    try:
        objects, robots, seeds = parse_arguments(args)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    load = f"load average {os.getloadavg()[0]:.1f} before the run on {os.cpu_count()} cores"
    started = time.perf_counter()

    def progress(judged: list[Request], seconds: float) -> None:
        r = judged[0]
        marks = ", ".join(f"{x.part}: {x.kind} -> " + ("lifted by the part" if x.by_part else x.failure or
                          ("no candidate" if not x.candidates else "none reachable")) for x in judged if not x.feasible)
        print(f"{r.robot} {r.object_id} seed {r.seed}: {len(judged)} requests, {seconds:.1f} s"
              + (f"; infeasible {marks}" if marks else ""), flush=True)

    requests = run(objects, robots, seeds, progress, args.clearance)
    options = [f"--robots {','.join(robots)}", f"--seeds {args.seeds}"]
    options += [f"--objects {','.join(objects)}"] if args.objects else []
    options += [f"--clearance {args.clearance}"] if args.clearance != "cell" else []
    command = "python bench/bench_infeasible.py " + " ".join(options + [f"--out {args.out}"])
    lines = report(requests, robots, command, time.perf_counter() - started, load, args.clearance)
    atomic_write_text(args.out, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
