"""Analytic antipodal grasp sampler for a parallel gripper (no learned weights).

1. Sample surface points (area-weighted, seeded; half of them concentrated near the centre of mass) with their face
   normals.
2. Cast a ray from each point along its inward normal; the first hit is the opposite contact.
3. Keep pairs whose axis lies inside both friction cones (half-angle atan(mu)) and whose distance fits the stroke.
4. Around each pair's axis (the gripper's x) sample approach directions (the gripper's z); with a table plane, a
   pair tilted a little from the table also gets a straight-down pose closing level with the table across its
   middle (`level_poses`: a round handle lying flat is held across its widest section, with a line contact).
   With a table plane, envelope poses (`envelope_poses`) come straight down closing level with the table around
   a whole cluster of surface, found along lines through surface points: what a finger cannot get between (a
   scissors ring whose hole is narrower than a finger, a pair of rings) is held from outside.
5. Depth search, deepest first: each pose is tried with the contacts `contact_depths` along the pad (3 mm steps
   from near the palm end to near the tip, never within 6.75 mm of either end) and keeps the deepest
   at which no finger, palm or wrist box contains object surface points (a dense surface sample) and no box dips
   below an optional table plane. A pose coming straight down onto the table (within `pinch_max_tilt_deg`) that
   finds no such depth is tried once more as a fingertip pinch (`pinch_contact_depths`, the fingertips
   `pinch_table_clearance` above the table): how a 2F-85 picks a part lying flat whose sides are lower than the
   pads reach with the normal margins (toothbrush handles, screwdriver shafts, eyeglass temples). A pinch is kept
   only where both pads touch the part over `pinch_min_band` of their length.
6. Footprint: the pads close on whatever is widest in their sweep (pad width x length, over the opening), so the
   grasp's width and contact points are taken from the surface points in that footprint, and the pose is centred
   between them. A level or envelope pose is kept only if the surface there faces the pads (`level_facing_deg`);
   an envelope's antipodality is measured from that surface.
7. Gravity torque: with the centre of mass (given, else the mesh's uniform-density estimate, which is all a real
   cell knows of a perceived object) and the table's up direction, the torque of the object's weight about the
   grasp axis after lifting; a grasp whose torque exceeds what the pads' torsional friction holds
   (`torsion_limit`) ranks after every grasp that holds.
8. Score = weighted sum of antipodality, closeness of the grasp to the centre of mass, when a table plane is
   given how much the approach points down onto the table (top-down grasps reach and lift best) minus the
   gravity torque as a fraction of the limit, minus a little for contacts away from the pad centres.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from seggrasp.grasp.clearance import COLLISION_CHUNK, collision_free
from seggrasp.grasp.pads import box_corners, pad_bands, pressed_centres, sweep
from seggrasp.grasp.poses import envelope_poses, level_poses, poses_around_axes
from seggrasp.grasp.types import GraspSet
from seggrasp.hands import ROBOTIQ_2F85, Hand

LOG = logging.getLogger(__name__)

#: Offset (metres) that moves ray origins off the surface so a ray does not hit its own face.
RAY_EPSILON = 1e-5
#: Rays cast in one call (`opposite_contacts`): bounds the intersector's memory.
RAY_CHUNK = 512


@dataclass(frozen=True)
class AntipodalConfig:
    """Sampler parameters. `friction_coefficient` sets the friction-cone half-angle atan(mu)."""

    n_surface_samples: int = 6000
    part_draw_samples: int = 2  # times n_surface_samples a draw on a part (`on_faces`) takes: a thin part's few holds
    part_draw_rounds: int = 4  # draws on a part at most, until top-k of its grasps hold it (`Episode.part_grasps`)
    n_approaches: int = 8
    near_com_fraction: float = 0.5  # of the surface samples drawn near the centre of mass
    near_com_scale: float = 0.05  # m
    friction_coefficient: float = 0.5
    min_width: float = 0.001
    width_margin: float = ROBOTIQ_2F85.width_margin  # contact distance must stay this far below the stroke (the hand's)
    collision_point_spacing: float = 0.004
    min_collision_points: int = 1500
    max_collision_points: int = 6000
    table_clearance: float = 0.0035
    # contacts this far from the pad centres (m, + towards the fingertips), tried in this order (deepest first):
    # the hand's (`Hand.contact_depths`; the defaults are the 2F-85's, `for_hand` takes another hand's)
    contact_depths: tuple[float, ...] = ROBOTIQ_2F85.contact_depths
    # fingertip pinch of a low part lying on the table, for straight-down poses that have no depth above: the
    # contact near the pad's end (`Hand.pinch_contact_depths`: the pad still touches the part's side from there to
    # its top) and the fingertips this far above the table (`Hand.pinch_table_clearance`)
    pinch_contact_depths: tuple[float, ...] = ROBOTIQ_2F85.pinch_contact_depths
    pinch_table_clearance: float = ROBOTIQ_2F85.pinch_table_clearance
    pinch_max_tilt_deg: float = 10.0
    # and the pads must touch the part's side over at least this much of their length (a pinch that only grazes
    # an edge does not hold), measured from the surface points within `pinch_band_tolerance` of each pad's first
    # touch; 0.5 mm, where 3 mm refused pinches on knife blades, scissor blades and eyeglass rims that the twin
    # lifts (docs/results/pinch-band-seeds0-4.md)
    pinch_min_band: float = 0.0005
    pinch_band_tolerance: float = 0.0015
    pad_half_width: float = ROBOTIQ_2F85.pad_half_width
    pad_half_length: float = ROBOTIQ_2F85.pad_half_length
    footprint_tolerance: float = 0.001  # the footprint must be this much wider on a side to move the contacts
    # a level pose (`level_poses`) needs the surface at both pads' first touch to face them within this angle (deg):
    # the pads then lie along it (a line across a round handle), not on an edge of a flared or slanted wall
    level_facing_deg: float = 18.0
    # envelope poses (`envelope_poses`): straight-down poses closing level with the table around everything the
    # fingers would straddle on a line through one of `envelope_centres` surface points, in `envelope_directions`
    # directions (0 centres: none); how a 2F-85 picks a ring, a frame or a flat cluster whose walls are too thin or
    # whose holes are too small for a finger (scissors handles lying flat), held from outside
    envelope_centres: int = 256
    envelope_directions: int = 8
    # gravity torque: the object's assumed mass (kg) when none is given, the grip force (N) and the effective
    # radius (m) of the pads' torsional friction; the limit is 2 * mu * grip_force * radius, the radius being the
    # mean contact radius of the narrowest patch a pad makes (a line across its width: `Hand.torsion_radius`, as
    # the twin's pads, sim/gripper.py PAD_SPINNING_FRICTION)
    default_mass: float = 0.3
    grip_force: float = ROBOTIQ_2F85.default_grip_force
    torsion_radius: float = ROBOTIQ_2F85.torsion_radius
    weight_torque: float = 0.3
    weight_antipodality: float = 0.4
    weight_center_of_mass: float = 0.4
    weight_top_down: float = 0.2
    weight_contact_depth: float = 0.1
    max_grasps: int | None = None

    def __post_init__(self) -> None:
        if self.friction_coefficient <= 0:
            raise ValueError(f"friction_coefficient must be positive, got {self.friction_coefficient}")
        if min(self.n_surface_samples, self.n_approaches, self.part_draw_samples, self.part_draw_rounds) < 1:
            raise ValueError("n_surface_samples, n_approaches, part_draw_samples, part_draw_rounds must be >= 1")
        for name in ("contact_depths", "pinch_contact_depths"):
            depths = getattr(self, name)
            if (name == "contact_depths" and not depths) or any(abs(d) >= self.pad_half_length for d in depths):
                raise ValueError(f"{name} must lie on the pad (|d| < {self.pad_half_length}), got {depths}")
        if min(self.pinch_table_clearance, self.pinch_min_band, self.pinch_band_tolerance) < 0:
            raise ValueError("pinch_table_clearance, pinch_min_band and pinch_band_tolerance must not be negative")
        if self.envelope_centres < 0 or self.envelope_directions < 1:
            raise ValueError("envelope_centres must not be negative and envelope_directions must be at least 1")
        if not 0 <= self.pinch_max_tilt_deg <= 90:
            raise ValueError(f"pinch_max_tilt_deg must be in [0, 90], got {self.pinch_max_tilt_deg}")

    @classmethod
    def for_hand(cls, hand: Hand, **settings) -> "AntipodalConfig":
        """The sampler's parameters for `hand`: its pads, contact depths, width margin, pinch clearance, default grip
        force and torsion radius; `settings` override any field (e.g. `grip_force`)."""
        return cls(**{
            "pad_half_width": hand.pad_half_width, "pad_half_length": hand.pad_half_length,
            "contact_depths": hand.contact_depths, "pinch_contact_depths": hand.pinch_contact_depths,
            "pinch_table_clearance": hand.pinch_table_clearance, "width_margin": hand.width_margin,
            "grip_force": hand.default_grip_force, "torsion_radius": hand.torsion_radius, **settings,
        })

    @property
    def all_contact_depths(self) -> np.ndarray:
        """The normal contact depths, then the pinch depths (the indices `_deepest_free_depths` returns)."""
        return np.asarray(self.contact_depths + self.pinch_contact_depths, dtype=np.float64)

    def widest_contact_distance(self, hand: Hand) -> float:
        """The widest contact distance (m) a grasp of `hand` may have: its stroke less `width_margin`."""
        return hand.stroke - self.width_margin

    @property
    def torsion_limit(self) -> float:
        """Gravity torque (N m) about the grasp axis the pads' friction holds."""
        return self.torque_held(self.torsion_radius)

    def torque_held(self, radius: float) -> float:
        """Torque (N m) about the closing axis two pads' friction holds at the grip force, each pad's contact patch
        of mean radius `radius` (m): 2 mu F r."""
        return 2.0 * self.friction_coefficient * self.grip_force * radius


