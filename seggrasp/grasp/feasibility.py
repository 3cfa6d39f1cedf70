"""Whether a hand can hold a prompted part at all, decided before the robot moves, and why not.

A request is feasible when one of the episode's grasp candidates (the sampler's set, which already keeps only
poses whose width fits the stroke and whose fingers, palm and wrist clear the table and the object; for a part
none of the first draw holds, the part's own first draw too: `Episode.feasibility`) has both
planned contacts on faces of the part AND pads that hold it (`PadSurface.holds`): each presses on the part over at
least the footprint's `min_share`, both of the surface under it and of what its face first lands on, and lands
deeper into the pad than the hand's `pad_end_margin` (`seggrasp.grasp.select.select_per_prompt` with a
`PadFootprint` ranks such a grasp first), AND whose pads can hold the object's weight from turning about the
closing axis even pressing with their whole faces (`whole_pad_torsion_limit`: the gravity torque at the grip force;
the sampler ranks against the narrower line contact of a round part, `AntipodalConfig.torsion_limit`). The share
is measured under the pads themselves: the footprint's `margin` widens them only for ranking (a thin part, an
eyeglass temple, fills none of the widened pads' share yet lifts by it in the twin). When none
does, the part's geometry names why, in one sentence with measured numbers, the first that applies of:

1. the part has no face (nothing labelled as it);
2. pads hold it, but wherever they do the weight's torque exceeds what whole pads hold (a kettle's body held
   by a Franka Hand's small pads, its centre of mass a hand's width away from the closing axis);
3. candidates touch it, but their pads press on it less than `min_share`, or, where they do, their faces first
   land elsewhere (a prouder neighbour, or the part meets only the fingertips' ends), or, where they land on it,
   only within `Hand.pad_end_margin` of the pads' ends (a 2F-85's finger curves away past its pad);
4. it stands lower above the table than a fingertip pinch needs (`AntipodalConfig.pinch_table_clearance` +
   `pinch_min_band`);
5. it lies flat, raised but thin: nowhere does a pinch's pad find `pinch_min_band` of it above the fingertips
   (a blade resting on its handle: the vertical chords down through it, `tallest_side`);
6. its narrowest section between facing surfaces (inward-normal chords inside the friction cone) is wider than
   the widest contact distance the hand closes on (`Hand.stroke` - `Hand.width_margin`);
7. otherwise: no collision-free pose of the hand closes on it.

The geometry is measured only for an infeasible request; a feasible one costs one footprint check of its best
candidate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
import trimesh

from seggrasp.grasp.antipodal import (
    RAY_EPSILON, AntipodalConfig, gravity_torque, mesh_center_of_mass, opposite_contacts,
)
from seggrasp.grasp.footprint import PadFootprint, PadReading
from seggrasp.grasp.select import UNASSIGNED, assign_parts, select_per_prompt
from seggrasp.grasp.types import GraspSet
from seggrasp.hands import Hand

#: Points sampled on a part to measure its narrowest section (seeded: the same part gives the same sentence).
SECTION_SAMPLES = 2000


@dataclass(frozen=True)
class Feasibility:
    """The judgement of one request: `feasible`, and when not, `reason`, one sentence naming why."""

    feasible: bool
    reason: str = ""


def judge_requests(
    requests: Sequence[int], prompts: Sequence[str], hand: Hand, config: AntipodalConfig, mesh: trimesh.Trimesh,
    face_labels: np.ndarray, grasps: GraspSet, footprint: PadFootprint, table_plane: np.ndarray,
    center_of_mass: np.ndarray | None = None, mass: float | None = None,
) -> dict[int, Feasibility]:
    """Per prompt index in `requests`, whether a candidate of `grasps` (object frame, as `mesh`) holds the faces
    labelled with it (`face_labels`, one prompt index per face), judged for `hand` with the sampler's `config` and
    the hand's `footprint`; `table_plane` (a, b, c, d) is the table top in the object frame, normal up;
    `center_of_mass` (object frame) and `mass` (kg) weigh the object as the sampler does (None: its estimates)."""
    labels = np.asarray(face_labels, dtype=np.int64)
    requests = list(requests)
    # one label per request, so the selection looks at the requested parts only
    local = np.full(len(labels), UNASSIGNED, dtype=np.int64)
    for j, k in enumerate(requests):
        local[labels == k] = j
    best = select_per_prompt(grasps, mesh, local, len(requests), top_k=1, footprint=footprint)
    surface = replace(footprint, margin=0.0).on(mesh)  # the pads themselves, without the ranking's safety margin
    com = mesh_center_of_mass(mesh) if center_of_mass is None else np.asarray(center_of_mass, dtype=np.float64)
    weight = _Weight(com, config.default_mass if mass is None else float(mass), np.asarray(table_plane[:3]),
                     whole_pad_torsion_limit(hand, config))
    held = weight.held(grasps)  # per candidate, whether whole pads could keep the weight from turning it
    parts: np.ndarray | None = None  # each candidate's part, found once the best-ranked one falls short
    judged = {}
    for j, k in enumerate(requests):
        is_part = local == j
        if len(best[j]) and surface.holds(grasps.subset(best[j]), is_part).all() and held[best[j]].all():
            judged[k] = Feasibility(True)
            continue
        parts = assign_parts(grasps, mesh, local) if parts is None else parts
        mine = np.flatnonzero(parts == j)
        on_part = grasps.subset(mine)
        reading = surface.read(on_part, is_part) if len(on_part) else None
        holding = reading.holds(footprint) if reading is not None else np.zeros(0, dtype=bool)
        if (holding & held[mine]).any():  # a lower-ranked candidate holds it
            judged[k] = Feasibility(True)
        elif holding.any():
            judged[k] = Feasibility(False, weight.reason(prompts[k], on_part.subset(np.flatnonzero(holding)), hand,
                                                         config))
        else:
            judged[k] = Feasibility(False, _reason(prompts[k], is_part, reading, hand, config, mesh, footprint,
                                                   table_plane))
    return judged


def whole_pad_torsion_limit(hand: Hand, config: AntipodalConfig) -> float:
    """The most gravity torque (N m) about the closing axis two pads of `hand` hold at the sampler's grip force and
    friction, each pressing with its whole face (`Hand.whole_pad_torsion_radius`): no grasp of the hand holds more."""
    return config.torque_held(hand.whole_pad_torsion_radius)


@dataclass(frozen=True)
class _Weight:
    """The object's weight as the judgement sees it: centre of mass and up direction in the object frame, mass,
    and the most torque about a grasp's closing axis any grasp of the hand holds (`whole_pad_torsion_limit`)."""

    com: np.ndarray
    mass: float
    up: np.ndarray
    limit: float

    def torque(self, grasps: GraspSet) -> np.ndarray:
        return gravity_torque(grasps.poses, self.com, self.up, self.mass)

    def held(self, grasps: GraspSet) -> np.ndarray:
        """Per grasp, whether the pads' torsional friction can hold the weight's torque about its closing axis."""
        return self.torque(grasps) <= self.limit

    def reason(self, name: str, holding: GraspSet, hand: Hand, config: AntipodalConfig) -> str:
        """The sentence for a part the pads press on well enough, but where the object would always turn."""
        return (f"{name}: wherever the pads hold it, the {self.mass:.2f} kg object's weight turns it about the "
                f"closing axis with at least {self.torque(holding).min():.2f} N m; the {hand.name}'s pads hold at "
                f"most {self.limit:.2f} N m at {config.grip_force:.0f} N, pressing with their whole faces")


