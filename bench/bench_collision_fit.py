"""How closely each twin object's collision model (its CoACD hulls, the surface the pads stop on) follows its mesh
(the surface the method plans on and the judge reads the touched part from).

    python bench/bench_collision_fit.py [--objects ID,...] [--samples 1500] [--out docs/results/collision-fit.md]

Each hull's surface is sampled (`--samples` points per hull, seeded); a point counts as outside surface unless it
lies inside or on another hull (within `SHARED_TOLERANCE`: the faces two hulls share are inside the compound). For
each outside point the distance to the mesh (exact closest point) says how far the collision surface stands off
the real one there: a pad stops that much early, or on a neighbouring part's hull.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.bench_lab import command_line, commit, publish  # noqa: E402
from seggrasp.object_physics import obj_group_names  # noqa: E402
from seggrasp.objects import asset_ids, load_asset  # noqa: E402

#: A sample this close (m) inside or onto another hull's faces lies on a face the two hulls share.
SHARED_TOLERANCE = 2e-4
PERCENTILES = (50, 90, 99)


@dataclass(frozen=True)
class Fit:
    """One object's collision fit: distances (m) from its hulls' outside surface samples to its mesh, and the part
    of the hull that stands farthest off."""

    object_id: str
    hulls: int
    distances: np.ndarray
    worst_part: str


def outside_samples(hulls: list[trimesh.Trimesh], per_hull: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points on the compound's outside surface (module doc) and the index of the hull each lies on."""
    convex = [trimesh.convex.convex_hull(h.vertices) for h in hulls]
    points, owner = [], []
    for k, hull in enumerate(convex):
        sample, _ = trimesh.sample.sample_surface(hull, per_hull, seed=seed + k)
        points.append(sample)
        owner.append(np.full(len(sample), k))
    points, owner = np.concatenate(points), np.concatenate(owner)
    covered = np.zeros(len(points), dtype=bool)
    for k, hull in enumerate(convex):
        offsets = np.einsum("ij,ij->i", hull.face_normals, hull.triangles[:, 0])
        covered |= ((points @ hull.face_normals.T - offsets) < SHARED_TOLERANCE).all(axis=1) & (owner != k)
    return points[~covered], owner[~covered]


def collision_fit(object_id: str, mesh: trimesh.Trimesh, hulls: list[trimesh.Trimesh], groups: list[str],
                  per_hull: int) -> Fit:
    """The fit of one object's `hulls` (their OBJ group names `groups`, "<part>_<k>") to its `mesh` (module doc)."""
    points, owner = outside_samples(hulls, per_hull)
    _, distances, _ = trimesh.proximity.closest_point(mesh, points)
    worst = groups[int(owner[np.argmax(distances)])]
    return Fit(object_id, len(hulls), np.asarray(distances), worst.rsplit("_", 1)[0])


def twin_fit(object_id: str, per_hull: int) -> Fit:
    """The fit of one twin object's committed collision model."""
    model = load_asset(object_id)
    return collision_fit(object_id, model.mesh, model.collision_hulls, obj_group_names(model.collision_path),
                         per_hull)


def report(fits: list[Fit], command: str, seconds: float) -> str:
    """The markdown page of the fits."""
    lines = [
        "# Collision models against meshes", "", f"`{command}`", "",
        f"Written {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())} at commit {commit()}; {seconds:.0f} s.", "",
        "How far the outside surface of each twin object's collision hulls (what the pads stop on) stands from its "
        "mesh (what grasps are planned on and the touched part is read from), over samples of the hulls' outside "
        "surface (bench/bench_collision_fit.py's docstring).", "",
        "| object | hulls | " + " | ".join(f"p{p} (mm)" for p in PERCENTILES) + " | max (mm) | part at the max |",
        "|---|---|" + "---|" * len(PERCENTILES) + "---|---|",
    ]
    for fit in fits:
        cells = " | ".join(f"{1000 * np.percentile(fit.distances, p):.2f}" for p in PERCENTILES)
        lines.append(f"| {fit.object_id} | {fit.hulls} | {cells} | {1000 * fit.distances.max():.2f} | {fit.worst_part} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--objects", help="comma-separated twin object ids (default: all)")
    parser.add_argument("--samples", type=int, default=1500, help="surface samples per hull")
    parser.add_argument("--out", type=Path, help="write the table here as markdown")
    args = parser.parse_args(argv)
    ids = args.objects.split(",") if args.objects else asset_ids()
    known = set(asset_ids())
    unknown = [i for i in ids if i not in known]
    if unknown:
        print(f"error: no twin object {', '.join(unknown)} (python -m assets list names them)", file=sys.stderr)
        return 2
    if args.samples < 1:
        print(f"error: --samples must be at least 1, got {args.samples}", file=sys.stderr)
        return 2
    start = time.time()
    fits = []
    for object_id in ids:
        fits.append(twin_fit(object_id, args.samples))
        print(f"{object_id}: {fits[-1].hulls} hulls, max {1000 * fits[-1].distances.max():.2f} mm", flush=True)
    publish(report(fits, command_line("bench_collision_fit.py", argv), time.time() - start), args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
