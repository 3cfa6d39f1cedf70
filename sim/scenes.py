"""Multi-object table scenes for the twin: the target among distractors, packed side by side or piled.

`plan_scene` draws a seeded `ScenePlan`: the target and its distractors with a drop pose each, either `packed`
(upright, side by side with a small gap between their footprints) or a `pile` (random orientations, dropped from
staggered heights onto each other). `place_scene` loads a plan into a `World` and lets it settle; `penetrations`
measures how deep the settled bodies overlap.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from seggrasp.objects import ObjectModel
from sim.world import TABLE_TOP_Z, WORKSPACE_CENTER, WORKSPACE_HALF_SIZE, WORKSPACE_JITTER, World

KINDS = ("packed", "pile")
N_OBJECTS = (2, 6)
#: Packed scenes: each object is placed this far (m, drawn uniformly) from a neighbour's footprint and at least the
#: lower bound from every other one.
PACK_GAP = (0.005, 0.03)
#: Packed footprints stay within this half side (m) of a square around WORKSPACE_CENTER (SimCell's perception box).
PACK_HALF_SIZE = WORKSPACE_HALF_SIZE
#: Placements tried per object before a packed plan gives up.
PACK_ATTEMPTS = 200
#: Piles: vertical gap (m) between consecutive objects' extents at the drop.
PILE_GAP = 0.01
#: Lowest point of a dropped object above the table (m), as in SimCell's single-object scenes.
DROP_CLEARANCE = 0.001
#: A body rests once it moves slower than this (m/s, rad/s) for `QUIET_TIME` seconds, as in SimCell.
QUIET_SPEED = (0.005, 0.05)
QUIET_TIME = 0.1
#: Linear and angular damping while a scene settles, so that a bottle on its side stops rolling before it leaves
#: the table: with PyBullet's default damping 27 of 40 six-object piles (8 targets x 5 seeds over the twin) lost an
#: object off the table, with this none. Afterwards the bodies get PyBullet's default back (the World keeps it).
SETTLE_DAMPING = (0.5, 0.99)
PYBULLET_DAMPING = 0.04


@dataclass(frozen=True)
class ScenePlan:
    """A seeded scene: `object_ids` (target first) and their drop poses `T_world_obj` as nested tuples (rows)."""

    kind: str
    seed: int
    target_id: str
    object_ids: tuple[str, ...]
    poses: tuple[tuple[tuple[float, ...], ...], ...]

    def pose(self, index: int) -> np.ndarray:
        """The 4x4 drop pose of object `index`."""
        return np.array(self.poses[index], dtype=float)

    def to_record(self) -> dict:
        """A JSON-able dict (`from_record` restores the plan exactly)."""
        return {
            "kind": self.kind, "seed": self.seed, "target_id": self.target_id,
            "object_ids": list(self.object_ids), "poses": [[list(row) for row in T] for T in self.poses],
        }

    @classmethod
    def from_record(cls, record: Mapping) -> ScenePlan:
        return cls(
            kind=str(record["kind"]), seed=int(record["seed"]), target_id=str(record["target_id"]),
            object_ids=tuple(record["object_ids"]),
            poses=tuple(_rows(np.array(T, dtype=float)) for T in record["poses"]),
        )


def plan_scene(objects: Sequence[ObjectModel], *, target_id: str, n_objects: int, kind: str, seed: int) -> ScenePlan:
    """A seeded plan of `n_objects` objects: the target and distractors drawn without replacement, other categories
    than the target's first and as many different ones as there are."""
    if kind not in KINDS:
        raise ValueError(f"unknown scene kind {kind!r}; use one of {KINDS}")
    if not N_OBJECTS[0] <= n_objects <= N_OBJECTS[1]:
        raise ValueError(f"n_objects must be between {N_OBJECTS[0]} and {N_OBJECTS[1]}, got {n_objects}")
    by_id = {o.object_id: o for o in objects}
    if target_id not in by_id:
        raise ValueError(f"target_id {target_id!r} is not among the objects")
    if n_objects > len(by_id):
        raise ValueError(f"a scene of {n_objects} objects needs as many distinct objects, got {len(by_id)}")
    rng = np.random.default_rng(seed)
    target = by_id[target_id]
    others = [by_id[i] for i in rng.permutation(sorted(set(by_id) - {target_id}))]
    counts: dict[str, int] = {}
    rank = []  # how many of the object's category come before it: one of each category first
    for other in others:
        rank.append(counts.get(other.category, 0))
        counts[other.category] = rank[-1] + 1
    order = sorted(range(len(others)), key=lambda i: (others[i].category == target.category, rank[i]))
    models = [target] + [others[i] for i in order[: n_objects - 1]]
    poses = _packed_poses(models, rng) if kind == "packed" else _pile_poses(models, rng)
    return ScenePlan(kind, int(seed), target_id, tuple(m.object_id for m in models), tuple(_rows(T) for T in poses))