def _reason(
    name: str, faces: np.ndarray, reading: PadReading | None, hand: Hand, config: AntipodalConfig,
    mesh: trimesh.Trimesh, footprint: PadFootprint, table_plane: np.ndarray,
) -> str:
    """The sentence for an infeasible part (module docstring); `reading`: what the pads of each candidate with both
    contacts on the part press on (None: no such candidate)."""
    if not faces.any():
        return f"{name}: no face of the mesh is labelled as it"
    if reading is not None:
        # per candidate, the worse of its two pads
        under, landed, reach = (value.min(axis=1) for value in reading)
        need = f"they need {100 * footprint.min_share:.0f} %"
        if under.max() < footprint.min_share:
            return f"{name}: the pads press on it for at most {100 * under.max():.0f} % of their footprint; {need}"
        best_landed = landed[under >= footprint.min_share].max()
        if best_landed < footprint.min_share:
            return (f"{name}: where the pads' footprint is mostly on it, their faces first land on it for at most "
                    f"{100 * best_landed:.0f} % (a prouder neighbour, or only the fingertips' ends, meet it first); "
                    f"{need}")
        pressing = (under >= footprint.min_share) & (landed >= footprint.min_share)
        return (f"{name}: where the pads press on it, they first land on it at most {1000 * reach[pressing].max():.1f} "
                f"mm into the pad from its end; the {hand.name}'s pads hold from {1000 * hand.pad_end_margin:.1f} mm")
    vertices = mesh.vertices[np.unique(mesh.faces[faces])]
    height = float((vertices @ table_plane[:3] + table_plane[3]).max())
    pinch = config.pinch_table_clearance + config.pinch_min_band
    if height < pinch:
        return (f"{name}: stands at most {1000 * height:.1f} mm above the table; a fingertip pinch needs "
                f"{1000 * pinch:.1f} mm (fingertips {1000 * config.pinch_table_clearance:.1f} mm above the table, "
                f"{1000 * config.pinch_min_band:.1f} mm of pad on the part)")
    side = tallest_side(mesh, faces, table_plane, config.pinch_table_clearance)
    if side < config.pinch_min_band:
        return (f"{name}: lies flat, at most {1000 * side:.1f} mm of it above a pinch's fingertips "
                f"({1000 * config.pinch_table_clearance:.1f} mm above the table) wherever a pad would touch its "
                f"side; a fingertip pinch needs {1000 * config.pinch_min_band:.1f} mm of pad on the part")
    widest = config.widest_contact_distance(hand)
    section = narrowest_section(mesh, faces, config)
    if section is not None and section > widest:
        return (f"{name}: narrowest section {1000 * section:.0f} mm, wider than the {1000 * widest:.0f} mm the "
                f"{hand.name} closes on ({1000 * hand.stroke:.0f} mm stroke less {1000 * config.width_margin:.0f} mm)")
    return f"{name}: no collision-free pose of the {hand.name} closes on it"


