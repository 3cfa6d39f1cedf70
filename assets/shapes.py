"""Solid primitives for the object generator: lofts, swept tubes and solids of revolution as manifold3d solids.

Every function returns a closed, consistently oriented `manifold3d.Manifold` in metres. Parts of an object are
built from these and joined with exact boolean unions (see `assets.generate`), so the object is one closed
surface and every output triangle knows which part it came from.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import manifold3d as mf
import numpy as np

#: A builder's parts in prompt order, and its result: the parts plus keep-open probe points (see `assets.catalog`).
Parts = list[tuple[str, mf.Manifold]]
Built = tuple[Parts, list[tuple[float, float, float]]]


def _check(solid: mf.Manifold, what: str) -> mf.Manifold:
    if solid.status() != mf.Error.NoError or solid.is_empty():
        raise ValueError(f"{what}: manifold3d could not build a valid solid (status {solid.status()})")
    return solid


def solid_from_arrays(vertices: np.ndarray, faces: np.ndarray, what: str = "mesh") -> mf.Manifold:
    """A Manifold from vertex and triangle arrays, flipping the winding if the enclosed volume comes out negative."""
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    tri = vertices[faces]
    signed_volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6.0
    if signed_volume < 0:
        faces = np.ascontiguousarray(faces[:, ::-1])
    return _check(mf.Manifold(mf.Mesh64(vertices, faces.astype(np.uint64))), what)


def loft(sections: np.ndarray, what: str = "loft") -> mf.Manifold:
    """Solid through a stack of closed rings `sections` (N, K, 3), capped at both ends by a fan to the ring centre.

    Consecutive rings must not cross each other and every ring must be star-shaped around its centroid.
    """
    sections = np.asarray(sections, dtype=np.float64)
    n_rings, k, _ = sections.shape
    if n_rings < 2 or k < 3:
        raise ValueError(f"{what}: need at least 2 rings of 3 points, got {sections.shape}")
    vertices = np.concatenate([sections.reshape(-1, 3), sections[0].mean(axis=0)[None], sections[-1].mean(axis=0)[None]])
    start_centre, end_centre = n_rings * k, n_rings * k + 1
    ring = np.arange(k)
    nxt = (ring + 1) % k
    faces = []
    for i in range(n_rings - 1):
        a, b = i * k + ring, (i + 1) * k + ring
        an, bn = i * k + nxt, (i + 1) * k + nxt
        faces.append(np.stack([a, an, bn], axis=1))
        faces.append(np.stack([a, bn, b], axis=1))
    faces.append(np.stack([np.full(k, start_centre), nxt, ring], axis=1))
    last = (n_rings - 1) * k
    faces.append(np.stack([np.full(k, end_centre), last + ring, last + nxt], axis=1))
    return solid_from_arrays(vertices, np.concatenate(faces), what)


def ellipse(half_a: float, half_b: float, n: int = 24) -> np.ndarray:
    """(n, 2) points of an ellipse with semi-axes `half_a` (first coordinate) and `half_b`, counter-clockwise."""
    angle = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    return np.stack([half_a * np.cos(angle), half_b * np.sin(angle)], axis=1)


def superellipse(half_a: float, half_b: float, exponent: float = 4.0, n: int = 32) -> np.ndarray:
    """(n, 2) points of a rounded rectangle |x/a|^p + |y/b|^p = 1 (p = 2 is an ellipse, large p a box)."""
    angle = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    c, s = np.cos(angle), np.sin(angle)
    power = 2.0 / exponent
    return np.stack([half_a * np.sign(c) * np.abs(c) ** power, half_b * np.sign(s) * np.abs(s) ** power], axis=1)


def lobed_circle(radius: float, lobes: int, depth: float, n: int = 48) -> np.ndarray:
    """(n, 2) points of a fluted grip section: r(θ) = radius (1 - depth (1 - cos(lobes θ)) / 2)."""
    angle = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
    r = radius * (1.0 - depth * 0.5 * (1.0 - np.cos(lobes * angle)))
    return np.stack([r * np.cos(angle), r * np.sin(angle)], axis=1)


def loft_along_x(
    stations: Sequence[float],
    section: Callable[[float], np.ndarray],
    centre: Callable[[float], tuple[float, float]] = lambda x: (0.0, 0.0),
    what: str = "loft",
) -> mf.Manifold:
    """Loft of 2-D sections in the (y, z) plane placed at each x of `stations`, offset by `centre(x)` = (y, z)."""
    rings = []
    for x in stations:
        yz = np.asarray(section(x), dtype=np.float64)
        cy, cz = centre(x)
        rings.append(np.column_stack([np.full(len(yz), x), yz[:, 0] + cy, yz[:, 1] + cz]))
    return loft(np.stack(rings), what)


def sweep(
    path: np.ndarray,
    section: Callable[[float], np.ndarray],
    normal_hint: Sequence[float] = (0.0, 0.0, 1.0),
    what: str = "sweep",
) -> mf.Manifold:
    """Tube along a 3-D polyline `path` (N, 3); `section(t)` gives the (K, 2) ring at arc-length fraction t.

    Ring coordinates are (u, v): u along a rotation-minimising normal started from `normal_hint`, v = tangent x u.
    """
    path = np.asarray(path, dtype=np.float64)
    seg = np.diff(path, axis=0)
    length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(seg, axis=1))])
    tangents = np.gradient(path, length, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    normal = np.asarray(normal_hint, dtype=np.float64)
    rings = []
    for i, (point, tangent) in enumerate(zip(path, tangents)):
        normal = normal - tangent * float(normal @ tangent)  # parallel transport by projection
        normal /= np.linalg.norm(normal)
        binormal = np.cross(tangent, normal)
        uv = np.asarray(section(length[i] / length[-1]), dtype=np.float64)
        rings.append(point + uv[:, :1] * normal + uv[:, 1:2] * binormal)
    return loft(np.stack(rings), what)


def revolve(profile: Sequence[tuple[float, float]], segments: int, what: str = "revolve") -> mf.Manifold:
    """Solid of revolution about z of a closed (radius, z) polygon; radius >= 0."""
    contour = np.asarray(profile, dtype=np.float64)
    x, y = contour[:, 0], contour[:, 1]
    if 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)) < 0:
        contour = contour[::-1]
    return _check(mf.Manifold.revolve(mf.CrossSection([contour]), circular_segments=segments), what)


def extrude(polygon: np.ndarray, height: float, what: str = "extrude") -> mf.Manifold:
    """Prism of a simple 2-D polygon (x, y) extruded from z = 0 to z = height."""
    contour = np.asarray(polygon, dtype=np.float64)
    x, y = contour[:, 0], contour[:, 1]
    if 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)) < 0:
        contour = contour[::-1]
    return _check(mf.Manifold.extrude(mf.CrossSection([contour]), height), what)


def box(size: Sequence[float], centre: Sequence[float] = (0.0, 0.0, 0.0)) -> mf.Manifold:
    """Axis-aligned box of the given size centred at `centre`."""
    return mf.Manifold.cube(tuple(float(s) for s in size), center=True).translate(tuple(float(c) for c in centre))


def cylinder(
    radius: float, length: float, axis: str = "z", centre: Sequence[float] = (0.0, 0.0, 0.0), segments: int = 32,
    radius_end: float | None = None,
) -> mf.Manifold:
    """Cylinder (or cone frustum to `radius_end`) of `length` along axis x, y or z, centred at `centre`."""
    solid = mf.Manifold.cylinder(
        float(length), float(radius), float(radius if radius_end is None else radius_end), segments, center=True
    )
    if axis == "x":
        solid = solid.rotate((0.0, 90.0, 0.0))
    elif axis == "y":
        solid = solid.rotate((-90.0, 0.0, 0.0))
    elif axis != "z":
        raise ValueError(f"axis must be 'x', 'y' or 'z', got {axis!r}")
    return solid.translate(tuple(float(c) for c in centre))


def rounded_polyline(points: Sequence[Sequence[float]], radii: Sequence[float], step: float) -> np.ndarray:
    """Polyline through `points` (M, 3) with each interior corner replaced by a circular arc of the given radius,
    resampled at about `step` metres."""
    points = np.asarray(points, dtype=np.float64)
    out = [points[0]]
    for i in range(1, len(points) - 1):
        prev, corner, nxt = points[i - 1], points[i], points[i + 1]
        d_in = (corner - prev) / np.linalg.norm(corner - prev)
        d_out = (nxt - corner) / np.linalg.norm(nxt - corner)
        turn = np.arccos(np.clip(d_in @ d_out, -1.0, 1.0))
        radius = radii[i - 1]
        if turn < 1e-6 or radius <= 0:
            out.append(corner)
            continue
        cut = radius * np.tan(turn / 2.0)
        start, end = corner - d_in * cut, corner + d_out * cut
        bisector = (d_out - d_in) / np.linalg.norm(d_out - d_in)
        centre = corner + bisector * radius / np.cos(turn / 2.0)
        a, b = start - centre, end - centre
        n_arc = max(3, int(np.ceil(radius * turn / step)))
        for t in np.linspace(0.0, 1.0, n_arc + 1):
            # slerp between the two radius vectors
            w0 = np.sin((1 - t) * turn) / np.sin(turn)
            w1 = np.sin(t * turn) / np.sin(turn)
            out.append(centre + w0 * a + w1 * b)
    out.append(points[-1])
    return resample(np.asarray(out), step)


def resample(path: np.ndarray, step: float) -> np.ndarray:
    """Polyline resampled at (about) uniform arc-length spacing `step`, keeping both ends."""
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    path = path[keep]
    length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))])
    n = max(2, int(np.ceil(length[-1] / step)) + 1)
    s = np.linspace(0.0, length[-1], n)
    return np.stack([np.interp(s, length, path[:, d]) for d in range(3)], axis=1)