class AntipodalSampler:
    """`GraspGenerator` that samples antipodal, collision-free grasps on a mesh (object frame)."""

    name = "antipodal"

    def __init__(self, config: AntipodalConfig | None = None, gripper: Hand = ROBOTIQ_2F85) -> None:
        """`gripper` is the hand (`seggrasp.hands`); `config` defaults to `AntipodalConfig.for_hand(gripper)` (a
        config given for another hand should be made with `for_hand` too: its pads and depths are the hand's)."""
        self.config = config or AntipodalConfig.for_hand(gripper)
        self.gripper = gripper

    def generate(
        self,
        mesh: trimesh.Trimesh,
        seed: int = 0,
        table_plane: np.ndarray | None = None,
        center_of_mass: np.ndarray | None = None,
        mass: float | None = None,
        on_faces: np.ndarray | None = None,
    ) -> GraspSet:
        """Antipodal grasps on `mesh` sorted best first; the same seed gives the same grasps.

        `center_of_mass` (mesh frame) and `mass` (kg) feed the gravity-torque term; None takes the mesh's
        uniform-density centre of mass (what the real cell uses for a perceived object) and `default_mass`.
        `on_faces` (boolean, one per face) draws `part_draw_samples` times the first contacts on those faces and on
        the faces within a pad's length of them only, at least half on the faces themselves (a part with too few
        grasps gets more of its own: a level pose from a pair on the neighbouring stem slides its pads down onto a
        wine glass's foot), and leaves out the envelope poses, which do not start from a contact."""
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise ValueError("AntipodalSampler needs a non-empty trimesh.Trimesh")
        cfg = self.config
        plane = _check_plane(table_plane)
        rng = np.random.default_rng(seed)
        normals_sign = -1.0 if (mesh.is_watertight and mesh.volume < 0) else 1.0
        face_normals = normals_sign * np.asarray(mesh.face_normals)

        com = mesh_center_of_mass(mesh) if center_of_mass is None else np.asarray(center_of_mass, dtype=np.float64)
        if on_faces is not None:
            on_faces = np.asarray(on_faces, dtype=bool)
            if on_faces.shape != (len(mesh.faces),) or not on_faces.any():
                raise ValueError(f"on_faces must mark some of the mesh's {len(mesh.faces)} faces, got shape "
                                 f"{on_faces.shape} with {int(on_faces.sum())} marked")
        draw = None if on_faces is None else part_draw_weights(mesh, on_faces, 2.0 * cfg.pad_half_length)
        pairs = self._friction_cone_pairs(mesh, face_normals, com, rng, draw)
        if pairs is None:
            LOG.info("antipodal sampler: no contact pair inside the friction cone")
            empty = np.zeros((0, 3))
            pairs = (empty, empty, empty, np.zeros(0), np.zeros(0))
        p, q, axis, width, antipodality = pairs

        poses = poses_around_axes(p, q, axis, cfg.n_approaches, rng, None if plane is None else -plane[:3])
        pair_of = np.repeat(np.arange(len(p)), cfg.n_approaches)
        from_sweep = np.zeros(len(poses), dtype=bool)
        if plane is not None:
            level, level_pairs = level_poses(p, q, axis, -plane[:3], float(np.arctan(cfg.friction_coefficient)))
            poses, pair_of = np.concatenate([poses, level]), np.concatenate([pair_of, level_pairs])
            from_sweep = np.r_[from_sweep, np.ones(len(level), dtype=bool)]
        widths = width[pair_of]
        contacts = np.stack([p[pair_of], q[pair_of]], axis=1)
        pose_antipodality = antipodality[pair_of]
        cloud, cloud_normals = _collision_cloud(mesh, normals_sign, cfg, int(rng.integers(2**31)))
        is_envelope = np.zeros(len(poses), dtype=bool)
        if plane is not None and cfg.envelope_centres and on_faces is None:
            envelope, envelope_widths = envelope_poses(cloud, plane, self.gripper, cfg)
            poses = np.concatenate([poses, envelope])
            widths = np.r_[widths, envelope_widths]
            # an envelope's contacts and antipodality come from what its pads press on, found below
            contacts = np.concatenate([contacts, np.full((len(envelope), 2, 3), np.nan)])
            pose_antipodality = np.r_[pose_antipodality, np.zeros(len(envelope))]
            from_sweep = np.r_[from_sweep, np.ones(len(envelope), dtype=bool)]
            is_envelope = np.r_[is_envelope, np.ones(len(envelope), dtype=bool)]
        if not len(poses):
            return GraspSet.empty()
        openings = self.gripper.pre_grasp_opening(widths)
        depth_index = self._deepest_free_depths(poses, openings, widths, plane, cloud)
        free = depth_index >= 0
        if not free.any():
            LOG.info("antipodal sampler: every candidate pose collides")
            return GraspSet.empty()
        contact_depth = cfg.all_contact_depths[depth_index[free]]
        poses, openings, contacts = poses[free].copy(), openings[free], contacts[free]
        pose_antipodality, from_sweep, is_envelope = pose_antipodality[free], from_sweep[free], is_envelope[free]
        poses[:, :3, 3] -= contact_depth[:, None] * poses[:, :3, 2]
        widths, alignment = self._apply_footprint(
            poses, contacts, widths[free].copy(), openings, cloud, cloud_normals, from_sweep
        )
        # an envelope's contacts are the middle of what each pad presses on (its outermost point may be anywhere on a
        # wall), and it is as antipodal as the surface its pads first touch
        envelope_index = np.flatnonzero(is_envelope)
        for start in range(0, len(envelope_index), COLLISION_CHUNK):
            chunk = envelope_index[start : start + COLLISION_CHUNK]
            contacts[chunk] = pressed_centres(poses[chunk], openings[chunk], cloud, cfg.pad_half_width,
                                              cfg.pad_half_length, cfg.pinch_band_tolerance)
        half_angle = float(np.arctan(cfg.friction_coefficient))
        pose_antipodality[is_envelope] = np.clip(
            1.0 - np.arccos(np.clip(alignment[is_envelope], -1.0, 1.0)) / half_angle, 0.0, 1.0)
        # the footprint may be wider than the stroke; a pose from the sweep must meet surface facing its pads; a pinch
        # must touch the part over `pinch_min_band` of its pads
        facing = alignment >= np.cos(np.deg2rad(cfg.level_facing_deg))
        fits = (widths <= cfg.widest_contact_distance(self.gripper)) & (facing | ~from_sweep)
        pinch = np.flatnonzero(fits & (depth_index[free] >= len(cfg.contact_depths)))
        if len(pinch):
            bands = np.concatenate([
                pad_bands(poses[chunk], openings[chunk], cloud, cfg.pad_half_width, cfg.pad_half_length,
                           cfg.pinch_band_tolerance)
                for chunk in np.array_split(pinch, -(-len(pinch) // COLLISION_CHUNK))
            ])
            fits[pinch] = bands >= cfg.pinch_min_band
        poses, contacts, widths = poses[fits], contacts[fits], widths[fits]
        contact_depth, pose_antipodality = contact_depth[fits], pose_antipodality[fits]
        if not len(poses):
            return GraspSet.empty()
        score = self._score(mesh, poses, com, pose_antipodality, contact_depth, plane, mass)
        grasps = GraspSet(poses, widths, score, contacts).sorted_by_score()
        if cfg.max_grasps is not None:
            grasps = grasps.subset(np.arange(min(cfg.max_grasps, len(grasps))))
        LOG.debug("antipodal sampler: %d pairs, %d poses, %d collision-free", len(p), len(free), len(grasps))
        return grasps

    def _friction_cone_pairs(
        self, mesh: trimesh.Trimesh, face_normals: np.ndarray, com: np.ndarray, rng: np.random.Generator,
        draw: np.ndarray | None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """Contact pairs (p, q, closing axis, width, antipodality in [0, 1]) that fit the stroke and lie inside both
        friction cones, the first contacts drawn with the per-face weights `draw` times area (None: anywhere);
        None when there is none."""
        cfg = self.config
        points, faces = _surface_samples(mesh, cfg, com, rng, draw)
        p, q, n_p, n_q = opposite_contacts(mesh, points, face_normals[faces], face_normals)
        width = np.linalg.norm(q - p, axis=1)
        ok = (width >= cfg.min_width) & (width <= cfg.widest_contact_distance(self.gripper))
        axis = np.zeros_like(p)
        axis[ok] = (q[ok] - p[ok]) / width[ok, None]
        half_angle = float(np.arctan(cfg.friction_coefficient))
        angle_p = np.arccos(np.clip(np.einsum("ij,ij->i", axis, -n_p), -1.0, 1.0))
        angle_q = np.arccos(np.clip(np.einsum("ij,ij->i", axis, n_q), -1.0, 1.0))
        ok &= (angle_p <= half_angle) & (angle_q <= half_angle)
        if not ok.any():
            return None
        antipodality = 1.0 - np.maximum(angle_p[ok], angle_q[ok]) / half_angle
        return p[ok], q[ok], axis[ok], width[ok], antipodality

    def _deepest_free_depths(
        self, poses: np.ndarray, openings: np.ndarray, widths: np.ndarray, plane: np.ndarray | None, cloud: np.ndarray
    ) -> np.ndarray:
        """Per pose, the index (into `config.all_contact_depths`) of the first contact depth, deepest first, at
        which the open gripper clears the table and the object and the fingers behind the pads clear it when closed;
        then, for the straight-down poses still without one, the first pinch depth; -1 if none."""
        cfg = self.config
        depth_index = np.full(len(poses), -1)
        searches = [(cfg.contact_depths, cfg.table_clearance, np.ones(len(poses), dtype=bool))]
        if plane is not None and cfg.pinch_contact_depths:
            down = -(poses[:, :3, 2] @ plane[:3]) >= np.cos(np.deg2rad(cfg.pinch_max_tilt_deg))
            searches.append((cfg.pinch_contact_depths, cfg.pinch_table_clearance, down))
        candidates = [(d, clearance, allowed) for depths, clearance, allowed in searches for d in depths]
        for index, (depth, clearance, allowed) in enumerate(candidates):
            todo = np.flatnonzero((depth_index < 0) & allowed)
            shifted = poses[todo].copy()
            shifted[:, :3, 3] -= depth * shifted[:, :3, 2]
            free = np.ones(len(todo), dtype=bool)
            if plane is not None:
                free &= self._above_plane(shifted, openings[todo], plane, clearance)
            free[free] = collision_free(self.gripper, shifted[free], openings[todo][free], cloud)
            # closing: the fingers behind the pads (they lean inwards) must not reach the object before the pads
            free[free] = collision_free(self.gripper, shifted[free], widths[todo][free], cloud, closed=True)
            depth_index[todo[free]] = index
        return depth_index

    def _score(
        self, mesh: trimesh.Trimesh, poses: np.ndarray, com: np.ndarray, antipodality: np.ndarray,
        contact_depth: np.ndarray, plane: np.ndarray | None, mass: float | None,
    ) -> np.ndarray:
        """Grasp score: antipodality, closeness to the centre of mass, shallow contact depth, a top-down approach, and
        a gravity torque the pads can hold (grasps whose torque exceeds the limit rank after all others)."""
        cfg = self.config
        radius = max(float(np.linalg.norm(mesh.vertices - com, axis=1).max()), 1e-9)
        closeness = 1.0 - np.clip(np.linalg.norm(poses[:, :3, 3] - com, axis=1) / radius, 0.0, 1.0)
        score = cfg.weight_antipodality * antipodality + cfg.weight_center_of_mass * closeness
        score -= cfg.weight_contact_depth * np.abs(contact_depth) / max(np.abs(cfg.contact_depths).max(), 1e-9)
        if plane is not None:
            score += cfg.weight_top_down * np.clip(-(poses[:, :3, 2] @ plane[:3]), 0.0, 1.0)
            torque = gravity_torque(poses, com, plane[:3], cfg.default_mass if mass is None else float(mass))
            score -= cfg.weight_torque * np.minimum(torque / cfg.torsion_limit, 1.0)
            score -= 2.0 * (torque > cfg.torsion_limit)  # ranks after every grasp whose torque the pads hold
        return score

    def _apply_footprint(
        self, poses: np.ndarray, contacts: np.ndarray, widths: np.ndarray, openings: np.ndarray, cloud: np.ndarray,
        cloud_normals: np.ndarray, from_sweep: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Where the pads' sweep (pad footprint over the opening) holds surface points wider apart than the
        contact pair, or for the poses `fromsweep` (not aimed at a pair's contacts) always, the pads stop on
        the sweep's outermost points: move the contacts there, centre the pose between them and return the widths
        they give and, per pose, how well the surface at the worse of the two outermost points faces its pad (the
        cosine of the angle between its outward normal and the pad's closing direction); poses and contacts are
        updated in place."""
        cfg = self.config
        alignment = np.full(len(poses), -1.0)
        for start in range(0, len(poses), COLLISION_CHUNK):
            sl = slice(start, start + COLLISION_CHUNK)
            span, x_low, x_high, low, high = sweep(poses[sl], openings[sl], cloud, cfg.pad_half_width,
                                                    -cfg.pad_half_length, cfg.pad_half_length)
            x_axis = poses[sl, :3, 0]
            alignment[sl] = np.where(np.isnan(span), -1.0, np.minimum(
                -np.einsum("ij,ij->i", cloud_normals[low], x_axis), np.einsum("ij,ij->i", cloud_normals[high], x_axis)))
            wider = (span > widths[sl] + 2.0 * cfg.footprint_tolerance) | (from_sweep[sl] & (span > 0.0))
            index = np.flatnonzero(wider) + start
            if len(index):
                poses[index, :3, 3] += 0.5 * (x_high[wider] + x_low[wider])[:, None] * poses[index, :3, 0]
                contacts[index, 0] = cloud[low[wider]]
                contacts[index, 1] = cloud[high[wider]]
                widths[index] = span[wider]
        return widths, alignment

    def _above_plane(self, poses: np.ndarray, openings: np.ndarray, plane: np.ndarray, clearance: float) -> np.ndarray:
        """True where every corner of every gripper box is at least `clearance` above the plane."""
        corners = box_corners(self.gripper.boxes(0.0))  # (B * 8, 3) at zero opening
        # the finger boxes move outwards by half the opening along x: -x finger first, then +x (Hand.boxes)
        n_finger = 8 * len(self.gripper.finger_boxes)
        shift = np.zeros(len(corners))
        shift[:n_finger], shift[n_finger : 2 * n_finger] = -0.5, 0.5
        up_in_gripper = np.einsum("gji,j->gi", poses[:, :3, :3], plane[:3])  # plane normal in each gripper frame
        heights = corners @ up_in_gripper.T  # (B * 8, G)
        heights += np.outer(shift, openings) * up_in_gripper[:, 0]
        heights += poses[:, :3, 3] @ plane[:3] + plane[3]
        return heights.min(axis=0) >= clearance


def _check_plane(table_plane: np.ndarray | None) -> np.ndarray | None:
    if table_plane is None:
        return None
    plane = np.asarray(table_plane, dtype=np.float64).reshape(-1)
    if plane.shape != (4,) or not np.isfinite(plane).all():
        raise ValueError(f"table_plane must be 4 finite numbers (a, b, c, d), got {table_plane!r}")
    norm = float(np.linalg.norm(plane[:3]))
    if norm < 1e-12:
        raise ValueError("table_plane normal (a, b, c) must not be zero")
    return plane / norm


def opposite_contacts(
    mesh: trimesh.Trimesh, points: np.ndarray, normals: np.ndarray, face_normals: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """First hit of a ray from each point along its inward normal: (p, q, n_p, n_q) for the rays that hit. The rays
    are cast `RAY_CHUNK` at a time: trimesh tests each ray against every triangle its bounding box meets, and all
    rays at once over a perceived mesh of a packed scene took more than 5 GB."""
    origins = points - RAY_EPSILON * normals
    rays, hits, triangles = [np.zeros(0, dtype=np.int64)], [np.zeros((0, 3))], [np.zeros(0, dtype=np.int64)]
    for start in range(0, len(origins), RAY_CHUNK):
        locations, ray_index, tri_index = mesh.ray.intersects_location(
            origins[start : start + RAY_CHUNK], -normals[start : start + RAY_CHUNK], multiple_hits=False)
        rays.append(np.asarray(ray_index, dtype=np.int64) + start)
        hits.append(np.asarray(locations).reshape(-1, 3))
        triangles.append(np.asarray(tri_index, dtype=np.int64))
    ray_index, locations, tri_index = np.concatenate(rays), np.concatenate(hits), np.concatenate(triangles)
    order = np.argsort(ray_index, kind="stable")  # the intersector's output order is not guaranteed
    ray_index, locations, tri_index = ray_index[order], locations[order], tri_index[order]
    return points[ray_index], locations, normals[ray_index], face_normals[tri_index]


def _collision_cloud(
    mesh: trimesh.Trimesh, normals_sign: float, cfg: AntipodalConfig, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Surface points dense enough that a finger cannot sit inside the object without containing some, and their
    outward face normals."""
    count = int(np.clip(mesh.area / cfg.collision_point_spacing**2, cfg.min_collision_points, cfg.max_collision_points))
    points, faces = trimesh.sample.sample_surface(mesh, count, seed=seed)
    return points, normals_sign * np.asarray(mesh.face_normals)[faces]


def _surface_samples(
    mesh: trimesh.Trimesh, cfg: AntipodalConfig, com: np.ndarray, rng: np.random.Generator,
    draw: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted surface points, `n_surface_samples` of them (`part_draw_samples` times as many with face
    weights `draw`: each face's area times its weight); `near_com_fraction` of them drawn with the face weights also
    falling off with the distance from the centre of mass (scale `near_com_scale`), where the grasps that hold lie
    (all of them area-weighted when no drawn face lies near it)."""
    area = mesh.area_faces if draw is None else mesh.area_faces * draw
    count = cfg.n_surface_samples * (1 if draw is None else cfg.part_draw_samples)
    distance = np.linalg.norm(mesh.triangles_center - com, axis=1)
    weight = area * np.exp(-((distance / cfg.near_com_scale) ** 2))
    n_near = int(round(cfg.near_com_fraction * count)) if weight.sum() > 0 else 0
    points, faces = trimesh.sample.sample_surface(mesh, count - n_near, face_weight=area,
                                                  seed=int(rng.integers(2**31)))
    if n_near == 0:
        return points, faces
    near, near_faces = trimesh.sample.sample_surface(mesh, n_near, face_weight=weight, seed=int(rng.integers(2**31)))
    return np.concatenate([points, near]), np.concatenate([faces, near_faces])


def gravity_torque(poses: np.ndarray, com: np.ndarray, up: np.ndarray, mass: float) -> np.ndarray:
    """|torque| (N m) of the weight at `com` about each grasp's closing axis (x) through its origin, with `up`
    the direction away from the table (all in the poses' frame)."""
    lever = np.asarray(com, dtype=np.float64)[None] - poses[:, :3, 3]
    return np.abs(np.einsum("ij,ij->i", np.cross(lever, -9.81 * mass * up[None]), poses[:, :3, 0]))


def part_draw_weights(mesh: trimesh.Trimesh, faces: np.ndarray, distance: float) -> np.ndarray:
    """Per face, the weight a part's first contacts are drawn with (times area): 1 on the faces `faces` (boolean
    mask), and on the ring of other faces with a vertex within `distance` (m) of theirs as much as keeps the ring's
    share of the draw at most the part's (a small knob on a wide lid is not drowned by the lid), else 0."""
    marked = np.unique(mesh.faces[faces])
    near = cKDTree(mesh.vertices[marked]).query(mesh.vertices, distance_upper_bound=distance)[0] <= distance
    ring = near[mesh.faces].any(axis=1) & ~faces
    ring_area = float(mesh.area_faces[ring].sum())
    weights = faces.astype(np.float64)
    if ring_area > 0:
        weights[ring] = min(1.0, float(mesh.area_faces[faces].sum()) / ring_area)
    return weights


def mesh_center_of_mass(mesh: trimesh.Trimesh) -> np.ndarray:
    """Uniform-density centre of mass for a closed mesh; area-weighted surface centroid otherwise."""
    if mesh.is_watertight and abs(mesh.volume) > 1e-12:
        return np.asarray(mesh.center_mass, dtype=np.float64)
    return np.asarray(mesh.triangles_center.T @ mesh.area_faces / mesh.area, dtype=np.float64)