def tallest_side(mesh: trimesh.Trimesh, faces: np.ndarray, table_plane: np.ndarray, clearance: float) -> float:
    """The most of the faces `faces` (boolean mask) a straight-down pinch's pads can touch (m): over points of its
    upward-facing faces, the vertical chord down through the mesh to the next surface (the table where there is
    none), above the fingertips `clearance` over the table."""
    up = np.asarray(table_plane[:3], dtype=np.float64)
    sign = -1.0 if (mesh.is_watertight and mesh.volume < 0) else 1.0
    upward = faces & (sign * np.asarray(mesh.face_normals) @ up > 0.0)
    if not upward.any():
        return 0.0
    points, _ = trimesh.sample.sample_surface(mesh, SECTION_SAMPLES, face_weight=mesh.area_faces * upward, seed=0)
    top = points @ up + table_plane[3]
    bottom = np.zeros(len(points))
    origins = points - RAY_EPSILON * up
    hits, ray, _ = mesh.ray.intersects_location(origins, np.broadcast_to(-up, points.shape), multiple_hits=False)
    bottom[ray] = np.maximum(hits @ up + table_plane[3], 0.0)
    return float(np.max(top - np.maximum(bottom, clearance)).clip(min=0.0))


def narrowest_section(mesh: trimesh.Trimesh, faces: np.ndarray, config: AntipodalConfig) -> float | None:
    """The shortest chord (m) from a point of the faces `faces` (boolean mask) along its inward normal to the
    surface it meets, among chords whose ends both lie inside the friction cone (`config.friction_coefficient`)
    and that are at least `config.min_width` long; None when there is none."""
    sign = -1.0 if (mesh.is_watertight and mesh.volume < 0) else 1.0
    normals = sign * np.asarray(mesh.face_normals)
    points, index = trimesh.sample.sample_surface(mesh, SECTION_SAMPLES, face_weight=mesh.area_faces * faces, seed=0)
    p, q, n_p, n_q = opposite_contacts(mesh, points, normals[index], normals)
    width = np.linalg.norm(q - p, axis=1)
    axis = (q - p) / np.maximum(width, 1e-12)[:, None]
    cone = np.cos(np.arctan(config.friction_coefficient))
    ok = (width >= config.min_width) & (np.einsum("ij,ij->i", axis, -n_p) >= cone) & \
        (np.einsum("ij,ij->i", axis, n_q) >= cone)
    return float(width[ok].min()) if ok.any() else None
