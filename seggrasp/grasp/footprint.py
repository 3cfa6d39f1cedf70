"""What lies under a grasp's pads: the faces nearest its contacts, and the surface each pad closes on.

A grasp's two contact points say little about what its pads (`Hand.pad_half_width` x `pad_half_length`) will press
on. `PadFootprint` finds, on a dense even sample of the mesh, the surface each pad touches when it closes from the
pre-grasp opening: the points its sweep holds within `tolerance` of its first touch
(`seggrasp.grasp.pads.pad_touches`), with the pad widened by `margin` on every side, because a neighbouring part
that stands proud within a few millimetres of the pad's edge takes the grip once the pose is a little off or the
object settles in the fingers (a wine glass held by its stem just under the bowl presses on the bowl, not on the
stem). The share of a part (or the mean of any per-face value) over those points, which sample the surface evenly
by area, says how much of what each pad presses on is that part. A rigid finger, though, pushes only on what it
first lands on: `first_touch` reads the part's share there (within `first_touch_tolerance`, the fingertip beyond
the pad included but holding nothing), and `part_shares`, the smaller of the two, is what selection and the
feasibility judgement compare with `min_share` (a kettle's body bulges under the lid's rim, and only the
fingertips' ends reach it). `first_touch` also reads how far into the pad from its fingertip end that touch
reaches: a hand's pad holds nothing it lands on only within `Hand.pad_end_margin` of that end (`PadReading.holds`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from seggrasp.grasp.pads import pad_touches
from seggrasp.grasp.types import GraspSet
from seggrasp.hands import ROBOTIQ_2F85, Hand

#: How many meshes' even surface samples `PadSurface` keeps (a plan reads the same mesh's footprint several times).
SAMPLES_KEPT = 8


def contact_faces(grasps: GraspSet, mesh: trimesh.Trimesh) -> np.ndarray:
    """(N, 2) index of the mesh face nearest to each contact point (contacts in the mesh's frame)."""
    if len(grasps) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    _, _, triangle = trimesh.proximity.closest_point(mesh, grasps.contacts.reshape(-1, 3))
    return np.asarray(triangle, dtype=np.int64).reshape(-1, 2)


@dataclass(frozen=True)
class PadFootprint:
    """The surface under each pad of a grasp (module docstring). Sizes in metres; `min_share` is the share of the
    prompted part each pad must press on for label-based selection to rank the grasp first (the twin judges a lift
    on the part the pads press on most, `seggrasp.truth.GroundTruth.touched_on_part`)."""

    margin: float = 0.003
    tolerance: float = 0.002
    first_touch_tolerance: float = 0.0005
    point_spacing: float = 0.0015
    min_points: int = 2000
    max_points: int = 40000
    min_share: float = 0.5
    seed: int = 0
    gripper: Hand = field(default=ROBOTIQ_2F85, repr=False)

    def __post_init__(self) -> None:
        if min(self.margin, self.tolerance, self.first_touch_tolerance) < 0 or self.point_spacing <= 0:
            raise ValueError(f"invalid pad footprint {self}: margin and tolerances must be >= 0, point_spacing > 0")
        if not 1 <= self.min_points <= self.max_points or not 0 < self.min_share <= 1:
            raise ValueError(f"invalid pad footprint {self}: need 1 <= min_points <= max_points, min_share in (0, 1]")

    def on(self, mesh: trimesh.Trimesh) -> "PadSurface":
        """This footprint on `mesh` (samples its surface once, for any number of grasp queries)."""
        return PadSurface(self, mesh)


class PadReading(NamedTuple):
    """What each pad of N grasps presses on, (N, 2) each, -x pad first: the share of a part under its footprint
    (`under`) and in what its face first lands on (`landed`), and how far into the pad from its fingertip end that
    first touch reaches (`reach`, m)."""

    under: np.ndarray
    landed: np.ndarray
    reach: np.ndarray

    def holds(self, footprint: PadFootprint) -> np.ndarray:
        """(N,) whether both pads press at least the footprint's `min_share` on the part, under them and where they
        land, and land at least its hand's `pad_end_margin` into the pad."""
        return ((np.minimum(self.under, self.landed) >= footprint.min_share)
                & (self.reach >= footprint.gripper.pad_end_margin)).all(axis=1)


class PadSurface:
    """A `PadFootprint` on one mesh: an even sample of its surface, and what each pad of a grasp closes on."""

    def __init__(self, footprint: PadFootprint, mesh: trimesh.Trimesh) -> None:
        self.footprint = footprint
        self.mesh = mesh
        count = int(np.clip(mesh.area / footprint.point_spacing**2, footprint.min_points, footprint.max_points))
        self.points, self.point_faces, self._tree = _even_samples(mesh, count, footprint.seed)

    def touched_faces(self, grasps: GraspSet) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per grasp, the mesh face of every sample point the -x pad and the +x pad close on (one entry per point,
        so faces repeat in proportion to their area under the pad; empty where a pad touches nothing)."""
        fp = self.footprint
        half_width = fp.gripper.pad_half_width + fp.margin
        half_length = fp.gripper.pad_half_length + fp.margin
        openings = fp.gripper.pre_grasp_opening(grasps.widths)
        touched = []
        for pose, opening, near in zip(grasps.poses, openings, self._near(grasps, margin=fp.margin)):
            if len(near) == 0:  # the pads are nowhere near the surface
                touched.append((near, near))
                continue
            low_pad, high_pad, _ = pad_touches(pose[None], np.array([opening]), self.points[near], half_width,
                                               half_length, fp.tolerance)
            touched.append((self.point_faces[near[low_pad[0]]], self.point_faces[near[high_pad[0]]]))
        return touched

    def _near(self, grasps: GraspSet, margin: float) -> list[np.ndarray]:
        """Per grasp, the sample points within reach of its fingers (pads widened by `margin`, and the tips)."""
        hand = self.footprint.gripper
        openings = hand.pre_grasp_opening(grasps.widths)
        length = max(hand.pad_half_length, hand.tip_beyond_origin) + margin
        reach = np.sqrt((0.5 * openings) ** 2 + (hand.pad_half_width + margin) ** 2 + length**2)
        return [np.asarray(self._tree.query_ball_point(pose[:3, 3], radius), dtype=np.int64)
                for pose, radius in zip(grasps.poses, reach)]

    def pad_means(self, grasps: GraspSet, face_values: np.ndarray) -> np.ndarray:
        """(N, 2, P) per grasp and pad the mean of `face_values` (F, P) over the surface the pad closes on (the
        face nearest the contact where it closes on none of the sample points)."""
        face_values = np.asarray(face_values, dtype=np.float64)
        if face_values.ndim != 2 or len(face_values) != len(self.mesh.faces):
            raise ValueError(f"need (F, P) face values for {len(self.mesh.faces)} faces, got {face_values.shape}")
        means = face_values[contact_faces(grasps, self.mesh)]  # (N, 2, P)
        for i, pads in enumerate(self.touched_faces(grasps)):
            for pad, faces in enumerate(pads):
                if len(faces):
                    means[i, pad] = face_values[faces].mean(axis=0)
        return means

    def first_touch(self, grasps: GraspSet, is_part: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per grasp and finger (N, 2 each), the share of a part (`is_part`, one bool per face) in what the rigid
        finger first lands on as it closes (within `first_touch_tolerance`; the pad and the fingertip beyond it),
        counting only points the pad's face itself presses, and how far into the pad from its fingertip end those
        points reach (m). A part that stands back a millimetre from a prouder neighbour, or that only the fingertip's
        rim reaches, takes none of the grip. Where the finger touches none of the sample points, the face nearest the
        contact gives the share and the reach is the pad's length."""
        hand, tolerance = self.footprint.gripper, self.footprint.first_touch_tolerance
        finger_end = max(hand.pad_half_length, hand.tip_beyond_origin)
        # a tip beyond the pad shorter than the first touch's own resolution cannot be told from the pad's end (the
        # Franka Hand's finger is pad to 0.1 mm of its end; the 2F-85's finger reaches 1.25 mm past its pad)
        pad_end = hand.pad_half_length if finger_end - hand.pad_half_length >= tolerance else finger_end
        is_part = np.asarray(is_part, dtype=bool)
        shares = is_part[contact_faces(grasps, self.mesh)].astype(np.float64)  # (N, 2)
        reach = np.full((len(grasps), 2), 2.0 * hand.pad_half_length)
        openings = hand.pre_grasp_opening(grasps.widths)
        for i, (pose, opening, near) in enumerate(zip(grasps.poses, openings, self._near(grasps, margin=0.0))):
            if len(near) == 0:
                continue
            low_pad, high_pad, z = pad_touches(pose[None], np.array([opening]), self.points[near], hand.pad_half_width,
                                               hand.pad_half_length, tolerance, tip=finger_end)
            pressed = z[0] <= pad_end
            for finger, touching in enumerate((low_pad[0], high_pad[0])):
                if touching.any():
                    held = touching & pressed
                    shares[i, finger] = (held & is_part[self.point_faces[near]]).sum() / touching.sum()
                    reach[i, finger] = pad_end - z[0][held].min() if held.any() else 0.0
        return shares, reach

    def read(self, grasps: GraspSet, is_part: np.ndarray) -> PadReading:
        """What each pad of `grasps` presses on of a part (`is_part`, one bool per face): `PadReading`."""
        under = self.pad_means(grasps, np.asarray(is_part, dtype=np.float64)[:, None])[:, :, 0]
        return PadReading(under, *self.first_touch(grasps, is_part))

    def holds(self, grasps: GraspSet, is_part: np.ndarray) -> np.ndarray:
        """(N,) whether each grasp's pads hold a part (`is_part`): `PadReading.holds` with this footprint."""
        return self.read(grasps, is_part).holds(self.footprint)

    def lands_on_pads(self, grasps: GraspSet) -> np.ndarray:
        """(N,) whether both pads of each grasp first land at least the hand's `pad_end_margin` into the pad, on
        whatever part."""
        _, reach = self.first_touch(grasps, np.zeros(len(self.mesh.faces), dtype=bool))
        return (reach >= self.footprint.gripper.pad_end_margin).all(axis=1)

    def part_shares(self, grasps: GraspSet, is_part: np.ndarray) -> np.ndarray:
        """(N, 2) per grasp and pad the share of a part (`is_part`, one bool per face) in what the pad presses on:
        the smaller of its shares under the footprint and where it first lands (`read`)."""
        reading = self.read(grasps, is_part)
        return np.minimum(reading.under, reading.landed)


@functools.lru_cache(maxsize=SAMPLES_KEPT)
def _even_samples(mesh: trimesh.Trimesh, count: int, seed: int) -> tuple[np.ndarray, np.ndarray, cKDTree]:
    """`count` points sampled evenly on `mesh` (seeded), their faces and their k-d tree. Kept for the last
    `SAMPLES_KEPT` meshes: trimesh hashes a mesh by its content, so a mesh changed in place is sampled anew. The
    arrays are shared: read only."""
    points, faces = trimesh.sample.sample_surface_even(mesh, count, seed=seed)
    points.flags.writeable = faces.flags.writeable = False
    return points, faces, cKDTree(points)