def place_scene(
    world: World, objects_by_id: Mapping[str, ObjectModel], plan: ScenePlan, *, settle_time: float,
    parked: int | None = None,
) -> list[int]:
    """Load the plan's objects at their drop poses and step until all rest or `settle_time` (s) runs out; the bodies,
    target first. The target is loaded last so that its solver settings (`World.load_object`) are the ones in force.

    The links of the `parked` body (the robot at home) that reach over the workspace (`overhanging_links`) are out
    of the objects' way while they settle, as a lab lays a scene out with the arm parked: a dropped hammer would
    otherwise come to rest leaning on the gripper (in 1 of 36 four-object UR5 piles, 3 of 36 with the floating
    gripper) and fall when it moves. The rest of the robot stays solid: a bottle that rolls off the pile stops
    against the arm's base. ValueError when a settled object still reaches into an overhanging link."""
    missing = [i for i in plan.object_ids if i not in objects_by_id]
    if missing:
        raise ValueError(f"the plan's objects {missing} are not in objects_by_id")
    order = list(range(1, len(plan.object_ids))) + [0]
    loaded = {i: world.load_object(objects_by_id[plan.object_ids[i]], plan.pose(i)) for i in order}
    bodies = [loaded[i] for i in range(len(plan.object_ids))]
    for body in bodies:
        world.client.changeDynamics(body, -1, linearDamping=SETTLE_DAMPING[0], angularDamping=SETTLE_DAMPING[1])
    overhanging = overhanging_links(world, parked) if parked is not None else []
    _collide(world, bodies, parked, overhanging, False)
    dt = world.physics.time_step
    quiet, needed = 0, round(QUIET_TIME / dt)
    for _ in range(round(settle_time / dt)):
        world.step()
        velocities = [world.client.getBaseVelocity(b) for b in bodies]
        still = all(np.linalg.norm(v) < QUIET_SPEED[0] and np.linalg.norm(w) < QUIET_SPEED[1] for v, w in velocities)
        quiet = quiet + 1 if still else 0
        if quiet >= needed:
            break
    for body in bodies:
        world.client.changeDynamics(body, -1, linearDamping=PYBULLET_DAMPING, angularDamping=PYBULLET_DAMPING)
    _collide(world, bodies, parked, overhanging, True)
    for index, body in enumerate(bodies):
        if any(world.client.getClosestPoints(body, parked, 0.0, -1, link) for link in overhanging):
            raise ValueError(f"the settled {plan.kind} scene of seed {plan.seed} (target {plan.target_id}) reaches "
                             f"into the parked robot: {plan.object_ids[index]} touches its gripper or wrist")
    return bodies


def overhanging_links(world: World, body: int) -> list[int]:
    """The links of `body` (-1 its base) whose bounding box reaches over the workspace square (`PACK_HALF_SIZE`
    around `WORKSPACE_CENTER`): for a robot at home, its wrist and gripper."""
    low, high = WORKSPACE_CENTER - PACK_HALF_SIZE, WORKSPACE_CENTER + PACK_HALF_SIZE
    links = []
    for link in range(-1, world.client.getNumJoints(body)):
        lower, upper = (np.asarray(corner)[:2] for corner in world.client.getAABB(body, link))
        if np.all(lower <= high) and np.all(upper >= low):
            links.append(link)
    return links


def _collide(world: World, bodies: Sequence[int], parked: int | None, links: Sequence[int], enable: bool) -> None:
    """Switch collisions between every object body and the `links` of the `parked` body on or off."""
    for link in links:
        for body in bodies:
            world.client.setCollisionFilterPair(body, parked, -1, link, int(enable))


def penetrations(world: World, bodies: Sequence[int]) -> float:
    """The deepest penetration (m) between any two of `bodies`, 0 when none touch."""
    deepest = 0.0
    for k, a in enumerate(bodies):
        for b in bodies[k + 1:]:
            for point in world.client.getClosestPoints(a, b, distance=0.0):
                deepest = max(deepest, -float(point[8]))
    return deepest


# --- planning -------------------------------------------------------------------------------------------------


def _rows(T: np.ndarray) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(float(v) for v in row) for row in T)


def _points(model: ObjectModel) -> np.ndarray:
    """The object's mesh and collision-hull vertices (object frame)."""
    return np.vstack([model.mesh.vertices] + [h.vertices for h in model.collision_hulls])


