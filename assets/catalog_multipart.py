"""Twin categories with three or more parts and thin parts: pliers (pivot), kettle (spout, neck, handle) and eyeglass
frames (bridge, temples), the shapes on which one-part-per-prompt anchoring fails most.

Same builder contract as `assets.catalog` (a parameter dict in metres -> parts in prompt order plus "keep open"
probe points), kept in a file of its own until the lead wires it into the catalog: `MULTIPART_BUILDERS`,
`MULTIPART_PARTS` and `MULTIPART_SPECS` go into `BUILDERS`, `CATEGORY_PARTS` and `OBJECT_SPECS`.
`multipart_meshes()` builds the labelled meshes through `assets.generate.build_mesh` without that wiring (for the
segmentation benchmark: `python bench/bench_seg.py --meshes multipart --quality`).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

import manifold3d as mf
import numpy as np

from assets.catalog import BUILDERS, CATEGORY_PARTS, Built, ObjectSpec
from assets.shapes import cylinder, ellipse, extrude, revolve, rounded_polyline, superellipse, sweep


def _flat(polygon: np.ndarray, thickness: float, z0: float) -> mf.Manifold:
    """A plate of `polygon` (x, y) from z0 to z0 + thickness."""
    return extrude(np.asarray(polygon), thickness).translate((0.0, 0.0, z0))


# -------------------------------------------------------------------------------------------------------- pliers
def build_pliers(p: dict) -> Built:
    """Pliers lying flat, slightly open: two tapered jaws (+x), a pivot rivet at the origin, two grips (-x)."""
    t, half_open = p["thickness"], np.radians(p["open_angle"]) / 2
    jaws = []
    for side in (-1.0, 1.0):
        direction = np.array([np.cos(half_open), side * np.sin(half_open)])
        normal = np.array([-direction[1], direction[0]])
        root, tip = p["jaw_root_width"] / 2, p["jaw_tip_width"] / 2
        start = -0.4 * p["pivot_radius"] * direction
        end = p["jaw_length"] * direction
        polygon = [start - root * normal, end - tip * normal, end + tip * normal, start + root * normal]
        jaws.append(_flat(polygon, t, side * 0.25 * t - 0.5 * t))
    jaw = mf.Manifold.batch_boolean(jaws, mf.OpType.Add)
    pivot = cylinder(p["pivot_radius"], 1.6 * t, "z", (0.0, 0.0, 0.0), segments=32)
    grips = []
    for side in (-1.0, 1.0):
        spread = np.radians(p["grip_spread"]) / 2
        bend = p["grip_length"] * 0.45
        path = rounded_polyline(
            [(0.3 * p["pivot_radius"], 0.0, side * 0.25 * t),
             (-bend, side * bend * np.tan(half_open + 0.3 * spread), side * 0.25 * t),
             (-p["grip_length"], side * p["grip_length"] * np.tan(spread), side * 0.25 * t)],
            [0.03], step=0.004)

        def section(s: float, side: float = side) -> np.ndarray:
            swell = 1.0 + p["grip_swell"] * np.sin(np.pi * min(1.0, 1.3 * s))
            return ellipse(p["grip_width"] / 2 * swell, p["grip_thickness"] / 2, 20)

        grips.append(sweep(path, section, normal_hint=(0.0, 0.0, 1.0), what="pliers grip"))
    handles = mf.Manifold.batch_boolean(grips, mf.OpType.Add)
    keep = [(-0.8 * p["grip_length"], 0.0, 0.0)]
    return [("handles", handles), ("pivot", pivot), ("jaws", jaw)], keep


# -------------------------------------------------------------------------------------------------------- kettle
def build_kettle(p: dict) -> Built:
    """Kettle on its base: revolved body, a narrower neck collar on top, a tapered spout and a side handle."""
    r, h = p["radius"], p["height"]
    shoulder = p["shoulder"] * h
    r_neck = p["neck_radius"]
    body_profile = [(0.0, 0.0), (r * 0.92, 0.0), (r, 0.06 * h), (r, shoulder)]
    body_profile += [(r_neck + (r - r_neck) * np.cos(a), shoulder + (h - shoulder) * np.sin(a))
                     for a in np.linspace(0.15, np.pi / 2, 8)]
    body_profile += [(0.0, h)]
    body = revolve(body_profile, int(p["segments"]), "kettle body")
    neck_top = h + p["neck_height"]
    neck = revolve([(0.0, h - 0.004), (r_neck, h - 0.004), (r_neck * 1.05, neck_top - 0.003),
                    (r_neck * 1.05 - 0.003, neck_top), (0.0, neck_top)], int(p["segments"]), "kettle neck")
    z0 = p["spout_base"] * h
    spout_path = rounded_polyline(
        [(r - 0.012, 0.0, z0), (r + 0.35 * p["spout_length"], 0.0, z0 + 0.25 * p["spout_length"]),
         (r + p["spout_length"], 0.0, z0 + p["spout_rise"] * p["spout_length"])], [0.03], step=0.004)
    spout = sweep(spout_path, lambda s: ellipse(*(np.array([p["spout_root"], p["spout_root"]]) * (1 - 0.55 * s)), 20),
                  normal_hint=(0.0, 1.0, 0.0), what="kettle spout")
    z_top, z_bottom = p["handle_top"] * h, p["handle_bottom"] * h
    x_out = -(r + p["handle_reach"])
    handle_path = rounded_polyline(
        [(-(r - 0.006), 0.0, z_top), (x_out, 0.0, z_top + 0.01), (x_out, 0.0, z_bottom), (-(r - 0.006), 0.0, z_bottom)],
        [0.025, 0.025], step=0.004)
    handle = sweep(handle_path, lambda s: ellipse(p["handle_width"] / 2, p["handle_thickness"] / 2, 20),
                   normal_hint=(0.0, 1.0, 0.0), what="kettle handle")
    keep = [(x_out + 0.5 * p["handle_reach"], 0.0, 0.5 * (z_top + z_bottom))]
    return [("handle", handle), ("spout", spout), ("neck", neck), ("body", body)], keep


# ---------------------------------------------------------------------------------------------------- eyeglasses
def build_eyeglasses(p: dict) -> Built:
    """Eyeglass frame lying flat, temples unfolded: two rims (flat rings), a thin arched bridge, two thin temples."""
    t = p["thickness"]
    a, b, w = p["rim_width"] / 2, p["rim_height"] / 2, p["rim_wire"]
    cx = p["bridge_gap"] / 2 + a
    rims = []
    for side in (-1.0, 1.0):
        outer = superellipse(a, b, p["rim_squareness"], 48) + [side * cx, 0.0]
        inner = superellipse(a - w, b - w, p["rim_squareness"], 48) + [side * cx, 0.0]
        rims.append(_flat(outer, t, 0.0) - _flat(inner, 2 * t, -0.5 * t))
    rim = mf.Manifold.batch_boolean(rims, mf.OpType.Add)
    gap = p["bridge_gap"] / 2 + 0.6 * w
    bridge_path = rounded_polyline([(-gap, 0.3 * b, 0.5 * t), (0.0, 0.3 * b + p["bridge_arch"], 0.5 * t),
                                    (gap, 0.3 * b, 0.5 * t)], [0.008], step=0.002)
    bridge = sweep(bridge_path, lambda s: ellipse(p["bridge_wire"] / 2, 0.45 * t, 16), normal_hint=(0.0, 0.0, 1.0),
                   what="eyeglass bridge")
    arms = []
    for side in (-1.0, 1.0):
        x = side * (cx + a - 0.4 * w)
        path = rounded_polyline([(x, 0.4 * b, 0.5 * t), (x + side * 0.004, -p["temple_length"] * 0.8, 0.5 * t),
                                 (x + side * 0.002, -p["temple_length"], 0.5 * t - 0.0)], [0.02], step=0.003)
        arms.append(sweep(path, lambda s: ellipse(p["temple_wire"] / 2, 0.45 * t, 12), normal_hint=(0.0, 0.0, 1.0),
                          what="eyeglass temple"))
    temples = mf.Manifold.batch_boolean(arms, mf.OpType.Add)
    keep = [(cx, 0.0, 0.5 * t), (-cx, 0.0, 0.5 * t)]
    return [("temples", temples), ("rims", rim), ("bridge", bridge)], keep


_PLIERS = dict(thickness=0.009, open_angle=8.0, jaw_length=0.055, jaw_root_width=0.016, jaw_tip_width=0.005,
               pivot_radius=0.008, grip_length=0.13, grip_spread=14.0, grip_width=0.016, grip_thickness=0.012,
               grip_swell=0.25)
_KETTLE = dict(radius=0.08, height=0.15, shoulder=0.55, neck_radius=0.045, neck_height=0.02, spout_base=0.25,
               spout_length=0.1, spout_rise=0.9, spout_root=0.013, handle_top=0.9, handle_bottom=0.3,
               handle_reach=0.04, handle_width=0.022, handle_thickness=0.014, segments=64)
_GLASSES = dict(thickness=0.004, rim_width=0.05, rim_height=0.036, rim_wire=0.004, rim_squareness=3.0,
                bridge_gap=0.018, bridge_arch=0.004, bridge_wire=0.0035, temple_length=0.14, temple_wire=0.003)


def _spec(object_id: str, category: str, base: dict, materials: tuple[str, ...], **changes: float) -> ObjectSpec:
    unknown = set(changes) - set(base)
    if unknown:
        raise ValueError(f"{object_id}: unknown parameters {sorted(unknown)}")
    return ObjectSpec(object_id, category, {**base, **changes}, materials)


MULTIPART_BUILDERS: dict[str, Callable[[dict], Built]] = {
    "pliers": build_pliers, "kettle": build_kettle, "eyeglasses": build_eyeglasses,
}
MULTIPART_PARTS: dict[str, tuple[str, ...]] = {
    "pliers": ("handles", "pivot", "jaws"),
    "kettle": ("handle", "spout", "neck", "body"),
    "eyeglasses": ("temples", "rims", "bridge"),
}
MULTIPART_SPECS: tuple[ObjectSpec, ...] = (
    _spec("pliers_combination", "pliers", _PLIERS, ("rubber_grip", "steel", "steel")),
    _spec("pliers_long_nose", "pliers", _PLIERS, ("plastic", "steel", "steel"), jaw_length=0.075,
          jaw_root_width=0.012, jaw_tip_width=0.0025, grip_length=0.12, pivot_radius=0.007),
    _spec("kettle_classic", "kettle", _KETTLE, ("bakelite", "steel", "steel", "steel")),
    _spec("kettle_tall", "kettle", _KETTLE, ("bakelite", "steel", "steel", "steel"), radius=0.065, height=0.2,
          neck_radius=0.035, spout_length=0.12, spout_root=0.011, handle_reach=0.035),
    _spec("eyeglasses_round", "eyeglasses", _GLASSES, ("plastic", "plastic", "steel"), rim_squareness=2.0,
          rim_width=0.046, rim_height=0.042),
    _spec("eyeglasses_wide", "eyeglasses", _GLASSES, ("plastic", "plastic", "steel"), rim_width=0.056,
          rim_height=0.032, rim_squareness=4.0, temple_length=0.145),
)


@contextlib.contextmanager
def registered() -> Iterator[None]:
    """`assets.catalog`'s builder and part tables with the categories here, for the duration of the block.

    The twin has its own kettle and eyeglasses (`assets.multipart`, other designs and part names); inside the
    block these categories' builders stand in for them, and the twin's entries come back afterwards.
    """
    saved = {c: (BUILDERS[c], CATEGORY_PARTS[c]) for c in MULTIPART_BUILDERS if c in BUILDERS}
    BUILDERS.update(MULTIPART_BUILDERS)
    CATEGORY_PARTS.update(MULTIPART_PARTS)
    try:
        yield
    finally:
        for category in MULTIPART_BUILDERS:
            if category in saved:
                BUILDERS[category], CATEGORY_PARTS[category] = saved[category]
            else:
                del BUILDERS[category], CATEGORY_PARTS[category]


def multipart_meshes(seed: int = 0) -> list:
    """The labelled meshes (`assets.generate.GeneratedMesh`) of every spec here."""
    from assets.generate import build_mesh

    with registered():
        return [build_mesh(spec, seed) for spec in MULTIPART_SPECS]