def _pose(R: np.ndarray, xy: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Rotation `R` with the points' lowest one `DROP_CLEARANCE` above the table and translation `xy`."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = [xy[0], xy[1], TABLE_TOP_Z + DROP_CLEARANCE - float((points @ R.T)[:, 2].min())]
    return T


def _packed_poses(models: Sequence[ObjectModel], rng: np.random.Generator) -> list[np.ndarray]:
    """Upright objects at random yaws, placed largest footprint first: the first near the workspace centre, each
    next one `PACK_GAP` from a random placed one's footprint (along a random direction) and clear of the others."""
    hulls = [ConvexHull(_points(model)[:, :2]) for model in models]
    outlines = [hull.points[hull.vertices] for hull in hulls]  # counter-clockwise
    placed: list[np.ndarray] = []  # world footprints
    poses: list[np.ndarray] = [np.eye(4)] * len(models)
    for index in sorted(range(len(models)), key=lambda i: -hulls[i].volume):
        for _ in range(PACK_ATTEMPTS):
            yaw = rng.uniform(-np.pi, np.pi)
            R2 = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
            local = outlines[index] @ R2.T
            if not placed:
                shift = WORKSPACE_CENTER + rng.uniform(-WORKSPACE_JITTER, WORKSPACE_JITTER, 2) - local.mean(axis=0)
            else:
                anchor = placed[int(rng.integers(len(placed)))]
                angle = rng.uniform(-np.pi, np.pi)
                shift = _shift_to_gap(anchor, local, np.array([np.cos(angle), np.sin(angle)]), rng.uniform(*PACK_GAP))
            footprint = local + shift
            if np.abs(footprint - WORKSPACE_CENTER).max() <= PACK_HALF_SIZE and all(
                _gap(footprint, other) >= PACK_GAP[0] for other in placed
            ):
                break
        else:
            raise ValueError(
                f"cannot pack {len(models)} objects around the workspace centre: object {models[index].object_id!r} "
                f"found no place in {PACK_ATTEMPTS} attempts"
            )
        placed.append(footprint)
        R = np.eye(3)
        R[:2, :2] = R2
        poses[index] = _pose(R, shift, _points(models[index]))
    return poses


def _shift_to_gap(anchor: np.ndarray, local: np.ndarray, direction: np.ndarray, gap: float) -> np.ndarray:
    """The shift of polygon `local` from the anchor's centre along `direction` that leaves `gap` between them
    (bisection: the distance between convex sets grows monotonically once they separate)."""
    origin = anchor.mean(axis=0) - local.mean(axis=0)
    low, high = 0.0, float(np.ptp(anchor, axis=0).sum() + np.ptp(local, axis=0).sum()) + gap
    for _ in range(30):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if _gap(anchor, local + origin + middle * direction) < gap else (low, middle)
    return origin + high * direction


def _gap(a: np.ndarray, b: np.ndarray) -> float:
    """Distance between two convex counter-clockwise polygons, 0 when they overlap."""
    if not (_separated(a, b) or _separated(b, a)):
        return 0.0
    return min(_distance_to_edges(a, b), _distance_to_edges(b, a))


def _separated(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether all of `b` lies outside one edge of `a` (a separating axis)."""
    edges = np.roll(a, -1, axis=0) - a
    outward = np.stack([edges[:, 1], -edges[:, 0]], axis=1)
    return bool((np.einsum("ek,bek->be", outward, b[:, None, :] - a[None]) > 0).all(axis=0).any())


def _distance_to_edges(points: np.ndarray, polygon: np.ndarray) -> float:
    """The smallest distance from `points` to the edges of `polygon`."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    offsets = points[:, None, :] - polygon[None]
    t = np.clip(np.einsum("pek,ek->pe", offsets, edges) / np.einsum("ek,ek->e", edges, edges), 0.0, 1.0)
    return float(np.linalg.norm(offsets - t[..., None] * edges, axis=2).min())


def _pile_poses(models: Sequence[ObjectModel], rng: np.random.Generator) -> list[np.ndarray]:
    """Random orientations above `WORKSPACE_CENTER` +- `WORKSPACE_JITTER`, stacked in a random order with
    `PILE_GAP` between their vertical extents so that they fall onto each other."""
    poses: list[np.ndarray] = [np.eye(4)] * len(models)
    floor = 0.0
    for index in rng.permutation(len(models)):
        points = _points(models[index])
        R = Rotation.random(random_state=rng).as_matrix()
        rotated = points @ R.T
        xy = WORKSPACE_CENTER + rng.uniform(-WORKSPACE_JITTER, WORKSPACE_JITTER, 2) - 0.5 * (
            rotated[:, :2].min(axis=0) + rotated[:, :2].max(axis=0)
        )
        T = _pose(R, xy, points)
        T[2, 3] += floor
        floor += float(np.ptp(rotated[:, 2])) + PILE_GAP
        poses[index] = T
    return poses
